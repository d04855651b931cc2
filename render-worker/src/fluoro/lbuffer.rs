//! The L-buffer passes (see the module map in `fluoro`): one renderer's needle, view uniforms,
//! per-mesh slot weights of each layout and culling boxes over the shared anatomy
//! (`anatomy.rs`), and the recording of the passes.
//!
//! - Geometric part: every anatomy triangle is drawn without depth test or culling, with
//!   additive blending, into an `R32Float` target if its mesh only changes the water-basis
//!   channel (soft tissue in soft tissue: a one-channel blend is the cheaper fragment) and into
//!   an `Rgba32Float` target otherwise. A fragment adds `s (w - w_ref)` times the mesh's
//!   *geometric* weights, where `w = row_w . (point - source)` is the axial depth of the
//!   triangle's point on the sample's ray (the reciprocal of the fragment position's `w`, which
//!   the rasteriser interpolates exactly: `1 / w` is affine in screen space), `s = -1` on front
//!   faces (entering) and `+1` on back faces. Summed over a closed mesh it is the mesh's chord
//!   times `(row_w . d) / |d|` for the sample's ray `d`; the resolve multiplies by
//!   `|d| / (row_w . d)`. `w_ref` (the axial depth of the mesh's box centre) cancels in each
//!   entering/leaving pair and keeps the summed terms small, so f32 cancellation stays near
//!   `ulp(mesh size)` instead of `ulp(source distance)`. The fragment shader is a multiply-add:
//!   on lavapipe the pass is fragment bound.
//! - Needle: its triangles go into an `Rg32Float` target with `Min` blending (nearest entering
//!   and farthest leaving distance: its hull interval `[t0, t1]` on the pixel's ray) and into an
//!   `R32Float` target with additive blending (its exact chord).
//! - Displaced part (only with a needle): the anatomy again, scissored to the needle's pixel
//!   box and culled to the chunks that reach it, into a second `Rgba32Float` target: a fragment
//!   adds `s (clamp(t, t0, t1) - t0)` times the mesh's *displaced* (negative) weights, the part
//!   of each chord the needle occupies. This is exact when the needle is convex along each ray.
//!
//! In the needle and displaced passes `t` is the exact distance along the ray: the fragment's
//! pixel ray (sim-core's [`Projection::gpu_ray_frame`]) meets the triangle's plane (outward unit
//! normal from an f64 cross product, passed flat) at `t = n.(v - s) |d| / n.d`, in f32, and the
//! sign of `n.d` says entering or leaving. (Interpolating `vertex - source` instead lost
//! 0.02 mm on the needle's long, thin side triangles seen nearly edge-on.) The anatomy's
//! triangles are not that thin, and its axial depths agree with the CPU as closely as the plane
//! did (the sphere and phantom chord tests in `tests/fluoro.rs`).
use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use sim_core::fluoro::nesting::{NestedMesh, soup_box};
use sim_core::fluoro::{FluoroMaterial, Projection};
use sim_core::material::MaterialClass;

use super::anatomy::{
    AnatomyBuffers, GpuAnatomy, MeshBuffers, NO_BUFFERS, triangle_vertices, upload,
};
use super::pipelines::{Pipelines, Targets};
use super::raster::{
    ChunkBoxes, GeometrySums, MeshWeights, NeedleTriangles, NotDrawn, SampleProjection, SampleRect,
    projected_box, same_matrix,
};
use super::types::{
    CANCELLOUS, CHANNELS, CHORD_CHANNELS, CORTICAL, FluoroGpuError, Layout, NO_NEEDLE, Passes,
    PixelRect, SLOTS, Vertex,
};
use crate::gpu::GpuContext;

/// The L-buffer passes' state of one renderer: the shared anatomy as drawn (uploaded once per
/// scene and device, see `anatomy.rs`), and this renderer's own needle (replaced whenever it
/// moves), per-region view uniforms, per-mesh slot weights and culling boxes.
pub(super) struct LBuffer {
    pub(super) anatomy: Arc<GpuAnatomy>,
    /// Each anatomy chunk's pixel bounding box under one projection (see `culled`).
    chunk_boxes: Option<(Projection, Vec<[f32; 4]>)>,
    needle: Option<Needle>,
    /// Uniforms of the full image (0) and of the supersampled needle region (1).
    view_buf: [wgpu::Buffer; 2],
    weights_buf: wgpu::Buffer,
    /// Whether the transmission layout's anatomy and needle passes run on the CPU (`raster`)
    /// when the anatomy has it (set by the renderer).
    pub(super) cpu_geometry: bool,
    /// The anatomy's chunk boxes for the CPU passes under the last projection.
    cpu_boxes: Option<ChunkBoxes>,
    /// The CPU geometric sums of the last supersampled region's padded box.
    kept_region: Option<KeptRegion>,
}

/// A supersampled region's geometric sums on the CPU, for a box padded around it.
struct KeptRegion {
    /// The projection they were made under.
    matrix: [[f64; 4]; 3],
    /// Samples per pixel axis.
    per_px: usize,
    /// The padded box, in samples of the full image's grid at that density.
    rect: SampleRect,
    sums: GeometrySums,
}

/// Samples a supersampled region's kept CPU sums reach beyond its box on each side once the
/// needle moves under one view. Simulator choice: 32 samples (16 pixels at 2 x 2) hold several
/// 1 mm needle steps at the default C-arm's magnification, for about twice the samples of a
/// needle's box drawn at the first step.
const REGION_PAD_SAMPLES: usize = 32;

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct ViewUniform {
    row_x: [f32; 4],
    row_y: [f32; 4],
    row_w: [f32; 4],
    source: [f32; 4],
    size: [f32; 4],
    needle_box: [f32; 4],
    p00: [f32; 4],
    step_u: [f32; 4],
    step_v: [f32; 4],
    region: [f32; 4],
}

struct Needle {
    bufs: MeshBuffers,
    centre_mm: [f64; 3],
    vertices_mm: Vec<[f64; 3]>,
}

impl LBuffer {
    /// This renderer's state over `anatomy`; no needle yet.
    pub(super) fn new(anatomy: Arc<GpuAnatomy>) -> LBuffer {
        let device = &anatomy.ctx.device;
        let view_buf = [0, 1].map(|_| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("fluoro view"),
                size: std::mem::size_of::<ViewUniform>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        let weights_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("fluoro weights"),
            size: (anatomy.meshes.len().max(1) * 3 * 16) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        LBuffer {
            anatomy,
            chunk_boxes: None,
            needle: None,
            view_buf,
            weights_buf,
            cpu_geometry: true,
            cpu_boxes: None,
            kept_region: None,
        }
    }

    /// Whether a needle is drawn.
    pub(super) fn has_needle(&self) -> bool {
        self.needle.is_some()
    }

    /// The needle's triangles' vertices, mm, three per triangle (none without a needle).
    pub(super) fn needle_vertices_mm(&self) -> &[[f64; 3]] {
        self.needle.as_ref().map_or(&[], |n| &n.vertices_mm)
    }

    /// Replaces the needle by a triangle soup (none if empty).
    pub(super) fn set_needle(&mut self, device: &wgpu::Device, tris: &[[[f64; 3]; 3]]) {
        if tris.is_empty() {
            self.needle = None;
            return;
        }
        let (lo, hi) = soup_box(tris);
        let vertices: Vec<Vertex> = tris.iter().flat_map(|t| triangle_vertices(t, 0)).collect();
        self.needle = Some(Needle {
            bufs: upload(device, &vertices),
            centre_mm: std::array::from_fn(|a| 0.5 * (lo[a] + hi[a])),
            vertices_mm: tris.iter().flatten().copied().collect(),
        });
    }
}

/// A mesh's geometric and displaced weights in `layout`: its own material's minus its
/// container's (see sim-core's `fluoro::nesting`).
pub(super) fn net_weights(mesh: &NestedMesh, layout: Layout) -> ([f32; SLOTS], [f32; SLOTS]) {
    let (mut g, mut d) = slot_weights(mesh.effective, layout);
    if let Some(c) = mesh.container {
        let (gc, dc) = slot_weights(c, layout);
        for k in 0..SLOTS {
            g[k] -= gc[k];
            d[k] -= dc[k];
        }
    }
    (g, d)
}

/// Whether a mesh's transmission weights touch only the water-basis channel (soft tissue inside
/// soft tissue): it is drawn into the one-channel target. The renderer orders its meshes with
/// sim-core's [`NestedMesh::water_basis_only`], which a unit test shows to be the same
/// decision.
#[cfg(test)]
fn is_scalar(mesh: &NestedMesh) -> bool {
    net_weights(mesh, Layout::Transmission).0[1..]
        .iter()
        .all(|&x| x == 0.0)
}

/// Per-material weights of the transmission layout: `g` multiplies the signed distance, `d`
/// the signed part inside the needle (so each channel accumulates `w (L - L_displaced)`).
fn transmission_weights(m: FluoroMaterial) -> ([f32; SLOTS], [f32; SLOTS]) {
    let (mut g, mut d) = ([0.0; SLOTS], [0.0; SLOTS]);
    let mu = m.mu_60kev_per_cm() as f32;
    match m {
        FluoroMaterial::Steel => {}
        FluoroMaterial::Tissue(MaterialClass::CorticalBone) => {
            (g[1], d[1], g[2]) = (mu, -mu, 1.0);
        }
        FluoroMaterial::Tissue(MaterialClass::Cancellous) => {
            (g[1], d[1], g[3]) = (mu, -mu, 1.0);
        }
        FluoroMaterial::Tissue(_) => {
            (g[0], d[0]) = (mu, -mu);
        }
    }
    (g, d)
}

fn chord_weights(m: FluoroMaterial, pass: usize) -> ([f32; SLOTS], [f32; SLOTS]) {
    let (mut gc, mut dc) = ([0.0f32; CHORD_CHANNELS], [0.0f32; CHORD_CHANNELS]);
    if m != FluoroMaterial::Steel {
        let i = m.index();
        gc[i] = 1.0;
        if m == CORTICAL {
            dc[CHANNELS - 1] = 1.0;
        } else if m == CANCELLOUS {
            dc[CHANNELS] = 1.0;
        } else {
            dc[i] = -1.0;
        }
    }
    let (mut g, mut d) = ([0.0; SLOTS], [0.0; SLOTS]);
    for k in 0..SLOTS {
        let c = pass * SLOTS + k;
        if c < CHORD_CHANNELS {
            g[k] = gc[c];
            d[k] = dc[c];
        }
    }
    (g, d)
}

fn slot_weights(m: FluoroMaterial, layout: Layout) -> ([f32; SLOTS], [f32; SLOTS]) {
    match layout {
        Layout::Transmission => transmission_weights(m),
        Layout::Chords(pass) => chord_weights(m, pass),
    }
}

impl LBuffer {
    /// Records into `encoder`: the geometric anatomy pass with `layout` (if `passes.geometry`),
    /// and with a needle its pass (if `passes.needle`) and the displaced anatomy pass scissored
    /// to its pixel box (if `passes.displaced`; the target is cleared even when the box is off
    /// the image). Returns that box in region samples, clipped (`None` without a needle or off
    /// the image). `t` are the targets of `region` (sized for it); with `culling`, only the
    /// anatomy triangles that can reach the target or the needle's box are drawn into them.
    /// `Interrupted` where newer input stopped the CPU's geometric pass (nothing is recorded
    /// then that the frame needs).
    #[expect(clippy::too_many_arguments, reason = "one private recording step")]
    pub(super) fn encode(
        &mut self,
        ctx: &GpuContext,
        pipelines: &Pipelines,
        t: &Targets,
        encoder: &mut wgpu::CommandEncoder,
        projection: &Projection,
        layout: Layout,
        passes: Passes,
        region: PixelRect,
        culling: bool,
    ) -> Result<Option<[u32; 4]>, FluoroGpuError> {
        let ri = region.index();
        let size = region.size;
        debug_assert_eq!(t.size(), size, "targets sized for the region");
        let frame = projection.frame();
        let rays = projection.gpu_ray_frame();
        let v4 = |v: [f32; 3]| [v[0], v[1], v[2], 0.0];
        let m = projection.projection_matrix();
        // Rectangle sample coordinates: n (px - x0), n (py - y0).
        let n = f64::from(region.n);
        let (x0, y0) = (f64::from(region.origin[0]), f64::from(region.origin[1]));
        let row = |r: [f64; 4], o: f64| {
            [
                (n * (r[0] - o * m[2][0])) as f32,
                (n * (r[1] - o * m[2][1])) as f32,
                (n * (r[2] - o * m[2][2])) as f32,
                0.0,
            ]
        };
        let src = frame.source_mm;
        let needle_ref = self
            .needle
            .as_ref()
            .map_or(0.0, |n| DVec3::from(n.centre_mm).distance(DVec3::from(src)));
        // Pixel box of the needle's projection, two pixels wider (rasterisation rounding); the
        // whole image if a vertex is not in front of the source.
        let needle_box = self.needle.as_ref().map_or([1.0, 1.0, -1.0, -1.0], |nd| {
            let mut b = [
                f32::INFINITY,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
            ];
            for &v in &nd.vertices_mm {
                match projection.project_point(v) {
                    Some([x, y]) => {
                        let (x, y) = (n * (x - x0), n * (y - y0));
                        b = [
                            b[0].min(x as f32 - 2.0),
                            b[1].min(y as f32 - 2.0),
                            b[2].max(x as f32 + 2.0),
                            b[3].max(y as f32 + 2.0),
                        ];
                    }
                    None => return [-1e30, -1e30, 1e30, 1e30],
                }
            }
            b
        });
        let view = ViewUniform {
            row_x: row(m[0], x0),
            row_y: row(m[1], y0),
            row_w: [m[2][0] as f32, m[2][1] as f32, m[2][2] as f32, 0.0],
            source: [src[0] as f32, src[1] as f32, src[2] as f32, 0.0],
            size: [size[0] as f32, size[1] as f32, needle_ref as f32, 0.0],
            needle_box,
            p00: v4(rays.pixel00_from_source_mm),
            step_u: v4(rays.step_u_mm),
            step_v: v4(rays.step_v_mm),
            region: [
                region.origin[0] as f32,
                region.origin[1] as f32,
                1.0 / n as f32,
                0.0,
            ],
        };
        let queue = &ctx.queue;
        queue.write_buffer(&self.view_buf[ri], 0, bytemuck::bytes_of(&view));
        let mut w: Vec<[f32; 4]> = Vec::with_capacity(self.anatomy.meshes.len() * 3);
        for mesh in &self.anatomy.meshes {
            let (g, d) = net_weights(mesh, layout);
            let tref = DVec3::from(mesh.centre_mm).distance(DVec3::from(src)) as f32;
            let c = mesh.centre_mm;
            let wref = (m[2][0] * c[0] + m[2][1] * c[1] + m[2][2] * c[2] + m[2][3]) as f32;
            w.push(g);
            w.push(d);
            w.push([tref, wref, 0.0, 0.0]);
        }
        if !w.is_empty() {
            queue.write_buffer(&self.weights_buf, 0, bytemuck::cast_slice(&w));
        }
        // The needle's pixel box in whole samples, clipped to the target.
        let clip = |lo: f32, hi: f32, n: u32| {
            let lo = lo.floor().clamp(0.0, n as f32) as u32;
            let hi = hi.ceil().clamp(0.0, n as f32) as u32;
            (lo, hi)
        };
        let (bx0, bx1) = clip(needle_box[0], needle_box[2], size[0]);
        let (by0, by1) = clip(needle_box[1], needle_box[3], size[1]);
        let rect = (self.needle.is_some() && bx1 > bx0 && by1 > by0)
            .then(|| [bx0, by0, bx1 - bx0, by1 - by0]);
        // The passes the CPU draws where the anatomy has them (software adapters), uploaded
        // into the same targets; what it refuses is drawn on the GPU below.
        let (geometry_on_cpu, needle_on_cpu) =
            if layout == Layout::Transmission && self.cpu_geometry {
                self.cpu_passes(queue, t, projection, region, &w, passes, rect, needle_ref)?
            } else {
                (false, false)
            };
        let passes = Passes {
            geometry: passes.geometry && !geometry_on_cpu,
            needle: passes.needle && !needle_on_cpu,
            displaced: passes.displaced && !needle_on_cpu,
        };
        // Rectangle samples to full-image pixel coordinates.
        let to_pixels = |r: [u32; 4]| {
            let (inv, o) = (1.0 / n as f32, region.origin.map(|x| x as f32));
            [
                o[0] + r[0] as f32 * inv,
                o[1] + r[1] as f32 * inv,
                o[0] + (r[0] + r[2]) as f32 * inv,
                o[1] + (r[1] + r[3]) as f32 * inv,
            ]
        };
        // Only the triangles that can reach the target are drawn into it (the anatomy often
        // extends beyond the image), and only those that can reach the needle's box into the
        // displaced pass. `None`: the whole list; `Some(None)`: no triangle reaches it.
        // In the transmission layout the scalar meshes go to their own target.
        let split = layout == Layout::Transmission;
        // The anatomy's buffers are made on first need where the CPU draws its passes.
        let anatomy = Arc::clone(&self.anatomy);
        let drawn = passes.geometry || (passes.displaced && rect.is_some());
        let buffers = if drawn {
            anatomy.buffers()
        } else {
            &NO_BUFFERS
        };
        let (scalar, chunks) = (buffers.scalar_chunks, buffers.chunks.len());
        let groups = if split {
            [0..scalar, scalar..chunks]
        } else {
            [0..0, 0..chunks]
        };
        // The vertices of a run of chunks (they cover the vertex buffer in order).
        let total = buffers.bufs.as_ref().map_or(0, |b| b.index_count);
        let vertex_at = |k: usize| buffers.chunks.get(k).map_or(total, |c| c.first_vertex);
        let whole = groups.clone().map(|g| vertex_at(g.start)..vertex_at(g.end));
        let geo_lists = (culling && passes.geometry).then(|| {
            let r = to_pixels([0, 0, size[0], size[1]]);
            groups.map(|g| self.culled(buffers, projection, r, g))
        });
        let disp_list = match rect {
            Some(r) if culling && passes.displaced => {
                Some(self.culled(buffers, projection, to_pixels(r), 0..chunks))
            }
            _ => None,
        };
        let device = &ctx.device;
        let view_of = |x: &wgpu::Texture| x.create_view(&wgpu::TextureViewDescriptor::default());
        let (va, vs, vd, vh, vc) = (
            view_of(&t.geometry.a),
            view_of(&t.geometry.s),
            view_of(&t.frame.d),
            view_of(&t.frame.hull),
            view_of(&t.frame.chord),
        );
        fn attach(
            v: &wgpu::TextureView,
            clear: f64,
        ) -> Option<wgpu::RenderPassColorAttachment<'_>> {
            Some(wgpu::RenderPassColorAttachment {
                view: v,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color {
                        r: clear,
                        g: clear,
                        b: clear,
                        a: clear,
                    }),
                    store: wgpu::StoreOp::Store,
                },
            })
        }
        let anatomy_bind = |pipeline: &wgpu::RenderPipeline, with_hull: bool| {
            let mut entries = vec![
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.view_buf[ri].as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: self.weights_buf.as_entire_binding(),
                },
            ];
            if with_hull {
                entries.push(wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&vh),
                });
            }
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("fluoro anatomy"),
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            })
        };
        fn pass_desc<'a>(
            label: &'a str,
            attachments: &'a [Option<wgpu::RenderPassColorAttachment<'a>>],
        ) -> wgpu::RenderPassDescriptor<'a> {
            wgpu::RenderPassDescriptor {
                label: Some(label),
                color_attachments: attachments,
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            }
        }
        if passes.geometry {
            // Scalar group (transmission layout; the target is cleared in every layout), then
            // the rest.
            let [scalar_list, list] = match geo_lists {
                Some([a, b]) => [Some(a), Some(b)],
                None => [None, None],
            };
            let draws = [
                (
                    &pipelines.anatomy_scalar,
                    &vs,
                    scalar_list,
                    whole[0].clone(),
                    "fluoro anatomy, water-basis channel",
                ),
                (
                    &pipelines.anatomy,
                    &va,
                    list,
                    whole[1].clone(),
                    "fluoro anatomy",
                ),
            ];
            for (pipeline, view, list, all, label) in draws {
                let bind = anatomy_bind(pipeline, false);
                let attachments = [attach(view, 0.0)];
                let mut pass = encoder.begin_render_pass(&pass_desc(label, &attachments));
                let Some(bufs) = &buffers.bufs else {
                    continue;
                };
                draw_runs(&mut pass, pipeline, &bind, bufs, runs_or(list, all));
            }
        }
        let Some(needle) = self.needle.as_ref() else {
            return Ok(None);
        };
        if passes.needle {
            let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("fluoro needle"),
                layout: &pipelines.needle.get_bind_group_layout(0),
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.view_buf[ri].as_entire_binding(),
                }],
            });
            let attachments = [attach(&vh, NO_NEEDLE), attach(&vc, 0.0)];
            let mut pass = encoder.begin_render_pass(&pass_desc("fluoro needle", &attachments));
            pass.set_pipeline(&pipelines.needle);
            pass.set_bind_group(0, &bind, &[]);
            pass.set_vertex_buffer(0, needle.bufs.vertices.slice(..));
            pass.set_index_buffer(needle.bufs.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..needle.bufs.index_count, 0, 0..1);
        }
        if passes.displaced {
            let bind = anatomy_bind(&pipelines.displaced, true);
            let attachments = [attach(&vd, 0.0)];
            let mut pass = encoder.begin_render_pass(&pass_desc("fluoro displaced", &attachments));
            if let (Some(bufs), Some([x, y, w, h])) = (&buffers.bufs, rect) {
                pass.set_scissor_rect(x, y, w, h);
                let runs = runs_or(disp_list, 0..bufs.index_count);
                draw_runs(&mut pass, &pipelines.displaced, &bind, bufs, runs);
            }
        }
        Ok(rect)
    }

    /// Draws on the CPU (`raster`) and uploads into `t`: the geometric pass (if
    /// `passes.geometry`) and, where the needle's box `rect` (samples of `region`) meets the
    /// target, the needle's and the displaced pass (if both are asked). `weights` are the
    /// meshes' uniforms (geometric, displaced, references). Returns whether each was drawn: what
    /// the CPU refuses (a triangle at the source) or the anatomy lacks is left to the adapter;
    /// `Interrupted` where newer input stopped the geometric pass (see `crate::interrupt`).
    #[expect(clippy::too_many_arguments, reason = "one private recording step")]
    fn cpu_passes(
        &mut self,
        queue: &wgpu::Queue,
        t: &Targets,
        projection: &Projection,
        region: PixelRect,
        weights: &[[f32; 4]],
        passes: Passes,
        rect: Option<[u32; 4]>,
        needle_ref: f64,
    ) -> Result<(bool, bool), FluoroGpuError> {
        let anatomy = Arc::clone(&self.anatomy);
        let Some(cpu) = anatomy.cpu.as_ref() else {
            return Ok((false, false));
        };
        let needle = rect.filter(|_| passes.needle && passes.displaced);
        if !passes.geometry && needle.is_none() {
            return Ok((false, false));
        }
        let m = projection.projection_matrix();
        if !self.cpu_boxes.as_ref().is_some_and(|b| b.under(&m)) {
            self.cpu_boxes = Some(cpu.chunk_boxes(&m, 0));
        }
        // Samples in the full image's grid at the region's density, `n px` and `n py` (the
        // region's samples are a rectangle of it, offset by `n` times its origin): a sample's
        // sums then do not depend on where the region lies, so a kept region's can be reused.
        let n = region.n as usize;
        let nf = f64::from(region.n);
        let scaled = |r: [f64; 4]| -> [f64; 4] { r.map(|v| nf * v) };
        let [full_w, full_h] = projection.detector_pixels.map(|v| v as usize * n);
        let p = SampleProjection {
            rows: [scaled(m[0]), scaled(m[1]), m[2]],
            origin_px: [0.0, 0.0],
            per_px: nf,
        };
        let offset = region.origin.map(|v| v as usize * n);
        let size = region.size;
        let target = SampleRect {
            cols: offset[0]..offset[0] + size[0] as usize,
            rows: offset[1]..offset[1] + size[1] as usize,
        };
        let meshes = &anatomy.meshes;
        let geometry = passes.geometry && {
            let mesh_weights: Vec<MeshWeights> = meshes
                .iter()
                .zip(weights.chunks_exact(3))
                .map(|(mesh, w3)| MeshWeights {
                    g: w3[0],
                    wref: w3[2][1],
                    scalar: mesh.water_basis_only(),
                })
                .collect();
            let boxes = self.cpu_boxes.as_ref().expect("boxes");
            let sums = if n == 1 {
                // The full image: kept between frames as the geometry cache's targets.
                cpu.rasterise_rect(&mesh_weights, &p, boxes, &target, 0)
            } else {
                let full = SampleRect {
                    cols: 0..full_w,
                    rows: 0..full_h,
                };
                let draw =
                    |rect: &SampleRect| cpu.rasterise_rect(&mesh_weights, &p, boxes, rect, 0);
                // The needle's supersampled box is a small part of a frame: never stopped.
                let _unwatched = crate::interrupt::unwatched();
                region_sums(&mut self.kept_region, &m, n, &target, &full, draw)
            };
            match sums {
                Ok(sums) => {
                    let whole = [0, 0, size[0], size[1]];
                    upload_texture(
                        queue,
                        &t.geometry.a,
                        whole,
                        16,
                        bytemuck::cast_slice(&sums.a),
                    );
                    upload_texture(
                        queue,
                        &t.geometry.s,
                        whole,
                        4,
                        bytemuck::cast_slice(&sums.s),
                    );
                    true
                }
                Err(NotDrawn::Refused) => false,
                Err(NotDrawn::Interrupted) => return Err(FluoroGpuError::Interrupted),
            }
        };
        let boxes = self.cpu_boxes.as_ref().expect("boxes");
        let needle_drawn = match (needle, &self.needle) {
            (Some(r), Some(nd)) => {
                let displaced: Vec<[f32; 4]> = weights.chunks_exact(3).map(|w3| w3[1]).collect();
                let (x, y) = (offset[0] + r[0] as usize, offset[1] + r[1] as usize);
                let sample_rect = SampleRect {
                    cols: x..x + r[2] as usize,
                    rows: y..y + r[3] as usize,
                };
                let triangles = NeedleTriangles {
                    triangles: bytemuck::cast_slice(&nd.vertices_mm),
                    reference_mm: needle_ref,
                };
                match cpu.needle_passes(&triangles, &displaced, &p, boxes, &sample_rect, 0) {
                    Ok(sums) => {
                        upload_texture(queue, &t.frame.d, r, 16, bytemuck::cast_slice(&sums.d));
                        upload_texture(
                            queue,
                            &t.frame.chord,
                            r,
                            4,
                            bytemuck::cast_slice(&sums.chord),
                        );
                        true
                    }
                    Err(NotDrawn::Refused) => false,
                    Err(NotDrawn::Interrupted) => return Err(FluoroGpuError::Interrupted),
                }
            }
            _ => false,
        };
        Ok((geometry, needle_drawn))
    }

    /// The runs of the anatomy's index buffer (ranges of it, in drawing order) that hold the
    /// triangles of every chunk whose pixel bounding box, widened by one pixel, meets the
    /// rectangle `r` (`x0, y0, x1, y1`, continuous full-image pixel coordinates): every pixel
    /// of `r` then blends the same fragments in the same order as with the whole list, so the
    /// result is bit-identical. Runs at most [`RUN_GAP_VERTICES`] apart are drawn as one (the
    /// triangles between them reach no pixel of `r`). `None` if no chunk does. A chunk's pixel
    /// box is the box of its eight projected 3-D box corners (the image of a box in front of the
    /// source is the hull of its corners); a chunk with a corner less than 1 mm in front of the
    /// source plane always qualifies. The boxes are computed once per projection (eight points
    /// per chunk instead of three per triangle). The runs draw from the one index buffer uploaded
    /// with the anatomy: a culled list used to be copied into a new index buffer every frame
    /// (13.5 MB and 8 ms of encoding for a C-arm-moved frame of the default phantom).
    fn culled(
        &mut self,
        buffers: &AnatomyBuffers,
        projection: &Projection,
        r: [f32; 4],
        chunks: std::ops::Range<usize>,
    ) -> Option<Vec<std::ops::Range<u32>>> {
        if self
            .chunk_boxes
            .as_ref()
            .is_none_or(|(p, _)| p != projection)
        {
            let m = projection.projection_matrix();
            let boxes = buffers
                .chunks
                .iter()
                .map(|c| projected_box(&m, c.lo.map(f64::from), c.hi.map(f64::from)))
                .collect();
            self.chunk_boxes = Some((*projection, boxes));
        }
        let boxes = &self.chunk_boxes.as_ref()?.1;
        let mut runs: Vec<std::ops::Range<u32>> = Vec::new();
        for (c, b) in buffers.chunks[chunks.clone()].iter().zip(&boxes[chunks]) {
            if b[2] >= r[0] - 1.0 && b[0] <= r[2] + 1.0 && b[3] >= r[1] - 1.0 && b[1] <= r[3] + 1.0
            {
                let (start, end) = (c.first_vertex, c.first_vertex + c.vertices);
                match runs.last_mut() {
                    // Close to the last run: one draw over both and the chunks between them,
                    // whose triangles reach no pixel of `r`.
                    Some(last) if start - last.end <= RUN_GAP_VERTICES => last.end = end,
                    _ => runs.push(start..end),
                }
            }
        }
        (!runs.is_empty()).then_some(runs)
    }
}

/// The geometric sums of a supersampled region `target` (samples of `full`, the full image's
/// grid at `n` samples per pixel axis) under `matrix`, drawn by `draw`. A supersampled region
/// follows the needle's box: its sums are kept in `kept`, and cut from while the projection
/// stays and the region lies within them. The first region under a projection is drawn as it
/// is (a C-arm-moved frame pays nothing more); once the needle has moved under it, the region
/// is drawn padded by [`REGION_PAD_SAMPLES`] (within `full`), so that the next steps only cut.
fn region_sums(
    kept: &mut Option<KeptRegion>,
    matrix: &[[f64; 4]; 3],
    n: usize,
    target: &SampleRect,
    full: &SampleRect,
    draw: impl FnOnce(&SampleRect) -> Result<GeometrySums, NotDrawn>,
) -> Result<GeometrySums, NotDrawn> {
    let under_this_view = kept
        .as_ref()
        .filter(|k| k.per_px == n && same_matrix(&k.matrix, matrix));
    if let Some(k) = under_this_view.filter(|k| k.rect.contains(target)) {
        return Ok(k.sums.crop(&k.rect, target));
    }
    let margin = if under_this_view.is_some() {
        REGION_PAD_SAMPLES
    } else {
        0
    };
    let pad = |r: &std::ops::Range<usize>, all: &std::ops::Range<usize>| {
        r.start.saturating_sub(margin).max(all.start)..(r.end + margin).min(all.end)
    };
    let padded = SampleRect {
        cols: pad(&target.cols, &full.cols),
        rows: pad(&target.rows, &full.rows),
    };
    let sums = draw(&padded)?;
    let cut = sums.crop(&padded, target);
    *kept = Some(KeptRegion {
        matrix: *matrix,
        per_px: n,
        rect: padded,
        sums,
    });
    Ok(cut)
}

/// Writes the rectangle `r` (`x, y, columns, rows`) of a texture from tightly packed rows of
/// `texel_bytes` per texel.
fn upload_texture(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    r: [u32; 4],
    texel_bytes: u32,
    data: &[u8],
) {
    queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d {
                x: r[0],
                y: r[1],
                z: 0,
            },
            aspect: wgpu::TextureAspect::All,
        },
        data,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(r[2] * texel_bytes),
            rows_per_image: Some(r[3]),
        },
        wgpu::Extent3d {
            width: r[2],
            height: r[3],
            depth_or_array_layers: 1,
        },
    );
}

/// The runs of the anatomy's index buffer to draw: the culled ones (`Some`), none
/// (`Some(None)`: no chunk reaches the target), or, without culling, `all`.
fn runs_or(
    culled: Option<Option<Vec<std::ops::Range<u32>>>>,
    all: std::ops::Range<u32>,
) -> Vec<std::ops::Range<u32>> {
    match culled {
        Some(Some(runs)) => runs,
        Some(None) => Vec::new(),
        None => vec![all],
    }
}

/// Records `pipeline` drawing `runs` of the anatomy's index buffer in `pass` (nothing when every
/// run is empty).
fn draw_runs(
    pass: &mut wgpu::RenderPass<'_>,
    pipeline: &wgpu::RenderPipeline,
    bind: &wgpu::BindGroup,
    bufs: &MeshBuffers,
    runs: Vec<std::ops::Range<u32>>,
) {
    if runs.iter().all(|r| r.is_empty()) {
        return;
    }
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind, &[]);
    pass.set_vertex_buffer(0, bufs.vertices.slice(..));
    pass.set_index_buffer(bufs.indices.slice(..), wgpu::IndexFormat::Uint32);
    for r in runs {
        pass.draw_indexed(r, 0, 0..1);
    }
}

/// Culled runs of the anatomy's index buffer at most this many vertices apart (two chunks) are
/// drawn as one. Simulator choice: fewer draw calls for a few triangles drawn in vain; on the
/// default phantom (lavapipe, 2 cores) gaps of 0 to 4 chunks gave the same frame times within
/// the machine's noise, while merging across 16 chunks or more made needle frames slower.
const RUN_GAP_VERTICES: u32 = 2 * 3 * 32;

#[cfg(test)]
mod tests {
    use super::*;

    /// The renderer orders its meshes by sim-core's `water_basis_only`; the one-channel target
    /// is right for exactly the meshes whose net transmission weights touch only channel 0, for
    /// every pair of tissue materials a plan can hold (an effective material never equals its
    /// container's, and neither is steel).
    #[test]
    fn water_basis_only_is_the_scalar_decision() {
        let tissues = MaterialClass::ALL.map(FluoroMaterial::Tissue);
        for effective in tissues {
            let containers = tissues.into_iter().filter(|&c| c != effective).map(Some);
            for container in std::iter::once(None).chain(containers) {
                let mesh = NestedMesh {
                    entry: 0,
                    name: String::new(),
                    effective,
                    container,
                    centre_mm: [0.0; 3],
                };
                assert_eq!(
                    mesh.water_basis_only(),
                    is_scalar(&mesh),
                    "{effective:?} in {container:?}"
                );
            }
        }
    }
}
