//! Who computes B-mode frames: the sim-core CPU reference, or the wgpu compute path checked
//! against it (`crate::ultrasound`), chosen once per device in `session::devices`.

use sim_core::ultrasound::{BModeFrame, ScanRequest, UltrasoundError};

use super::medium::AcousticVolume;
use crate::gpu::GpuContext;
use crate::interrupt::Interrupt;
use crate::ultrasound::{GpuUltrasound, UltrasoundGpuError};

/// Why a B-mode renderer could not make a frame (the counterpart of the fluoroscopy seam's
/// `FluoroRenderError`).
#[derive(Debug, thiserror::Error)]
pub enum UltrasoundRenderError {
    /// The CPU reference refused the request (it names the offending field).
    #[error(transparent)]
    Cpu(#[from] UltrasoundError),
    /// The GPU path failed (an invalid request, buffer limits, readback).
    #[error(transparent)]
    Gpu(#[from] UltrasoundGpuError),
    /// Newer input made the frame obsolete before it was done (see `crate::interrupt`).
    #[error("the frame was superseded by newer input")]
    Interrupted,
}

/// A B-mode renderer kind on one device, shared by every session there.
pub trait UltrasoundBackend: Send + Sync {
    /// What renders, in words (`"sim-core CPU reference"`, `"wgpu on <adapter>"`).
    fn describe(&self) -> String;

    /// A renderer for one session (it may hold device buffers).
    fn renderer(&self) -> Box<dyn UltrasoundRenderer>;

    /// Whether a live session shows a draft (`Sampling::draft`) before each full frame: where
    /// the full frame takes tens of milliseconds, so a moving probe is answered at once.
    fn drafts(&self) -> bool {
        false
    }
}

/// Makes frames for one session.
pub trait UltrasoundRenderer: Send {
    /// The frame of `req`, whose medium is `volume.indexed` (the same tissue as
    /// `volume.medium()`).
    fn scan(
        &mut self,
        req: &ScanRequest<'_>,
        volume: &AcousticVolume,
    ) -> Result<BModeFrame, UltrasoundRenderError>;
}

/// The sim-core reference (`sim_core::ultrasound::scan`).
#[derive(Debug, Clone, Copy, Default)]
pub struct CpuUltrasoundBackend;

impl UltrasoundBackend for CpuUltrasoundBackend {
    fn describe(&self) -> String {
        "sim-core CPU reference".into()
    }

    fn renderer(&self) -> Box<dyn UltrasoundRenderer> {
        Box::new(CpuUltrasoundBackend)
    }

    /// On the CPU a session frame costs about 40 ms square to the lattice and 75 ms rocked on
    /// two cores, its draft 12-17 ms (the render-worker `ultrasound_session` bench).
    fn drafts(&self) -> bool {
        true
    }
}

impl UltrasoundRenderer for CpuUltrasoundBackend {
    fn scan(
        &mut self,
        req: &ScanRequest<'_>,
        _volume: &AcousticVolume,
    ) -> Result<BModeFrame, UltrasoundRenderError> {
        // Stopped between pieces of the deposit once newer input supersedes a watched frame.
        let interrupt = Interrupt::of_this_thread();
        sim_core::ultrasound::scan_unless(req, &|| interrupt.is_raised())?
            .ok_or(UltrasoundRenderError::Interrupted)
    }
}

/// The wgpu compute path (`crate::ultrasound`), checked against the reference by
/// `tests/ultrasound_gpu.rs` (envelope NCC >= 0.99999, mean |dB| <= 0.02).
#[derive(Debug, Clone)]
pub struct GpuUltrasoundBackend {
    /// The device.
    pub ctx: GpuContext,
}

impl UltrasoundBackend for GpuUltrasoundBackend {
    fn describe(&self) -> String {
        format!("wgpu compute on {}", self.ctx.summary.name)
    }

    fn renderer(&self) -> Box<dyn UltrasoundRenderer> {
        Box::new(GpuUltrasoundRenderer {
            ctx: self.ctx.clone(),
            gpu: None,
        })
    }
}

/// One session's GPU pipelines and uploaded tissue, made at its first frame.
struct GpuUltrasoundRenderer {
    ctx: GpuContext,
    gpu: Option<GpuUltrasound>,
}

impl UltrasoundRenderer for GpuUltrasoundRenderer {
    fn scan(
        &mut self,
        req: &ScanRequest<'_>,
        volume: &AcousticVolume,
    ) -> Result<BModeFrame, UltrasoundRenderError> {
        let gpu = match &mut self.gpu {
            Some(g) => g,
            None => self.gpu.insert(GpuUltrasound::new(&self.ctx)?),
        };
        Ok(gpu.scan(req, &volume.medium(), volume.key)?)
    }
}
