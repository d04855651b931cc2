//! The `render-worker` process: hosts training sessions over HTTP and websockets (see
//! `render_worker::session::http`) and reports health at `GET /healthz`.
//!
//! Its settings come from the environment, as described (with their defaults) by
//! `render_worker::session::config::WORKER_SETTINGS` and the README: where it listens, the
//! assets folder, its capacity, and, to join a server, the server's `/api/workers` and the
//! cluster token. A value that is refused stops start-up with the variable named.
//!
//! In the embedded default the server runs a `SessionHost` in-process and this binary is not
//! needed; it is the unit that scales out (see docker-compose.yml).

use std::process::ExitCode;

use render_worker::session::calibration::{calibrate_when_ready, prepare_fluoroscopy_regions};
use render_worker::session::config::{self, WorkerConfig, WorkerRegistration};
use render_worker::session::{Backends, HostConfig, SessionConfig, SessionHost};

fn main() -> ExitCode {
    render_worker::alloc::limit_malloc_arenas();
    tracing_subscriber::fmt()
        .with_env_filter(WorkerConfig::log_filter(config::env))
        .init();
    let WorkerConfig {
        bind,
        assets,
        capacity,
        registration,
        public_url,
        drain,
    } = match WorkerConfig::from_lookup(config::env) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("render-worker: {e}");
            return ExitCode::from(2);
        }
    };
    // Sessions render on the GPU when one opens, passes its self-test and has what the
    // renderers need; otherwise on the CPU references (a worker without an adapter still
    // serves, more slowly). The choice is `Backends::open`, shared with the server.
    let (backends, adapter) = Backends::open();
    let adapter = adapter.and_then(|a| serde_json::to_value(a).ok());
    let config = HostConfig {
        stations_dir: assets.join("stations"),
        assets_root: assets,
        capacity: capacity.unwrap_or(config::DEFAULT_WORKER_CAPACITY),
        session: SessionConfig::default(),
    };
    let host = match SessionHost::new(config, backends, adapter) {
        Ok(h) => h,
        Err(e) => {
            eprintln!("render-worker: {e}");
            return ExitCode::FAILURE;
        }
    };
    // Load (or build) the stations' anatomy now, in the background: session requests that come
    // first get 503 with Retry-After and the progress, never a request held for the build.
    host.prepare_in_background();
    // Then time this machine's renderers on the heaviest station: the faster one renders new
    // sessions and, unless RENDER_WORKER_CAPACITY fixes it, its figure becomes the capacity
    // (reported in /healthz and announced to the server at the next heartbeat).
    let calibrated = host.clone();
    let spawned = std::thread::Builder::new()
        .name("render-calibration".into())
        .spawn(move || {
            match calibrate_when_ready(&calibrated, capacity) {
                Ok(c) => tracing::info!(renderer = %c.renderer.kind, device = %c.renderer.device,
                    calibrated = c.capacity, capacity = calibrated.capacity(), took_s = c.took_s,
                    "render calibration done"),
                Err(e) => tracing::error!(error = %e,
                    "render calibration failed; keeping the renderer and capacity it started with"),
            }
            // The chosen renderer's regions (those of the renderer it started with were made
            // before the calibration, and it keeps them).
            prepare_fluoroscopy_regions(&calibrated);
        });
    if let Err(e) = spawned {
        tracing::error!(error = %e, "could not start the render calibration");
    }
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("render-worker: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let code = runtime.block_on(async move {
        let listener = match tokio::net::TcpListener::bind(&bind).await {
            Ok(l) => l,
            Err(e) => {
                eprintln!("render-worker: cannot bind {bind}: {e}");
                return 1;
            }
        };
        let addr = listener.local_addr().map(|a| a.to_string()).unwrap_or(bind);
        println!(
            "render-worker ready at http://{addr}/healthz (stations: {})",
            host.station_ids().join(", ")
        );
        // Cluster mode: heartbeats to the server (see render_worker::cluster); on SIGTERM it
        // drains, then the session threads release their GPU resources before the process exits.
        let serving = render_worker::cluster::Serving {
            register: registration.map(|WorkerRegistration { url, token }| (url, token)),
            public_url,
            drain,
        };
        let served = render_worker::cluster::serve_until_drained(
            listener,
            host,
            serving,
            render_worker::cluster::stop_signal(),
        )
        .await;
        match served {
            Ok(()) => 0,
            Err(e) => {
                eprintln!("render-worker: {e}");
                1
            }
        }
    });
    // The sessions are joined; a blocking task still running holds nothing that must be kept.
    runtime.shutdown_timeout(std::time::Duration::from_secs(2));
    // Leave without the C library's exit handlers, which race with driver work still running
    // on other threads (the start-up calibration): see `render_worker::exit`.
    render_worker::exit::after_shutdown(code)
}
