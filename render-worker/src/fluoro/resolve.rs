//! The resolve pass (see the module map in `fluoro`): the spectral bins and the `ln T` table,
//! the iodine texture, the recording of the resolve over a rectangle, and the read-back.
//!
//! The resolve is a fragment pass over one screen-covering triangle, scissored, writing a
//! storage buffer (on lavapipe it then runs on the rasteriser's threads; as a compute kernel it
//! ran on a separate pool after them). It adds the L-buffer parts, clamps the cancellous chord,
//! computes the optical depths, marches the iodine field and evaluates
//! `T = sum_E w_E exp(-sum_b A_b R_b(E))`; on rays without steel or iodine `ln T` comes from a
//! table instead (see `ensure_spectral`). Two pipeline constants give four variants: without the
//! iodine march (frames without a contrast field: lavapipe executes a skipped branch masked, so
//! the branch alone was a noticeable part of the resolve) and without the needle's inputs (zero
//! outside its pixel box). The needle's box is one scissored draw with them, the rest of the
//! rectangle up to four draws without them, and every sample is resolved by exactly one draw
//! (storage writes of different draws are not ordered within a pass). Both variants give
//! bit-identical transmission where their inputs agree (tests in `tests/fluoro.rs`).
//!
//! # Cancellous clamp
//! The CPU clamps the cancellous chord of each contiguous run of bone to
//! `[0, run - 2 x shell]`, then removes the needle. The L-buffer has only the pixel's totals, so
//! the GPU clamps the total cancellous chord to `[0, bone total - 2 x shell]`: identical for rays
//! through one run of bone, and for any ray where the CPU clamp does not bind (every valid
//! inset); weaker otherwise. In transmission frames the needle is removed from the bone before
//! the clamp's excess moves to cortex, which differs from the CPU only where the clamp binds on a
//! ray through the needle (`render_chords` follows the CPU's order exactly).
use bytemuck::{Pod, Zeroable};
use sim_core::fluoro::{EnergyModel, FluoroMaterial, IodineField, Projection, SpectralModel};
use sim_core::material::MaterialClass;
use std::time::Instant;
use wgpu::util::DeviceExt;

use super::pipelines::{Pipelines, Targets};
use super::types::{
    FluoroGpuError, FrameTimings, Pending, PixelRect, PixelRectOut, intersect_rect, subtract_rect,
};
use crate::gpu::{GpuContext, GpuError, ReadbackError};

/// Size of the `ln T(A_water, A_bone)` table (columns, rows).
const LUT_DIMS: [usize; 2] = [512, 256];
/// Optical depths the table spans, from 0 (60 keV: 16 is 80 cm of soft tissue, 8 is 15 cm of
/// cortical bone); deeper pixels take the exact sum.
const LUT_MAX_DEPTH: [f64; 2] = [16.0, 8.0];

/// The resolve pass's state: its uniforms per region, the spectral tables of the last energy
/// model, and the empty iodine grid bound when a frame has none.
pub(super) struct ResolvePass {
    /// Uniforms of the full image (0) and of the supersampled needle region (1).
    uniforms: [wgpu::Buffer; 2],
    spectral: Option<SpectralTables>,
    empty_iodine: wgpu::Texture,
}

/// What one resolve reads besides the L-buffer targets.
pub(super) struct ResolveInput<'a> {
    pub(super) projection: &'a Projection,
    pub(super) model: &'a SpectralModel,
    pub(super) iodine: Option<&'a IodineField>,
    pub(super) region: PixelRect,
    /// The rectangle to resolve, `[x, y, w, h]` in region samples.
    pub(super) rect: [u32; 4],
    /// The needle's pixel box in region samples (where its inputs are read).
    pub(super) needle_rect: Option<[u32; 4]>,
    pub(super) has_needle: bool,
    pub(super) cortical_shell_mm: f64,
    /// Iodine ray-march step as a fraction of the smallest voxel spacing.
    pub(super) iodine_step_fraction: f64,
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

/// Spectral bins and the `ln T` table of one energy model, kept until the model changes.
struct SpectralTables {
    model: EnergyModel,
    bins: wgpu::Buffer,
    lut: wgpu::Buffer,
    lut_enabled: bool,
}

impl ResolvePass {
    pub(super) fn new(ctx: &GpuContext) -> ResolvePass {
        let uniforms = [0, 1].map(|_| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("fluoro resolve"),
                size: std::mem::size_of::<ResolveUniform>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            })
        });
        ResolvePass {
            uniforms,
            spectral: None,
            empty_iodine: iodine_texture(ctx, [1, 1, 1], &[0.0]),
        }
    }

    /// Uploads the spectral bins and, for polychromatic models, the `ln T` table.
    ///
    /// Without steel or iodine on a ray, `T` depends on the water and bone depths only; the
    /// resolve pass then interpolates `ln T` bilinearly in a 512 x 256 table over
    /// `[0, 16] x [0, 8]` (steps of 0.031) instead of summing ~75 exponentials. The error is
    /// `h^2 / 8` times the curvature of `ln T`, the variance of `R_b(E)` under the transmitted
    /// spectrum (below 0.1 at 80 kVp): under `1.2e-5` in `ln T` per axis.
    fn ensure_spectral(&mut self, device: &wgpu::Device, model: &SpectralModel) {
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

    /// Records the resolve of `input.rect` of one region into `enc`, then the copy of the
    /// resolved rows (whole rows of the region) to the region's read-back buffer; returns the
    /// bytes to read back. `t` are the region's targets, holding its L-buffer.
    pub(super) fn encode(
        &mut self,
        ctx: &GpuContext,
        pipelines: &Pipelines,
        t: &Targets,
        enc: &mut wgpu::CommandEncoder,
        input: &ResolveInput<'_>,
    ) -> u64 {
        let (projection, model, region, rect) =
            (input.projection, input.model, input.region, input.rect);
        let ri = region.index();
        let size = region.size;
        self.ensure_spectral(&ctx.device, model);
        let device = &ctx.device;
        let tables = self.spectral.as_ref().expect("spectral tables");
        let frame = projection.gpu_ray_frame();
        let v4 = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
        let col = projection.collimation;
        let clampf = |x: f64| x.clamp(-1e30, 1e30) as f32;
        let (iod_tex, iod_origin, iod_inv, iod_dims) = match input.iodine {
            Some(f) if !f.volume.grid.is_empty() => {
                let g = &f.volume.grid;
                let step = input.iodine_step_fraction
                    * g.spacing_mm.iter().copied().fold(f64::INFINITY, f64::min);
                (
                    iodine_texture(ctx, g.dims, &f.volume.data),
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
                input.cortical_shell_mm as f32,
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
                u32::from(input.has_needle),
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
        ctx.queue
            .write_buffer(&self.uniforms[ri], 0, bytemuck::bytes_of(&params));
        let view_of = |x: &wgpu::Texture| x.create_view(&wgpu::TextureViewDescriptor::default());
        let iod_view = iod_tex.create_view(&wgpu::TextureViewDescriptor::default());
        let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("fluoro resolve"),
            layout: &pipelines.resolve_layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.uniforms[ri].as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.geometry.a)),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.frame.chord)),
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
                    resource: t.frame.out_t.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: tables.lut.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.frame.d)),
                },
                wgpu::BindGroupEntry {
                    binding: 8,
                    resource: wgpu::BindingResource::TextureView(&view_of(&t.geometry.s)),
                },
            ],
        });
        {
            let target = t
                .frame
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
            let pipelines = &pipelines.resolve[usize::from(iod_dims[3] != 0)];
            pass.set_bind_group(0, &bind, &[]);
            let boxed = input.needle_rect.and_then(|n| intersect_rect(n, rect));
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
            &t.frame.out_t,
            row_bytes * u64::from(rect[1]),
            &t.frame.staging,
            0,
            bytes,
        );
        bytes
    }
}

/// Submits `enc` once, waits, and reads back every pending region from its targets (`targets`,
/// by region index), adding the wait and the copy to `timings`.
pub(super) fn submit_and_read(
    ctx: &GpuContext,
    targets: &[Option<Targets>; 2],
    enc: wgpu::CommandEncoder,
    pending: &[Pending],
    timings: &mut FrameTimings,
) -> Result<Vec<PixelRectOut>, FluoroGpuError> {
    let started = Instant::now();
    ctx.queue.submit([enc.finish()]);
    let mut receivers = Vec::new();
    for p in pending.iter().filter(|p| p.bytes > 0) {
        let (tx, rx) = std::sync::mpsc::channel();
        let t = targets[p.ri].as_ref().expect("targets");
        t.frame
            .staging
            .map_async(wgpu::MapMode::Read, ..p.bytes, move |r| {
                // The receiver lives until recv() below returns, so a send error cannot happen.
                let _ = tx.send(r);
            });
        receivers.push(rx);
    }
    ctx.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(readback)?;
    for rx in receivers {
        rx.recv().map_err(readback)?.map_err(readback)?;
    }
    timings.gpu_ms += started.elapsed().as_secs_f64() * 1e3;
    let started = Instant::now();
    let mut outs = Vec::with_capacity(pending.len());
    for p in pending {
        let data = if p.bytes > 0 {
            let t = targets[p.ri].as_ref().expect("targets");
            let data = {
                let view = t
                    .frame
                    .staging
                    .get_mapped_range(..p.bytes)
                    .map_err(readback)?;
                bytemuck::cast_slice::<u8, f32>(&view).to_vec()
            };
            t.frame.staging.unmap();
            data
        } else {
            Vec::new()
        };
        outs.push(PixelRectOut {
            rows: p.rows.clone(),
            cols: p.cols.clone(),
            data,
            needle_rect: p.needle_rect,
        });
    }
    timings.readback_ms += started.elapsed().as_secs_f64() * 1e3;
    Ok(outs)
}

/// A 3-D `R32Float` texture of an iodine concentration grid (x fastest).
pub(super) fn iodine_texture(ctx: &GpuContext, dims: [usize; 3], data: &[f32]) -> wgpu::Texture {
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

/// A failed read-back as the renderer reports it.
fn readback(e: impl Into<ReadbackError>) -> FluoroGpuError {
    FluoroGpuError::Gpu(GpuError::Readback(e.into()))
}
