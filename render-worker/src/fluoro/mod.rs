//! GPU fluoroscopy: per-pixel path lengths by rasterising closed meshes into an L-buffer, then one
//! resolve pass for nesting, basis depths, the iodine column and the spectral sum. The reference
//! is `sim_core::fluoro` (read its "Contract for the GPU renderer"); tests in
//! `render-worker/tests/fluoro.rs` compare the two pixel by pixel.
//!
//! # Passes per frame
//! 1. **Anatomy L-buffer, geometric part**: every anatomy triangle is drawn without depth test
//!    or culling, with additive blending, into an `R32Float` target if its mesh is *scalar*
//!    (soft tissue in soft tissue: it only changes the water-basis channel, see
//!    [`DrawnMesh::is_scalar`]; about 80 % of the phantom's fragments) and into an
//!    `Rgba32Float` target otherwise (a one-channel fragment is the cheaper blend). A fragment adds
//!    `s (w - w_ref)` times the mesh's *geometric* weights, where `w = row_w . (point - source)`
//!    is the axial depth of the triangle's point on the sample's ray (the reciprocal of the
//!    fragment position's `w`, which the rasteriser interpolates exactly: `1 / w` is affine in
//!    screen space), `s = -1` on front faces (entering) and `+1` on back faces; summed over a
//!    closed mesh it is the mesh's chord times `(row_w . d) / |d|` for the sample's ray `d`, and
//!    the resolve multiplies by `|d| / (row_w . d)`. `w_ref` (the axial depth of the mesh's box
//!    centre) cancels in each entering/leaving pair and keeps the summed terms small, so f32
//!    cancellation stays near `ulp(mesh size)` instead of `ulp(source distance)`. The four
//!    channels of a frame are the water-basis and bone-basis `sum mu_60 L`, and the cortical and
//!    cancellous geometric chords (for the clamp); the one-channel target adds to the first. It
//!    does not depend on the needle. The fragment shader is a multiply-add: on lavapipe the
//!    pass is fragment bound (5 mm phantom, 1024 x 1024: 160 ms per frame with a ray-plane
//!    intersection per fragment, 90 ms with this).
//! 2. **Needle** (only when one is set): its triangles are drawn without depth test into a
//!    `Rg32Float` target with `Min` blending, holding the nearest entering and the farthest leaving
//!    distance (the needle's hull interval `[t0, t1]` on the pixel's ray), and into an `R32Float`
//!    target with additive blending, holding its exact chord (sum of leaving minus entering
//!    distances).
//! 3. **Anatomy L-buffer, displaced part** (only with a needle): the anatomy again, scissored to
//!    the needle's projected pixel box, into a second `Rgba32Float` target (cleared to zero): a
//!    fragment adds `s (clamp(t, t0, t1) - t0)` times the mesh's *displaced* weights, summing to
//!    the part of each chord the needle occupies (negative weights: the channels end up net of
//!    the needle). Only the triangles whose pixel bounding box meets the scissor box are drawn
//!    (see `culled`).
//! 4. **Resolve** (a fragment pass over one screen-covering triangle, scissored, writing a
//!    storage buffer): adds the L-buffer parts, then cancellous clamp, optical depths, iodine
//!    ray march and `T = sum_E w_E exp(-sum_b A_b R_b(E))`; on rays without steel or iodine,
//!    `ln T` comes from a table over (water depth, bone depth) instead (see `ensure_spectral`:
//!    < 2e-5 in `ln T`). The shader has four variants through two pipeline constants. Without
//!    the iodine march, for frames without a contrast field: lavapipe executes a skipped branch
//!    masked, which cost a quarter of the resolve (512 x 512 demo frame: GPU phase 24 ms to
//!    18 ms); both give bit-identical transmission where the column is zero (test in
//!    `render-worker/tests/fluoro.rs`). Without the needle's inputs (its chord and the displaced
//!    part, zero outside its pixel box), for every sample outside that box: the box is one
//!    scissored draw with them, the rest of the rectangle up to four draws without them (about
//!    5 ms of a 1024 x 1024 frame), and every sample is resolved by exactly one draw (storage
//!    writes of different draws are not ordered within a pass). As a fragment pass the resolve
//!    runs on lavapipe's rasteriser threads (as a compute kernel it ran on a separate thread
//!    pool after them; the fragment pass measured about 4 % faster per 1024 x 1024 frame).
//!
//! # Caches (sessions: the needle moves far more often than the C-arm)
//! With [`GpuFluoroRenderer::caching`] (the default) the renderer keeps, between frames, the
//! geometric L-buffer of the last projection (pass 1 is skipped while the C-arm stays), the last
//! full-image transmission without iodine (only the union of the needle's old and new pixel
//! boxes is resolved and read back: outside it every input of the resolve is unchanged), and the
//! last displayed transmission (a shot with nothing changed costs only the CPU's noise and
//! display). Each cached frame is bit-identical to a frame from scratch, and so is culling
//! (tests in `render-worker/tests/fluoro_cache.rs`). [`GpuFluoroRenderer::last_timings`] gives
//! the phases of the last frame.
//!
//! [`GpuFluoroRenderer::render_chords`] (validation) uses the same passes with per-material
//! channels, four L-buffer passes, resolved on the CPU.
//!
//! In the needle and displaced passes, `t` is the exact distance along the ray: the fragment's
//! pixel ray (from sim-core's [`Projection::gpu_ray_frame`]) meets the triangle's plane
//! (outward unit normal from an f64 cross product, passed flat) at `t = n.(v - s) |d| / n.d`, in
//! f32 (about `1e-4` mm at 1 m), and the sign of `n.d` says entering or leaving. (Interpolating
//! `vertex - source` instead lost 0.02 mm on the needle's long, thin side triangles seen nearly
//! edge-on.) The anatomy's triangles are not that thin, and its axial depths agree with the CPU
//! as closely as the plane did (sphere and phantom chord tests: worst 1.2e-3 mm).
//!
//! # Nesting
//! The CPU assigns each point of a ray to the highest-priority mesh containing it. An L-buffer
//! only sees per-mesh chords, so at construction every anatomy mesh gets its *direct container*
//! (the smallest mesh holding 90 % of points sampled just inside it; sampled with sim-core's BVH)
//! and the *effective* material of its interior (the highest priority on its chain of
//! containers; on equal priority the later entry wins, as on the CPU). A mesh adds its chord to
//! its effective material and subtracts it from its container's: for a laminar family of meshes
//! (every pair disjoint or nested) this is exactly the priority rule ("own chord minus the
//! chords of the meshes directly inside"). Meshes whose effective material equals their
//! container's add nothing and are not drawn. Partially overlapping meshes are *not* resolved by
//! priority: their overlap counts twice (the phantom's disjoint-mask structures touch with sub-
//! voxel gaps and overlaps, which the tests measure).
//!
//! The needle is subtracted from whatever holds it exactly when it is convex along each ray (a
//! straight shaft with a bevel is): its hull interval `[t0, t1]` is then its occupied segment.
//!
//! # Cancellous clamp
//! The CPU clamps the cancellous chord of each contiguous run of bone to
//! `[0, run - 2 x shell]`, then removes the needle. The L-buffer has only the pixel's totals, so
//! the GPU clamps the total cancellous chord to `[0, bone total - 2 x shell]`: identical for rays
//! through one run of bone, and for any ray where the CPU clamp does not bind (every valid
//! inset); weaker otherwise. In transmission frames the needle is removed from the bone before
//! the clamp's excess moves to cortex, which differs from the CPU only where the clamp binds on a
//! ray through the needle (`render_chords` follows the CPU's order exactly).
//!
//! # Differences from the CPU frame
//! - Sampling: [`GpuFluoroRenderer::render_frame`] supersamples the pixels within 1.5 pixels of
//!   the needle's projected edges exactly as the CPU (same flags, same `n x n` positions; a second
//!   set of passes over their bounding box at `n` times the resolution). The CPU also supersamples
//!   anatomy silhouettes (pixels whose neighbours' rays cross other meshes); the GPU takes their
//!   centre sample. `render_transmission` and `render_chords` sample pixel centres only, like
//!   sim-core's `render_chords`.
//! - Iodine: midpoint rule with steps of at most [`GpuFluoroRenderer::iodine_step_fraction`]
//!   voxels (the CPU integrates the trilinear field exactly).
//! - Display (automatic brightness, noise, log mapping, shutters) runs on the CPU with
//!   sim-core's own functions on the transmission read back from the GPU.

use bytemuck::{Pod, Zeroable};
use sim_core::fluoro::spectrum::UnknownKvp;
use sim_core::fluoro::{
    EnergyModel, FluoroMaterial, Image, IodineField, Projection, RenderSettings, Scene,
    SpectralModel, TransmissionImage,
};
use sim_core::material::MaterialClass;
use sim_core::mesh::TriMesh;
use std::time::Instant;

use thiserror::Error;
use wgpu::util::DeviceExt;

use crate::gpu::{GpuContext, GpuError};

/// Number of per-pixel chord channels [`GpuFluoroRenderer::render_chords`] returns (one per
/// [`FluoroMaterial`], in [`FluoroMaterial::index`] order).
pub const CHANNELS: usize = FluoroMaterial::COUNT;

/// Why the GPU renderer could not be built or could not render.
#[derive(Debug, Error)]
pub enum FluoroGpuError {
    /// Device-level failure (no adapter, readback).
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The device lacks a feature the L-buffer needs.
    #[error(
        "the GPU device lacks {0:?}, needed for additive blending into 32-bit float render targets"
    )]
    MissingFeature(wgpu::Features),
    /// The adapter cannot write storage buffers from fragment shaders (the resolve pass does).
    #[error("the GPU adapter lacks {0:?}, needed by the resolve pass")]
    MissingDownlevel(wgpu::DownlevelFlags),
    /// The requested tube voltage has no committed spectrum.
    #[error(transparent)]
    UnknownKvp(#[from] UnknownKvp),
}

/// Channels of the `Rgba32Float` L-buffer targets (the geometric one and the displaced one).
/// Transmission layout: (water-basis `sum mu_60 L`, bone-basis `sum mu_60 L`, both net of what
/// the needle displaces; cortical and cancellous geometric `L` for the clamp).
const SLOTS: usize = 4;

/// One anatomy mesh as the GPU draws it: its raw chord is added to `effective` and subtracted
/// from `container` (see the module doc's "Nesting").
#[derive(Debug, Clone, PartialEq)]
pub struct DrawnMesh {
    /// Index of the scene entry.
    pub entry: usize,
    /// Scene entry name.
    pub name: String,
    /// Effective material of its interior (after nesting).
    pub effective: FluoroMaterial,
    /// Effective material of its direct container, if any.
    pub container: Option<FluoroMaterial>,
    /// Box centre, mm (for the reference depth).
    centre_mm: [f64; 3],
}

impl DrawnMesh {
    /// Its geometric and displaced weights in `layout`: its own material's minus its
    /// container's (see the module doc's "Nesting").
    fn net_weights(&self, layout: Layout) -> ([f32; SLOTS], [f32; SLOTS]) {
        let (mut g, mut d) = slot_weights(self.effective, layout);
        if let Some(c) = self.container {
            let (gc, dc) = slot_weights(c, layout);
            for k in 0..SLOTS {
                g[k] -= gc[k];
                d[k] -= dc[k];
            }
        }
        (g, d)
    }

    /// Whether its transmission weights touch only the water-basis channel (soft tissue inside
    /// soft tissue): it is drawn into the one-channel target.
    fn is_scalar(&self) -> bool {
        self.net_weights(Layout::Transmission).0[1..]
            .iter()
            .all(|&x| x == 0.0)
    }
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Vertex {
    pos: [f32; 3],
    mesh: u32,
    /// Outward unit normal of the vertex's triangle (f64 cross product; zero if degenerate).
    normal: [f32; 3],
    pad: u32,
}

/// The three vertices of a triangle with its unit normal.
fn triangle_vertices(t: &[[f64; 3]; 3], mesh: u32) -> [Vertex; 3] {
    let (e1, e2) = (sub3(t[1], t[0]), sub3(t[2], t[0]));
    let c = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let len = norm3(c);
    let normal = if len > 0.0 {
        c.map(|x| (x / len) as f32)
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

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct ResolveUniform {
    p00: [f32; 4],
    step_u: [f32; 4],
    step_v: [f32; 4],
    source: [f32; 4],
    blades: [f32; 4],
    misc: [f32; 4],
    dims: [u32; 4],
    mu: [f32; 4],
    iod_origin: [f32; 4],
    iod_inv_spacing: [f32; 4],
    iod_dims: [u32; 4],
    lut_scale: [f32; 4],
    region: [f32; 4],
    full: [u32; 4],
    lut_dims: [u32; 4],
    rect: [u32; 4],
    row_w: [f32; 4],
}

struct Needle {
    bufs: MeshBuffers,
    centre_mm: [f64; 3],
    vertices_mm: Vec<[f64; 3]>,
}

struct MeshBuffers {
    vertices: wgpu::Buffer,
    indices: wgpu::Buffer,
    index_count: u32,
}

/// Triangles per culling chunk. Simulator choice: 32 keeps the per-projection box work at
/// 8 corners per 32 triangles while a needle box still draws only nearby chunks.
const CHUNK_TRIANGLES: usize = 32;

/// A run of consecutive anatomy triangles (in drawing order) and its bounding box, mm.
struct Chunk {
    first_vertex: u32,
    vertices: u32,
    lo: [f32; 3],
    hi: [f32; 3],
}

/// Render targets of one detector size.
struct Targets {
    size: [u32; 2],
    /// Geometric L-buffer (needle-independent): the non-scalar meshes in the transmission
    /// layout, every mesh in the chord layout.
    a: wgpu::Texture,
    /// Geometric L-buffer of the scalar meshes, transmission layout (water-basis channel).
    s: wgpu::Texture,
    /// Displaced part (zero outside the needle's pixel box).
    d: wgpu::Texture,
    hull: wgpu::Texture,
    chord: wgpu::Texture,
    out_t: wgpu::Buffer,
    /// The resolve's render target: it only sizes the pass (write mask empty; cleared, one byte
    /// per sample, and discarded); the output is `out_t`.
    resolve: wgpu::Texture,
    /// Kept mapped-readable copy of `out_t` (no allocation per frame).
    staging: wgpu::Buffer,
}

/// A rectangle of the detector sampled `n x n` per pixel: sample `(i, j)` of the region lies at
/// continuous pixel coordinates `origin + ((i, j) + 0.5) / n` (the CPU's stratified sub-pixel
/// positions). The full image is `origin 0, n 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Region {
    origin: [u32; 2],
    n: u32,
    /// Samples per axis (pixels x n).
    size: [u32; 2],
}

impl Region {
    fn full(p: &Projection) -> Region {
        Region {
            origin: [0, 0],
            n: 1,
            size: p.detector_pixels,
        }
    }

    /// Which set of targets and uniforms it uses.
    fn index(&self) -> usize {
        usize::from(self.n > 1)
    }
}

/// Spectral bins and the `ln T` table of one energy model, kept until the model changes.
struct SpectralTables {
    model: EnergyModel,
    bins: wgpu::Buffer,
    lut: wgpu::Buffer,
    lut_enabled: bool,
}

/// Size of the `ln T(A_water, A_bone)` table (columns, rows).
const LUT_DIMS: [usize; 2] = [512, 256];
/// Optical depths the table spans, from 0 (60 keV: 16 is 80 cm of soft tissue, 8 is 15 cm of
/// cortical bone); deeper pixels take the exact sum.
const LUT_MAX_DEPTH: [f64; 2] = [16.0, 8.0];

/// What [`GpuFluoroRenderer::render_transmission`] returns: the per-pixel transmission (pixel
/// centres, 0 behind the collimator), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuTransmission {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Transmission per pixel.
    pub transmission: Vec<f32>,
}

/// The GPU fluoroscopy renderer of one scene: static anatomy uploaded once, a needle that can
/// move every frame.
pub struct GpuFluoroRenderer {
    ctx: GpuContext,
    meshes: Vec<DrawnMesh>,
    anatomy: Option<MeshBuffers>,
    /// Runs of [`CHUNK_TRIANGLES`] consecutive anatomy triangles with their bounding boxes, for
    /// culling on the CPU.
    chunks: Vec<Chunk>,
    /// The scalar meshes (see [`DrawnMesh::is_scalar`]) come first: the number of their chunks.
    scalar_chunks: usize,
    /// Each chunk's pixel bounding box under one projection (see `culled`).
    chunk_boxes: Option<(Projection, Vec<[f32; 4]>)>,
    needle: Option<Needle>,
    needle_pipeline: wgpu::RenderPipeline,
    anatomy_pipeline: wgpu::RenderPipeline,
    anatomy_scalar_pipeline: wgpu::RenderPipeline,
    displaced_pipeline: wgpu::RenderPipeline,
    /// The resolve, `[iodine][needle]`: without and with the iodine ray march, and without
    /// and with the needle's inputs (drawn over the needle's pixel box only); one bind group
    /// layout (`resolve_layout`) serves all four.
    resolve_pipelines: [[wgpu::RenderPipeline; 2]; 2],
    resolve_layout: wgpu::BindGroupLayout,
    /// Uniforms of the full image (0) and of the supersampled needle region (1).
    view_buf: [wgpu::Buffer; 2],
    resolve_buf: [wgpu::Buffer; 2],
    weights_buf: wgpu::Buffer,
    empty_iodine: wgpu::Texture,
    targets: [Option<Targets>; 2],
    spectral: Option<SpectralTables>,
    cortical_shell_mm: f64,
    /// What the full-image geometric L-buffer (`targets[0].a`) holds, if anything.
    geo_key: Option<(Projection, Layout)>,
    /// The last full-image transmission resolve without iodine (see [`Resolved`]).
    resolved: Option<Resolved>,
    /// Bumped whenever the needle changes.
    needle_generation: u64,
    /// The last displayed-frame transmission and what decided it.
    last_frame: Option<(FrameKey, GpuTransmission)>,
    /// The last frame's input to sim-core's finishing step, reused while the detector and the
    /// collimator stay (its exposure mask and its storage).
    finishing: Option<(ExposureKey, TransmissionImage)>,
    /// Use the caches (default `true`; `false` renders every frame from scratch, for the
    /// benchmark's before/after rows and the cache tests).
    pub caching: bool,
    /// Draw only the anatomy triangles that can reach the needle's pixel box or the
    /// supersampled region into them (default `true`; bit-identical either way, see
    /// `culled`).
    pub culling: bool,
    timings: FrameTimings,
    /// Iodine ray-march step as a fraction of the smallest voxel spacing (default 0.25).
    pub iodine_step_fraction: f64,
}

/// The full-image transmission of the last resolve: for which projection and energy model, the
/// needle's pixel rectangle then (where the displaced pass and the steel wrote), and the values.
/// Outside the union of that rectangle and the next frame's, every input of the resolve is the
/// same (same geometric L-buffer, no displaced part, no steel), so only that union is resolved
/// and read back again, and the result is bit-identical to a frame from scratch.
struct Resolved {
    projection: Projection,
    model: EnergyModel,
    needle_rect: Option<[u32; 4]>,
    transmission: Vec<f32>,
}

/// Everything that decides [`GpuFluoroRenderer::render_transmission_supersampled`] without
/// iodine.
#[derive(Debug, Clone, Copy, PartialEq)]
struct FrameKey {
    projection: Projection,
    energy: EnergyModel,
    supersample: u32,
    needle_generation: u64,
}

/// Wall-clock phases of the last frame rendered by [`GpuFluoroRenderer::render_frame`] (or the
/// transmission calls), ms. GPU work is measured from submit to the end of the wait for the
/// read-back (lavapipe runs it on the CPU); `cpu_*` are work on the calling thread.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameTimings {
    /// Recording passes and uploading uniforms.
    pub encode_ms: f64,
    /// Submit until the read-back buffer is mapped (rasterising, resolve, copy).
    pub gpu_ms: f64,
    /// Copying the mapped read-back into the frame.
    pub readback_ms: f64,
    /// Needle-edge flags and averaging the supersampled region.
    pub supersample_ms: f64,
    /// sim-core's finishing step (noise, brightness, tone map, shutters).
    pub finish_ms: f64,
    /// Transmission samples resolved on the GPU (full image and supersampled region).
    pub resolved_samples: u64,
    /// Whether the full-image geometric L-buffer was reused.
    pub geometry_reused: bool,
    /// Whether the whole transmission was reused (nothing changed).
    pub frame_reused: bool,
}

impl FrameTimings {
    /// Sum of the phases, ms.
    pub fn total_ms(&self) -> f64 {
        self.encode_ms + self.gpu_ms + self.readback_ms + self.supersample_ms + self.finish_ms
    }
}

const FMT_A: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
/// The scalar meshes' geometric L-buffer: the water-basis channel only. On lavapipe a fragment
/// blended into one float channel costs about 0.6 of one blended into four (5 mm phantom,
/// 1024 x 1024: 71 against 90 ms with every mesh in one or in four channels), and about 80 % of
/// the phantom's fragments are soft tissue.
const FMT_SCALAR: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// The resolve pass's colour target (write mask empty: it only sets the pass's size).
const FMT_RESOLVE: wgpu::TextureFormat = wgpu::TextureFormat::R8Unorm;
const FMT_HULL: wgpu::TextureFormat = wgpu::TextureFormat::Rg32Float;
const FMT_CHORD: wgpu::TextureFormat = wgpu::TextureFormat::R32Float;
/// Marker of "no needle on this pixel" in the hull target (as in the shader).
const NO_NEEDLE: f64 = 1.0e30;

fn additive() -> wgpu::BlendState {
    let c = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Add,
    };
    wgpu::BlendState { color: c, alpha: c }
}

fn minimum() -> wgpu::BlendState {
    let c = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::One,
        dst_factor: wgpu::BlendFactor::One,
        operation: wgpu::BlendOperation::Min,
    };
    wgpu::BlendState { color: c, alpha: c }
}

fn target(format: wgpu::TextureFormat, blend: wgpu::BlendState) -> Option<wgpu::ColorTargetState> {
    Some(wgpu::ColorTargetState {
        format,
        blend: Some(blend),
        write_mask: wgpu::ColorWrites::ALL,
    })
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

/// Chord-layout channels: 0..11, tissue `i`'s chord net of the needle (for the two bone
/// classes: geometric); 11 and 12, the cortical and cancellous parts the needle displaces.
const CHORD_CHANNELS: usize = CHANNELS + 1;
/// L-buffer passes for [`GpuFluoroRenderer::render_chords`], four channels each.
const CHORD_PASSES: usize = CHORD_CHANNELS.div_ceil(SLOTS);
const CORTICAL: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::CorticalBone);
const CANCELLOUS: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::Cancellous);

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

/// Which passes [`GpuFluoroRenderer::encode_lbuffer`] records.
#[derive(Debug, Clone, Copy)]
struct Passes {
    geometry: bool,
    needle: bool,
    displaced: bool,
}

impl Passes {
    const ALL: Passes = Passes {
        geometry: true,
        needle: true,
        displaced: true,
    };
}

/// The slot layout of one pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Layout {
    Transmission,
    Chords(usize),
}

fn slot_weights(m: FluoroMaterial, layout: Layout) -> ([f32; SLOTS], [f32; SLOTS]) {
    match layout {
        Layout::Transmission => transmission_weights(m),
        Layout::Chords(pass) => chord_weights(m, pass),
    }
}

fn sub3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm3(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

fn soup_volume(tris: &[[[f64; 3]; 3]]) -> f64 {
    tris.iter()
        .map(|[a, b, c]| {
            (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0
        })
        .sum()
}

fn soup_box(tris: &[[[f64; 3]; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for t in tris {
        for v in t {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
    }
    (lo, hi)
}

/// Up to 48 points just inside the mesh (triangle centroids moved 0.01 mm against the outward
/// normal), spread over its triangles.
fn inner_points(tris: &[[[f64; 3]; 3]]) -> Vec<[f64; 3]> {
    let n = tris.len().min(48);
    (0..n)
        .filter_map(|k| {
            let [a, b, c] = tris[k * tris.len() / n];
            let (e1, e2) = (sub3(b, a), sub3(c, a));
            let nrm = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            let len = norm3(nrm);
            (len > 0.0)
                .then(|| std::array::from_fn(|i| (a[i] + b[i] + c[i]) / 3.0 - 0.01 * nrm[i] / len))
        })
        .collect()
}

impl GpuFluoroRenderer {
    /// Uploads a scene: every non-steel entry is anatomy (nesting resolved once, here); the steel
    /// entries, if any, become the initial needle (see [`GpuFluoroRenderer::update_needle`]).
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
        let entries = scene.entries();
        let anatomy: Vec<usize> = (0..entries.len())
            .filter(|&e| entries[e].material != FluoroMaterial::Steel)
            .collect();
        // Containment: direct container = smallest containing mesh.
        let volumes: Vec<f64> = entries
            .iter()
            .map(|e| soup_volume(e.bvh.triangles_mm()).abs())
            .collect();
        let mut container: Vec<Option<usize>> = vec![None; entries.len()];
        for &m in &anatomy {
            let pts = inner_points(entries[m].bvh.triangles_mm());
            if pts.is_empty() {
                continue;
            }
            let (lo, hi) = soup_box(entries[m].bvh.triangles_mm());
            container[m] = anatomy
                .iter()
                .copied()
                .filter(|&c| c != m && volumes[c] > volumes[m])
                .filter(|&c| {
                    let Some((clo, chi)) = entries[c].bvh.bounds_mm() else {
                        return false;
                    };
                    if (0..3).any(|a| lo[a] < clo[a] || hi[a] > chi[a]) {
                        return false;
                    }
                    let inside = pts.iter().filter(|&&p| entries[c].bvh.contains(p)).count();
                    inside * 10 >= pts.len() * 9
                })
                .min_by(|&a, &b| volumes[a].total_cmp(&volumes[b]));
        }
        // Effective material: highest (priority, index) on the chain of containers.
        let effective = |m: usize| {
            let mut best = m;
            let mut cur = container[m];
            while let Some(c) = cur {
                if (entries[c].priority, c) > (entries[best].priority, best) {
                    best = c;
                }
                cur = container[c];
            }
            entries[best].material
        };
        // Drawn meshes; those whose transmission weights (own minus container's) have only the
        // water-basis channel (soft tissue in soft tissue) first, for the scalar pass.
        let mut drawn: Vec<DrawnMesh> = Vec::new();
        for &m in &anatomy {
            let eff = effective(m);
            let cont = container[m].map(effective);
            if cont == Some(eff) {
                continue; // Adds and removes the same material: invisible.
            }
            let (lo, hi) = soup_box(entries[m].bvh.triangles_mm());
            drawn.push(DrawnMesh {
                entry: m,
                name: entries[m].name.clone(),
                effective: eff,
                container: cont,
                centre_mm: std::array::from_fn(|a| 0.5 * (lo[a] + hi[a])),
            });
        }
        drawn.sort_by_cached_key(|d| !d.is_scalar());
        let scalar_meshes = drawn.partition_point(DrawnMesh::is_scalar);
        let add = |vertices: &mut Vec<Vertex>, ids: std::ops::Range<usize>| {
            for id in ids {
                let tris = entries[drawn[id].entry].bvh.triangles_mm();
                vertices.extend(tris.iter().flat_map(|t| triangle_vertices(t, id as u32)));
            }
        };
        let mut vertices: Vec<Vertex> = Vec::new();
        add(&mut vertices, 0..scalar_meshes);
        let mut chunks = chunks_of(&vertices, 0);
        let scalar_chunks = chunks.len();
        let scalar_vertices = vertices.len();
        add(&mut vertices, scalar_meshes..drawn.len());
        // Chunks never straddle the two groups.
        chunks.extend(chunks_of(&vertices, scalar_vertices));
        let meshes = drawn;
        let anatomy_bufs = (!vertices.is_empty()).then(|| upload(device, &vertices));
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("fluoro lbuffer"),
            source: wgpu::ShaderSource::Wgsl(include_str!("lbuffer.wgsl").into()),
        });
        let resolve_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("fluoro resolve"),
            source: wgpu::ShaderSource::Wgsl(include_str!("resolve.wgsl").into()),
        });
        let vertex_layout = wgpu::VertexBufferLayout {
            array_stride: std::mem::size_of::<Vertex>() as u64,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &wgpu::vertex_attr_array![0 => Float32x3, 1 => Uint32, 2 => Float32x3],
        };
        // WGSL's fragment position w is 1 / w_clip; wgpu's D3D12 backend passes w_clip
        // (gfx-rs/wgpu#4963), so the geometric pass is told which it gets.
        let position_w_is_reciprocal = ctx.summary.backend != "dx12";
        let raster =
            |label: &str, vs: &str, fs: &str, targets: &[Option<wgpu::ColorTargetState>]| {
                device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                    label: Some(label),
                    layout: None,
                    vertex: wgpu::VertexState {
                        module: &module,
                        entry_point: Some(vs),
                        compilation_options: Default::default(),
                        buffers: &[Some(vertex_layout.clone())],
                    },
                    primitive: wgpu::PrimitiveState {
                        topology: wgpu::PrimitiveTopology::TriangleList,
                        strip_index_format: None,
                        // Outward-wound (CCW seen from outside) triangles facing the source appear
                        // clockwise in clip space, because the detector's (u, up) frame has
                        // u x up = +n, pointing away from the source.
                        front_face: wgpu::FrontFace::Cw,
                        cull_mode: None,
                        unclipped_depth: false,
                        polygon_mode: wgpu::PolygonMode::Fill,
                        conservative: false,
                    },
                    depth_stencil: None,
                    multisample: wgpu::MultisampleState::default(),
                    fragment: Some(wgpu::FragmentState {
                        module: &module,
                        entry_point: Some(fs),
                        compilation_options: wgpu::PipelineCompilationOptions {
                            constants: &[(
                                "position_w_is_reciprocal",
                                f64::from(u8::from(position_w_is_reciprocal)),
                            )],
                            ..Default::default()
                        },
                        targets,
                    }),
                    multiview_mask: None,
                    cache: None,
                })
            };
        let needle_pipeline = raster(
            "fluoro needle",
            "vs_needle",
            "fs_needle",
            &[target(FMT_HULL, minimum()), target(FMT_CHORD, additive())],
        );
        let anatomy_pipeline = raster(
            "fluoro anatomy",
            "vs_geometry",
            "fs_anatomy",
            &[target(FMT_A, additive())],
        );
        let anatomy_scalar_pipeline = raster(
            "fluoro anatomy, water-basis channel",
            "vs_geometry",
            "fs_anatomy_scalar",
            &[target(FMT_SCALAR, additive())],
        );
        let displaced_pipeline = raster(
            "fluoro displaced",
            "vs_anatomy",
            "fs_displaced",
            &[target(FMT_A, additive())],
        );
        // Four specialisations of one shader sharing one layout: with and without the iodine
        // ray march and the needle's inputs (`has_iodine`, `has_needle` in the shader).
        let resolve_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("fluoro resolve"),
            entries: &resolve_layout_entries(),
        });
        let resolve_pipeline_layout =
            device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("fluoro resolve"),
                bind_group_layouts: &[Some(&resolve_layout)],
                immediate_size: 0,
            });
        let resolve_kernel = |label: &str, has_iodine: bool, has_needle: bool| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&resolve_pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &resolve_module,
                    entry_point: Some("vs_cover"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: None,
                multisample: wgpu::MultisampleState::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &resolve_module,
                    entry_point: Some("fs_resolve"),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: &[
                            ("has_iodine", f64::from(u8::from(has_iodine))),
                            ("has_needle", f64::from(u8::from(has_needle))),
                        ],
                        ..Default::default()
                    },
                    targets: &[Some(wgpu::ColorTargetState {
                        format: FMT_RESOLVE,
                        blend: None,
                        write_mask: wgpu::ColorWrites::empty(),
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let resolve_pipelines = [false, true].map(|iodine| {
            [false, true].map(|needle| {
                let label = format!("fluoro resolve (iodine {iodine}, needle {needle})");
                resolve_kernel(&label, iodine, needle)
            })
        });
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
            anatomy: anatomy_bufs,
            chunks,
            scalar_chunks,
            chunk_boxes: None,
            needle: None,
            needle_pipeline,
            anatomy_pipeline,
            anatomy_scalar_pipeline,
            displaced_pipeline,
            resolve_pipelines,
            resolve_layout,
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
        let steel: Vec<[[f64; 3]; 3]> = entries
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
    /// scalar ones (see [`DrawnMesh::is_scalar`]) first.
    pub fn drawn(&self) -> &[DrawnMesh] {
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

    fn set_needle_soup(&mut self, tris: &[[[f64; 3]; 3]]) {
        self.needle_generation += 1;
        if tris.is_empty() {
            self.needle = None;
            return;
        }
        let (lo, hi) = soup_box(tris);
        let vertices: Vec<Vertex> = tris.iter().flat_map(|t| triangle_vertices(t, 0)).collect();
        self.needle = Some(Needle {
            bufs: upload(&self.ctx.device, &vertices),
            centre_mm: std::array::from_fn(|a| 0.5 * (lo[a] + hi[a])),
            vertices_mm: tris.iter().flatten().copied().collect(),
        });
    }

    fn ensure_targets(&mut self, ri: usize, size: [u32; 2]) {
        if self.targets[ri].as_ref().is_some_and(|t| t.size == size) {
            return;
        }
        let tex = |label: &str, format| {
            self.ctx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some(label),
                size: wgpu::Extent3d {
                    width: size[0],
                    height: size[1],
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING
                    | wgpu::TextureUsages::COPY_SRC,
                view_formats: &[],
            })
        };
        if ri == 0 {
            self.geo_key = None;
            self.resolved = None;
        }
        self.targets[ri] = Some(Targets {
            size,
            a: tex("fluoro lbuffer", FMT_A),
            s: tex("fluoro lbuffer, water-basis channel", FMT_SCALAR),
            d: tex("fluoro displaced lbuffer", FMT_A),
            hull: tex("fluoro needle hull", FMT_HULL),
            chord: tex("fluoro needle chord", FMT_CHORD),
            resolve: tex("fluoro resolve target", FMT_RESOLVE),
            out_t: self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("fluoro transmission"),
                size: u64::from(size[0]) * u64::from(size[1]) * 4,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            }),
            staging: self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("fluoro transmission readback"),
                size: u64::from(size[0]) * u64::from(size[1]) * 4,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        });
    }

    /// Records into `encoder`: the geometric anatomy pass with `layout` (if `passes.geometry`),
    /// and with a needle its pass (if `passes.needle`) and the displaced anatomy pass scissored
    /// to its pixel box (if `passes.displaced`; the target is cleared even when the box is off
    /// the image). Returns that box in region samples, clipped (`None` without a needle or off
    /// the image).
    fn encode_lbuffer(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        projection: &Projection,
        layout: Layout,
        passes: Passes,
        region: Region,
    ) -> Option<[u32; 4]> {
        let ri = region.index();
        let size = region.size;
        self.ensure_targets(ri, size);
        let frame = projection.frame();
        let rays = projection.gpu_ray_frame();
        let v4 = |v: [f32; 3]| [v[0], v[1], v[2], 0.0];
        let m = projection.projection_matrix();
        // Region pixel coordinates: n (px - x0), n (py - y0).
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
            .map_or(0.0, |n| norm3(sub3(n.centre_mm, src)));
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
        let queue = &self.ctx.queue;
        queue.write_buffer(&self.view_buf[ri], 0, bytemuck::bytes_of(&view));
        let mut w: Vec<[f32; 4]> = Vec::with_capacity(self.meshes.len() * 3);
        for mesh in &self.meshes {
            let (g, d) = mesh.net_weights(layout);
            let tref = norm3(sub3(mesh.centre_mm, src)) as f32;
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
        // Region samples to full-image pixel coordinates.
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
        let groups = if split {
            [0..self.scalar_chunks, self.scalar_chunks..self.chunks.len()]
        } else {
            [0..0, 0..self.chunks.len()]
        };
        // The vertices of a run of chunks (they cover the vertex buffer in order).
        let total = self.anatomy.as_ref().map_or(0, |b| b.index_count);
        let vertex_at = |k: usize| self.chunks.get(k).map_or(total, |c| c.first_vertex);
        let whole = groups.clone().map(|g| vertex_at(g.start)..vertex_at(g.end));
        let geo_lists = (self.culling && passes.geometry).then(|| {
            let r = to_pixels([0, 0, size[0], size[1]]);
            groups.map(|g| self.culled(projection, r, g))
        });
        let disp_list = match rect {
            Some(r) if self.culling && passes.displaced => {
                Some(self.culled(projection, to_pixels(r), 0..self.chunks.len()))
            }
            _ => None,
        };
        let device = &self.ctx.device;
        let t = self.targets[ri].as_ref().expect("targets");
        let view_of = |x: &wgpu::Texture| x.create_view(&wgpu::TextureViewDescriptor::default());
        let (va, vs, vd, vh, vc) = (
            view_of(&t.a),
            view_of(&t.s),
            view_of(&t.d),
            view_of(&t.hull),
            view_of(&t.chord),
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
                    &self.anatomy_scalar_pipeline,
                    &vs,
                    scalar_list,
                    whole[0].clone(),
                    "fluoro anatomy, water-basis channel",
                ),
                (
                    &self.anatomy_pipeline,
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
                let Some(bufs) = &self.anatomy else {
                    continue;
                };
                let (indices, range) = match &list {
                    Some(Some((b, c))) => (b, 0..*c),
                    Some(None) => (&bufs.indices, 0..0),
                    None => (&bufs.indices, all),
                };
                if !range.is_empty() {
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, &bind, &[]);
                    pass.set_vertex_buffer(0, bufs.vertices.slice(..));
                    pass.set_index_buffer(indices.slice(..), wgpu::IndexFormat::Uint32);
                    pass.draw_indexed(range, 0, 0..1);
                }
            }
        }
        let needle = self.needle.as_ref()?;
        if passes.needle {
            let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("fluoro needle"),
                layout: &self.needle_pipeline.get_bind_group_layout(0),
                entries: &[wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.view_buf[ri].as_entire_binding(),
                }],
            });
            let attachments = [attach(&vh, NO_NEEDLE), attach(&vc, 0.0)];
            let mut pass = encoder.begin_render_pass(&pass_desc("fluoro needle", &attachments));
            pass.set_pipeline(&self.needle_pipeline);
            pass.set_bind_group(0, &bind, &[]);
            pass.set_vertex_buffer(0, needle.bufs.vertices.slice(..));
            pass.set_index_buffer(needle.bufs.indices.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..needle.bufs.index_count, 0, 0..1);
        }
        if passes.displaced {
            let bind = anatomy_bind(&self.displaced_pipeline, true);
            let attachments = [attach(&vd, 0.0)];
            let mut pass = encoder.begin_render_pass(&pass_desc("fluoro displaced", &attachments));
            if let (Some(bufs), Some([x, y, w, h])) = (&self.anatomy, rect) {
                let (indices, count) = match &disp_list {
                    Some(Some((b, c))) => (b, *c),
                    Some(None) => (&bufs.indices, 0),
                    None => (&bufs.indices, bufs.index_count),
                };
                if count > 0 {
                    pass.set_pipeline(&self.displaced_pipeline);
                    pass.set_bind_group(0, &bind, &[]);
                    pass.set_scissor_rect(x, y, w, h);
                    pass.set_vertex_buffer(0, bufs.vertices.slice(..));
                    pass.set_index_buffer(indices.slice(..), wgpu::IndexFormat::Uint32);
                    pass.draw_indexed(0..count, 0, 0..1);
                }
            }
        }
        rect
    }

    /// An index buffer of the anatomy triangles of every chunk whose pixel bounding box,
    /// widened by one pixel, meets the rectangle `r` (`x0, y0, x1, y1`, continuous full-image
    /// pixel coordinates), in drawing order: every pixel of `r` then blends the same fragments
    /// in the same order as with the whole list, so the result is bit-identical. `None` if no
    /// chunk does. A chunk's pixel box is the box of its eight projected 3-D box corners (the
    /// image of a box in front of the source is the hull of its corners); a chunk with a corner
    /// less than 1 mm in front of the source plane always qualifies. The boxes are computed once
    /// per projection (eight points per chunk instead of three per triangle).
    fn culled(
        &mut self,
        projection: &Projection,
        r: [f32; 4],
        chunks: std::ops::Range<usize>,
    ) -> Option<(wgpu::Buffer, u32)> {
        if self
            .chunk_boxes
            .as_ref()
            .is_none_or(|(p, _)| p != projection)
        {
            let m = projection.projection_matrix();
            let dot =
                |row: [f64; 4], v: [f64; 3]| row[0] * v[0] + row[1] * v[1] + row[2] * v[2] + row[3];
            let everywhere = [
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
                f32::INFINITY,
                f32::INFINITY,
            ];
            let boxes = self
                .chunks
                .iter()
                .map(|c| {
                    let mut b = [
                        f32::INFINITY,
                        f32::INFINITY,
                        f32::NEG_INFINITY,
                        f32::NEG_INFINITY,
                    ];
                    for corner in 0..8 {
                        let v: [f64; 3] = std::array::from_fn(|a| {
                            f64::from(if corner & (1 << a) == 0 {
                                c.lo[a]
                            } else {
                                c.hi[a]
                            })
                        });
                        let w = dot(m[2], v);
                        if w < 1.0 {
                            return everywhere;
                        }
                        let (x, y) = ((dot(m[0], v) / w) as f32, (dot(m[1], v) / w) as f32);
                        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
                    }
                    b
                })
                .collect();
            self.chunk_boxes = Some((*projection, boxes));
        }
        let boxes = &self.chunk_boxes.as_ref()?.1;
        let mut indices: Vec<u32> = Vec::new();
        for (c, b) in self.chunks[chunks.clone()].iter().zip(&boxes[chunks]) {
            if b[2] >= r[0] - 1.0 && b[0] <= r[2] + 1.0 && b[3] >= r[1] - 1.0 && b[1] <= r[3] + 1.0
            {
                indices.extend(c.first_vertex..c.first_vertex + c.vertices);
            }
        }
        (!indices.is_empty()).then(|| {
            let buffer = self
                .ctx
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("fluoro culled indices"),
                    contents: bytemuck::cast_slice(&indices),
                    usage: wgpu::BufferUsages::INDEX,
                });
            (buffer, indices.len() as u32)
        })
    }

    /// Uploads the spectral bins and, for polychromatic models, the `ln T` table.
    ///
    /// Without steel or iodine on a ray, `T` depends on the water and bone depths only; the
    /// resolve pass then interpolates `ln T` bilinearly in a 512 x 256 table over
    /// `[0, 16] x [0, 8]` (steps of 0.031) instead of summing ~75 exponentials. The error is
    /// `h^2 / 8` times the curvature of `ln T`, the variance of `R_b(E)` under the transmitted
    /// spectrum (below 0.1 at 80 kVp): under `1.2e-5` in `ln T` per axis.
    fn ensure_spectral(&mut self, model: &SpectralModel) {
        if self
            .spectral
            .as_ref()
            .is_some_and(|s| s.model == model.model)
        {
            return;
        }
        use sim_core::fluoro::Basis;
        let log2e = std::f64::consts::LOG2_E;
        let mut bins: Vec<[f32; 4]> = Vec::with_capacity(2 * model.weights.len());
        for (w, r) in model.weights.iter().zip(&model.ratio_to_60kev) {
            let f = |b: Basis| (r[b.index()] * log2e) as f32;
            bins.push([
                f(Basis::Water),
                f(Basis::Bone),
                f(Basis::Iodine),
                f(Basis::Iron),
            ]);
            bins.push([*w as f32, 0.0, 0.0, 0.0]);
        }
        let lut_enabled = model.weights.len() > 1;
        let lut: Vec<f32> = if lut_enabled {
            let [nw, nb] = LUT_DIMS;
            (0..nw * nb)
                .map(|k| {
                    let mut a = [0.0; Basis::COUNT];
                    a[Basis::Water.index()] = (k % nw) as f64 * LUT_MAX_DEPTH[0] / (nw - 1) as f64;
                    a[Basis::Bone.index()] = (k / nw) as f64 * LUT_MAX_DEPTH[1] / (nb - 1) as f64;
                    model.transmission(&a).ln() as f32
                })
                .collect()
        } else {
            vec![0.0]
        };
        let device = &self.ctx.device;
        let buf = |label: &str, data: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: data,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        self.spectral = Some(SpectralTables {
            model: model.model,
            bins: buf("fluoro spectral bins", bytemuck::cast_slice(&bins)),
            lut: buf("fluoro ln T table", bytemuck::cast_slice(&lut)),
            lut_enabled,
        });
    }

    /// Reads a whole float texture back, `channels` f32 per texel, row-major without padding.
    fn read_texture(&self, tex: &wgpu::Texture, channels: usize) -> Result<Vec<f32>, GpuError> {
        let [w, h] = self.targets[0].as_ref().expect("targets").size;
        let row = w as usize * channels * 4;
        let padded = row.div_ceil(256) * 256;
        let buf = self.ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("fluoro texture readback"),
            size: (padded * h as usize) as u64,
            usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self
            .ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: tex,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buf,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(padded as u32),
                    rows_per_image: Some(h),
                },
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
        self.ctx.queue.submit([enc.finish()]);
        let bytes = self.ctx.read_buffer(&buf, (padded * h as usize) as u64)?;
        let mut out = Vec::with_capacity(w as usize * h as usize * channels);
        for r in 0..h as usize {
            out.extend_from_slice(bytemuck::cast_slice::<u8, f32>(
                &bytes[r * padded..r * padded + row],
            ));
        }
        Ok(out)
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
        let [w, h] = projection.detector_pixels.map(|x| x as usize);
        let mut raw = vec![[0f32; CHORD_CHANNELS]; w * h];
        let mut steel = Vec::new();
        // The geometric part is in axial depth: times |d| / (row_w . d) along each pixel's ray
        // (as the resolve does on the GPU).
        let row_w = projection.projection_matrix()[2];
        let f = projection.frame();
        let scale: Vec<f32> = (0..w * h)
            .map(|q| {
                let (i, j) = ((q % w) as f64, (q / w) as f64);
                let d: [f64; 3] = std::array::from_fn(|a| {
                    f.pixel00_mm[a] + i * f.step_u_mm[a] + j * f.step_v_mm[a] - f.source_mm[a]
                });
                let axial = row_w[0] * d[0] + row_w[1] * d[1] + row_w[2] * d[2];
                (norm3(d) / axial) as f32
            })
            .collect();
        for pass in 0..CHORD_PASSES {
            let mut enc = self
                .ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            let full = Region::full(projection);
            let passes = Passes {
                needle: pass == 0,
                ..Passes::ALL
            };
            self.encode_lbuffer(&mut enc, projection, Layout::Chords(pass), passes, full);
            self.geo_key = Some((*projection, Layout::Chords(pass)));
            self.ctx.queue.submit([enc.finish()]);
            let t = self.targets[0].as_ref().expect("targets");
            let (ta, td, tc) = (t.a.clone(), t.d.clone(), t.chord.clone());
            let mut a = self.read_texture(&ta, 4)?;
            for (x, k) in a.chunks_exact_mut(4).zip(&scale) {
                x.iter_mut().for_each(|c| *c *= k);
            }
            if self.needle.is_some() {
                let d = self.read_texture(&td, 4)?;
                for (x, y) in a.iter_mut().zip(d) {
                    *x += y;
                }
            }
            if pass == 0 {
                steel = if self.needle.is_some() {
                    self.read_texture(&tc, 1)?
                } else {
                    vec![0.0; w * h]
                };
            }
            for (p, r) in raw.iter_mut().enumerate() {
                for s in 0..SLOTS {
                    let c = pass * SLOTS + s;
                    if c < CHORD_CHANNELS {
                        r[c] = a[4 * p + s];
                    }
                }
            }
        }
        let (cort, canc) = (CORTICAL.index(), CANCELLOUS.index());
        let (disp_cort, disp_canc) = (CHANNELS - 1, CHANNELS);
        let shell = self.cortical_shell_mm as f32;
        Ok(raw
            .iter()
            .zip(&steel)
            .map(|(r, &st)| {
                let mut out = [0f32; CHANNELS];
                out[..CHANNELS - 1].copy_from_slice(&r[..CHANNELS - 1]);
                // Bone: clamp on the geometric chords, then remove the needle (as the CPU).
                let total = (r[cort] + r[canc]).max(0.0);
                let c = r[canc].clamp(0.0, (total - 2.0 * shell).max(0.0));
                let canc_left = (c - r[disp_canc]).max(0.0);
                out[canc] = canc_left;
                out[cort] = (total - r[disp_cort] - r[disp_canc] - canc_left).max(0.0);
                out[FluoroMaterial::Steel.index()] = st.max(0.0);
                out
            })
            .collect())
    }

    /// Transmission at every pixel centre (0 behind the collimator) for `energy`, with an
    /// optional iodine field: geometric L-buffer pass, needle and displaced passes, one resolve
    /// pass, then a read-back. With [`GpuFluoroRenderer::caching`], the geometric pass is kept
    /// while the projection stays, and without iodine only the rows the needle covers now or
    /// covered in the previous frame are resolved and read back (bit-identical to a frame from
    /// scratch, see [`Resolved`]).
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

    /// Records the full image's passes and resolve into `enc`, from the caches where they
    /// apply; [`GpuFluoroRenderer::end_full`] completes it after the read-back.
    fn begin_full(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        projection: &Projection,
        model: &SpectralModel,
        iodine: Option<&IodineField>,
    ) -> FullFrame {
        let full = Region::full(projection);
        self.ensure_targets(0, full.size);
        let key = (*projection, Layout::Transmission);
        let geometry = !(self.caching && self.geo_key == Some(key));
        self.timings.geometry_reused = !geometry;
        let previous = if !geometry && iodine.is_none() {
            self.resolved
                .take()
                .filter(|r| r.projection == *projection && r.model == model.model)
        } else {
            None
        };
        self.resolved = None;
        let passes = Passes {
            geometry,
            ..Passes::ALL
        };
        // Invalidated until the frame is read back: a failure leaves no stale key behind.
        self.geo_key = None;
        let pending = self.encode_region(
            enc,
            projection,
            model,
            iodine,
            full,
            passes,
            previous.as_ref().map(|p| p.needle_rect),
        );
        FullFrame {
            pending,
            key,
            model: model.model,
            previous,
            width: full.size[0] as usize,
        }
    }

    /// The full-image transmission from its read-back `out`, kept for the next frame.
    fn end_full(
        &mut self,
        frame: FullFrame,
        out: RegionOut,
        iodine: Option<&IodineField>,
    ) -> Vec<f32> {
        let FullFrame {
            key,
            model,
            previous,
            width: w,
            ..
        } = frame;
        let projection = &key.0;
        self.geo_key = Some(key);
        let transmission = match previous {
            Some(mut p) => {
                let start = out.rows.start as usize * w;
                p.transmission[start..start + out.data.len()].copy_from_slice(&out.data);
                p.transmission
            }
            None => out.data,
        };
        if self.caching && iodine.is_none() {
            self.resolved = Some(Resolved {
                projection: *projection,
                model,
                needle_rect: out.needle_rect,
                transmission: transmission.clone(),
            });
        }
        transmission
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
        region: Region,
        passes: Passes,
        previous: Option<Option<[u32; 4]>>,
    ) -> Pending {
        let started = Instant::now();
        let ri = region.index();
        let size = region.size;
        let needle_rect =
            self.encode_lbuffer(enc, projection, Layout::Transmission, passes, region);
        let rect = match previous {
            None => [0, 0, size[0], size[1]],
            Some(old) => match union_rect(old, needle_rect) {
                Some(r) => r,
                // No needle then or now: nothing to resolve.
                None => {
                    return Pending {
                        ri,
                        rows: 0..0,
                        bytes: 0,
                        needle_rect,
                    };
                }
            },
        };
        self.ensure_spectral(model);
        let device = &self.ctx.device;
        let tables = self.spectral.as_ref().expect("spectral tables");
        let frame = projection.gpu_ray_frame();
        let v4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
        let col = projection.collimation;
        let clampf = |x: f64| x.clamp(-1e30, 1e30) as f32;
        let (iod_tex, iod_origin, iod_inv, iod_dims) = match iodine {
            Some(f) if !f.volume.grid.is_empty() => {
                let g = &f.volume.grid;
                let step = self.iodine_step_fraction
                    * g.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
                (
                    iodine_texture(&self.ctx, g.dims, &f.volume.data),
                    [
                        g.origin_mm[0] as f32,
                        g.origin_mm[1] as f32,
                        g.origin_mm[2] as f32,
                        step as f32,
                    ],
                    g.spacing_mm.map(|s| (1.0 / s) as f32),
                    [g.dims[0] as u32, g.dims[1] as u32, g.dims[2] as u32, 1],
                )
            }
            _ => (
                self.empty_iodine.clone(),
                [0.0, 0.0, 0.0, 1.0],
                [1.0; 3],
                [1, 1, 1, 0],
            ),
        };
        let mu = |m: FluoroMaterial| m.mu_60kev_per_cm() as f32;
        let params = ResolveUniform {
            p00: v4(frame.pixel00_from_source_mm, 0.0),
            step_u: v4(frame.step_u_mm, 0.0),
            step_v: v4(frame.step_v_mm, 0.0),
            source: v4(frame.source_mm, 0.0),
            blades: [
                clampf(col.x_min_mm),
                clampf(col.x_max_mm),
                clampf(col.y_min_mm),
                clampf(col.y_max_mm),
            ],
            misc: [
                col.iris_radius_mm.map_or(-1.0, |r| (r * r) as f32),
                projection.pixel_pitch_mm[0] as f32,
                projection.pixel_pitch_mm[1] as f32,
                self.cortical_shell_mm as f32,
            ],
            dims: [size[0], size[1], model.weights.len() as u32, iod_dims[3]],
            lut_scale: [
                ((LUT_DIMS[0] - 1) as f64 / LUT_MAX_DEPTH[0]) as f32,
                ((LUT_DIMS[1] - 1) as f64 / LUT_MAX_DEPTH[1]) as f32,
                0.0,
                0.0,
            ],
            region: [
                region.origin[0] as f32,
                region.origin[1] as f32,
                1.0 / region.n as f32,
                0.0,
            ],
            full: [
                projection.detector_pixels[0],
                projection.detector_pixels[1],
                u32::from(self.needle.is_some()),
                0,
            ],
            lut_dims: [
                LUT_DIMS[0] as u32,
                LUT_DIMS[1] as u32,
                u32::from(tables.lut_enabled),
                0,
            ],
            rect,
            mu: [
                mu(FluoroMaterial::Tissue(MaterialClass::CorticalBone)),
                mu(FluoroMaterial::Tissue(MaterialClass::Cancellous)),
                mu(FluoroMaterial::Steel),
                sim_core::fluoro::attenuation::iodine_stock_mu_60kev_per_cm() as f32,
            ],
            iod_origin,
            iod_inv_spacing: [iod_inv[0], iod_inv[1], iod_inv[2], 0.0],
            iod_dims,
            row_w: {
                let r = projection.projection_matrix()[2];
                [r[0] as f32, r[1] as f32, r[2] as f32, 0.0]
            },
        };
        self.ctx
            .queue
            .write_buffer(&self.resolve_buf[ri], 0, bytemuck::bytes_of(&params));
        let t = self.targets[ri].as_ref().expect("targets");
        let view_of = |x: &wgpu::Texture| x.create_view(&wgpu::TextureViewDescriptor::default());
        let iod_view = iod_tex.create_view(&wgpu::TextureViewDescriptor::default());
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("fluoro resolve"),
            layout: &self.resolve_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.resolve_buf[ri].as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.a)),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.chord)),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: tables.bins.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: wgpu::BindingResource::TextureView(&iod_view),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: t.out_t.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: tables.lut.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.d)),
                },
                wgpu::BindGroupEntry {
                    binding: 8,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.s)),
                },
            ],
        });
        {
            let target = t
                .resolve
                .create_view(&wgpu::TextureViewDescriptor::default());
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("fluoro resolve"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &target,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Discard,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            // The needle's box with the needle's inputs, and the rest of the rectangle (up to
            // four bands) without them (zero there: bit-identical). Each sample is resolved by
            // exactly one draw: the draws' storage writes are not ordered within a pass.
            let pipelines = &self.resolve_pipelines[usize::from(iod_dims[3] != 0)];
            pass.set_bind_group(0, &bind, &[]);
            let boxed = needle_rect.and_then(|n| intersect_rect(n, rect));
            let draws = boxed
                .map(|b| (1, b))
                .into_iter()
                .chain(subtract_rect(rect, boxed).into_iter().map(|b| (0, b)));
            for (variant, r) in draws {
                pass.set_pipeline(&pipelines[variant]);
                pass.set_scissor_rect(r[0], r[1], r[2], r[3]);
                pass.draw(0..3, 0..1);
            }
        }
        let row_bytes = u64::from(size[0]) * 4;
        let bytes = row_bytes * u64::from(rect[3]);
        enc.copy_buffer_to_buffer(
            &t.out_t,
            row_bytes * u64::from(rect[1]),
            &t.staging,
            0,
            bytes,
        );
        self.timings.resolved_samples += u64::from(rect[2]) * u64::from(rect[3]);
        self.timings.encode_ms += started.elapsed().as_secs_f64() * 1e3;
        Pending {
            ri,
            rows: rect[1]..rect[1] + rect[3],
            bytes,
            needle_rect,
        }
    }

    /// Submits `enc` once, waits, and reads back every pending region.
    fn submit_and_read(
        &mut self,
        enc: wgpu::CommandEncoder,
        pending: &[Pending],
    ) -> Result<Vec<RegionOut>, FluoroGpuError> {
        let started = Instant::now();
        self.ctx.queue.submit([enc.finish()]);
        let fail = |e: String| FluoroGpuError::Gpu(GpuError::Readback(e));
        let mut receivers = Vec::new();
        for p in pending.iter().filter(|p| p.bytes > 0) {
            let (tx, rx) = std::sync::mpsc::channel();
            let t = self.targets[p.ri].as_ref().expect("targets");
            t.staging
                .map_async(wgpu::MapMode::Read, ..p.bytes, move |r| {
                    // The receiver lives until recv() below returns, so a send error cannot happen.
                    let _ = tx.send(r);
                });
            receivers.push(rx);
        }
        self.ctx
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| fail(e.to_string()))?;
        for rx in receivers {
            rx.recv()
                .map_err(|e| fail(e.to_string()))?
                .map_err(|e| fail(e.to_string()))?;
        }
        self.timings.gpu_ms += started.elapsed().as_secs_f64() * 1e3;
        let started = Instant::now();
        let mut outs = Vec::with_capacity(pending.len());
        for p in pending {
            let data = if p.bytes > 0 {
                let t = self.targets[p.ri].as_ref().expect("targets");
                let data = {
                    let view = t
                        .staging
                        .get_mapped_range(..p.bytes)
                        .map_err(|e| fail(e.to_string()))?;
                    bytemuck::cast_slice::<u8, f32>(&view).to_vec()
                };
                t.staging.unmap();
                data
            } else {
                Vec::new()
            };
            outs.push(RegionOut {
                rows: p.rows.clone(),
                data,
                needle_rect: p.needle_rect,
            });
        }
        self.timings.readback_ms += started.elapsed().as_secs_f64() * 1e3;
        Ok(outs)
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
        let full = Region::full(projection);
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
            Region {
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

/// The resolve pass's bindings (see `resolve.wgsl`): its uniforms, the L-buffer, the needle's
/// chord, the spectral bins, the iodine grid, the transmission out, the `ln T` table, the
/// displaced L-buffer and the scalar meshes' L-buffer.
fn resolve_layout_entries() -> [wgpu::BindGroupLayoutEntry; 9] {
    let entry = |binding: u32, ty: wgpu::BindingType| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::FRAGMENT,
        ty,
        count: None,
    };
    let buffer = |ty: wgpu::BufferBindingType| wgpu::BindingType::Buffer {
        ty,
        has_dynamic_offset: false,
        min_binding_size: None,
    };
    let texture = |view_dimension: wgpu::TextureViewDimension| wgpu::BindingType::Texture {
        sample_type: wgpu::TextureSampleType::Float { filterable: false },
        view_dimension,
        multisampled: false,
    };
    let read = wgpu::BufferBindingType::Storage { read_only: true };
    [
        entry(0, buffer(wgpu::BufferBindingType::Uniform)),
        entry(1, texture(wgpu::TextureViewDimension::D2)),
        entry(2, texture(wgpu::TextureViewDimension::D2)),
        entry(3, buffer(read)),
        entry(4, texture(wgpu::TextureViewDimension::D3)),
        entry(
            5,
            buffer(wgpu::BufferBindingType::Storage { read_only: false }),
        ),
        entry(6, buffer(read)),
        entry(7, texture(wgpu::TextureViewDimension::D2)),
        entry(8, texture(wgpu::TextureViewDimension::D2)),
    ]
}

/// A region recorded for resolve and read-back.
#[derive(Debug, Clone)]
struct Pending {
    ri: usize,
    rows: std::ops::Range<u32>,
    /// Bytes to read back (0: nothing was resolved).
    bytes: u64,
    needle_rect: Option<[u32; 4]>,
}

/// The full image between [`GpuFluoroRenderer::begin_full`] and
/// [`GpuFluoroRenderer::end_full`].
struct FullFrame {
    pending: Pending,
    key: (Projection, Layout),
    model: EnergyModel,
    previous: Option<Resolved>,
    width: usize,
}

/// Resolved rows of one region.
struct RegionOut {
    rows: std::ops::Range<u32>,
    data: Vec<f32>,
    needle_rect: Option<[u32; 4]>,
}

/// Overlap of two rectangles `[x, y, w, h]` (`None` if they do not overlap).
fn intersect_rect(a: [u32; 4], b: [u32; 4]) -> Option<[u32; 4]> {
    let (x0, y0) = (a[0].max(b[0]), a[1].max(b[1]));
    let x1 = (a[0] + a[2]).min(b[0] + b[2]);
    let y1 = (a[1] + a[3]).min(b[1] + b[3]);
    (x1 > x0 && y1 > y0).then(|| [x0, y0, x1 - x0, y1 - y0])
}

/// `a` less `b` (which lies inside `a`, if given) as up to four disjoint, non-empty bands: the
/// rows above and below `b`, and the parts of `b`'s rows left and right of it.
fn subtract_rect(a: [u32; 4], b: Option<[u32; 4]>) -> Vec<[u32; 4]> {
    let Some(b) = b else {
        return vec![a];
    };
    let (ax1, ay1, bx1, by1) = (a[0] + a[2], a[1] + a[3], b[0] + b[2], b[1] + b[3]);
    [
        [a[0], a[1], a[2], b[1] - a[1]],
        [a[0], by1, a[2], ay1 - by1],
        [a[0], b[1], b[0] - a[0], b[3]],
        [bx1, b[1], ax1 - bx1, b[3]],
    ]
    .into_iter()
    .filter(|r| r[2] > 0 && r[3] > 0)
    .collect()
}

/// Smallest rectangle `[x, y, w, h]` holding both (`None` if both are).
fn union_rect(a: Option<[u32; 4]>, b: Option<[u32; 4]>) -> Option<[u32; 4]> {
    match (a, b) {
        (None, r) | (r, None) => r,
        (Some(a), Some(b)) => {
            let (x0, y0) = (a[0].min(b[0]), a[1].min(b[1]));
            let x1 = (a[0] + a[2]).max(b[0] + b[2]);
            let y1 = (a[1] + a[3]).max(b[1] + b[3]);
            Some([x0, y0, x1 - x0, y1 - y0])
        }
    }
}

/// What decides which pixels the beam reaches (see `Projection::is_exposed`).
#[derive(Debug, Clone, Copy, PartialEq)]
struct ExposureKey {
    pixels: [u32; 2],
    pitch_mm: [f64; 2],
    collimation: sim_core::fluoro::Collimation,
}

impl ExposureKey {
    fn of(p: &Projection) -> ExposureKey {
        ExposureKey {
            pixels: p.detector_pixels,
            pitch_mm: p.pixel_pitch_mm,
            collimation: p.collimation,
        }
    }
}

/// Which pixels the collimator exposes (decided at pixel centres, as the CPU).
fn exposed_mask(projection: &Projection) -> Vec<bool> {
    let w = projection.detector_pixels[0] as usize;
    let n = w * projection.detector_pixels[1] as usize;
    (0..n)
        .map(|p| projection.is_exposed([(p % w) as f64 + 0.5, (p / w) as f64 + 0.5]))
        .collect()
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

fn upload(device: &wgpu::Device, vertices: &[Vertex]) -> MeshBuffers {
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

fn iodine_texture(ctx: &GpuContext, dims: [usize; 3], data: &[f32]) -> wgpu::Texture {
    ctx.device.create_texture_with_data(
        &ctx.queue,
        &wgpu::TextureDescriptor {
            label: Some("fluoro iodine"),
            size: wgpu::Extent3d {
                width: dims[0] as u32,
                height: dims[1] as u32,
                depth_or_array_layers: dims[2] as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::R32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytemuck::cast_slice(data),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every sample of `a` is covered exactly once by `b` (if any, inside `a`) and the bands
    /// `subtract_rect` returns, for every placement of `b` on a small grid.
    #[test]
    fn the_needle_box_and_the_bands_cover_the_rectangle_once() {
        let a = [2, 3, 7, 5];
        let mut boxes = vec![None];
        for x in 2..9 {
            for y in 3..8 {
                for w in 1..=9 - x {
                    for h in 1..=8 - y {
                        boxes.push(Some([x, y, w, h]));
                    }
                }
            }
        }
        for b in boxes {
            let mut count = [[0u8; 12]; 12];
            for r in b.into_iter().chain(subtract_rect(a, b)) {
                assert!(r[2] > 0 && r[3] > 0, "{b:?}: empty band {r:?}");
                for y in r[1]..r[1] + r[3] {
                    for x in r[0]..r[0] + r[2] {
                        count[y as usize][x as usize] += 1;
                    }
                }
            }
            for (y, row) in count.iter().enumerate() {
                for (x, &c) in row.iter().enumerate() {
                    let inside = (2..9).contains(&x) && (3..8).contains(&y);
                    assert_eq!(
                        c,
                        u8::from(inside),
                        "{b:?}: sample ({x}, {y}) covered {c} times"
                    );
                }
            }
            assert_eq!(intersect_rect(a, a), Some(a));
            if let Some(b) = b {
                assert_eq!(intersect_rect(a, b), Some(b));
            }
        }
    }
}
