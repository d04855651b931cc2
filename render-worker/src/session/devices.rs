//! The renderers a device offers, chosen once per device in one place: the `render-worker`
//! binary and the server's in-process worker both call [`open_gpu`] and [`Backends::for_device`].
//!
//! A GPU is used when it opens, passes a compute self-test and has what the renderers rely on
//! (float blending for the fluoroscopy L-buffer); otherwise every modality renders on its CPU
//! reference (slower, same output within the stated tolerances).

use std::sync::Arc;

use crate::gpu::{AdapterSummary, GpuContext, saxpy};

use super::modalities::Renderers;
use super::modalities::fluoro::{self, CpuFluoroBackend, FluoroBackend, GpuFluoroBackend};
use super::modalities::ultrasound::{
    self, CpuUltrasoundBackend, GpuUltrasoundBackend, UltrasoundBackend,
};

/// Why a GPU is not used.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// No adapter or no device.
    #[error(transparent)]
    Open(#[from] crate::gpu::GpuError),
    /// The compute self-test failed or returned wrong values.
    #[error("GPU self-test failed on {}: {message}", adapter.name)]
    SelfTest {
        /// The adapter.
        adapter: AdapterSummary,
        /// What went wrong.
        message: String,
    },
    /// The adapter lacks a feature a renderer needs.
    #[error("GPU {} lacks {feature}, which the fluoroscopy L-buffer needs", adapter.name)]
    MissingFeature {
        /// The adapter.
        adapter: AdapterSummary,
        /// The feature.
        feature: &'static str,
    },
}

/// Opens the best adapter headless and proves it: a SAXPY kernel whose results are exact in f32
/// for small integers, and the float blending the fluoroscopy L-buffer accumulates with.
pub fn open_gpu() -> Result<GpuContext, DeviceError> {
    let ctx = GpuContext::new_headless()?;
    let x: Vec<f32> = (0..256).map(|i| i as f32).collect();
    let y = saxpy(&ctx, 2.0, &x, 1.0).map_err(|e| DeviceError::SelfTest {
        adapter: ctx.summary.clone(),
        message: e.to_string(),
    })?;
    // Exact in f32 for these small integers.
    if y.iter().zip(&x).any(|(y, x)| *y != 2.0 * x + 1.0) {
        return Err(DeviceError::SelfTest {
            adapter: ctx.summary.clone(),
            message: "wrong values".into(),
        });
    }
    if !ctx
        .device
        .features()
        .contains(wgpu::Features::FLOAT32_BLENDABLE)
    {
        return Err(DeviceError::MissingFeature {
            adapter: ctx.summary.clone(),
            feature: "FLOAT32_BLENDABLE",
        });
    }
    Ok(ctx)
}

/// Environment variable choosing the B-mode renderer on a device with a GPU: `cpu` (the
/// sim-core reference), `gpu` (the wgpu compute path) or `auto` (the default).
pub const ULTRASOUND_RENDERER_ENV: &str = "PAINSIM_ULTRASOUND_RENDERER";

/// Whether B-mode frames are computed on the GPU: `gpu` or `cpu` as asked; by default on a
/// hardware adapter, and on the CPU reference under a software one (on 2-core lavapipe the
/// compute path is 1.1 to 1.6 times slower than the reference on the same cores, measured by
/// `benches/ultrasound_gpu.rs`).
pub fn ultrasound_on_gpu(ctx: &GpuContext, choice: Option<&str>) -> bool {
    match choice.map(str::trim) {
        Some("gpu") => true,
        Some("cpu") => false,
        Some(other) if other != "auto" => {
            tracing::warn!(
                "{ULTRASOUND_RENDERER_ENV}={other:?} is not cpu, gpu or auto; choosing automatically"
            );
            !ctx.summary.is_software
        }
        _ => !ctx.summary.is_software,
    }
}

/// The renderer of each modality on one device, shared by every session there. The built-in
/// modalities' renderers are fields (the device report names them); an embedder's modality adds
/// its own with [`Backends::with_renderer`]. Modalities see them all as [`Renderers`].
#[derive(Clone)]
pub struct Backends {
    /// Fluoroscopy.
    pub fluoro: Arc<dyn FluoroBackend>,
    /// Ultrasound B-mode.
    pub ultrasound: Arc<dyn UltrasoundBackend>,
    /// Renderers of other modalities.
    others: Renderers,
}

impl std::fmt::Debug for Backends {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Backends")
            .field("fluoro", &self.fluoro.profile())
            .field("ultrasound", &self.ultrasound.describe())
            .finish()
    }
}

impl DeviceError {
    /// The adapter that opened but is not used, if any.
    pub fn adapter(&self) -> Option<&AdapterSummary> {
        match self {
            DeviceError::Open(_) => None,
            DeviceError::SelfTest { adapter, .. } | DeviceError::MissingFeature { adapter, .. } => {
                Some(adapter)
            }
        }
    }
}

impl Backends {
    /// The given built-in renderers and no other.
    pub fn new(fluoro: Arc<dyn FluoroBackend>, ultrasound: Arc<dyn UltrasoundBackend>) -> Backends {
        Backends {
            fluoro,
            ultrasound,
            others: Renderers::new(),
        }
    }

    /// Adds the renderer of another modality (what its builder asks [`Renderers::get`] for).
    pub fn with_renderer<T: std::any::Any + Send + Sync>(
        mut self,
        modality: &'static str,
        renderer: T,
    ) -> Backends {
        self.others = self.others.with(modality, renderer);
        self
    }

    /// Every renderer by modality name, as modalities see them.
    pub fn renderers(&self) -> Renderers {
        self.others
            .clone()
            .with(fluoro::SPEC.name, Arc::clone(&self.fluoro))
            .with(ultrasound::SPEC.name, Arc::clone(&self.ultrasound))
    }

    /// The GPU renderers on `gpu` (a context from [`open_gpu`]), else the CPU references.
    pub fn for_device(gpu: Option<GpuContext>) -> Backends {
        match gpu {
            Some(ctx) => Backends::gpu(ctx),
            None => Backends::cpu(0),
        }
    }

    /// The GPU renderers on `ctx`.
    pub fn gpu(ctx: GpuContext) -> Backends {
        let ultrasound: Arc<dyn UltrasoundBackend> = if ultrasound_on_gpu(
            &ctx,
            crate::session::config::ultrasound_renderer(crate::session::config::env).as_deref(),
        ) {
            Arc::new(GpuUltrasoundBackend { ctx: ctx.clone() })
        } else {
            Arc::new(CpuUltrasoundBackend)
        };
        Backends::new(Arc::new(GpuFluoroBackend::new(ctx)), ultrasound)
    }

    /// The CPU references, with `threads` render threads per frame (0: all cores).
    pub fn cpu(threads: usize) -> Backends {
        Backends::new(
            Arc::new(CpuFluoroBackend { threads }),
            Arc::new(CpuUltrasoundBackend),
        )
    }

    /// Opens this machine's GPU with [`open_gpu`] and chooses: the GPU renderers when it is
    /// usable, else the CPU references with a warning. Also returns the summary of the adapter
    /// that opened, used or not. The fluoroscopy renderer keeps each region's anatomy once made
    /// ([`GpuFluoroBackend::keeping_uploads`], as the server's own worker): a worker prepares
    /// its regions at start-up, and a region's first session after a quiet spell finds them
    /// made instead of making them before its first image (0.45 s on the default phantom on 2
    /// cores; kept: about 50 MB of host memory per region on a software adapter).
    pub fn open() -> (Backends, Option<AdapterSummary>) {
        match open_gpu() {
            Ok(ctx) => {
                let summary = ctx.summary.clone();
                let mut backends = Backends::gpu(ctx.clone());
                backends.fluoro = Arc::new(GpuFluoroBackend::keeping_uploads(ctx));
                (backends, Some(summary))
            }
            Err(e) => {
                tracing::warn!("GPU not used ({e}); rendering on the CPU references");
                (Backends::cpu(0), e.adapter().cloned())
            }
        }
    }
}
