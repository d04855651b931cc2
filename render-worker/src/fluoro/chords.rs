//! The validation path: per-material chords from four L-buffer passes in the chord layout,
//! read back and resolved on the CPU in the CPU reference's order.

use glam::DVec3;
use sim_core::fluoro::{FluoroMaterial, Projection};

use super::pipelines::Targets;
use super::types::{CANCELLOUS, CHANNELS, CHORD_CHANNELS, CORTICAL, SLOTS};
use crate::gpu::{GpuContext, GpuError};

/// Reads a whole float texture of `t`'s size back, `channels` f32 per texel, row-major without
/// padding.
fn read_texture(
    ctx: &GpuContext,
    t: &Targets,
    tex: &wgpu::Texture,
    channels: usize,
) -> Result<Vec<f32>, GpuError> {
    let [w, h] = t.size();
    let row = w as usize * channels * 4;
    let padded = row.div_ceil(256) * 256;
    let buf = ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("fluoro texture readback"),
        size: (padded * h as usize) as u64,
        usage: wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = ctx
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
    ctx.queue.submit([enc.finish()]);
    let bytes = ctx.read_buffer(&buf, (padded * h as usize) as u64)?;
    let mut out = Vec::with_capacity(w as usize * h as usize * channels);
    for r in 0..h as usize {
        out.extend_from_slice(bytemuck::cast_slice::<u8, f32>(
            &bytes[r * padded..r * padded + row],
        ));
    }
    Ok(out)
}

/// Per pixel (row-major), the factor from the geometric L-buffer's axial depth to the chord:
/// `|d| / (row_w . d)` along the pixel centre's ray `d` (as the resolve does on the GPU).
pub(super) fn axial_to_chord(projection: &Projection) -> Vec<f32> {
    let [w, h] = projection.detector_pixels.map(|x| x as usize);
    let row_w = projection.projection_matrix()[2];
    let f = projection.frame();
    (0..w * h)
        .map(|q| {
            let (i, j) = ((q % w) as f64, (q / w) as f64);
            let d: [f64; 3] = std::array::from_fn(|a| {
                f.pixel00_mm[a] + i * f.step_u_mm[a] + j * f.step_v_mm[a] - f.source_mm[a]
            });
            let axial = row_w[0] * d[0] + row_w[1] * d[1] + row_w[2] * d[2];
            (DVec3::from(d).length() / axial) as f32
        })
        .collect()
}

/// Reads back chord pass `pass` (recorded and submitted into `t`, with the needle if
/// `has_needle`) into its four channels of `raw`, the geometric part times `scale` (see
/// [`axial_to_chord`]); pass 0 also fills `steel` with the needle's chords.
pub(super) fn read_pass(
    ctx: &GpuContext,
    t: &Targets,
    pass: usize,
    has_needle: bool,
    scale: &[f32],
    raw: &mut [[f32; CHORD_CHANNELS]],
    steel: &mut Vec<f32>,
) -> Result<(), GpuError> {
    let mut a = read_texture(ctx, t, &t.geometry.a, 4)?;
    for (x, k) in a.chunks_exact_mut(4).zip(scale) {
        x.iter_mut().for_each(|c| *c *= k);
    }
    if has_needle {
        let d = read_texture(ctx, t, &t.frame.d, 4)?;
        for (x, y) in a.iter_mut().zip(d) {
            *x += y;
        }
    }
    if pass == 0 {
        *steel = if has_needle {
            read_texture(ctx, t, &t.frame.chord, 1)?
        } else {
            vec![0.0; raw.len()]
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
    Ok(())
}

/// The chords per material from the read-back channels, in the CPU reference's order: clamp
/// the bone on the geometric chords, then remove the needle.
pub(super) fn resolve_chords(
    raw: &[[f32; CHORD_CHANNELS]],
    steel: &[f32],
    cortical_shell_mm: f64,
) -> Vec<[f32; CHANNELS]> {
    let (cort, canc) = (CORTICAL.index(), CANCELLOUS.index());
    let (disp_cort, disp_canc) = (CHANNELS - 1, CHANNELS);
    let shell = cortical_shell_mm as f32;
    raw.iter()
        .zip(steel)
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
        .collect()
}
