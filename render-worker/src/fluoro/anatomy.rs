//! The static anatomy of one scene on one device (see the module map in `fluoro`): the nesting
//! plan, the drawn triangles' vertex and index buffers, their culling chunks and the pipelines.
//! Nothing here changes after it is built, so every renderer of the same scene on the same device
//! draws from one [`GpuAnatomy`] behind an `Arc`. On a software adapter such as lavapipe its
//! buffers are host memory: 108 bytes per drawn triangle (three 32-byte vertices, three 4-byte
//! indices), about 416 MB for the default lumbar phantom's 3.85 M triangles. There the CPU draws
//! the L-buffer passes (`raster`), so the buffers are made from its geometry on first need only
//! (the adapter's own passes, or a view the CPU refuses): the upload was 0.6 s of the 0.95 s
//! that a region's anatomy took to build on 2 cores (default phantom). Culled passes draw
//! runs of this one index buffer; no per-frame index list is made. The render targets that no
//! frame is using are pooled here too (`TargetPool`). What changes per renderer (needle,
//! uniforms, the full image's geometric L-buffer, caches) is in `LBuffer`, `ResolvePass` and
//! `FrameCache`.

use std::any::Any;
use std::sync::{Arc, Mutex, OnceLock, PoisonError, Weak};

use sim_core::fluoro::Scene;
use sim_core::fluoro::nesting::{NestedMesh, nesting_plan, triangle_cross};
use wgpu::util::DeviceExt;

use super::pipelines::{Pipelines, TargetPool};
use super::raster::CpuGeometry;
use super::types::{FluoroGpuError, Vertex};
use crate::gpu::GpuContext;

/// The read-only anatomy of one scene uploaded to one device, shared by every
/// [`GpuFluoroRenderer`](super::GpuFluoroRenderer) made with
/// [`GpuFluoroRenderer::with_anatomy`](super::GpuFluoroRenderer::with_anatomy). Its device
/// memory is freed when the last renderer holding it is dropped.
pub struct GpuAnatomy {
    pub(super) ctx: GpuContext,
    /// The nesting plan, in drawing order: the meshes that add to the water-basis channel only
    /// first (drawn into the one-channel target).
    pub(super) meshes: Vec<NestedMesh>,
    /// The drawn triangles on the device: made with the anatomy when it has no CPU geometry,
    /// else from that geometry on first need ([`GpuAnatomy::buffers`]).
    buffers: OnceLock<AnatomyBuffers>,
    pub(super) pipelines: Pipelines,
    /// Cortical shell used by the cancellous clamp, mm (the scene's).
    pub(super) cortical_shell_mm: f64,
    /// The render targets no frame of its renderers is using.
    pub(super) pool: TargetPool,
    /// The L-buffer passes on the CPU (`raster`), on a software adapter only: there the
    /// worker's own rasteriser is several times faster than the adapter's.
    pub(super) cpu: Option<CpuGeometry>,
}

impl std::fmt::Debug for GpuAnatomy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuAnatomy")
            .field("adapter", &self.ctx.summary.name)
            .field("meshes", &self.meshes.len())
            .field("vertices", &self.vertex_count())
            .finish()
    }
}

impl GpuAnatomy {
    /// Checks that the device has what the renderer needs, resolves the nesting of `scene`'s
    /// non-steel entries once (sim-core's [`nesting_plan`]) and uploads their triangles, the
    /// meshes that only touch the water-basis channel first. Steel entries are left out: they
    /// are a renderer's needle.
    ///
    /// On a software adapter the anatomy also gets the CPU geometric pass (its own compact copy
    /// of the drawn triangles' corners, `raster::CpuGeometry`).
    pub fn new(ctx: &GpuContext, scene: &Scene) -> Result<Arc<GpuAnatomy>, FluoroGpuError> {
        GpuAnatomy::build(ctx, scene, ctx.summary.is_software)
    }

    /// [`GpuAnatomy::new`] with the CPU geometric pass whatever the adapter (to compare it
    /// with a hardware rasteriser's).
    pub fn with_cpu_geometry(
        ctx: &GpuContext,
        scene: &Scene,
    ) -> Result<Arc<GpuAnatomy>, FluoroGpuError> {
        GpuAnatomy::build(ctx, scene, true)
    }

    /// The anatomy of `scene`, with the CPU geometric pass if `cpu`.
    fn build(
        ctx: &GpuContext,
        scene: &Scene,
        cpu: bool,
    ) -> Result<Arc<GpuAnatomy>, FluoroGpuError> {
        let needed = wgpu::Features::FLOAT32_BLENDABLE;
        if !ctx.device.features().contains(needed) {
            return Err(FluoroGpuError::MissingFeature(needed));
        }
        let needed = wgpu::DownlevelFlags::FRAGMENT_WRITABLE_STORAGE;
        if !ctx.downlevel.contains(needed) {
            return Err(FluoroGpuError::MissingDownlevel(needed));
        }
        // The meshes that add to the water-basis channel only (soft tissue in soft tissue) come
        // first, for the scalar pass (a stable sort: entry order within each group).
        let mut meshes = nesting_plan(scene);
        meshes.sort_by_cached_key(|d| !d.water_basis_only());
        let cpu = cpu.then(|| CpuGeometry::new(scene, &meshes));
        let buffers = OnceLock::new();
        if cpu.is_none() {
            let (vertices, scalar) = scene_vertices(scene, &meshes);
            let _ = buffers.set(AnatomyBuffers::upload(&ctx.device, &vertices, scalar));
        }
        Ok(Arc::new(GpuAnatomy {
            cpu,
            ctx: ctx.clone(),
            meshes,
            buffers,
            pipelines: Pipelines::new(ctx),
            cortical_shell_mm: scene.cortical_shell_mm,
            pool: TargetPool::default(),
        }))
    }

    /// The drawn meshes with their nesting, in drawing order.
    pub fn drawn(&self) -> &[NestedMesh] {
        &self.meshes
    }

    /// Vertices uploaded (three per drawn triangle; 0 while the buffers are not made).
    pub fn vertex_count(&self) -> u32 {
        self.buffers
            .get()
            .and_then(|b| b.bufs.as_ref())
            .map_or(0, |b| b.index_count)
    }

    /// Bytes of the uploaded vertex and index buffers (0 while they are not made).
    pub fn uploaded_bytes(&self) -> u64 {
        self.buffers
            .get()
            .and_then(|b| b.bufs.as_ref())
            .map_or(0, |b| b.vertices.size() + b.indices.size())
    }

    /// The drawn triangles on the device, made now from the CPU geometry if they were not
    /// (the same vertices, bit for bit, as from the scene: `lazy_buffers_hold_the_scenes_vertices`).
    pub(super) fn buffers(&self) -> &AnatomyBuffers {
        self.buffers.get_or_init(|| {
            let cpu = self
                .cpu
                .as_ref()
                .expect("an anatomy made without its buffers has its CPU geometry");
            let (vertices, scalar) = cpu_vertices(cpu, &self.meshes);
            AnatomyBuffers::upload(&self.ctx.device, &vertices, scalar)
        })
    }

    /// Render-target sets that no frame of this anatomy's renderers is using now, kept for the
    /// next frame of any of them: (supersampled regions' geometric L-buffers, frame targets).
    pub fn free_target_sets(&self) -> (usize, usize) {
        self.pool.free_sets()
    }

    /// Whether this anatomy lives on `ctx`'s device.
    pub fn is_on(&self, ctx: &GpuContext) -> bool {
        Arc::ptr_eq(&self.ctx.device, &ctx.device)
    }
}

/// One [`GpuAnatomy`] per owner of a scene (a session server's region) and device, shared by
/// every renderer made for that owner while any of them lives: the first renderer uploads, the
/// others reuse, and the upload is freed with the last renderer holding it (the cache keeps only
/// weak references).
#[derive(Default)]
pub struct AnatomyCache {
    entries: Mutex<Vec<CacheEntry>>,
}

struct CacheEntry {
    /// The scene's owner, held weakly: while this entry exists the owner's allocation (not its
    /// contents) stays reserved, so no other owner can come to have its address.
    owner: Weak<dyn Any + Send + Sync>,
    anatomy: Weak<GpuAnatomy>,
}

impl std::fmt::Debug for AnatomyCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AnatomyCache")
            .field("live", &self.live())
            .finish()
    }
}

impl AnatomyCache {
    /// An empty cache.
    pub fn new() -> AnatomyCache {
        AnatomyCache::default()
    }

    /// The anatomy of `owner`'s scene (`scene(owner)`) on `ctx`'s device: the one uploaded
    /// before if a renderer still holds it, else a new upload ([`GpuAnatomy::new`]). Owners are
    /// told apart by identity (the same `Arc`), not by content. Callers for the same owner at the
    /// same time wait for one upload instead of making two.
    pub fn get_or_upload<K: Send + Sync + 'static>(
        &self,
        ctx: &GpuContext,
        owner: &Arc<K>,
        scene: impl FnOnce(&K) -> &Scene,
    ) -> Result<Arc<GpuAnatomy>, FluoroGpuError> {
        let mut entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        entries.retain(|e| e.anatomy.strong_count() > 0);
        let key = Arc::as_ptr(owner).cast::<()>();
        let found = entries
            .iter()
            .filter(|e| e.owner.as_ptr().cast::<()>() == key)
            .filter_map(|e| e.anatomy.upgrade())
            .find(|a| a.is_on(ctx));
        if let Some(anatomy) = found {
            return Ok(anatomy);
        }
        let anatomy = GpuAnatomy::new(ctx, scene(owner))?;
        let weak_owner: Weak<K> = Arc::downgrade(owner);
        entries.push(CacheEntry {
            owner: weak_owner as Weak<dyn Any + Send + Sync>,
            anatomy: Arc::downgrade(&anatomy),
        });
        Ok(anatomy)
    }

    /// Anatomies uploaded and still held by some renderer.
    pub fn live(&self) -> usize {
        let entries = self.entries.lock().unwrap_or_else(PoisonError::into_inner);
        entries
            .iter()
            .filter(|e| e.anatomy.strong_count() > 0)
            .count()
    }
}

/// The buffers of an anatomy with no triangle drawn (for frames that draw none of them).
pub(super) static NO_BUFFERS: AnatomyBuffers = AnatomyBuffers {
    bufs: None,
    chunks: Vec::new(),
    scalar_chunks: 0,
};

/// The anatomy as drawn: one vertex buffer (the scalar meshes' triangles first, then the rest,
/// each mesh's in its BVH's order) and its culling chunks.
pub(super) struct AnatomyBuffers {
    /// `None` when no mesh is drawn.
    pub(super) bufs: Option<MeshBuffers>,
    /// Runs of [`CHUNK_TRIANGLES`] consecutive anatomy triangles with their bounding boxes, for
    /// culling on the CPU.
    pub(super) chunks: Vec<Chunk>,
    /// The scalar meshes come first: the number of their chunks.
    pub(super) scalar_chunks: usize,
}

pub(super) struct MeshBuffers {
    pub(super) vertices: wgpu::Buffer,
    pub(super) indices: wgpu::Buffer,
    pub(super) index_count: u32,
}

/// A run of consecutive anatomy triangles (in drawing order) and its bounding box, mm.
pub(super) struct Chunk {
    pub(super) first_vertex: u32,
    pub(super) vertices: u32,
    pub(super) lo: [f32; 3],
    pub(super) hi: [f32; 3],
}

/// The vertices of the triangles of `meshes` in `scene`, in drawing order (the scalar meshes
/// first, as the renderer orders them), and how many belong to the scalar meshes.
fn scene_vertices(scene: &Scene, meshes: &[NestedMesh]) -> (Vec<Vertex>, usize) {
    let entries = scene.entries();
    let scalar_meshes = meshes.partition_point(NestedMesh::water_basis_only);
    let mut vertices: Vec<Vertex> = Vec::new();
    let mut scalar_vertices = 0;
    for (id, mesh) in meshes.iter().enumerate() {
        let tris = entries[mesh.entry].bvh.triangles_mm();
        if id < scalar_meshes {
            scalar_vertices += 3 * tris.len();
        }
        vertices.extend(tris.iter().flat_map(|t| triangle_vertices(t, id as u32)));
    }
    (vertices, scalar_vertices)
}

/// [`scene_vertices`] from the CPU geometry of the same meshes: it keeps every triangle of
/// every drawn mesh in drawing order with its corners' exact values, so these are the same.
fn cpu_vertices(cpu: &CpuGeometry, meshes: &[NestedMesh]) -> (Vec<Vertex>, usize) {
    let scalar_meshes = meshes.partition_point(NestedMesh::water_basis_only);
    let mut vertices: Vec<Vertex> = Vec::with_capacity(3 * cpu.triangle_count());
    let mut scalar_vertices = 0;
    cpu.for_each_triangle(|mesh, t| {
        if (mesh as usize) < scalar_meshes {
            scalar_vertices += 3;
        }
        vertices.extend(triangle_vertices(&t, mesh));
    });
    (vertices, scalar_vertices)
}

impl AnatomyBuffers {
    /// Uploads `vertices` (the scalar meshes' first `scalar_vertices`, then the rest) and cuts
    /// them into culling chunks.
    fn upload(
        device: &wgpu::Device,
        vertices: &[Vertex],
        scalar_vertices: usize,
    ) -> AnatomyBuffers {
        let mut chunks = chunks_of(&vertices[..scalar_vertices], 0);
        let scalar_chunks = chunks.len();
        // Chunks never straddle the two groups.
        chunks.extend(chunks_of(vertices, scalar_vertices));
        AnatomyBuffers {
            bufs: (!vertices.is_empty()).then(|| upload(device, vertices)),
            chunks,
            scalar_chunks,
        }
    }
}

/// The three vertices of a triangle with its unit normal.
pub(super) fn triangle_vertices(t: &[[f64; 3]; 3], mesh: u32) -> [Vertex; 3] {
    let c = triangle_cross(*t);
    let len = c.length();
    let normal = if len > 0.0 {
        (c / len).to_array().map(|x| x as f32)
    } else {
        [0.0; 3]
    };
    t.map(|v| Vertex {
        pos: v.map(|x| x as f32),
        mesh,
        normal,
        pad: 0,
    })
}

/// Triangles per culling chunk. Simulator choice: 32 keeps the per-projection box work at
/// 8 corners per 32 triangles while a needle box still draws only nearby chunks.
const CHUNK_TRIANGLES: usize = 32;

/// Culling chunks of `vertices[start..]`: runs of [`CHUNK_TRIANGLES`] triangles and their boxes.
fn chunks_of(vertices: &[Vertex], start: usize) -> Vec<Chunk> {
    vertices[start..]
        .chunks(3 * CHUNK_TRIANGLES)
        .enumerate()
        .map(|(k, vs)| {
            let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
            for v in vs {
                for a in 0..3 {
                    lo[a] = lo[a].min(v.pos[a]);
                    hi[a] = hi[a].max(v.pos[a]);
                }
            }
            Chunk {
                first_vertex: (start + k * 3 * CHUNK_TRIANGLES) as u32,
                vertices: vs.len() as u32,
                lo,
                hi,
            }
        })
        .collect()
}

/// Uploads a triangle list: the vertices and the identity index list over them.
pub(super) fn upload(device: &wgpu::Device, vertices: &[Vertex]) -> MeshBuffers {
    let indices: Vec<u32> = (0..vertices.len() as u32).collect();
    MeshBuffers {
        vertices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("fluoro vertices"),
            contents: bytemuck::cast_slice(vertices),
            usage: wgpu::BufferUsages::VERTEX,
        }),
        indices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("fluoro indices"),
            contents: bytemuck::cast_slice(&indices),
            usage: wgpu::BufferUsages::INDEX,
        }),
        index_count: indices.len() as u32,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluoro::GpuFluoroRenderer;
    use sim_core::fluoro::analytic::SpherePhantom;
    use sim_core::fluoro::{Projection, QuantumNoise, RenderSettings};
    use sim_core::geom::{capped_cylinder, equal_area_vertex_radius};

    fn phantom() -> Scene {
        SpherePhantom {
            subdivisions: 3,
            volume_matched: true,
            needle_segments: 16,
        }
        .build()
        .0
    }

    /// `scene` with every corner rounded to `f32` (each triangle its own three corners).
    fn rounded_to_f32(scene: &Scene) -> Scene {
        let mut out = Scene::new();
        for e in scene.entries() {
            let tris = e.bvh.triangles_mm();
            let mesh = sim_core::mesh::TriMesh {
                vertices_mm: tris
                    .iter()
                    .flatten()
                    .map(|v| v.map(|x| f64::from(x as f32)))
                    .collect(),
                triangles: (0..tris.len() as u32)
                    .map(|k| [3 * k, 3 * k + 1, 3 * k + 2])
                    .collect(),
            };
            out.add_with_priority(e.name.clone(), e.material, e.priority, &mesh);
        }
        out
    }

    /// The buffers made on first need from the CPU geometry hold the vertices made from the
    /// scene, bit for bit, with the same split between the scalar meshes and the rest: for a
    /// scene whose corners the CPU geometry keeps in f64 and one it keeps in f32.
    #[test]
    fn lazy_buffers_hold_the_scenes_vertices() {
        for scene in [phantom(), rounded_to_f32(&phantom())] {
            let mut meshes = nesting_plan(&scene);
            meshes.sort_by_cached_key(|d| !d.water_basis_only());
            let (want, want_scalar) = scene_vertices(&scene, &meshes);
            let (got, got_scalar) = cpu_vertices(&CpuGeometry::new(&scene, &meshes), &meshes);
            assert!(
                0 < want_scalar && want_scalar < want.len(),
                "both groups drawn"
            );
            assert_eq!(got_scalar, want_scalar);
            let bytes = |v: &[Vertex]| bytemuck::cast_slice::<Vertex, u8>(v).to_vec();
            assert!(
                bytes(&got) == bytes(&want),
                "the same vertices, bit for bit"
            );
        }
    }

    #[test]
    fn renderers_of_one_owner_share_one_upload_freed_with_the_last() {
        let Some(ctx) = crate::gpu::context_for_tests() else {
            return;
        };
        let cache = AnatomyCache::new();
        let owner = Arc::new(phantom());
        let a = cache.get_or_upload(&ctx, &owner, |s| s).expect("upload");
        let b = cache.get_or_upload(&ctx, &owner, |_| panic!("uploaded again"));
        assert!(Arc::ptr_eq(&a, &b.expect("shared")));
        assert_eq!(cache.live(), 1);
        // Made on first need where the CPU draws the passes (a software adapter).
        assert_eq!(a.uploaded_bytes() == 0, a.cpu.is_some());
        a.buffers();
        assert!(a.uploaded_bytes() > 0);
        // Another owner with the same content is another region: its own upload.
        let other = Arc::new(phantom());
        let c = cache.get_or_upload(&ctx, &other, |s| s).expect("upload");
        assert!(!Arc::ptr_eq(&a, &c));
        assert_eq!(cache.live(), 2);
        drop((a, c));
        assert_eq!(cache.live(), 0);
        // With no renderer left the next one uploads again.
        let mut uploaded = false;
        let _d = cache
            .get_or_upload(&ctx, &owner, |s| {
                uploaded = true;
                s
            })
            .expect("upload");
        assert!(uploaded);
    }

    /// Two renderers drawing one shared anatomy, taking turns with different needles, give the
    /// frames of renderers with their own uploads, bit for bit: nothing of one renderer's state
    /// lives in the shared part.
    #[test]
    fn renderers_on_a_shared_anatomy_draw_the_frames_of_private_uploads() {
        let Some(ctx) = crate::gpu::context_for_tests() else {
            return;
        };
        let scene = phantom();
        let shared = GpuAnatomy::new(&ctx, &scene).expect("anatomy");
        let mut a = GpuFluoroRenderer::with_anatomy(Arc::clone(&shared));
        let mut b = GpuFluoroRenderer::with_anatomy(shared);
        let mut private_a = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
        let mut private_b = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
        let r = equal_area_vertex_radius(0.36, 16);
        let needle = |x: f64| capped_cylinder([x, -60.0, 10.0], [x + 30.0, 10.0, 30.0], r, 16);
        let p = Projection {
            detector_pixels: [96, 96],
            pixel_pitch_mm: [1.2; 2],
            ..Projection::default()
        };
        let settings = RenderSettings {
            noise: Some(QuantumNoise {
                photons_per_pixel: 3000.0,
                seed: 3,
            }),
            ..RenderSettings::default()
        };
        for (k, x) in [-40.0, -38.0, -20.0].into_iter().enumerate() {
            a.update_needle(&needle(x));
            private_a.update_needle(&needle(x));
            b.update_needle(&needle(-x));
            private_b.update_needle(&needle(-x));
            let p = Projection {
                orbital_deg: 10.0 * k as f64,
                ..p
            };
            let fa = a.render_frame(&p, &settings, None).expect("frame");
            let fb = b.render_frame(&p, &settings, None).expect("frame");
            assert_eq!(
                fa,
                private_a.render_frame(&p, &settings, None).expect("frame")
            );
            assert_eq!(
                fb,
                private_b.render_frame(&p, &settings, None).expect("frame")
            );
            assert_ne!(fa, fb, "different needles");
        }
        assert_eq!(
            a.render_chords(&p).expect("chords"),
            private_a.render_chords(&p).expect("chords")
        );
    }

    /// Renderers of one anatomy take turns with the pooled targets: each frame writes another
    /// renderer's leftovers. Needle-only frames resolve only the needle's columns of a few rows
    /// on top of the kept transmission, and a renderer without a needle or with iodine shares the
    /// same sets, yet every frame equals, bit for bit, the frame of a renderer with its own
    /// upload and pool; the pool then holds the sets, no renderer does.
    #[test]
    fn renderers_taking_turns_with_pooled_targets_draw_their_own_frames() {
        let Some(ctx) = crate::gpu::context_for_tests() else {
            return;
        };
        let scene = phantom();
        let shared = GpuAnatomy::new(&ctx, &scene).expect("anatomy");
        let mut on_shared: Vec<_> = (0..3)
            .map(|_| GpuFluoroRenderer::with_anatomy(Arc::clone(&shared)))
            .collect();
        let mut private: Vec<_> = (0..3)
            .map(|_| GpuFluoroRenderer::new(&ctx, &scene).expect("renderer"))
            .collect();
        let r = equal_area_vertex_radius(0.36, 16);
        let needle =
            |x: f64, depth: f64| capped_cylinder([x, -60.0, 10.0], [x + 30.0, depth, 30.0], r, 16);
        let ap = Projection {
            detector_pixels: [96, 80],
            pixel_pitch_mm: [1.2; 2],
            ..Projection::default()
        };
        let oblique = Projection {
            orbital_deg: 20.0,
            ..ap
        };
        let settings = RenderSettings {
            supersample: 2,
            ..RenderSettings::default()
        };
        let field = sim_core::fluoro::IodineField {
            volume: sim_core::volume::Volume {
                grid: sim_core::volume::VolumeGrid {
                    dims: [6, 6, 6],
                    spacing_mm: [5.0; 3],
                    origin_mm: [-12.0; 3],
                },
                data: vec![0.3; 216],
            },
        };
        let mut partial = 0;
        for step in 0..8 {
            for (k, (s, p)) in on_shared.iter_mut().zip(&mut private).enumerate() {
                // Renderer 0 feeds its needle under a fixed AP view (partial resolves), 1 moves
                // its needle sideways under an oblique view, 2 has no needle until step 4 and
                // then iodine on odd steps.
                let (projection, mesh, iodine) = match k {
                    0 => (
                        ap,
                        Some(needle(-30.0, -20.0 + 4.0 * f64::from(step))),
                        false,
                    ),
                    1 => (oblique, Some(needle(f64::from(step) - 10.0, 0.0)), false),
                    _ => (ap, (step >= 4).then(|| needle(5.0, 5.0)), step % 2 == 1),
                };
                for renderer in [&mut *s, &mut *p] {
                    match &mesh {
                        Some(m) => renderer.update_needle(m),
                        None => renderer.clear_needle(),
                    }
                }
                let iodine = iodine.then_some(&field);
                // Renderer 0 without supersampling: what it resolves is its needle's rectangle.
                let settings = RenderSettings {
                    supersample: if k == 0 { 1 } else { 2 },
                    ..settings
                };
                let a = s
                    .render_transmission_supersampled(&projection, &settings, iodine)
                    .expect("frame");
                let resolved = s.last_timings().resolved_samples;
                let b = p
                    .render_transmission_supersampled(&projection, &settings, iodine)
                    .expect("frame");
                let differ = a
                    .transmission
                    .iter()
                    .zip(&b.transmission)
                    .filter(|(x, y)| x.to_bits() != y.to_bits())
                    .count();
                assert_eq!(differ, 0, "renderer {k}, step {step}");
                if k == 0 && step > 0 {
                    assert!(resolved < 96 * 80, "renderer 0 resolves its needle only");
                    partial += 1;
                }
            }
        }
        assert!(partial >= 7);
        let (regions, frames) = shared.free_target_sets();
        assert!(
            (1..=super::super::pipelines::POOL_KEEP).contains(&frames)
                && regions <= super::super::pipelines::POOL_KEEP,
            "{regions} region and {frames} frame sets free"
        );
    }
}
