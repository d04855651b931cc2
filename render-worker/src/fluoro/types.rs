//! The renderer's types and constants, below every pass: the passes (`lbuffer`, `resolve`,
//! `cache`, `pipelines`, `chords`) implement their part of [`GpuFluoroRenderer`] on these and
//! import nothing from one another but functions further down (`resolve` uses `cache`'s
//! rectangle helpers, `pipelines` the resolve pass's layout).

use bytemuck::{Pod, Zeroable};
use sim_core::fluoro::nesting::NestedMesh;
use sim_core::fluoro::spectrum::UnknownKvp;
use sim_core::fluoro::{EnergyModel, FluoroMaterial, Projection, TransmissionImage};
use sim_core::material::MaterialClass;
use thiserror::Error;

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

/// A rectangle of the detector sampled `n x n` per pixel: sample `(i, j)` of it lies at
/// continuous pixel coordinates `origin + ((i, j) + 0.5) / n` (the CPU's stratified sub-pixel
/// positions). The full image is `origin 0, n 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct PixelRect {
    pub(super) origin: [u32; 2],
    pub(super) n: u32,
    /// Samples per axis (pixels x n).
    pub(super) size: [u32; 2],
}

impl PixelRect {
    pub(super) fn full(p: &Projection) -> PixelRect {
        PixelRect {
            origin: [0, 0],
            n: 1,
            size: p.detector_pixels,
        }
    }

    /// Which set of targets and uniforms it uses.
    pub(super) fn index(&self) -> usize {
        usize::from(self.n > 1)
    }
}

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
    pub(super) ctx: GpuContext,
    /// The nesting plan, in drawing order: the meshes that add to the water-basis channel only
    /// first (drawn into the one-channel target).
    pub(super) meshes: Vec<NestedMesh>,
    pub(super) anatomy: AnatomyBuffers,
    /// Each anatomy chunk's pixel bounding box under one projection (see `culled`).
    pub(super) chunk_boxes: Option<(Projection, Vec<[f32; 4]>)>,
    pub(super) needle: Option<Needle>,
    pub(super) pipelines: Pipelines,
    /// Uniforms of the full image (0) and of the supersampled needle region (1).
    pub(super) view_buf: [wgpu::Buffer; 2],
    pub(super) resolve_buf: [wgpu::Buffer; 2],
    pub(super) weights_buf: wgpu::Buffer,
    pub(super) empty_iodine: wgpu::Texture,
    pub(super) targets: [Option<Targets>; 2],
    pub(super) spectral: Option<SpectralTables>,
    pub(super) cortical_shell_mm: f64,
    /// What the full-image geometric L-buffer (`targets[0].a`) holds, if anything.
    pub(super) geo_key: Option<(Projection, Layout)>,
    /// The last full-image transmission resolve without iodine (see [`Resolved`]).
    pub(super) resolved: Option<Resolved>,
    /// Bumped whenever the needle changes.
    pub(super) needle_generation: u64,
    /// The last displayed-frame transmission and what decided it.
    pub(super) last_frame: Option<(FrameKey, GpuTransmission)>,
    /// The last frame's input to sim-core's finishing step, reused while the detector and the
    /// collimator stay (its exposure mask and its storage).
    pub(super) finishing: Option<(ExposureKey, TransmissionImage)>,
    /// Use the caches (default `true`; `false` renders every frame from scratch, for the
    /// benchmark's before/after rows and the cache tests).
    pub caching: bool,
    /// Draw only the anatomy triangles that can reach the needle's pixel box or the
    /// supersampled region into them (default `true`; bit-identical either way, see
    /// `culled`).
    pub culling: bool,
    pub(super) timings: FrameTimings,
    /// Iodine ray-march step as a fraction of the smallest voxel spacing (default 0.25).
    pub iodine_step_fraction: f64,
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

/// Channels of the `Rgba32Float` L-buffer targets (the geometric one and the displaced one).
/// Transmission layout: (water-basis `sum mu_60 L`, bone-basis `sum mu_60 L`, both net of what
/// the needle displaces; cortical and cancellous geometric `L` for the clamp).
pub(super) const SLOTS: usize = 4;

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

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct Vertex {
    pub(super) pos: [f32; 3],
    pub(super) mesh: u32,
    /// Outward unit normal of the vertex's triangle (f64 cross product; zero if degenerate).
    pub(super) normal: [f32; 3],
    pub(super) pad: u32,
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct ViewUniform {
    pub(super) row_x: [f32; 4],
    pub(super) row_y: [f32; 4],
    pub(super) row_w: [f32; 4],
    pub(super) source: [f32; 4],
    pub(super) size: [f32; 4],
    pub(super) needle_box: [f32; 4],
    pub(super) p00: [f32; 4],
    pub(super) step_u: [f32; 4],
    pub(super) step_v: [f32; 4],
    pub(super) region: [f32; 4],
}

pub(super) struct Needle {
    pub(super) bufs: MeshBuffers,
    pub(super) centre_mm: [f64; 3],
    pub(super) vertices_mm: Vec<[f64; 3]>,
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

/// Chord-layout channels: 0..11, tissue `i`'s chord net of the needle (for the two bone
/// classes: geometric); 11 and 12, the cortical and cancellous parts the needle displaces.
pub(super) const CHORD_CHANNELS: usize = CHANNELS + 1;

/// L-buffer passes for [`GpuFluoroRenderer::render_chords`], four channels each.
pub(super) const CHORD_PASSES: usize = CHORD_CHANNELS.div_ceil(SLOTS);

pub(super) const CORTICAL: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::CorticalBone);

pub(super) const CANCELLOUS: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::Cancellous);

/// Which passes [`GpuFluoroRenderer::encode_lbuffer`] records.
#[derive(Debug, Clone, Copy)]
pub(super) struct Passes {
    pub(super) geometry: bool,
    pub(super) needle: bool,
    pub(super) displaced: bool,
}

impl Passes {
    pub(super) const ALL: Passes = Passes {
        geometry: true,
        needle: true,
        displaced: true,
    };
}

/// The slot layout of one pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Layout {
    Transmission,
    Chords(usize),
}

/// Marker of "no needle on this pixel" in the hull target (as in the shader).
pub(super) const NO_NEEDLE: f64 = 1.0e30;

/// Every pipeline of the renderer, built once per device.
pub(super) struct Pipelines {
    /// The needle's hull and chord pass.
    pub(super) needle: wgpu::RenderPipeline,
    /// The geometric anatomy pass into the four-channel L-buffer.
    pub(super) anatomy: wgpu::RenderPipeline,
    /// The geometric anatomy pass into the one-channel (water-basis) L-buffer.
    pub(super) anatomy_scalar: wgpu::RenderPipeline,
    /// The displaced anatomy pass.
    pub(super) displaced: wgpu::RenderPipeline,
    /// The resolve, `[iodine][needle]`: without and with the iodine ray march, and without
    /// and with the needle's inputs (drawn over the needle's pixel box only); one bind group
    /// layout (`resolve_layout`) serves all four.
    pub(super) resolve: [[wgpu::RenderPipeline; 2]; 2],
    pub(super) resolve_layout: wgpu::BindGroupLayout,
}

/// Render targets of one detector size.
pub(super) struct Targets {
    pub(super) size: [u32; 2],
    /// Geometric L-buffer (needle-independent): the non-scalar meshes in the transmission
    /// layout, every mesh in the chord layout.
    pub(super) a: wgpu::Texture,
    /// Geometric L-buffer of the scalar meshes, transmission layout (water-basis channel).
    pub(super) s: wgpu::Texture,
    /// Displaced part (zero outside the needle's pixel box).
    pub(super) d: wgpu::Texture,
    pub(super) hull: wgpu::Texture,
    pub(super) chord: wgpu::Texture,
    pub(super) out_t: wgpu::Buffer,
    /// The resolve's render target: it only sizes the pass (write mask empty; cleared, one byte
    /// per sample, and discarded); the output is `out_t`.
    pub(super) resolve: wgpu::Texture,
    /// Kept mapped-readable copy of `out_t` (no allocation per frame).
    pub(super) staging: wgpu::Buffer,
}

/// The full-image transmission of the last resolve: for which projection and energy model, the
/// needle's pixel rectangle then (where the displaced pass and the steel wrote), and the values.
/// Outside the union of that rectangle and the next frame's, every input of the resolve is the
/// same (same geometric L-buffer, no displaced part, no steel), so only that union is resolved
/// and read back again, and the result is bit-identical to a frame from scratch.
pub(super) struct Resolved {
    pub(super) projection: Projection,
    pub(super) model: EnergyModel,
    pub(super) needle_rect: Option<[u32; 4]>,
    pub(super) transmission: Vec<f32>,
}

/// Everything that decides [`GpuFluoroRenderer::render_transmission_supersampled`] without
/// iodine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct FrameKey {
    pub(super) projection: Projection,
    pub(super) energy: EnergyModel,
    pub(super) supersample: u32,
    pub(super) needle_generation: u64,
}

/// The full image between [`GpuFluoroRenderer::begin_full`] and
/// [`GpuFluoroRenderer::end_full`].
pub(super) struct FullFrame {
    pub(super) pending: Pending,
    pub(super) key: (Projection, Layout),
    pub(super) model: EnergyModel,
    pub(super) previous: Option<Resolved>,
    pub(super) width: usize,
}

/// What decides which pixels the beam reaches (see `Projection::is_exposed`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ExposureKey {
    pub(super) pixels: [u32; 2],
    pub(super) pitch_mm: [f64; 2],
    pub(super) collimation: sim_core::fluoro::Collimation,
}

impl ExposureKey {
    pub(super) fn of(p: &Projection) -> ExposureKey {
        ExposureKey {
            pixels: p.detector_pixels,
            pitch_mm: p.pixel_pitch_mm,
            collimation: p.collimation,
        }
    }
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct ResolveUniform {
    pub(super) p00: [f32; 4],
    pub(super) step_u: [f32; 4],
    pub(super) step_v: [f32; 4],
    pub(super) source: [f32; 4],
    pub(super) blades: [f32; 4],
    pub(super) misc: [f32; 4],
    pub(super) dims: [u32; 4],
    pub(super) mu: [f32; 4],
    pub(super) iod_origin: [f32; 4],
    pub(super) iod_inv_spacing: [f32; 4],
    pub(super) iod_dims: [u32; 4],
    pub(super) lut_scale: [f32; 4],
    pub(super) region: [f32; 4],
    pub(super) full: [u32; 4],
    pub(super) lut_dims: [u32; 4],
    pub(super) rect: [u32; 4],
    pub(super) row_w: [f32; 4],
}

/// Spectral bins and the `ln T` table of one energy model, kept until the model changes.
pub(super) struct SpectralTables {
    pub(super) model: EnergyModel,
    pub(super) bins: wgpu::Buffer,
    pub(super) lut: wgpu::Buffer,
    pub(super) lut_enabled: bool,
}

/// A [`PixelRect`] recorded for resolve and read-back.
#[derive(Debug, Clone)]
pub(super) struct Pending {
    pub(super) ri: usize,
    pub(super) rows: std::ops::Range<u32>,
    /// Bytes to read back (0: nothing was resolved).
    pub(super) bytes: u64,
    pub(super) needle_rect: Option<[u32; 4]>,
}

/// Resolved rows of one [`PixelRect`].
pub(super) struct PixelRectOut {
    pub(super) rows: std::ops::Range<u32>,
    pub(super) data: Vec<f32>,
    pub(super) needle_rect: Option<[u32; 4]>,
}
