//! GPU fluoroscopy: per-pixel path lengths by rasterising closed meshes into an L-buffer, then one
//! resolve pass for the basis depths, the iodine column and the spectral sum. The reference is
//! `sim_core::fluoro` (read its "Contract for the GPU renderer"); `render-worker/tests/fluoro.rs`
//! compares the two pixel by pixel, `tests/fluoro_cache.rs` checks every cache bit for bit.
//!
//! # Map
//! - Types (`types.rs`): the renderer and every type and constant the passes share, below all of
//!   them, so the pass modules form no import cycle (each implements its part of
//!   [`GpuFluoroRenderer`] and imports only `types` and functions further down).
//! - Construction, [`GpuFluoroRenderer::new`]: sim-core's [`nesting_plan`] decides which mesh
//!   adds its chord to which material and subtracts it from which container (CPU geometry,
//!   tested in sim-core); `AnatomyBuffers` (`lbuffer.rs`) uploads the drawn triangles, the meshes
//!   that only touch the water-basis channel first; `Pipelines` (`pipelines.rs`) builds every pass.
//! - Pass 1, geometric anatomy L-buffer (`lbuffer.rs`, `encode_lbuffer`; `lbuffer.wgsl`
//!   `fs_anatomy`, `fs_anatomy_scalar`): signed axial depths times per-mesh weights, additive
//!   blending, no depth test; independent of the needle.
//! - Pass 2, needle (`encode_lbuffer`; `fs_needle`): the needle's hull interval and exact chord
//!   per pixel.
//! - Pass 3, displaced anatomy (`encode_lbuffer`, `culled`; `fs_displaced`): the part of each
//!   chord the needle occupies, scissored to the needle's pixel box.
//! - Pass 4, resolve (`resolve.rs`, `encode_region`; `resolve.wgsl`): sums the parts, clamps
//!   cancellous bone, adds iodine, and evaluates `T` (or reads the `ln T` table built by
//!   `ensure_spectral`); then `submit_and_read` reads the rows back.
//! - Caches (`cache.rs`, `begin_full` / `end_full`): between frames the geometric L-buffer, the
//!   last transmission (only the needle's old and new pixel rectangles are resolved again) and
//!   the last displayed frame are kept while what decides them stays.
//! - Validation (`chords.rs`, [`GpuFluoroRenderer::render_chords`]): the same passes in a
//!   per-material layout, resolved on the CPU.
//! - Display ([`GpuFluoroRenderer::render_frame`]): supersampling near the needle's edges
//!   (`render_transmission_supersampled`), then sim-core's noise, brightness, log mapping and
//!   shutters on the CPU.
//!
//! # Differences from the CPU frame
//! - Nesting: partially overlapping meshes are not resolved by priority (their overlap counts
//!   twice; see sim-core's `fluoro::nesting`), and the needle is subtracted exactly only where it
//!   is convex along each ray (a straight shaft with a bevel is).
//! - Cancellous clamp: on the pixel's totals instead of per run of bone (see `resolve.rs`).
//! - Sampling: the pixels near the needle's projected edges are supersampled exactly as on the
//!   CPU; anatomy silhouettes are not (the GPU takes their centre sample).
//! - Iodine: midpoint rule with steps of at most [`GpuFluoroRenderer::iodine_step_fraction`]
//!   voxels (the CPU integrates the trilinear field exactly).

mod cache;
mod chords;
mod lbuffer;
mod pipelines;
mod resolve;
mod types;

use sim_core::fluoro::nesting::{NestedMesh, nesting_plan};
use sim_core::fluoro::{
    EnergyModel, FluoroMaterial, Image, IodineField, Projection, RenderSettings, Scene,
    SpectralModel, TransmissionImage,
};
use sim_core::mesh::TriMesh;
use std::time::Instant;


use crate::gpu::GpuContext;
use cache::exposed_mask;

use resolve::iodine_texture;
use types::*;

pub use types::{CHANNELS, FluoroGpuError, FrameTimings, GpuFluoroRenderer, GpuTransmission};









impl GpuFluoroRenderer {
    /// Uploads a scene: every non-steel entry is anatomy (nesting resolved once, here, by
    /// sim-core's [`nesting_plan`]); the steel entries, if any, become the initial needle (see
    /// [`GpuFluoroRenderer::update_needle`]).
    pub fn new(ctx: &GpuContext, scene: &Scene) -> Result<GpuFluoroRenderer, FluoroGpuError> {
        let needed = wgpu::Features::FLOAT32_BLENDABLE;
        if !ctx.device.features().contains(needed) {
            return Err(FluoroGpuError::MissingFeature(needed));
        }
        let needed = wgpu::DownlevelFlags::FRAGMENT_WRITABLE_STORAGE;
        if !ctx.downlevel.contains(needed) {
            return Err(FluoroGpuError::MissingDownlevel(needed));
        }
        let device = &ctx.device;
        // The meshes that add to the water-basis channel only (soft tissue in soft tissue) come
        // first, for the scalar pass (a stable sort: entry order within each group).
        let mut meshes = nesting_plan(scene);
        meshes.sort_by_cached_key(|d| !d.water_basis_only());
        let anatomy = AnatomyBuffers::upload(device, scene, &meshes);
        let uniform = |label: &str, size: usize| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        };
        let view_buf = [0, 1].map(|_| uniform("fluoro view", std::mem::size_of::<ViewUniform>()));
        let resolve_buf =
            [0, 1].map(|_| uniform("fluoro resolve", std::mem::size_of::<ResolveUniform>()));
        let weights_buf = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("fluoro weights"),
            size: (meshes.len().max(1) * 3 * 16) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let empty_iodine = iodine_texture(ctx, [1, 1, 1], &[0.0]);
        let mut r = GpuFluoroRenderer {
            ctx: ctx.clone(),
            meshes,
            anatomy,
            chunk_boxes: None,
            needle: None,
            pipelines: Pipelines::new(ctx),
            view_buf,
            resolve_buf,
            weights_buf,
            empty_iodine,
            targets: [None, None],
            spectral: None,
            cortical_shell_mm: scene.cortical_shell_mm,
            geo_key: None,
            resolved: None,
            needle_generation: 0,
            last_frame: None,
            finishing: None,
            caching: true,
            culling: true,
            timings: FrameTimings::default(),
            iodine_step_fraction: 0.25,
        };
        let steel: Vec<[[f64; 3]; 3]> = scene
            .entries()
            .iter()
            .filter(|e| e.material == FluoroMaterial::Steel)
            .flat_map(|e| e.bvh.triangles_mm().iter().copied())
            .collect();
        r.set_needle_soup(&steel);
        Ok(r)
    }

    /// Builds a scene from `(name, material, priority, mesh)` and uploads it (see
    /// [`GpuFluoroRenderer::new`]).
    pub fn from_meshes(
        ctx: &GpuContext,
        meshes: &[(&str, FluoroMaterial, i32, &TriMesh)],
    ) -> Result<GpuFluoroRenderer, FluoroGpuError> {
        let mut scene = Scene::new();
        for &(name, material, priority, mesh) in meshes {
            scene.add_with_priority(name, material, priority, mesh);
        }
        GpuFluoroRenderer::new(ctx, &scene)
    }

    /// The adapter this renderer runs on.
    pub fn adapter_name(&self) -> &str {
        &self.ctx.summary.name
    }

    /// The drawn anatomy meshes with their nesting (what the L-buffer adds and subtracts), the
    /// ones that add to the water-basis channel only ([`NestedMesh::water_basis_only`]) first.
    pub fn drawn(&self) -> &[NestedMesh] {
        &self.meshes
    }

    /// Number of anatomy meshes drawn (meshes that add nothing after nesting are dropped).
    pub fn drawn_meshes(&self) -> usize {
        self.meshes.len()
    }

    /// Replaces the needle (a closed, outward-wound steel mesh; convex along each ray for an
    /// exact subtraction from the anatomy, see the module doc). Cheap: only its vertices are
    /// uploaded.
    pub fn update_needle(&mut self, needle: &TriMesh) {
        let soup: Vec<[[f64; 3]; 3]> = (0..needle.triangle_count())
            .map(|i| needle.triangle(i))
            .collect();
        self.set_needle_soup(&soup);
    }

    /// Removes the needle.
    pub fn clear_needle(&mut self) {
        self.needle = None;
        self.needle_generation += 1;
    }

    /// Phases of the last frame.
    pub fn last_timings(&self) -> FrameTimings {
        self.timings
    }

    /// Transmission at every pixel centre (0 behind the collimator) for `energy`, with an
    /// optional iodine field: geometric L-buffer pass, needle and displaced passes, one resolve
    /// pass, then a read-back. With [`GpuFluoroRenderer::caching`], the geometric pass is kept
    /// while the projection stays, and without iodine only the rows the needle covers now or
    /// covered in the previous frame are resolved and read back (bit-identical to a frame from
    /// scratch, see `types::Resolved`).
    pub fn render_transmission(
        &mut self,
        projection: &Projection,
        energy: &EnergyModel,
        iodine: Option<&IodineField>,
    ) -> Result<GpuTransmission, FluoroGpuError> {
        let model = SpectralModel::new(*energy)?;
        self.timings = FrameTimings::default();
        let mut enc = self.encoder();
        let full = self.begin_full(&mut enc, projection, &model, iodine);
        let mut outs = self.submit_and_read(enc, std::slice::from_ref(&full.pending))?;
        let t = self.end_full(full, outs.remove(0), iodine);
        Ok(GpuTransmission {
            width: projection.detector_pixels[0],
            height: projection.detector_pixels[1],
            transmission: t,
        })
    }

    fn encoder(&self) -> wgpu::CommandEncoder {
        self.ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None })
    }

    /// Pixels within 1.5 pixels of a projected edge of the needle: the CPU reference's steel-edge
    /// rule (same triangles, same f64 projection, same 0.5-pixel steps along each edge), so a
    /// needle thinner than a pixel is still supersampled. Row-major; all `false` without needle.
    pub fn needle_edge_pixels(&self, projection: &Projection) -> Vec<bool> {
        let [w, h] = projection.detector_pixels.map(|x| x as usize);
        let mut flag = vec![false; w * h];
        if let Some(needle) = &self.needle {
            let triangles = needle
                .vertices_mm
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]]);
            sim_core::fluoro::render::mark_projected_edges(projection, triangles, &mut flag, w, h);
        }
        flag
    }

    /// Transmission as the displayed frame samples it: pixel centres, and `n x n` stratified
    /// samples (`settings.supersample`, the CPU's positions) averaged at the
    /// [`GpuFluoroRenderer::needle_edge_pixels`]. The samples come from a second needle,
    /// L-buffer and resolve pass over the flagged pixels' bounding box at `n` times the
    /// resolution. Unlike the CPU, anatomy silhouettes are not supersampled and
    /// `settings.adaptive = false` supersamples only near the needle too. With
    /// [`GpuFluoroRenderer::caching`] and no iodine, a call with the same projection, energy,
    /// supersampling and needle as the previous one returns its result without GPU work.
    pub fn render_transmission_supersampled(
        &mut self,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<GpuTransmission, FluoroGpuError> {
        let model = SpectralModel::new(settings.energy)?;
        self.timings = FrameTimings::default();
        let key = FrameKey {
            projection: *projection,
            energy: settings.energy,
            supersample: settings.supersample,
            needle_generation: self.needle_generation,
        };
        if self.caching && iodine.is_none() {
            if let Some((k, t)) = &self.last_frame {
                if *k == key {
                    self.timings.frame_reused = true;
                    self.timings.geometry_reused = true;
                    return Ok(t.clone());
                }
            }
        }
        self.last_frame = None;
        let full = PixelRect::full(projection);
        let started = Instant::now();
        let w = full.size[0] as usize;
        let flags = self.needle_edge_pixels(projection);
        let (mut lo, mut hi) = ([usize::MAX; 2], [0usize; 2]);
        for (q, _) in flags.iter().enumerate().filter(|(_, f)| **f) {
            let (i, j) = (q % w, q / w);
            lo = [lo[0].min(i), lo[1].min(j)];
            hi = [hi[0].max(i), hi[1].max(j)];
        }
        let n = settings.supersample.max(1) as usize;
        let sub = (n > 1 && lo[0] != usize::MAX).then(|| {
            let (bw, bh) = (hi[0] - lo[0] + 1, hi[1] - lo[1] + 1);
            let max_dim = self.ctx.limits.max_texture_dimension_2d as usize;
            let n = n.min(max_dim / bw.max(bh)).max(1);
            PixelRect {
                origin: [lo[0] as u32, lo[1] as u32],
                n: n as u32,
                size: [(bw * n) as u32, (bh * n) as u32],
            }
        });
        self.timings.supersample_ms += started.elapsed().as_secs_f64() * 1e3;
        // The full image and the supersampled region in one submission and one wait.
        let mut enc = self.encoder();
        let frame = self.begin_full(&mut enc, projection, &model, iodine);
        let mut pending = vec![frame.pending.clone()];
        if let Some(region) = sub {
            pending.push(self.encode_region(
                &mut enc,
                projection,
                &model,
                iodine,
                region,
                Passes::ALL,
                None,
            ));
        }
        let mut outs = self.submit_and_read(enc, &pending)?.into_iter();
        let main = outs.next().expect("full image read back");
        let mut t = self.end_full(frame, main, iodine);
        if let (Some(region), Some(sub)) = (sub, outs.next()) {
            let started = Instant::now();
            let sub = sub.data;
            let n = region.n as usize;
            let sw = region.size[0] as usize;
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    if !flags[j * w + i] {
                        continue;
                    }
                    let mut acc = 0f64;
                    for b in 0..n {
                        let row = ((j - lo[1]) * n + b) * sw + (i - lo[0]) * n;
                        acc += sub[row..row + n].iter().map(|&x| f64::from(x)).sum::<f64>();
                    }
                    t[j * w + i] = (acc / (n * n) as f64) as f32;
                }
            }
            self.timings.supersample_ms += started.elapsed().as_secs_f64() * 1e3;
        }
        let out = GpuTransmission {
            width: full.size[0],
            height: full.size[1],
            transmission: t,
        };
        if self.caching && iodine.is_none() {
            self.last_frame = Some((key, out.clone()));
        }
        Ok(out)
    }

    /// The displayed 8-bit frame: [`GpuFluoroRenderer::render_transmission_supersampled`], then
    /// sim-core's noise, automatic brightness, log mapping and shutters on the CPU. Same output
    /// type as `sim_core::fluoro::render_frame`.
    pub fn render_frame(
        &mut self,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<Image, FluoroGpuError> {
        let g = self.render_transmission_supersampled(projection, settings, iodine)?;
        let started = Instant::now();
        // The collimator mask depends on the detector and the blades only, not on the C-arm's
        // pose: kept across C-arm moves, and so is the image's storage (a 1024 x 1024 frame's
        // f64 transmission is 8 MB to allocate and fault in).
        let key = ExposureKey::of(projection);
        let image = match &mut self.finishing {
            Some((k, image)) if *k == key && image.transmission.len() == g.transmission.len() => {
                image
            }
            slot => {
                let (image_w, image_h) = (g.width, g.height);
                &mut slot
                    .insert((
                        key,
                        TransmissionImage {
                            width: image_w,
                            height: image_h,
                            transmission: vec![0.0; g.transmission.len()],
                            exposed: exposed_mask(projection),
                            supersampled_pixels: 0,
                        },
                    ))
                    .1
            }
        };
        for (out, &x) in image.transmission.iter_mut().zip(&g.transmission) {
            *out = f64::from(x);
        }
        let frame = sim_core::fluoro::render::finish_frame(image, settings);
        self.timings.finish_ms = started.elapsed().as_secs_f64() * 1e3;
        Ok(frame)
    }
}

/// Converts a GPU transmission into sim-core's [`TransmissionImage`] (exposure from the
/// projection's collimation, as the CPU decides it).
pub fn to_transmission_image(projection: &Projection, g: &GpuTransmission) -> TransmissionImage {
    let w = g.width as usize;
    TransmissionImage {
        width: g.width,
        height: g.height,
        transmission: g.transmission.iter().map(|&x| f64::from(x)).collect(),
        exposed: (0..g.transmission.len())
            .map(|p| projection.is_exposed([(p % w) as f64 + 0.5, (p / w) as f64 + 0.5]))
            .collect(),
        supersampled_pixels: 0,
    }
}
