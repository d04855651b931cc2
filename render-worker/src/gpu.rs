//! Headless GPU access: one wgpu device and queue, on a real GPU or on Mesa's lavapipe.
//!
//! No window or display is involved. The adapter can be chosen with wgpu's own environment
//! variables (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`, `WGPU_POWER_PREF`); without them the
//! high-performance adapter is preferred and a software (fallback) adapter is accepted.

use std::sync::Arc;

use thiserror::Error;

/// Why no GPU context could be created.
#[derive(Debug, Error)]
pub enum GpuError {
    /// No adapter at all: neither a GPU nor a software Vulkan/GL implementation.
    #[error(
        "no wgpu adapter found ({0}); on Debian install the software Vulkan driver with \
         `apt-get install mesa-vulkan-drivers` (lavapipe)"
    )]
    NoAdapter(String),
    /// The adapter refused to create a device.
    #[error("the wgpu adapter {adapter} could not create a device: {source}")]
    RequestDevice {
        /// Adapter name.
        adapter: String,
        /// wgpu's reason.
        source: wgpu::RequestDeviceError,
    },
    /// Reading back a GPU buffer failed.
    #[error("reading back a GPU buffer failed: {0}")]
    Readback(#[from] ReadbackError),
}

/// Why reading a GPU buffer back failed.
#[derive(Debug, Error)]
pub enum ReadbackError {
    /// Waiting for the device to finish failed.
    #[error("waiting for the device failed: {0}")]
    Poll(#[from] wgpu::PollError),
    /// The buffer could not be mapped.
    #[error(transparent)]
    Map(#[from] wgpu::BufferAsyncError),
    /// The mapping callback was dropped without reporting.
    #[error("the buffer-mapping callback was dropped without reporting")]
    CallbackDropped(#[from] std::sync::mpsc::RecvError),
    /// The mapped range could not be viewed.
    #[error(transparent)]
    MappedRange(#[from] wgpu::MapRangeError),
}

/// Which kind of adapter a context runs on (reported in health checks and benchmarks).
#[derive(Debug, Clone, serde::Serialize)]
pub struct AdapterSummary {
    /// Adapter name, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)" or "NVIDIA H100".
    pub name: String,
    /// Backend, e.g. "vulkan".
    pub backend: String,
    /// Device type: "discrete_gpu", "integrated_gpu", "cpu" (software), ...
    pub device_type: String,
    /// True for a software rasterizer such as lavapipe.
    pub is_software: bool,
}

/// A device and queue shared by every renderer of a worker.
#[derive(Debug, Clone)]
pub struct GpuContext {
    /// The logical device.
    pub device: Arc<wgpu::Device>,
    /// Its submission queue.
    pub queue: Arc<wgpu::Queue>,
    /// What it runs on.
    pub summary: AdapterSummary,
    /// The adapter's limits, as granted to the device.
    pub limits: wgpu::Limits,
    /// What the adapter supports below full WebGPU (renderers check what they rely on).
    pub downlevel: wgpu::DownlevelFlags,
}

impl GpuContext {
    /// Opens the best available adapter without any window or display handle.
    pub fn new_headless() -> Result<GpuContext, GpuError> {
        pollster::block_on(Self::new_headless_async())
    }

    async fn new_headless_async() -> Result<GpuContext, GpuError> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = match wgpu::util::initialize_adapter_from_env_or_default(&instance, None).await {
            Ok(a) => a,
            Err(first) => instance
                .request_adapter(&wgpu::RequestAdapterOptions { force_fallback_adapter: true, ..Default::default() })
                .await
                .map_err(|second| GpuError::NoAdapter(format!("{first}; fallback: {second}")))?,
        };
        let info = adapter.get_info();
        let downlevel = adapter.get_downlevel_capabilities().flags;
        // Ask for the adapter's own limits: storage buffers for large scenes need more than the
        // conservative WebGPU defaults, and a headless worker has no portability constraint.
        let limits = adapter.limits();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("render-worker"),
                required_limits: limits.clone(),
                // The fluoroscopy L-buffer blends into 32-bit float targets; requested when the
                // adapter has it (lavapipe and desktop GPUs do), checked by the renderer.
                required_features: adapter.features() & wgpu::Features::FLOAT32_BLENDABLE,
                ..Default::default()
            })
            .await
            .map_err(|source| GpuError::RequestDevice { adapter: info.name.clone(), source })?;
        let summary = AdapterSummary {
            is_software: info.device_type == wgpu::DeviceType::Cpu,
            name: info.name,
            backend: format!("{:?}", info.backend).to_lowercase(),
            device_type: format!("{:?}", info.device_type),
        };
        Ok(GpuContext { device: Arc::new(device), queue: Arc::new(queue), summary, limits, downlevel })
    }

    /// Copies `size` bytes of a GPU buffer back to the CPU (blocking).
    pub fn read_buffer(&self, source: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder = self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("readback") });
        encoder.copy_buffer_to_buffer(source, 0, &staging, 0, size);
        self.queue.submit([encoder.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, .., move |r| {
            // The receiver lives until recv() below returns, so a send error cannot happen.
            let _ = tx.send(r);
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(ReadbackError::from)?;
        rx.recv()
            .map_err(ReadbackError::from)?
            .map_err(ReadbackError::from)?;
        let bytes = staging.get_mapped_range(..).map_err(ReadbackError::from)?.to_vec();
        staging.unmap();
        Ok(bytes)
    }
}

/// The smallest useful GPU program: `y[i] = a * x[i] + b` on a compute shader.
///
/// It proves that shader compilation, storage buffers, dispatch and readback work on this
/// adapter; `/healthz` and the test suite use it. Results are exact in `f32` for the inputs the
/// tests use (small integers), so they are compared bit for bit with the CPU.
pub fn saxpy(ctx: &GpuContext, a: f32, x: &[f32], b: f32) -> Result<Vec<f32>, GpuError> {
    use wgpu::util::DeviceExt;
    const SHADER: &str = r#"
        struct Params { a: f32, b: f32, n: u32, pad: u32 }
        @group(0) @binding(0) var<uniform> params: Params;
        @group(0) @binding(1) var<storage, read> x: array<f32>;
        @group(0) @binding(2) var<storage, read_write> y: array<f32>;
        @compute @workgroup_size(64)
        fn main(@builtin(global_invocation_id) id: vec3<u32>) {
            if (id.x < params.n) {
                y[id.x] = params.a * x[id.x] + params.b;
            }
        }
    "#;
    let device = &ctx.device;
    let n = x.len() as u32;
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("saxpy"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("saxpy"),
        layout: None,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    });
    let params: [u32; 4] = [a.to_bits(), b.to_bits(), n, 0];
    let params_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("saxpy params"),
        contents: bytemuck::cast_slice(&params),
        usage: wgpu::BufferUsages::UNIFORM,
    });
    let x_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("saxpy x"),
        contents: bytemuck::cast_slice(x),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let size = (x.len().max(1) * 4) as u64;
    let y_buf = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("saxpy y"),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("saxpy"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry { binding: 0, resource: params_buf.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 1, resource: x_buf.as_entire_binding() },
            wgpu::BindGroupEntry { binding: 2, resource: y_buf.as_entire_binding() },
        ],
    });
    let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("saxpy") });
    {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor { label: Some("saxpy"), timestamp_writes: None });
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.dispatch_workgroups(n.div_ceil(64), 1, 1);
    }
    ctx.queue.submit([encoder.finish()]);
    let bytes = ctx.read_buffer(&y_buf, size)?;
    Ok(bytemuck::cast_slice::<u8, f32>(&bytes)[..x.len()].to_vec())
}

/// The GPU context for tests and benchmarks, or `None` (after a loud warning) when this machine
/// has no adapter at all.
///
/// With `REQUIRE_GPU=1` in the environment (CI sets it, and installs lavapipe) a missing adapter
/// is a failure instead of a skip, so GPU tests can never pass silently by not running.
///
/// Only with the `test-support` feature (the crate's own tests enable it through a
/// dev-dependency on itself): a production build has no test helpers.
#[cfg(feature = "test-support")]
pub fn context_for_tests() -> Option<GpuContext> {
    match GpuContext::new_headless() {
        Ok(ctx) => Some(ctx),
        Err(e) if std::env::var_os("REQUIRE_GPU").is_some_and(|v| v != "0") => {
            panic!("REQUIRE_GPU is set but no GPU context could be created: {e}")
        }
        Err(e) => {
            eprintln!(
                "\n==================== GPU TEST SKIPPED ====================\n\
                 {e}\n\
                 Set REQUIRE_GPU=1 to make this a failure.\n\
                 ==========================================================\n"
            );
            None
        }
    }
}
