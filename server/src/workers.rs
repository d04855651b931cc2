//! Render workers as the server sees them.
//!
//! By default one worker runs in-process: at start-up it opens the GPU (a real adapter, or
//! lavapipe) on a background thread and proves it with a compute self-test, so the HTTP server
//! is up at once and `/healthz` reports the worker as starting, ready or failed.

use std::sync::{Arc, RwLock};

use render_worker::gpu::{AdapterSummary, GpuContext};
use render_worker::session::SessionHost;
use render_worker::session::calibration::{Calibration, calibrate_host};
use render_worker::session::modalities::ultrasound::UltrasoundBackend;
use render_worker::session::{Backends, FluoroBackend, GpuFluoroBackend};
use serde::Serialize;

/// Readiness of a worker.
#[derive(Debug, Clone)]
pub enum WorkerState {
    /// The GPU is being opened.
    Starting,
    /// The GPU is open and passed its self-test.
    Ready(Box<GpuContext>),
    /// The GPU could not be opened or failed its self-test.
    Failed(String),
}

/// What `/healthz` says about the render worker.
#[derive(Debug, Clone, Serialize)]
pub struct WorkerStatus {
    /// True when sessions can be rendered.
    pub ready: bool,
    /// `in-process` (later also `remote`).
    pub mode: &'static str,
    /// `starting`, `ready` or `failed`.
    pub state: &'static str,
    /// The adapter, once known.
    pub adapter: Option<AdapterSummary>,
    /// Why it failed (adapter problems only; no secrets).
    pub error: Option<String>,
    /// The start-up calibration: `pending` until the GPU settled and a fluoroscopy station's
    /// region is loaded, then `done` with the renderer chosen, every candidate's frame times and
    /// the capacity, or `failed` with the reason.
    pub calibration: CalibrationStatus,
}

/// Where the start-up calibration stands.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum CalibrationStatus {
    /// Not made (waiting for the GPU and the anatomy, or not asked for).
    Pending,
    /// Made.
    Done(Box<Calibration>),
    /// No renderer could be measured.
    Failed {
        /// Why, in words.
        reason: String,
    },
}

/// The render workers available to this server.
///
/// Architecture invariant: this module knows nothing of session dispatch, which builds on it
/// (its in-process renderer asks [`Workers::gpu`]); the dispatcher in use travels in the
/// application state (`AppState::dispatcher`).
#[derive(Debug, Clone)]
pub struct Workers {
    state: Arc<RwLock<WorkerState>>,
    calibration: Arc<RwLock<CalibrationStatus>>,
    gpu_renderers: Arc<std::sync::OnceLock<GpuRenderers>>,
}

/// The in-process worker's GPU renderers, made once when the GPU is first seen ready and shared
/// by every session after (and by the calibration): the fluoroscopy renderer's anatomy uploads
/// are made once per region and kept ([`GpuFluoroBackend::keeping_uploads`]). A renderer made
/// per session would upload the whole default phantom again for each, hundreds of megabytes of
/// host memory on lavapipe and most of a new session's first frame.
pub struct GpuRenderers {
    /// Fluoroscopy.
    pub fluoro: Arc<dyn FluoroBackend>,
    /// Ultrasound B-mode.
    pub ultrasound: Arc<dyn UltrasoundBackend>,
}

impl std::fmt::Debug for GpuRenderers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuRenderers")
            .field("fluoro", &self.fluoro.profile())
            .finish()
    }
}

impl Workers {
    /// Starts the in-process worker on a background thread.
    pub fn start_in_process() -> Workers {
        let state = Arc::new(RwLock::new(WorkerState::Starting));
        let shared = state.clone();
        std::thread::Builder::new()
            .name("render-worker-init".into())
            .spawn(move || {
                let next = match open_and_self_test() {
                    Ok(ctx) => {
                        tracing::info!(adapter = %ctx.summary.name, backend = %ctx.summary.backend, "in-process render worker ready");
                        WorkerState::Ready(Box::new(ctx))
                    }
                    Err(e) => {
                        tracing::error!(error = %e, "in-process render worker failed");
                        WorkerState::Failed(e)
                    }
                };
                *shared.write().unwrap_or_else(|p| p.into_inner()) = next;
            })
            .expect("spawning a thread at start-up");
        Workers {
            state,
            calibration: Arc::new(RwLock::new(CalibrationStatus::Pending)),
            gpu_renderers: Arc::default(),
        }
    }

    /// The GPU renderers once the GPU is ready (made on the first call that sees it).
    pub fn gpu_renderers(&self) -> Option<&GpuRenderers> {
        if let Some(r) = self.gpu_renderers.get() {
            return Some(r);
        }
        let ctx = self.gpu()?;
        Some(self.gpu_renderers.get_or_init(|| GpuRenderers {
            fluoro: Arc::new(GpuFluoroBackend::keeping_uploads(ctx.clone())),
            ultrasound: Backends::gpu(ctx).ultrasound,
        }))
    }

    /// True when the start-up calibration chose the CPU reference over the GPU renderer.
    pub fn prefers_cpu(&self) -> bool {
        match &*self.calibration.read().unwrap_or_else(|p| p.into_inner()) {
            CalibrationStatus::Done(c) => c.renderer.kind == "cpu-reference",
            _ => false,
        }
    }

    /// The calibration's status.
    pub fn calibration(&self) -> CalibrationStatus {
        self.calibration
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Calibrates on a background thread once the GPU settled and one of `host`'s fluoroscopy
    /// stations has its region loaded: times the GPU renderer (if the GPU opened) and the CPU
    /// reference on a real session of the heaviest such station, makes the faster one the
    /// in-process renderer, and sets `host`'s capacity from it unless `fixed_capacity` (the
    /// operator's `PAINSIM_IN_PROCESS_CAPACITY`) is given. See
    /// [`render_worker::session::calibration`].
    pub fn calibrate_in_background(&self, host: SessionHost, fixed_capacity: Option<usize>) {
        let me = self.clone();
        let spawned = std::thread::Builder::new().name("render-calibration".into()).spawn(move || {
            // Poll: the GPU opens within seconds, a cold phantom takes tens of seconds.
            loop {
                let settled = me.status().state != "starting";
                let building = host.regions_readiness().values().any(|r| {
                    matches!(r, render_worker::session::host::RegionReadiness::Building { .. })
                });
                if settled && !building && !host.fluoroscopy_stations().is_empty() {
                    break;
                }
                std::thread::sleep(std::time::Duration::from_millis(250));
            }
            // Learners who start while the calibration runs get prepared regions.
            render_worker::session::calibration::prepare_fluoroscopy_regions(&host);
            let mut candidates: Vec<Arc<dyn FluoroBackend>> = Vec::new();
            // The sessions' own GPU renderer: its upload of the region is kept for them.
            if let Some(r) = me.gpu_renderers() {
                candidates.push(Arc::clone(&r.fluoro));
                // On a software adapter: the same renderer with the adapter's own L-buffer passes.
                candidates.extend(r.fluoro.alternatives());
            }
            candidates.push(Backends::cpu(0).fluoro);
            let next = match calibrate_host(&host, &candidates, fixed_capacity) {
                Ok(c) => {
                    tracing::info!(renderer = %c.renderer.kind, device = %c.renderer.device, capacity = c.capacity,
                        applied = host.capacity(), took_s = c.took_s, "render calibration done");
                    CalibrationStatus::Done(Box::new(c))
                }
                Err(e) => {
                    tracing::error!(error = %e, "render calibration failed; keeping the configured renderer and capacity");
                    CalibrationStatus::Failed { reason: e.to_string() }
                }
            };
            *me.calibration.write().unwrap_or_else(|p| p.into_inner()) = next;
            // Again with the renderer chosen (nothing to do when it is the one prepared above).
            render_worker::session::calibration::prepare_fluoroscopy_regions(&host);
        });
        if let Err(e) = spawned {
            tracing::error!(error = %e, "could not start the render calibration");
        }
    }

    /// The in-process worker's GPU, once it is open and passed its self-test.
    pub fn gpu(&self) -> Option<GpuContext> {
        match &*self.state.read().unwrap_or_else(|p| p.into_inner()) {
            WorkerState::Ready(ctx) => Some((**ctx).clone()),
            _ => None,
        }
    }

    /// Blocks until the worker is no longer starting, or `timeout` passes; returns the status.
    ///
    /// Tests call this before they end: a process that exits while a Vulkan driver is still
    /// initialising on another thread can crash in the driver's teardown.
    pub fn wait_until_settled(&self, timeout: std::time::Duration) -> WorkerStatus {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let status = self.status();
            if status.state != "starting" || std::time::Instant::now() >= deadline {
                return status;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// Current status.
    pub fn status(&self) -> WorkerStatus {
        let state = self.state.read().unwrap_or_else(|p| p.into_inner());
        match &*state {
            WorkerState::Starting => WorkerStatus {
                ready: false,
                mode: "in-process",
                state: "starting",
                adapter: None,
                error: None,
                calibration: self.calibration(),
            },
            WorkerState::Ready(ctx) => WorkerStatus {
                ready: true,
                mode: "in-process",
                state: "ready",
                adapter: Some(ctx.summary.clone()),
                error: None,
                calibration: self.calibration(),
            },
            WorkerState::Failed(e) => WorkerStatus {
                ready: false,
                mode: "in-process",
                state: "failed",
                adapter: None,
                error: Some(e.clone()),
                calibration: self.calibration(),
            },
        }
    }
}

fn open_and_self_test() -> Result<GpuContext, String> {
    render_worker::session::devices::open_gpu().map_err(|e| e.to_string())
}
