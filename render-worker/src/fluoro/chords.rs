//! The validation path: per-material chords from four L-buffer passes in the chord layout,
//! read back and resolved on the CPU in the CPU reference's order.

use glam::DVec3;
use sim_core::fluoro::{FluoroMaterial, Projection};

use super::types::*;
use crate::gpu::GpuError;

impl GpuFluoroRenderer {
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
                (DVec3::from(d).length() / axial) as f32
            })
            .collect();
        for pass in 0..CHORD_PASSES {
            let mut enc = self
                .ctx
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None });
            let full = PixelRect::full(projection);
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
}
