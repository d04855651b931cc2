//! The `render-worker` process: hosts training sessions over HTTP and websockets (see
//! `render_worker::session::http`) and reports health at `GET /healthz`.
//!
//! Environment: `RENDER_WORKER_BIND` (default `127.0.0.1:8081`), `RENDER_WORKER_ASSETS` (region
//! folders and `stations/`, default `assets`), `RENDER_WORKER_CAPACITY` (sessions, default 8).
//! With `RENDER_WORKER_REGISTER_URL` (the server's `/api/workers`) and `RENDER_WORKER_TOKEN` (its
//! `PAINSIM_WORKER_TOKEN`) it registers with the server, announcing `RENDER_WORKER_PUBLIC_URL`
//! (default `http://` and the bound address).
//!
//! In the embedded default the server runs a `SessionHost` in-process and this binary is not
//! needed; it is the unit that scales out (see docker-compose.yml).

use std::path::PathBuf;
use std::process::ExitCode;

use render_worker::session::{Backends, HostConfig, SessionConfig, SessionHost, http};

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .init();
    let bind = std::env::var("RENDER_WORKER_BIND").unwrap_or_else(|_| "127.0.0.1:8081".to_owned());
    let assets = PathBuf::from(
        std::env::var("RENDER_WORKER_ASSETS").unwrap_or_else(|_| "assets".to_owned()),
    );
    let capacity = std::env::var("RENDER_WORKER_CAPACITY")
        .ok()
        .and_then(|c| c.parse().ok())
        .unwrap_or(8);
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
        if let (Ok(register), Ok(token)) = (
            std::env::var("RENDER_WORKER_REGISTER_URL"),
            std::env::var("RENDER_WORKER_TOKEN"),
        ) {
            let health = host.health();
            let me = render_worker::cluster::Registration {
                url: std::env::var("RENDER_WORKER_PUBLIC_URL")
                    .unwrap_or_else(|_| format!("http://{addr}")),
                capacity: health.capacity,
                renderer: serde_json::to_value(&health.renderer).unwrap_or_default(),
                adapter: health.adapter,
            };
            tokio::spawn(render_worker::cluster::register_forever(
                register, token, me,
            ));
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
