//! GPU fluoroscopy: per-pixel path lengths by rasterising closed meshes into an L-buffer, then one
//! resolve pass for the basis depths, the iodine column and the spectral sum. The reference is
//! `sim_core::fluoro` (read its "Contract for the GPU renderer"); `render-worker/tests/fluoro.rs`
//! compares the two pixel by pixel, `tests/fluoro_cache.rs` checks every cache bit for bit.
//!
//! # Map
//! The modules form a DAG: `types` (shared constants, formats, pixel rectangles, errors) at the
//! bottom; `pipelines` (pipelines, target formats, per-size targets) on it; `anatomy` (the
//! shared read-only anatomy and its pipelines) on that; the passes `lbuffer`, `resolve`, `cache`
//! and `chords` on those, each owning its state in its own struct with methods taking explicit
//! inputs; this module's [`GpuFluoroRenderer`] on top, composing
//! them and orchestrating a frame.
//! - Construction, [`GpuAnatomy::new`] (`anatomy.rs`), once per scene and device: sim-core's
//!   [`nesting_plan`] decides which mesh adds its chord to which material and subtracts it from
//!   which container (CPU geometry, tested in sim-core); the drawn triangles are uploaded, the
//!   meshes that only touch the water-basis channel first; `Pipelines::new` (`pipelines.rs`)
//!   builds every pass. This is read-only (but for its pool of render targets no frame is
//!   using, `pipelines::TargetPool`) and shared behind an `Arc` by every renderer of that scene
//!   on that device ([`GpuFluoroRenderer::with_anatomy`]; a session server keeps one per
//!   region). Each renderer adds its own state: `LBuffer::new` (`lbuffer.rs`: needle, uniforms,
//!   culling boxes), the full image's geometric L-buffer, `ResolvePass` and `FrameCache`; the
//!   other targets it takes from the pool for each frame. [`GpuFluoroRenderer::new`] does both
//!   for one scene.
//! - Pass 1, geometric anatomy L-buffer (`lbuffer.rs`, `LBuffer::encode`; `lbuffer.wgsl`
//!   `fs_anatomy`, `fs_anatomy_scalar`): signed axial depths times per-mesh weights, additive
//!   blending, no depth test; independent of the needle. On a software adapter (lavapipe)
//!   the worker's own cores rasterise it and passes 2 and 3 instead (`raster`: the same sums
//!   in f64 from the scene's f64 triangles, uploaded into the targets the resolve reads),
//!   which is several times faster there; [`GpuFluoroRenderer::set_cpu_geometry`] switches
//!   them off.
//! - Pass 2, needle (`LBuffer::encode`; `fs_needle`): the needle's hull interval and exact
//!   chord per pixel.
//! - Pass 3, displaced anatomy (`LBuffer::encode`, `culled`; `fs_displaced`): the part of each
//!   chord the needle occupies, scissored to the needle's pixel box.
//! - Pass 4, resolve (`resolve.rs`, `ResolvePass::encode`; `resolve.wgsl`): sums the parts,
//!   clamps cancellous bone, adds iodine, and evaluates `T` (or reads the `ln T` table built by
//!   `ensure_spectral`); then `submit_and_read` reads the rows back. `encode_region` here
//!   records passes 1 to 4 for one region.
//! - Caches (`cache.rs`, `FrameCache`; `begin_full` / `end_full` here): between frames the
//!   geometric L-buffer, the last transmission (only the needle's old and new pixel rectangles
//!   are resolved again) and the last displayed frame are kept while what decides them stays.
//! - Validation (`chords.rs`, [`GpuFluoroRenderer::render_chords`]): the same passes in a
//!   per-material layout, resolved on the CPU.
//! - Drafts (`draft.rs`): a frame rendered by a renderer of the region's draft scene at half
//!   the resolution and doubled, the cheap preview of progressive frames.
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

mod anatomy;
mod cache;
mod chords;
pub mod draft;
mod lbuffer;
mod pipelines;
mod raster;
mod resolve;
mod types;

use sim_core::fluoro::nesting::NestedMesh;
#[cfg(doc)]
use sim_core::fluoro::nesting::nesting_plan;
use sim_core::fluoro::render::DetectorSignal;
use sim_core::fluoro::{
    EnergyModel, FluoroMaterial, Image, IodineField, Projection, RenderSettings, Scene,
    SpectralModel, TransmissionImage,
};
use sim_core::mesh::TriMesh;
use std::sync::Arc;
use std::time::Instant;

use crate::gpu::GpuContext;
use cache::{FrameCache, FrameKey, FullPlan};
use lbuffer::LBuffer;
use pipelines::{GeometryTargets, Targets};
use resolve::{ResolveInput, ResolvePass};
use types::{
    CHORD_CHANNELS, CHORD_PASSES, Layout, Passes, Pending, PixelRect, PixelRectOut, union_rect,
};

pub use anatomy::{AnatomyCache, GpuAnatomy};
pub use types::{CHANNELS, FluoroGpuError, FrameTimings, GpuTransmission};

/// The GPU fluoroscopy renderer of one scene: static anatomy uploaded once (and shareable with
/// other renderers of the same scene, see [`GpuAnatomy`]), a needle that can move every frame.
pub struct GpuFluoroRenderer {
    ctx: GpuContext,
    /// The shared static anatomy (pipelines, nesting plan, drawn triangles).
    anatomy: Arc<GpuAnatomy>,
    /// The L-buffer passes' state: this renderer's needle, uniforms and culling boxes.
    lbuffer: LBuffer,
    /// Targets of the full image (0) and of the supersampled needle region (1) while a frame
    /// is recorded and read back; given back to the anatomy's pool when it ends
    /// (`release_targets`), except the full image's geometric L-buffer (`kept_geometry`).
    targets: [Option<Targets>; 2],
    /// The full image's geometric L-buffer between frames (what the geometry cache refers to).
    kept_geometry: Option<GeometryTargets>,
    /// The turn at the pool (`TargetPool::enter`) a frame of this renderer holds, from its
    /// first target to `release_targets`.
    admitted: Option<pipelines::Turn>,
    resolve: ResolvePass,
    cache: FrameCache,
    /// Bumped whenever the needle changes.
    needle_generation: u64,
    /// Use the caches (default `true`; `false` renders every frame from scratch, for the
    /// benchmark's before/after rows and the cache tests).
    pub caching: bool,
    /// Draw only the anatomy triangles that can reach the needle's pixel box or the
    /// supersampled region into them (default `true`; bit-identical either way, see
    /// `LBuffer::culled`).
    pub culling: bool,
    timings: FrameTimings,
    /// Iodine ray-march step as a fraction of the smallest voxel spacing (default 0.25).
    pub iodine_step_fraction: f64,
}

/// The full image between [`GpuFluoroRenderer::begin_full`] and
/// [`GpuFluoroRenderer::end_full`].
struct FullFrame {
    pending: Pending,
    plan: FullPlan,
    width: usize,
}

impl GpuFluoroRenderer {
    /// Uploads a scene: every non-steel entry is anatomy (nesting resolved once, here, by
    /// sim-core's [`nesting_plan`], see [`GpuAnatomy::new`]); the steel entries, if any, become
    /// the initial needle (see [`GpuFluoroRenderer::update_needle`]). The anatomy is this
    /// renderer's alone; [`GpuFluoroRenderer::with_anatomy`] shares one.
    pub fn new(ctx: &GpuContext, scene: &Scene) -> Result<GpuFluoroRenderer, FluoroGpuError> {
        let mut r = GpuFluoroRenderer::with_anatomy(GpuAnatomy::new(ctx, scene)?);
        let steel: Vec<[[f64; 3]; 3]> = scene
            .entries()
            .iter()
            .filter(|e| e.material == FluoroMaterial::Steel)
            .flat_map(|e| e.bvh.triangles_mm().iter().copied())
            .collect();
        r.set_needle_soup(&steel);
        Ok(r)
    }

    /// A renderer drawing `anatomy` (on the anatomy's device), no needle yet. Every renderer of
    /// the same anatomy reads its buffers and pipelines and shares its pool of targets; what this
    /// one allocates is its own needle, uniforms, the full image's geometric L-buffer (sized on
    /// the first frame) and caches. Its frames are those of
    /// a renderer made by [`GpuFluoroRenderer::new`] from the same scene, bit for bit.
    pub fn with_anatomy(anatomy: Arc<GpuAnatomy>) -> GpuFluoroRenderer {
        let ctx = anatomy.ctx.clone();
        GpuFluoroRenderer {
            lbuffer: LBuffer::new(Arc::clone(&anatomy)),
            targets: [None, None],
            kept_geometry: None,
            admitted: None,
            resolve: ResolvePass::new(&ctx),
            cache: FrameCache::default(),
            needle_generation: 0,
            caching: true,
            culling: true,
            timings: FrameTimings::default(),
            iodine_step_fraction: 0.25,
            anatomy,
            ctx,
        }
    }

    /// Whether the L-buffer passes of transmission frames (anatomy, needle, displaced; full
    /// image and supersampled region) are rasterised on the CPU (`raster`): on a software
    /// adapter, unless switched off with [`GpuFluoroRenderer::set_cpu_geometry`].
    pub fn cpu_geometry(&self) -> bool {
        self.lbuffer.cpu_geometry && self.anatomy.cpu.is_some()
    }

    /// Switches the CPU geometric pass off (`false`: the adapter draws every pass) or back on
    /// where the anatomy has it. Forgets the kept geometric L-buffer, so that the next frame
    /// draws it the chosen way.
    pub fn set_cpu_geometry(&mut self, on: bool) {
        if self.lbuffer.cpu_geometry != on {
            self.lbuffer.cpu_geometry = on;
            self.cache = FrameCache::default();
        }
    }

    /// The static anatomy this renderer draws (shared with the renderers made from it).
    pub fn anatomy(&self) -> &Arc<GpuAnatomy> {
        &self.anatomy
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
        self.anatomy.drawn()
    }

    /// Number of anatomy meshes drawn (meshes that add nothing after nesting are dropped).
    pub fn drawn_meshes(&self) -> usize {
        self.anatomy.meshes.len()
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
        self.lbuffer.set_needle(&self.ctx.device, &[]);
        self.needle_generation += 1;
    }

    fn set_needle_soup(&mut self, tris: &[[[f64; 3]; 3]]) {
        self.needle_generation += 1;
        self.lbuffer.set_needle(&self.ctx.device, tris);
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
    /// scratch, see `cache::Resolved`).
    pub fn render_transmission(
        &mut self,
        projection: &Projection,
        energy: &EnergyModel,
        iodine: Option<&IodineField>,
    ) -> Result<GpuTransmission, FluoroGpuError> {
        self.framed(|r| r.transmission_in_frame(projection, energy, iodine))
    }

    fn transmission_in_frame(
        &mut self,
        projection: &Projection,
        energy: &EnergyModel,
        iodine: Option<&IodineField>,
    ) -> Result<GpuTransmission, FluoroGpuError> {
        let model = SpectralModel::new(*energy)?;
        self.timings = FrameTimings::default();
        let mut enc = self.encoder();
        let full = self.begin_full(&mut enc, projection, &model, iodine)?;
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
        if self.lbuffer.has_needle() {
            let triangles = self
                .lbuffer
                .needle_vertices_mm()
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
        self.framed(|r| r.supersampled_in_frame(projection, settings, iodine))
    }

    fn supersampled_in_frame(
        &mut self,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<GpuTransmission, FluoroGpuError> {
        let model = SpectralModel::new(settings.energy)?;
        self.timings = FrameTimings::default();
        let key = self.frame_key(projection, settings);
        if self.caching && iodine.is_none() {
            if let Some(t) = self.cache.frame(&key) {
                self.timings.frame_reused = true;
                self.timings.geometry_reused = true;
                return Ok(t.clone());
            }
        }
        self.cache.forget_frame();
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
        let frame = self.begin_full(&mut enc, projection, &model, iodine)?;
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
            )?);
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
            self.cache.keep_frame(key, out.clone());
        }
        Ok(out)
    }

    /// What decides the displayed transmission of a frame of `projection` (see [`FrameKey`]).
    fn frame_key(&self, projection: &Projection, settings: &RenderSettings) -> FrameKey {
        FrameKey {
            projection: *projection,
            energy: settings.energy,
            supersample: settings.supersample,
            needle_generation: self.needle_generation,
        }
    }

    /// Whether a frame of `projection` would find its geometric L-buffer kept (the C-arm has not
    /// moved since the last frame: only the needle's pixels, or nothing, are drawn again).
    pub fn geometry_cached(&self, projection: &Projection) -> bool {
        self.caching && self.cache.holds_geometry_of(projection)
    }

    /// Renders ahead, into the caches, what a frame of `projection` without iodine needs (the
    /// supersampled transmission and the exposure mask), so that a later
    /// [`GpuFluoroRenderer::render_frame`] with the same projection, energy, supersampling and
    /// needle costs only the noise and the display; its frame is the same bit for bit (the
    /// caches' invariant). Without [`GpuFluoroRenderer::caching`] it does nothing.
    pub fn prefetch(
        &mut self,
        projection: &Projection,
        settings: &RenderSettings,
    ) -> Result<(), FluoroGpuError> {
        if !self.caching {
            return Ok(());
        }
        self.render_transmission_supersampled(projection, settings, None)?;
        self.cache.exposure_mask(projection);
        Ok(())
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
        // A new shot of the kept transmission: its kept detector signal (scatter, glare, the
        // receptor's blur) is the one this frame would make, so only the noise and the display
        // are redone (the same frame bit for bit: `DetectorSignal`).
        let key = self.frame_key(projection, settings);
        let keeps = self.caching
            && iodine.is_none()
            && (settings.scatter.is_some() || settings.receptor.is_some());
        if keeps && self.timings.frame_reused {
            if let Some(signal) = self.cache.signal(&key, settings) {
                let frame = signal.finish(settings);
                self.timings.signal_reused = true;
                self.timings.finish_ms = started.elapsed().as_secs_f64() * 1e3;
                return Ok(frame);
            }
        }
        // The collimator mask depends on the detector and the blades only, not on the C-arm's
        // pose: kept across C-arm moves. The f32 transmission is finished as it is, without an
        // f64 copy (8 MB at 1024 x 1024 to allocate and fault in, and to hold per session).
        let exposed = self.cache.exposure_mask(projection);
        let frame = if keeps {
            let signal =
                DetectorSignal::of_f32(g.width, g.height, &g.transmission, exposed, settings);
            let frame = signal.finish(settings);
            self.cache.keep_signal(key, signal);
            frame
        } else {
            sim_core::fluoro::render::finish_frame_f32(
                g.width,
                g.height,
                &g.transmission,
                exposed,
                settings,
            )
        };
        self.timings.finish_ms = started.elapsed().as_secs_f64() * 1e3;
        Ok(frame)
    }
}

/// A renderer dropped in the middle of a frame (a panic while rendering) gives its turn back;
/// the targets it held are dropped (see `GpuFluoroRenderer::release_targets`).
impl Drop for GpuFluoroRenderer {
    fn drop(&mut self) {
        self.release_targets(false);
    }
}

/// Recording a frame: the passes of one region, the caches of the full image, the chords.
impl GpuFluoroRenderer {
    /// Makes `targets[ri]` `size` samples for this frame. The full image's geometric L-buffer is
    /// the one kept from the last frame when its size matches (another drops what the caches
    /// kept of it); everything else comes from the anatomy's pool. `Interrupted` where newer
    /// input made the frame obsolete while it waited for its turn (`TargetPool::enter`).
    fn ensure_targets(&mut self, ri: usize, size: [u32; 2]) -> Result<(), FluoroGpuError> {
        if self.targets[ri].as_ref().is_some_and(|t| t.size() == size) {
            return Ok(());
        }
        self.release_target(ri, true);
        if self.admitted.is_none() {
            let refining =
                crate::priority::Priority::of_this_thread() == crate::priority::Priority::Refining;
            let turn = self
                .anatomy
                .pool
                .enter(refining, &crate::interrupt::Interrupt::of_this_thread());
            self.admitted = Some(turn.ok_or(FluoroGpuError::Interrupted)?);
        }
        let pool = &self.anatomy.pool;
        let device = &self.ctx.device;
        let kept = match ri {
            0 => self.kept_geometry.take().filter(|g| g.size == size),
            _ => None,
        };
        let geometry = kept.unwrap_or_else(|| {
            if ri == 0 {
                self.cache.targets_replaced();
            }
            pool.take_geometry(device, size)
        });
        self.targets[ri] = Some(Targets {
            geometry,
            frame: pool.take_frame(device, size),
        });
        Ok(())
    }

    /// Ends a frame's hold on `targets[ri]`: the full image keeps its geometric L-buffer, the
    /// rest goes back to the pool if `pool` (else it is dropped).
    fn release_target(&mut self, ri: usize, pool: bool) {
        let Some(t) = self.targets[ri].take() else {
            return;
        };
        let geometry = if ri == 0 {
            self.kept_geometry = Some(t.geometry);
            None
        } else {
            Some(t.geometry)
        };
        if pool {
            self.anatomy.pool.give_back(geometry, t.frame);
        }
    }

    /// Runs one frame, `frame`, then ends it (`release_targets`), whether it succeeded or not:
    /// every public rendering call goes through here.
    fn framed<T>(
        &mut self,
        frame: impl FnOnce(&mut Self) -> Result<T, FluoroGpuError>,
    ) -> Result<T, FluoroGpuError> {
        let result = frame(self);
        // An interrupted frame stopped before anything was submitted: its targets are clean.
        self.release_targets(matches!(result, Ok(_) | Err(FluoroGpuError::Interrupted)));
        result
    }

    /// Ends a frame (see [`GpuFluoroRenderer::release_target`]) and its turn at the pool. A
    /// frame that failed (`completed` false) drops its frame targets instead of pooling them: a
    /// failed read-back can leave a read-back buffer mapped, which would fail the next frame of
    /// whichever renderer took it.
    fn release_targets(&mut self, completed: bool) {
        (0..self.targets.len()).for_each(|ri| self.release_target(ri, completed));
        if let Some(turn) = self.admitted.take() {
            self.anatomy.pool.leave(turn);
        }
    }

    /// Records the passes of `passes`, then the resolve over one region, or (with `previous`,
    /// the needle rectangle of the previous frame in the same targets) only over the union of
    /// that rectangle and the needle's new one, and the copy of the resolved rows (whole rows
    /// of the region) to the region's read-back buffer.
    #[expect(clippy::too_many_arguments, reason = "one private recording step")]
    fn encode_region(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        projection: &Projection,
        model: &SpectralModel,
        iodine: Option<&IodineField>,
        region: PixelRect,
        passes: Passes,
        previous: Option<Option<[u32; 4]>>,
    ) -> Result<Pending, FluoroGpuError> {
        let started = Instant::now();
        let ri = region.index();
        let size = region.size;
        self.ensure_targets(ri, size)?;
        let t = self.targets[ri].as_ref().expect("targets");
        let needle_rect = self.lbuffer.encode(
            &self.ctx,
            &self.anatomy.pipelines,
            t,
            enc,
            projection,
            Layout::Transmission,
            passes,
            region,
            self.culling,
        )?;
        let rect = match previous {
            None => [0, 0, size[0], size[1]],
            Some(old) => match union_rect(old, needle_rect) {
                Some(r) => r,
                // No needle then or now: nothing to resolve.
                None => {
                    return Ok(Pending {
                        ri,
                        rows: 0..0,
                        cols: 0..0,
                        bytes: 0,
                        needle_rect,
                    });
                }
            },
        };
        let input = ResolveInput {
            projection,
            model,
            iodine,
            region,
            rect,
            needle_rect,
            has_needle: self.lbuffer.has_needle(),
            cortical_shell_mm: self.anatomy.cortical_shell_mm,
            iodine_step_fraction: self.iodine_step_fraction,
        };
        let bytes = self
            .resolve
            .encode(&self.ctx, &self.anatomy.pipelines, t, enc, &input);
        self.timings.resolved_samples += u64::from(rect[2]) * u64::from(rect[3]);
        self.timings.encode_ms += started.elapsed().as_secs_f64() * 1e3;
        Ok(Pending {
            ri,
            rows: rect[1]..rect[1] + rect[3],
            cols: rect[0]..rect[0] + rect[2],
            bytes,
            needle_rect,
        })
    }

    /// Submits `enc` once, waits, and reads back every pending region.
    fn submit_and_read(
        &mut self,
        enc: wgpu::CommandEncoder,
        pending: &[Pending],
    ) -> Result<Vec<PixelRectOut>, FluoroGpuError> {
        resolve::submit_and_read(&self.ctx, &self.targets, enc, pending, &mut self.timings)
    }

    /// Records the full image's passes and resolve into `enc`, from the caches where they
    /// apply; [`GpuFluoroRenderer::end_full`] completes it after the read-back.
    fn begin_full(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        projection: &Projection,
        model: &SpectralModel,
        iodine: Option<&IodineField>,
    ) -> Result<FullFrame, FluoroGpuError> {
        let full = PixelRect::full(projection);
        self.ensure_targets(0, full.size)?;
        let plan = self
            .cache
            .plan_full(self.caching, projection, model.model, iodine.is_some());
        self.timings.geometry_reused = !plan.geometry;
        let pending = self.encode_region(
            enc,
            projection,
            model,
            iodine,
            full,
            plan.passes(),
            plan.previous_needle_rect(),
        )?;
        Ok(FullFrame {
            pending,
            plan,
            width: full.size[0] as usize,
        })
    }

    /// The full-image transmission from its read-back `out`, kept for the next frame.
    fn end_full(
        &mut self,
        frame: FullFrame,
        out: PixelRectOut,
        iodine: Option<&IodineField>,
    ) -> Vec<f32> {
        self.cache
            .end_full(self.caching, frame.plan, out, frame.width, iodine.is_some())
    }

    /// Per-pixel chord length per material, mm, at pixel centres (row-major, channels in
    /// [`FluoroMaterial::index`] order): the GPU counterpart of `sim_core::fluoro::render_chords`.
    /// Validation path: four L-buffer passes (13 channels: 9 soft-tissue chords net of the
    /// needle, cortical and cancellous geometric chords and their displaced parts), read back and
    /// resolved on the CPU in the CPU reference's order (clamp, then remove the needle).
    pub fn render_chords(
        &mut self,
        projection: &Projection,
    ) -> Result<Vec<[f32; CHANNELS]>, FluoroGpuError> {
        self.framed(|r| r.chords_in_frame(projection))
    }

    fn chords_in_frame(
        &mut self,
        projection: &Projection,
    ) -> Result<Vec<[f32; CHANNELS]>, FluoroGpuError> {
        let [w, h] = projection.detector_pixels.map(|x| x as usize);
        let mut raw = vec![[0f32; CHORD_CHANNELS]; w * h];
        let mut steel = Vec::new();
        // The geometric part is in axial depth: times |d| / (row_w . d) along each pixel's ray
        // (as the resolve does on the GPU).
        let scale = chords::axial_to_chord(projection);
        for pass in 0..CHORD_PASSES {
            let mut enc = self.encoder();
            let full = PixelRect::full(projection);
            let passes = Passes {
                needle: pass == 0,
                ..Passes::ALL
            };
            self.ensure_targets(0, full.size)?;
            let t = self.targets[0].as_ref().expect("targets");
            self.lbuffer.encode(
                &self.ctx,
                &self.anatomy.pipelines,
                t,
                &mut enc,
                projection,
                Layout::Chords(pass),
                passes,
                full,
                self.culling,
            )?;
            self.cache
                .geometry_holds((*projection, Layout::Chords(pass)));
            self.ctx.queue.submit([enc.finish()]);
            let has_needle = self.lbuffer.has_needle();
            chords::read_pass(&self.ctx, t, pass, has_needle, &scale, &mut raw, &mut steel)?;
        }
        Ok(chords::resolve_chords(
            &raw,
            &steel,
            self.anatomy.cortical_shell_mm,
        ))
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
