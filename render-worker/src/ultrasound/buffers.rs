//! GPU memory of the B-mode path: the medium (uploaded once per key), the buffers of one frame
//! shape (made again only when the shape changes), the per-frame uploads and the read-back.

use sim_core::material::MaterialClass;
use sim_core::ultrasound::CtMedium;
use sim_core::volume::VolumeGrid;
use wgpu::util::DeviceExt;

use super::error::{UltrasoundGpuError, gpu};
use super::plan::{FramePlan, Shape};
use super::tables::LABEL_BASE;
use crate::gpu::GpuContext;

/// The medium on the GPU: one `f32` code per voxel (see the module docs of `ultrasound`).
pub(super) struct MediumUpload {
    pub(super) key: u64,
    pub(super) grid: VolumeGrid,
    pub(super) codes: wgpu::Buffer,
}

impl MediumUpload {
    /// Checks the volumes against their grid and the adapter's limits, and uploads the codes:
    /// the HU clamped to +-1e5, or `LABEL_BASE + label` where the label volume holds a class.
    pub(super) fn new(
        ctx: &GpuContext,
        medium: &CtMedium<'_>,
        key: u64,
    ) -> Result<MediumUpload, UltrasoundGpuError> {
        let hu = medium.hu;
        let grid = hu.grid;
        if hu.data.len() != grid.len() || medium.labels.is_some_and(|l| l.data.len() != grid.len())
        {
            return Err(gpu("the HU and label volumes do not match their grid"));
        }
        let bytes = (grid.len().max(1) * 4) as u64;
        if bytes > ctx.limits.max_storage_buffer_binding_size || bytes > ctx.limits.max_buffer_size
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
        let buf = ctx
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("ultrasound medium"),
                contents: bytemuck::cast_slice(&codes),
                usage: wgpu::BufferUsages::STORAGE,
            });
        Ok(MediumUpload {
            key,
            grid,
            codes: buf,
        })
    }
}

/// Buffers of one frame shape.
pub(super) struct FrameBuffers {
    pub(super) shape: Shape,
    pub(super) tables: wgpu::Buffer,
    pub(super) grid_re: wgpu::Buffer,
    pub(super) grid_im: wgpu::Buffer,
    pub(super) lat_weights: wgpu::Buffer,
    pub(super) lat: wgpu::Buffer,
    pub(super) axial_taps: wgpu::Buffer,
    pub(super) speckle: wgpu::Buffer,
    pub(super) log_gain: wgpu::Buffer,
    pub(super) echo: wgpu::Buffer,
    pub(super) envelope: wgpu::Buffer,
    pub(super) pixels: wgpu::Buffer,
    pub(super) staging: wgpu::Buffer,
}

impl FrameBuffers {
    /// Buffers for frames of `shape`, refused when one exceeds the adapter's storage buffer
    /// binding limit.
    pub(super) fn new(ctx: &GpuContext, shape: Shape) -> Result<FrameBuffers, UltrasoundGpuError> {
        let limits = &ctx.limits;
        let device = &ctx.device;
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
        Ok(FrameBuffers {
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
        })
    }

    /// Writes the plan's tables and weights into this frame's buffers (the uniforms go with
    /// the pipelines), and makes the point-target buffer when the frame has targets.
    pub(super) fn upload_plan(&self, ctx: &GpuContext, plan: &FramePlan) -> Option<wgpu::Buffer> {
        let queue = &ctx.queue;
        queue.write_buffer(&self.tables, 0, bytemuck::cast_slice(&plan.tables));
        queue.write_buffer(
            &self.lat_weights,
            0,
            bytemuck::cast_slice(&plan.lat_weights),
        );
        queue.write_buffer(&self.axial_taps, 0, bytemuck::cast_slice(&plan.axial_taps));
        (!plan.points.is_empty()).then(|| {
            ctx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("ultrasound point targets"),
                    contents: bytemuck::cast_slice(&plan.points),
                    usage: wgpu::BufferUsages::STORAGE,
                })
        })
    }

    /// Maps the staging buffer (filled by the last pass's copies) and returns the envelope and
    /// the pixel words.
    pub(super) fn read_back(
        &self,
        ctx: &GpuContext,
    ) -> Result<(Vec<f32>, Vec<u32>), UltrasoundGpuError> {
        let s = &self.shape;
        let (tx, rx) = std::sync::mpsc::channel();
        self.staging.map_async(wgpu::MapMode::Read, .., move |r| {
            // The receiver lives until recv() below returns.
            let _ = tx.send(r);
        });
        ctx.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| gpu(&e.to_string()))?;
        rx.recv()
            .map_err(|e| gpu(&e.to_string()))?
            .map_err(|e| gpu(&e.to_string()))?;
        let n_env = s.lines * s.samples;
        let out = {
            let view = self
                .staging
                .get_mapped_range(..)
                .map_err(|e| gpu(&e.to_string()))?;
            let words: &[u32] = bytemuck::cast_slice(&view);
            let env: Vec<f32> = words[..n_env].iter().map(|&w| f32::from_bits(w)).collect();
            (env, words[n_env..n_env + s.width * s.height].to_vec())
        };
        self.staging.unmap();
        Ok(out)
    }
}
