//! The compute pipelines of the B-mode passes, the buffers that live as long as they do (the
//! tissue property table, the interface-normal directions and the uniforms), the bind groups of
//! one frame and the recording and submission of its passes.

use std::time::Instant;

use sim_core::ultrasound::scatter::{
    FASCICLE_CELL_MM, FASCICLE_INSIDE, FASCICLE_OUTSIDE, FASCICLE_RADIUS_MM,
};
use wgpu::util::DeviceExt;

use super::buffers::{FrameBuffers, MediumUpload};
use super::error::{UltrasoundGpuError, gpu};
use super::plan::{FramePlan, Params};
use super::tables::{UltrasoundTimings, ms, property_table, sphere_directions};

const COMMON: &str = include_str!("common.wgsl");
const MEDIUM: &str = include_str!("medium.wgsl");

/// The pipelines of the five passes and the buffers every frame binds unchanged.
pub(super) struct Pipelines {
    deposit_lattice: wgpu::ComputePipeline,
    deposit_points: wgpu::ComputePipeline,
    lateral: wgpu::ComputePipeline,
    axial: wgpu::ComputePipeline,
    march: wgpu::ComputePipeline,
    display: wgpu::ComputePipeline,
    /// Tissue properties per HU and per class (`tables::property_table`).
    lut: wgpu::Buffer,
    /// sim-core's interface-normal directions.
    sphere: wgpu::Buffer,
    /// The uniforms ([`Params`]), written once per frame.
    params: wgpu::Buffer,
}

/// The bind groups of one frame (they name the frame's buffers).
pub(super) struct BindGroups {
    deposit_lattice: wgpu::BindGroup,
    deposit_points: Option<wgpu::BindGroup>,
    lateral: wgpu::BindGroup,
    axial: wgpu::BindGroup,
    march: wgpu::BindGroup,
    display: wgpu::BindGroup,
}

/// The dispatches of one stage: pipeline, bind group, workgroup counts.
type Stage<'a> = Vec<(&'a wgpu::ComputePipeline, &'a wgpu::BindGroup, [u32; 3])>;

impl Pipelines {
    /// Compiles the shaders (each entry point with the constants sim-core gives it) and uploads
    /// the tables that do not change between frames.
    pub(super) fn new(device: &wgpu::Device) -> Pipelines {
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
        let storage = |label: &str, bytes: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage: wgpu::BufferUsages::STORAGE,
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
            lut: storage(
                "ultrasound property table",
                bytemuck::cast_slice(&property_table()),
            ),
            sphere: storage(
                "ultrasound normal directions",
                bytemuck::cast_slice(&sphere_directions()),
            ),
            params: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("ultrasound params"),
                size: std::mem::size_of::<Params>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        }
    }

    /// Writes one frame's uniforms.
    pub(super) fn write_params(&self, queue: &wgpu::Queue, params: &Params) {
        queue.write_buffer(&self.params, 0, bytemuck::bytes_of(params));
    }

    /// The bind groups of a frame over the medium `m` and the frame buffers `b`. Binding numbers
    /// are those of `common.wgsl` and the pass shaders; 6 is the point targets, bound only when
    /// there are some.
    pub(super) fn bind_groups(
        &self,
        device: &wgpu::Device,
        m: &MediumUpload,
        b: &FrameBuffers,
        points: Option<&wgpu::Buffer>,
    ) -> BindGroups {
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
        BindGroups {
            deposit_lattice: group(&self.deposit_lattice, &[0, 1, 2, 3, 4, 5], None),
            deposit_points: points.map(|x| group(&self.deposit_points, &[0, 4, 5], Some(x))),
            lateral: group(&self.lateral, &[0, 4, 5, 7, 8], None),
            axial: group(&self.axial, &[0, 8, 9, 10], None),
            march: group(&self.march, &[0, 1, 2, 3, 10, 11, 12, 13, 14], None),
            display: group(&self.display, &[0, 14, 15], None),
        }
    }

    /// Records and submits the passes of a frame (deposit, convolutions, march, display) and
    /// the copy of envelope and pixels to the staging buffer, and waits for them. With
    /// `profile`, each stage is submitted and waited for on its own and timed in `timings`;
    /// otherwise all go in one submission. The grid is cleared first either way.
    pub(super) fn run(
        &self,
        ctx: &crate::gpu::GpuContext,
        b: &FrameBuffers,
        plan: &FramePlan,
        g: &BindGroups,
        profile: bool,
        timings: &mut UltrasoundTimings,
    ) -> Result<(), UltrasoundGpuError> {
        let s = plan.shape;
        let cols = [plan.params.cols[0], plan.params.cols[1]];
        let mut deposit: Stage<'_> = vec![(
            &self.deposit_lattice,
            &g.deposit_lattice,
            [cols[0].div_ceil(8), cols[1].div_ceil(8), 1],
        )];
        if let Some(dp) = &g.deposit_points {
            deposit.push((
                &self.deposit_points,
                dp,
                [(plan.points.len() as u32).div_ceil(64), 1, 1],
            ));
        }
        let lines = s.lines as u32;
        let convolve: Stage<'_> = vec![
            (
                &self.lateral,
                &g.lateral,
                [(s.stride() as u32).div_ceil(64), lines, 1],
            ),
            (
                &self.axial,
                &g.axial,
                [(s.samples as u32).div_ceil(64), lines, 1],
            ),
        ];
        let march: Stage<'_> = vec![(&self.march, &g.march, [lines.div_ceil(8), 1, 1])];
        let display: Stage<'_> = vec![(
            &self.display,
            &g.display,
            [(s.width as u32).div_ceil(64), s.height as u32, 1],
        )];
        let env_bytes = (s.lines * s.samples * 4) as u64;
        let pix_bytes = (s.width * s.height * 4) as u64;
        let device = &ctx.device;
        let new_encoder = || {
            device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("ultrasound"),
            })
        };
        let copy_out = |enc: &mut wgpu::CommandEncoder| {
            enc.copy_buffer_to_buffer(&b.envelope, 0, &b.staging, 0, env_bytes);
            enc.copy_buffer_to_buffer(&b.pixels, 0, &b.staging, env_bytes, pix_bytes);
        };
        let wait = || {
            device
                .poll(wgpu::PollType::wait_indefinitely())
                .map(|_| ())
                .map_err(|e| gpu(&e.to_string()))
        };
        let t = Instant::now();
        if profile {
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
                ctx.queue.submit([enc.finish()]);
                wait()?;
                times[k] = ms(t);
            }
            timings.deposit_ms = times[0];
            timings.convolve_ms = times[1];
            timings.march_ms = times[2];
            timings.display_ms = times[3];
        } else {
            let mut enc = new_encoder();
            enc.clear_buffer(&b.grid_re, 0, None);
            enc.clear_buffer(&b.grid_im, 0, None);
            for stage in [&deposit, &convolve, &march, &display] {
                record(&mut enc, stage);
            }
            copy_out(&mut enc);
            ctx.queue.submit([enc.finish()]);
            wait()?;
        }
        timings.gpu_ms = ms(t);
        Ok(())
    }
}

/// Records one stage as one compute pass.
fn record(enc: &mut wgpu::CommandEncoder, stage: &Stage<'_>) {
    let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
        label: Some("ultrasound"),
        timestamp_writes: None,
    });
    for (pipe, group, n) in stage {
        pass.set_pipeline(pipe);
        pass.set_bind_group(0, *group, &[]);
        pass.dispatch_workgroups(n[0], n[1], n[2]);
    }
}
