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

use render_worker::session::config::{self, WorkerConfig, WorkerRegistration};
use render_worker::session::{Backends, HostConfig, SessionConfig, SessionHost, http};

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(WorkerConfig::log_filter(config::env))
        .init();
    let WorkerConfig {
        bind,
        assets,
        capacity,
        registration,
        public_url,
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
        capacity,
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
    let runtime = match tokio::runtime::Runtime::new() {
        Ok(r) => r,
        Err(e) => {
            eprintln!("render-worker: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    runtime.block_on(async move {
        let listener = match tokio::net::TcpListener::bind(&bind).await {
            Ok(l) => l,
            Err(e) => {
                eprintln!("render-worker: cannot bind {bind}: {e}");
                return ExitCode::FAILURE;
            }
        };
        let addr = listener.local_addr().map(|a| a.to_string()).unwrap_or(bind);
        // Cluster mode: announce this worker to the server (see render_worker::cluster).
        if let Some(WorkerRegistration { url, token }) = registration {
            let health = host.health();
            let me = render_worker::cluster::Registration {
                url: public_url.unwrap_or_else(|| format!("http://{addr}")),
                capacity: health.capacity,
                renderer: serde_json::to_value(&health.renderer).unwrap_or_default(),
                adapter: health.adapter,
            };
            tokio::spawn(render_worker::cluster::register_forever(url, token, me));
        }
        println!(
            "render-worker ready at http://{addr}/healthz (stations: {})",
            host.station_ids().join(", ")
        );
        let shutdown = async {
            let _ = tokio::signal::ctrl_c().await;
        };
        let sessions = host.clone();
        let served = axum::serve(listener, http::router(host))
            .with_graceful_shutdown(shutdown)
            .await;
        // Session threads release their GPU resources before the process exits.
        let _ = tokio::task::spawn_blocking(move || sessions.shutdown()).await;
        match served {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("render-worker: {e}");
                ExitCode::FAILURE
            }
        }
    })
}
