//! GPU B-mode ultrasound: the frame of `sim_core::ultrasound::scan` on wgpu compute shaders.
//!
//! The reference is sim-core's CPU model (read its module docs); `tests/ultrasound_gpu.rs`
//! compares the two on the same seed and `benches/ultrasound_gpu.rs` reports time against error.
//!
//! # Passes (one submission per frame)
//! 1. Deposit (`deposit.wgsl`): one invocation per lattice column along the region axis closest
//!    to the elevation direction, exactly the columns and cells the CPU visits (same reach, same
//!    SplitMix64 cell hash of the seed and the cell's indices, emulated on 32-bit words), so the
//!    SAME speckle appears. Each scatterer is weighted by the elevation profile and the tissue's
//!    echogenicity (and the nerve honeycomb), phase-rotated and deposited bilinearly into a padded
//!    (line, sample) grid of fixed-point I/Q with integer atomics ([`FIXED_POINT_SCALE`]): integer
//!    sums do not depend on the order, so repeated frames are bit-identical. The point targets
//!    are weighted and phase-rotated on the CPU (f64) and deposited by a second entry point.
//! 2. Lateral convolution (`convolve.wgsl`, `lateral`): per-depth Gaussian across lines, weights
//!    computed on the CPU exactly as sim-core's (f32, per padded sample).
//! 3. Axial convolution (`axial`): the pulse envelope along each line.
//! 4. Line march (`march.wgsl`): one invocation per line marches the tissue (interface echoes
//!    with the 48-direction normal, `1 - R^2`, two-way attenuation, needle echo, reverberation and
//!    shadow) and writes the envelope `|gain x speckle + echoes|`.
//! 5. Display (`display.wgsl`): log compression, gain, TGC and scan conversion to square pixels.
//!
//! The envelope and the pixels are read back in one copy; the needle's [`NeedleView`] and the
//! frame's bookkeeping are sim-core's own functions on the CPU.
//!
//! # Medium
//! The tissue is the [`CtMedium`] the request's `medium` refers to (the caller passes both; the
//! GPU reads only the voxels). It is uploaded once per `medium_key` as one `f32` code per voxel:
//! the HU clamped to +-1e5 (sim-core's `hu_props` is constant beyond -400 and 1000 HU, so the
//! clamp changes nothing), or `LABEL_BASE + label` (1e6 + label; HU never reach it) where the
//! label volume holds a class. Properties come from a table built on the CPU from sim-core's
//! `hu_props` (one row per integer HU from -400 to 1000, interpolated linearly: `hu_props` is
//! piecewise linear with integer knots, so this reproduces it up to f32 rounding) and
//! `class_props` (one row per label; row 0 is air, outside the grid).
//!
//! # Differences from the CPU frame
//! - Precision: geometry, phases and sums in f32 (the CPU uses f64 geometry and f32 grids);
//!   positions are formed from small lattice offsets around the probe so that the f32 phase
//!   error stays below 1e-3 rad at 8 cm. Lattice cells exactly at the reach limits, and march
//!   samples exactly on voxel faces, may fall on the other side (rare, local).
//! - Speckle sums in fixed point with 2^-24 resolution (quantisation 1e-5 of a -44 dB
//!   scatterer's amplitude).
//! - `exp` and `cos`/`sin` are the shader's (the CPU interpolates tables within 1e-5).
//! - The scatterer keep/drop test of sparse tissue compares 24 bits of the hash (the CPU 53).
//! - The nerve texture uses the honeycomb without a fibre axis (what [`CtMedium`] gives the CPU).
//!
//! # Agreement measured (lavapipe, `tests/ultrasound_gpu.rs`: 128 lines, 8 cm, seed 11)
//! | probe, scene | envelope NCC | mean abs dB | mean dB | image NCC | mean abs grey |
//! |---|---|---|---|---|---|
//! | linear, uniform 40 HU | 1 - 1.4e-10 | 0.0002 | -4e-5 | 1 - 5e-8 | 0.0002 |
//! | curvilinear, uniform | 1 - 1.9e-8 | 0.0016 | 4e-5 | 1 - 6.4e-7 | 0.0025 |
//! | linear, fat/muscle, bone plate, needle, target | 1 - 8e-11 | 0.0003 | -5e-5 | 1 - 9e-8 | 0.0002 |
//! | curvilinear, same | 1 - 8.8e-9 | 0.0016 | 2e-5 | 1 - 4.9e-7 | 0.0018 |
//!
//! # Time (bench `ultrasound_gpu`, 8 cm, layered scene with needle; 2 cores shared with
//! other jobs, so absolute times are noisy: compare GPU and CPU within one run)
//! On lavapipe the GPU path is slower than the CPU reference on the same cores. Without the
//! voxel cache of the deposit (load about 2): linear default (422 lines x 907 samples) 436 ms
//! against 278 ms, 256 lines 416 against 264; curvilinear default (386 x 374) 131 against 101.
//! With it (load about 3): linear default 700 against 647, 256 lines 641 against 580;
//! curvilinear default 186 against 170, 256 lines 173 against 167. The deposit is 80-90 % of
//! the GPU frame (linear, quiet run: deposit 390 ms, convolutions 49, march 19, display 5,
//! read-back 1, set-up 1; medium upload 50 ms once per key): about 10^7 scatterers, each with
//! two emulated 64-bit SplitMix64 hashes and an exponential, which llvmpipe runs on 8-wide AVX2
//! lanes without native 64-bit multiplies. On a hardware GPU the same work is parallel over
//! 10^5 columns; the design targets that case.

use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use sim_core::material::MaterialClass;
use sim_core::ultrasound::needle::{
    NEEDLE_ROUGHNESS, REVERB_COUNT, REVERB_RATIO, SPECULAR_LOBE_DEG, STEEL_REFLECTION,
};
use sim_core::ultrasound::scatter::{
    FASCICLE_CELL_MM, FASCICLE_INSIDE, FASCICLE_OUTSIDE, FASCICLE_RADIUS_MM, LatticeBounds,
    lattice_bounds,
};
use sim_core::ultrasound::{
    BModeFrame, Beam, CtMedium, Envelope, ProbeKind, ScanGeometry, ScanRequest, UltrasoundError,
    needle_view,
};
use sim_core::volume::VolumeGrid;
use wgpu::util::DeviceExt;

use crate::gpu::GpuContext;

mod tables;
pub use tables::UltrasoundTimings;
#[cfg(feature = "test-support")]
pub use tables::layered_test_volume;
use tables::*;

/// Fixed-point scale of the deposit grid: one unit is `2^-24` of a unit amplitude (simulator
/// choice). A node overflows at 128 (a hundred coincident unit point targets); tissue scatterers
/// are below 0.01 each.
pub const FIXED_POINT_SCALE: f32 = 16_777_216.0;

/// Why a GPU frame could not be made.
#[derive(Debug, thiserror::Error)]
pub enum UltrasoundGpuError {
    /// The request is invalid: the same refusal, naming the same field, as the CPU's.
    #[error(transparent)]
    Invalid(#[from] UltrasoundError),
    /// The GPU could not make the frame (buffer limits, readback, mismatched volumes).
    #[error("ultrasound GPU: {0}")]
    Gpu(String),
}

/// The GPU B-mode scanner: pipelines built once, the medium uploaded once per key.
pub struct GpuUltrasound {
    ctx: GpuContext,
    pipelines: Pipelines,
    lut: wgpu::Buffer,
    sphere: wgpu::Buffer,
    params: wgpu::Buffer,
    medium: Option<MediumUpload>,
    buffers: Option<FrameBuffers>,
    timings: UltrasoundTimings,
    /// Submit and wait for each pass separately to time it (slower; for the bench).
    pub profile: bool,
}

struct Pipelines {
    deposit_lattice: wgpu::ComputePipeline,
    deposit_points: wgpu::ComputePipeline,
    lateral: wgpu::ComputePipeline,
    axial: wgpu::ComputePipeline,
    march: wgpu::ComputePipeline,
    display: wgpu::ComputePipeline,
}

struct MediumUpload {
    key: u64,
    grid: VolumeGrid,
    codes: wgpu::Buffer,
}

/// Buffers of one frame shape.
struct FrameBuffers {
    shape: Shape,
    tables: wgpu::Buffer,
    grid_re: wgpu::Buffer,
    grid_im: wgpu::Buffer,
    lat_weights: wgpu::Buffer,
    lat: wgpu::Buffer,
    axial_taps: wgpu::Buffer,
    speckle: wgpu::Buffer,
    log_gain: wgpu::Buffer,
    echo: wgpu::Buffer,
    envelope: wgpu::Buffer,
    pixels: wgpu::Buffer,
    staging: wgpu::Buffer,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Shape {
    lines: usize,
    samples: usize,
    pad_l: usize,
    pad_s: usize,
    n_march: usize,
    width: usize,
    height: usize,
}

impl Shape {
    fn stride(&self) -> usize {
        self.samples + 2 * self.pad_s
    }
    fn grid_len(&self) -> usize {
        (self.lines + 2 * self.pad_l) * self.stride()
    }
}

/// The uniforms of every pass (layout of `Params` in `common.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
struct Params {
    geo_u: [u32; 4],
    pad_u: [u32; 4],
    geo_f: [f32; 4],
    samp_f: [f32; 4],
    lateral: [f32; 4],
    beam: [f32; 4],
    elevation: [f32; 4],
    vorigin: [f32; 4],
    inv_spacing: [f32; 4],
    dims: [u32; 4],
    axes: [u32; 4],
    seed: [u32; 4],
    idx: [i32; 4],
    n0: [i32; 4],
    cols: [u32; 4],
    q_zero: [f32; 4],
    unit_a: [f32; 4],
    unit_b: [f32; 4],
    unit_m: [f32; 4],
    vlattice: [f32; 4],
    reach: [f32; 4],
    elev_beam: [f32; 4],
    display: [f32; 4],
    display_u: [u32; 4],
    display_f: [f32; 4],
    tgc_a: [f32; 4],
    tgc_b: [f32; 4],
    needle_a: [f32; 4],
    needle_b: [f32; 4],
    needle_c: [f32; 4],
    march_f: [f32; 4],
    march_u: [u32; 4],
}

const COMMON: &str = include_str!("common.wgsl");
const MEDIUM: &str = include_str!("medium.wgsl");

impl Pipelines {
    fn new(device: &wgpu::Device) -> Pipelines {
        let module = |label: &str, parts: &[&str]| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(parts.concat().into()),
            })
        };
        let deposit = module(
            "ultrasound deposit",
            &[COMMON, MEDIUM, include_str!("deposit.wgsl")],
        );
        let convolve = module(
            "ultrasound convolve",
            &[COMMON, include_str!("convolve.wgsl")],
        );
        let march = module(
            "ultrasound march",
            &[COMMON, MEDIUM, include_str!("march.wgsl")],
        );
        let display = module(
            "ultrasound display",
            &[COMMON, include_str!("display.wgsl")],
        );
        let fascicle: [(&str, f64); 4] = [
            ("fascicle_cell_mm", FASCICLE_CELL_MM),
            ("fascicle_radius_mm", FASCICLE_RADIUS_MM),
            ("fascicle_inside", FASCICLE_INSIDE),
            ("fascicle_outside", FASCICLE_OUTSIDE),
        ];
        let pipeline = |m: &wgpu::ShaderModule, entry: &str, constants: &[(&str, f64)]| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: m,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants,
                    ..Default::default()
                },
                cache: None,
            })
        };
        Pipelines {
            deposit_lattice: pipeline(&deposit, "deposit_lattice", &fascicle),
            deposit_points: pipeline(&deposit, "deposit_points", &fascicle),
            lateral: pipeline(&convolve, "lateral", &[]),
            axial: pipeline(&convolve, "axial", &[]),
            march: pipeline(
                &march,
                "march",
                &[
                    ("gel_max_mm", sim_core::ultrasound::GEL_MAX_MM),
                    ("air_below_mrayl", sim_core::ultrasound::AIR_BELOW_MRAYL),
                ],
            ),
            display: pipeline(&display, "display", &[]),
        }
    }
}

/// Everything of one frame computed on the CPU before the passes.
struct FramePlan {
    geo: ScanGeometry,
    beam: Beam,
    shape: Shape,
    params: Params,
    tables: Vec<[f32; 4]>,
    lat_weights: Vec<f32>,
    axial_taps: Vec<f32>,
    points: Vec<[f32; 4]>,
    dz: f64,
    origin_mm: [f64; 2],
}

impl GpuUltrasound {
    /// Builds the pipelines on a context (cloned: it shares the device and queue).
    pub fn new(ctx: &GpuContext) -> Result<GpuUltrasound, UltrasoundGpuError> {
        let device = &ctx.device;
        let storage = |label: &str, bytes: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let lut = storage(
            "ultrasound property table",
            bytemuck::cast_slice(&property_table()),
        );
        let sphere = storage(
            "ultrasound normal directions",
            bytemuck::cast_slice(&sphere_directions()),
        );
        let params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("ultrasound params"),
            size: std::mem::size_of::<Params>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(GpuUltrasound {
            ctx: ctx.clone(),
            pipelines: Pipelines::new(device),
            lut,
            sphere,
            params,
            medium: None,
            buffers: None,
            timings: UltrasoundTimings::default(),
            profile: false,
        })
    }

    /// The adapter this scanner runs on.
    pub fn adapter_name(&self) -> &str {
        &self.ctx.summary.name
    }

    /// Phases of the last frame.
    pub fn last_timings(&self) -> UltrasoundTimings {
        self.timings
    }

    /// The same frame as `sim_core::ultrasound::scan(req)` within the tolerances of
    /// `tests/ultrasound_gpu.rs`. `medium` is the medium `req.medium` refers to, as voxels; it is
    /// uploaded once and reused while `medium_key` stays the same. Inputs are validated exactly
    /// as on the CPU ([`ScanRequest::geometry`]).
    pub fn scan(
        &mut self,
        req: &ScanRequest<'_>,
        medium: &CtMedium<'_>,
        medium_key: u64,
    ) -> Result<BModeFrame, UltrasoundGpuError> {
        let (geo, beam) = req.geometry()?;
        self.timings = UltrasoundTimings::default();
        let t = Instant::now();
        self.upload_medium(medium, medium_key)?;
        self.timings.medium_upload_ms = ms(t);
        let t = Instant::now();
        let grid = self
            .medium
            .as_ref()
            .map(|m| m.grid)
            .ok_or_else(|| gpu("no medium"))?;
        let plan = plan_frame(req, geo, beam, &grid);
        self.ensure_buffers(plan.shape)?;
        let b = self
            .buffers
            .as_ref()
            .ok_or_else(|| gpu("no frame buffers"))?;
        let queue = &self.ctx.queue;
        queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&plan.params));
        queue.write_buffer(&b.tables, 0, bytemuck::cast_slice(&plan.tables));
        queue.write_buffer(&b.lat_weights, 0, bytemuck::cast_slice(&plan.lat_weights));
        queue.write_buffer(&b.axial_taps, 0, bytemuck::cast_slice(&plan.axial_taps));
        let points = (!plan.points.is_empty()).then(|| {
            self.ctx
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("ultrasound point targets"),
                    contents: bytemuck::cast_slice(&plan.points),
                    usage: wgpu::BufferUsages::STORAGE,
                })
        });
        let groups = self.bind_groups(points.as_ref());
        self.timings.setup_ms = ms(t);
        self.run_passes(&plan, &groups, points.is_some())?;
        let t = Instant::now();
        let (envelope, words) = self.read_back(&plan.shape)?;
        self.timings.readback_ms = ms(t);
        let t = Instant::now();
        let frame = finish_frame(req, &plan, envelope, &words);
        self.timings.finish_ms = ms(t);
        Ok(frame)
    }

    fn upload_medium(&mut self, medium: &CtMedium<'_>, key: u64) -> Result<(), UltrasoundGpuError> {
        if self.medium.as_ref().is_some_and(|m| m.key == key) {
            return Ok(());
        }
        let hu = medium.hu;
        let grid = hu.grid;
        if hu.data.len() != grid.len() || medium.labels.is_some_and(|l| l.data.len() != grid.len())
        {
            return Err(gpu("the HU and label volumes do not match their grid"));
        }
        let bytes = (grid.len().max(1) * 4) as u64;
        if bytes > self.ctx.limits.max_storage_buffer_binding_size
            || bytes > self.ctx.limits.max_buffer_size
        {
            return Err(gpu(&format!(
                "the medium ({bytes} bytes) exceeds the adapter's storage buffer limit"
            )));
        }
        let codes: Vec<f32> = (0..grid.len().max(1))
            .map(|i| {
                let Some(&h) = hu.data.get(i) else {
                    return -1e5;
                };
                if let Some(l) = medium.labels.map(|l| l.data[i])
                    && MaterialClass::from_label(l).is_some()
                {
                    return LABEL_BASE + f32::from(l);
                }
                // NaN maps to cortex, as `hu_props(NaN)` does (no knot compares true).
                if h.is_nan() { 1e5 } else { h.clamp(-1e5, 1e5) }
            })
            .collect();
        let buf = self
            .ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("ultrasound medium"),
                contents: bytemuck::cast_slice(&codes),
                usage: wgpu::BufferUsages::STORAGE,
            });
        self.medium = Some(MediumUpload {
            key,
            grid,
            codes: buf,
        });
        Ok(())
    }

    fn ensure_buffers(&mut self, shape: Shape) -> Result<(), UltrasoundGpuError> {
        if self.buffers.as_ref().is_some_and(|b| b.shape == shape) {
            return Ok(());
        }
        let limits = &self.ctx.limits;
        let device = &self.ctx.device;
        let st = shape.stride();
        let sizes = [
            shape.grid_len() * 4,
            shape.lines * st * 8,
            shape.lines * shape.samples * 8,
            shape.lines * shape.n_march * 4,
            shape.width * shape.height * 4,
        ];
        if let Some(s) = sizes
            .iter()
            .find(|&&s| s as u64 > limits.max_storage_buffer_binding_size)
        {
            return Err(gpu(&format!(
                "a frame buffer of {s} bytes exceeds the adapter's storage buffer limit"
            )));
        }
        let buf = |label: &str, size: usize, extra: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16) as u64,
                usage: wgpu::BufferUsages::STORAGE | extra,
                mapped_at_creation: false,
            })
        };
        let dst = wgpu::BufferUsages::COPY_DST;
        let src = wgpu::BufferUsages::COPY_SRC;
        let env_bytes = shape.lines * shape.samples * 4;
        let pix_bytes = shape.width * shape.height * 4;
        self.buffers = Some(FrameBuffers {
            shape,
            tables: buf("ultrasound tables", shape.samples * 16, dst),
            grid_re: buf("ultrasound grid I", sizes[0], dst),
            grid_im: buf("ultrasound grid Q", sizes[0], dst),
            lat_weights: buf(
                "ultrasound lateral weights",
                (2 * shape.pad_l + 1) * st * 4,
                dst,
            ),
            lat: buf("ultrasound lateral", sizes[1], dst),
            axial_taps: buf("ultrasound axial taps", (2 * shape.pad_s + 1) * 4, dst),
            speckle: buf("ultrasound speckle", sizes[2], dst),
            log_gain: buf("ultrasound log gain", sizes[3], dst),
            echo: buf("ultrasound echoes", sizes[2], dst),
            envelope: buf("ultrasound envelope", env_bytes, src),
            pixels: buf("ultrasound pixels", pix_bytes, src),
            staging: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("ultrasound readback"),
                size: (env_bytes + pix_bytes) as u64,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        });
        Ok(())
    }

    fn bind_groups(&self, points: Option<&wgpu::Buffer>) -> BindGroups {
        let device = &self.ctx.device;
        let b = self
            .buffers
            .as_ref()
            .expect("buffers are ensured before binding");
        let m = self
            .medium
            .as_ref()
            .expect("the medium is uploaded before binding");
        let resource = |i: u32| -> &wgpu::Buffer {
            match i {
                0 => &self.params,
                1 => &m.codes,
                2 => &self.lut,
                3 => &b.tables,
                4 => &b.grid_re,
                5 => &b.grid_im,
                7 => &b.lat_weights,
                8 => &b.lat,
                9 => &b.axial_taps,
                10 => &b.speckle,
                11 => &self.sphere,
                12 => &b.log_gain,
                13 => &b.echo,
                14 => &b.envelope,
                _ => &b.pixels,
            }
        };
        let group = |p: &wgpu::ComputePipeline, bindings: &[u32], extra: Option<&wgpu::Buffer>| {
            let mut entries: Vec<wgpu::BindGroupEntry<'_>> = bindings
                .iter()
                .map(|&i| wgpu::BindGroupEntry {
                    binding: i,
                    resource: resource(i).as_entire_binding(),
                })
                .collect();
            if let Some(x) = extra {
                entries.push(wgpu::BindGroupEntry {
                    binding: 6,
                    resource: x.as_entire_binding(),
                });
            }
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &p.get_bind_group_layout(0),
                entries: &entries,
            })
        };
        let p = &self.pipelines;
        BindGroups {
            deposit_lattice: group(&p.deposit_lattice, &[0, 1, 2, 3, 4, 5], None),
            deposit_points: points.map(|x| group(&p.deposit_points, &[0, 4, 5], Some(x))),
            lateral: group(&p.lateral, &[0, 4, 5, 7, 8], None),
            axial: group(&p.axial, &[0, 8, 9, 10], None),
            march: group(&p.march, &[0, 1, 2, 3, 10, 11, 12, 13, 14], None),
            display: group(&p.display, &[0, 14, 15], None),
        }
    }

    fn run_passes(
        &mut self,
        plan: &FramePlan,
        g: &BindGroups,
        has_points: bool,
    ) -> Result<(), UltrasoundGpuError> {
        let b = self
            .buffers
            .as_ref()
            .expect("buffers are ensured before the passes");
        let s = plan.shape;
        let p = &self.pipelines;
        let cols = [plan.params.cols[0], plan.params.cols[1]];
        type Stage<'a> = Vec<(&'a wgpu::ComputePipeline, &'a wgpu::BindGroup, [u32; 3])>;
        let mut deposit: Stage<'_> = vec![(
            &p.deposit_lattice,
            &g.deposit_lattice,
            [cols[0].div_ceil(8), cols[1].div_ceil(8), 1],
        )];
        if let (true, Some(dp)) = (has_points, &g.deposit_points) {
            deposit.push((
                &p.deposit_points,
                dp,
                [(plan.points.len() as u32).div_ceil(64), 1, 1],
            ));
        }
        let lines = s.lines as u32;
        let convolve: Stage<'_> = vec![
            (
                &p.lateral,
                &g.lateral,
                [(s.stride() as u32).div_ceil(64), lines, 1],
            ),
            (
                &p.axial,
                &g.axial,
                [(s.samples as u32).div_ceil(64), lines, 1],
            ),
        ];
        let march: Stage<'_> = vec![(&p.march, &g.march, [lines.div_ceil(8), 1, 1])];
        let display: Stage<'_> = vec![(
            &p.display,
            &g.display,
            [(s.width as u32).div_ceil(64), s.height as u32, 1],
        )];
        let env_bytes = (s.lines * s.samples * 4) as u64;
        let pix_bytes = (s.width * s.height * 4) as u64;
        let record = |enc: &mut wgpu::CommandEncoder, stage: &Stage<'_>| {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("ultrasound"),
                timestamp_writes: None,
            });
            for (pipe, group, n) in stage {
                pass.set_pipeline(pipe);
                pass.set_bind_group(0, *group, &[]);
                pass.dispatch_workgroups(n[0], n[1], n[2]);
            }
        };
        let device = &self.ctx.device;
        let new_encoder = || {
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("ultrasound"),
            })
        };
        let copy_out = |enc: &mut wgpu::CommandEncoder| {
            enc.copy_buffer_to_buffer(&b.envelope, 0, &b.staging, 0, env_bytes);
            enc.copy_buffer_to_buffer(&b.pixels, 0, &b.staging, env_bytes, pix_bytes);
        };
        let t = Instant::now();
        if self.profile {
            let mut times = [0.0; 4];
            for (k, stage) in [&deposit, &convolve, &march, &display]
                .into_iter()
                .enumerate()
            {
                let t = Instant::now();
                let mut enc = new_encoder();
                if k == 0 {
                    enc.clear_buffer(&b.grid_re, 0, None);
                    enc.clear_buffer(&b.grid_im, 0, None);
                }
                record(&mut enc, stage);
                if k == 3 {
                    copy_out(&mut enc);
                }
                self.ctx.queue.submit([enc.finish()]);
                device
                    .poll(wgpu::PollType::wait_indefinitely())
                    .map_err(|e| gpu(&e.to_string()))?;
                times[k] = ms(t);
            }
            self.timings.deposit_ms = times[0];
            self.timings.convolve_ms = times[1];
            self.timings.march_ms = times[2];
            self.timings.display_ms = times[3];
        } else {
            let mut enc = new_encoder();
            enc.clear_buffer(&b.grid_re, 0, None);
            enc.clear_buffer(&b.grid_im, 0, None);
            for stage in [&deposit, &convolve, &march, &display] {
                record(&mut enc, stage);
            }
            copy_out(&mut enc);
            self.ctx.queue.submit([enc.finish()]);
            device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| gpu(&e.to_string()))?;
        }
        self.timings.gpu_ms = ms(t);
        Ok(())
    }

    fn read_back(&self, s: &Shape) -> Result<(Vec<f32>, Vec<u32>), UltrasoundGpuError> {
        let b = self
            .buffers
            .as_ref()
            .expect("buffers exist after the passes");
        let (tx, rx) = std::sync::mpsc::channel();
        b.staging.map_async(wgpu::MapMode::Read, .., move |r| {
            // The receiver lives until recv() below returns.
            let _ = tx.send(r);
        });
        self.ctx
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| gpu(&e.to_string()))?;
        rx.recv()
            .map_err(|e| gpu(&e.to_string()))?
            .map_err(|e| gpu(&e.to_string()))?;
        let n_env = s.lines * s.samples;
        let out = {
            let view = b
                .staging
                .get_mapped_range(..)
                .map_err(|e| gpu(&e.to_string()))?;
            let words: &[u32] = bytemuck::cast_slice(&view);
            let env: Vec<f32> = words[..n_env].iter().map(|&w| f32::from_bits(w)).collect();
            (env, words[n_env..n_env + s.width * s.height].to_vec())
        };
        b.staging.unmap();
        Ok(out)
    }
}

struct BindGroups {
    deposit_lattice: wgpu::BindGroup,
    deposit_points: Option<wgpu::BindGroup>,
    lateral: wgpu::BindGroup,
    axial: wgpu::BindGroup,
    march: wgpu::BindGroup,
    display: wgpu::BindGroup,
}

fn gpu(msg: &str) -> UltrasoundGpuError {
    UltrasoundGpuError::Gpu(msg.to_owned())
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The CPU part of a frame: sim-core's padding, tables, weights and lattice bounds (the same
/// expressions as `sim_core::ultrasound::scan` and `scatter::deposit_scatterers`).
fn plan_frame(
    req: &ScanRequest<'_>,
    geo: ScanGeometry,
    beam: Beam,
    grid: &VolumeGrid,
) -> FramePlan {
    let samples = req.sampling.samples_per_line;
    let tables = Tables::new(&beam, geo.depth_mm, samples);
    let dz = tables.dz;
    let max_lat_lines = (0..samples)
        .map(|s| tables.rows[s][2] / geo.line_spacing_mm(s as f64 * dz))
        .fold(0.0f64, f64::max);
    let pad_l = (3.5 * conv_sigma(max_lat_lines)).ceil() as usize + 1;
    let pad_s = (3.5 * conv_sigma(tables.axial_sigma_mm / dz)).ceil() as usize + 1;
    let step = req.sampling.march_step_mm;
    let n_march = (geo.depth_mm / step).ceil() as usize + 1;
    let (x0, x1, y0, y1) = geo.image_extent_mm();
    let pixel_mm = req.sampling.pixel_mm;
    let shape = Shape {
        lines: geo.lines,
        samples,
        pad_l,
        pad_s,
        n_march,
        width: ((x1 - x0) / pixel_mm).floor() as usize + 1,
        height: ((y1 - y0) / pixel_mm).floor() as usize + 1,
    };
    let st = shape.stride();

    // Lateral weights per padded sample (convolve_lateral), axial taps (convolve_axial).
    let ntap = 2 * pad_l + 1;
    let mut lat_weights = vec![0f32; ntap * st];
    for sp in 0..st {
        let s = sp as isize - pad_s as isize;
        let z = s as f64 * dz;
        let si = (s.max(0) as usize).min(samples - 1);
        let sig = conv_sigma(tables.rows[si][2] / geo.line_spacing_mm(z.max(0.0)));
        let taps = gaussian_taps(sig, pad_l);
        let en = tables.rows[si][3] as f32;
        for t in 0..ntap {
            lat_weights[t * st + sp] = taps[t] * en;
        }
    }
    let axial_taps = gaussian_taps(conv_sigma(tables.axial_sigma_mm / dz), pad_s);

    // Lattice bounds: sim-core's own (`scatter::lattice_bounds`), so both visit the same cells.
    let f = &geo.frame;
    let h = req.sampling.scatter_cell_mm;
    let t_e = ELEV_REACH_FWHM * tables.max_elev_fwhm_mm;
    let m = 1.5 * tables.max_lat_fwhm_mm + 4.0 * tables.axial_sigma_mm;
    let LatticeBounds {
        lo_cell,
        hi_cell,
        column_axis: am,
        across: (aa, ab),
    } = lattice_bounds(f, (x0 - m, x1 + m, y0 - m, y1 + m), t_e, h);
    let idx_lo = |a: usize| lo_cell[a];
    let idx_hi = |a: usize| hi_cell[a];
    let unit: [DVec3; 3] = std::array::from_fn(|a| f.to_probe(f.origin + DVec3::AXES[a]));
    let drift = unit[am].x.hypot(unit[am].y) / unit[am].z.abs();
    let lip = beam.elevation_aperture_mm / beam.elevation_focus_mm / std::f64::consts::SQRT_2;
    let wander = t_e * drift;
    // The lattice point nearest the probe: positions on the GPU are small offsets from it.
    let n0: [i64; 3] = std::array::from_fn(|a| (f.origin[a] / h).round() as i64);
    let n0_mm = DVec3::new(n0[0] as f64 * h, n0[1] as f64 * h, n0[2] as f64 * h);
    let q_zero = f.to_probe(n0_mm);
    let spacing = DVec3::from(grid.spacing_mm);
    let grid_origin = DVec3::from(grid.origin_mm);
    let vorigin = (f.origin - grid_origin) / spacing;
    let vlattice = (n0_mm - grid_origin) / spacing;
    let norm = amplitude_norm(&beam, &tables, h);

    // Point targets (scan), weighted and phase-rotated here in f64.
    let k0 = 2.0 * std::f64::consts::PI / beam.wavelength_mm();
    let points = req
        .targets
        .iter()
        .map(|t| {
            let q = f.to_probe(t.position_mm);
            let (u, z) = geo.plane_to_line(q.x, q.y);
            let w = t.amplitude * tables.elevation_weight(q.z, z);
            let (sn, cs) = (2.0 * k0 * z).sin_cos();
            [u as f32, (z / dz) as f32, (w * cs) as f32, (w * sn) as f32]
        })
        .collect();

    let (needle_a, needle_b) = match &req.needle {
        Some(n) => (
            v4(n.hub_mm - f.origin, n.diameter_mm),
            v4(n.tip_mm - n.hub_mm, 0.0),
        ),
        None => ([0.0; 4], [0.0; 4]),
    };
    let tgc = req.settings.tgc_db;
    let i32_of = |x: i64| x.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
    let params = Params {
        geo_u: [
            u32::from(geo.spec.kind == ProbeKind::Curvilinear),
            geo.lines as u32,
            samples as u32,
            n_march as u32,
        ],
        pad_u: [
            pad_l as u32,
            pad_s as u32,
            st as u32,
            (geo.lines + 2 * pad_l) as u32,
        ],
        geo_f: [
            geo.spec.footprint_mm as f32,
            geo.spec.radius_mm as f32,
            geo.half_sector_rad() as f32,
            geo.depth_mm as f32,
        ],
        samp_f: [
            dz as f32,
            step as f32,
            (2.0 / beam.wavelength_mm()) as f32,
            tables.axial_sigma_mm as f32,
        ],
        lateral: v4(f.lateral, 0.0),
        beam: v4(f.beam, 0.0),
        elevation: v4(f.elevation, 0.0),
        vorigin: v4(vorigin, 0.0),
        inv_spacing: v4(DVec3::ONE / spacing, 0.0),
        dims: [
            grid.dims[0] as u32,
            grid.dims[1] as u32,
            grid.dims[2] as u32,
            0,
        ],
        axes: [aa as u32, ab as u32, am as u32, 0],
        seed: [
            req.seed as u32,
            (req.seed >> 32) as u32,
            FIXED_POINT_SCALE.to_bits(),
            0,
        ],
        idx: [
            i32_of(idx_lo(aa)),
            i32_of(idx_lo(ab)),
            i32_of(idx_lo(am)),
            i32_of(idx_hi(am)),
        ],
        n0: [i32_of(n0[0]), i32_of(n0[1]), i32_of(n0[2]), 0],
        cols: [
            (idx_hi(aa) - idx_lo(aa) + 1).max(0) as u32,
            (idx_hi(ab) - idx_lo(ab) + 1).max(0) as u32,
            0,
            0,
        ],
        q_zero: v4(q_zero, h),
        unit_a: v4(unit[aa], 0.0),
        unit_b: v4(unit[ab], 0.0),
        unit_m: v4(unit[am], 0.0),
        vlattice: v4(vlattice, 0.0),
        reach: [
            t_e as f32,
            (ELEV_REACH_FWHM * lip * wander) as f32,
            pad_l as f32,
            (pad_s as f64 * dz) as f32,
        ],
        elev_beam: [
            beam.wavelength_mm() as f32,
            beam.elevation_focus_mm as f32,
            beam.elevation_aperture_mm as f32,
            norm as f32,
        ],
        display: [
            pixel_mm as f32,
            x0 as f32,
            y0 as f32,
            req.settings.gain_db as f32,
        ],
        display_u: [shape.width as u32, shape.height as u32, 0, 0],
        display_f: [
            req.settings.dynamic_range_db as f32,
            (geo.depth_mm / sim_core::ultrasound::TGC_BANDS as f64) as f32,
            0.0,
            0.0,
        ],
        tgc_a: [tgc[0] as f32, tgc[1] as f32, tgc[2] as f32, tgc[3] as f32],
        tgc_b: [tgc[4] as f32, tgc[5] as f32, 0.0, 0.0],
        needle_a,
        needle_b,
        needle_c: [
            STEEL_REFLECTION as f32,
            SPECULAR_LOBE_DEG.to_radians() as f32,
            NEEDLE_ROUGHNESS as f32,
            REVERB_RATIO as f32,
        ],
        march_f: [
            MIN_INTERFACE_R as f32,
            INTERFACE_LOBE_DEG.to_radians() as f32,
            NORMAL_STEP_MM as f32,
            (2.0 * beam.frequency_mhz * step * 0.1 * NP_PER_DB) as f32,
        ],
        march_u: [
            REVERB_COUNT as u32,
            sim_core::ultrasound::sphere_directions().len() as u32,
            0,
            0,
        ],
    };
    FramePlan {
        geo,
        beam,
        shape,
        params,
        tables: tables.rows.iter().map(|r| r.map(|x| x as f32)).collect(),
        lat_weights,
        axial_taps,
        points,
        dz,
        origin_mm: [x0, y0],
    }
}

/// The frame from the read-back envelope and pixel words.
fn finish_frame(
    req: &ScanRequest<'_>,
    plan: &FramePlan,
    envelope: Vec<f32>,
    words: &[u32],
) -> BModeFrame {
    let s = plan.shape;
    BModeFrame {
        width: s.width,
        height: s.height,
        pixel_mm: req.sampling.pixel_mm,
        origin_mm: plan.origin_mm,
        pixels: words.iter().map(|&w| (w & 0xFF) as u8).collect(),
        inside: words.iter().map(|&w| w & 0x100 != 0).collect(),
        envelope: Envelope {
            lines: s.lines,
            samples: s.samples,
            sample_mm: plan.dz,
            data: envelope,
        },
        needle: req
            .needle
            .as_ref()
            .map(|n| needle_view(n, &plan.geo, &plan.beam)),
        settings: req.settings,
    }
}
