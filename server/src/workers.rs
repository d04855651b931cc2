//! Render workers as the server sees them.
//!
//! By default one worker runs in-process: at start-up it opens the GPU (a real adapter, or
//! lavapipe) on a background thread and proves it with a compute self-test, so the HTTP server
//! is up at once and `/healthz` reports the worker as starting, ready or failed.

use std::sync::{Arc, RwLock};

use render_worker::gpu::{AdapterSummary, GpuContext};
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
}

/// The render workers available to this server.
///
/// Architecture invariant: this module knows nothing of session dispatch, which builds on it
/// (its in-process renderer asks [`Workers::gpu`]); the dispatcher in use travels in the
/// application state (`AppState::dispatcher`).
#[derive(Debug, Clone)]
pub struct Workers {
    state: Arc<RwLock<WorkerState>>,
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
        Workers { state }
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
            WorkerState::Starting => WorkerStatus { ready: false, mode: "in-process", state: "starting", adapter: None, error: None },
            WorkerState::Ready(ctx) => {
                WorkerStatus { ready: true, mode: "in-process", state: "ready", adapter: Some(ctx.summary.clone()), error: None }
            }
            WorkerState::Failed(e) => {
                WorkerStatus { ready: false, mode: "in-process", state: "failed", adapter: None, error: Some(e.clone()) }
            }
        }
    }
}

fn open_and_self_test() -> Result<GpuContext, String> {
    render_worker::session::devices::open_gpu().map_err(|e| e.to_string())
}
