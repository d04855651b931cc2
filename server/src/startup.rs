//! Start-up and shutdown: database (embedded or external), migrations, workers, HTTP server.

use std::future::IntoFuture;
use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use sqlx::PgPool;
use sqlx::postgres::PgConnectOptions;
use tokio::net::TcpListener;

use crate::embedded_pg::PrivateCluster;
use crate::{AppState, Config, app, db, workers::Workers};

/// The database in use and, when embedded, the cluster to stop at shutdown.
pub struct Database {
    /// Pool with the schema migrated.
    pub pool: PgPool,
    /// The private cluster, when embedded.
    pub cluster: Option<PrivateCluster>,
}

/// Connects to `DATABASE_URL`, or starts the private cluster under `data_dir/pg`; then migrates.
pub async fn open_database(config: &Config) -> anyhow::Result<Database> {
    let (options, cluster) = match &config.database_url {
        Some(url) => {
            let options: PgConnectOptions = url.parse().context("DATABASE_URL is not a valid PostgreSQL URL")?;
            (options, None)
        }
        None => {
            let root = config.data_dir.join("pg");
            let cluster = tokio::task::spawn_blocking(move || PrivateCluster::start(&root)).await??;
            ensure_database(&cluster, "painsim").await?;
            (cluster.connect_options("painsim"), Some(cluster))
        }
    };
    let pool = match db::connect(options, 20).await {
        Ok(p) => p,
        Err(e) => {
            if let Some(c) = cluster {
                let _ = tokio::task::spawn_blocking(move || c.stop()).await;
            }
            return Err(e).context("connecting to the database");
        }
    };
    db::migrate(&pool).await.context("applying migrations")?;
    let (id, starts): (uuid::Uuid, i64) = sqlx::query_as(
        "INSERT INTO installation (id, starts) VALUES ($1, 1)
         ON CONFLICT (singleton) DO UPDATE SET starts = installation.starts + 1
         RETURNING id, starts",
    )
    .bind(uuid::Uuid::new_v4())
    .fetch_one(&pool)
    .await
    .context("recording this start")?;
    tracing::info!(installation = %id, starts, "database ready");
    Ok(Database { pool, cluster })
}

async fn ensure_database(cluster: &PrivateCluster, name: &str) -> anyhow::Result<()> {
    use sqlx::Connection;
    let mut conn = sqlx::PgConnection::connect_with(&cluster.connect_options("postgres")).await.context("connecting to the private cluster")?;
    let exists: bool = sqlx::query_scalar("SELECT EXISTS (SELECT 1 FROM pg_database WHERE datname = $1)").bind(name).fetch_one(&mut conn).await?;
    if !exists {
        sqlx::query(&format!("CREATE DATABASE \"{name}\"")).execute(&mut conn).await?;
    }
    conn.close().await.ok();
    Ok(())
}

/// Runs the server until SIGTERM or SIGINT, then shuts down in order: stop accepting, finish
/// in-flight requests, close the pool, stop the embedded cluster.
pub async fn run(config: Config) -> anyhow::Result<()> {
    let listener = TcpListener::bind(config.bind).await.with_context(|| format!("binding {}", config.bind))?;
    let workers = Workers::start_in_process();
    let Database { pool, cluster } = open_database(&config).await?;
    let demo_notice = crate::records::prepare(&pool, &config.records, cluster.is_some()).await?;
    let mut state = AppState { pool: pool.clone(), embedded_db: cluster.is_some(), workers, dispatcher: None, config: config.clone() };
    // One dispatcher for the router and /healthz; its anatomy (the phantom: tens of seconds the
    // first time) starts loading now, so the first session does not wait for it in its request.
    let dispatcher = crate::dispatch::Dispatcher::for_app(
        state.dispatcher.as_ref(),
        &state.workers,
        &state.config.dispatch,
        &state.config.records.stations_dir,
    );
    if config.dispatch.prepare_at_start {
        dispatcher.prepare_in_background();
    }
    let local_sessions = dispatcher.local_host().cloned();
    // Which renderer the in-process worker uses and how many sessions it takes come from timing
    // both on this machine, once the GPU settled and a station's anatomy is loaded.
    if let Some(host) = &local_sessions
        && config.dispatch.in_process_capacity != Some(0)
    {
        state.workers.calibrate_in_background(host.clone(), config.dispatch.in_process_capacity);
    }
    // The platform's records become xAPI statements, forwarded from the durable outbox; both stop
    // with the server (what they had not finished is in their tables, resumed at the next start).
    let (background_stop, background_stopped) = tokio::sync::watch::channel(false);
    let stopped = move || {
        let mut rx = background_stopped.clone();
        async move {
            let _ = rx.wait_for(|s| *s).await;
        }
    };
    // LTI grade passback delivers through the same outbox.
    let outbox = crate::outbox::Outbox::new(pool.clone());
    outbox.register(crate::xapi::forward::Forwarder::new(pool.clone()));
    let lti_records = crate::records::RecordsState::from_parts(pool.clone(), config.records.clone());
    crate::lti::start(pool.clone(), lti_records, &config.public_url, outbox.clone());
    let outbox_task = outbox.spawn(stopped());
    let projector = crate::xapi::platform::Projector::new(pool.clone(), &config.public_url, Some(outbox));
    let projector_task = projector.spawn(stopped());
    state.dispatcher = Some(dispatcher);
    let addr = listener.local_addr()?;
    tracing::info!(web = %show_path(&config.web_dir), "serving the web client");
    println!("pain-sim is running at http://{addr}/  (health: http://{addr}/healthz)");
    if let Some(notice) = demo_notice {
        // After the URL line (which tools read first); a closed stdout must not stop the server.
        use std::io::Write;
        let _ = writeln!(std::io::stdout().lock(), "{notice}");
    }
    let (signalled_tx, signalled) = tokio::sync::oneshot::channel::<()>();
    let signal = async move {
        shutdown_signal().await;
        let _ = signalled_tx.send(());
    };
    let listener = render_worker::cluster::accepting(listener);
    let serve = axum::serve(listener, app(state).into_make_service_with_connect_info::<std::net::SocketAddr>()).with_graceful_shutdown(signal).into_future();
    // Graceful: in-flight requests finish; a connection still open DRAIN_LIMIT after the signal
    // (a stuck client, an upgraded socket) is dropped rather than holding the process.
    let served = tokio::select! {
        r = serve => r,
        () = async {
            if signalled.await.is_err() {
                std::future::pending::<()>().await;
            }
            tokio::time::sleep(DRAIN_LIMIT).await;
        } => {
            tracing::warn!(limit_s = DRAIN_LIMIT.as_secs(), "connections still open after the drain limit; closing them");
            Ok(())
        }
    };
    let stopping = std::time::Instant::now();
    tracing::info!("shutting down");
    let _ = background_stop.send(true);
    let background = async {
        let _ = outbox_task.await;
        let _ = projector_task.await;
    };
    if tokio::time::timeout(BACKGROUND_STOP_LIMIT, background).await.is_err() {
        tracing::warn!(limit_s = BACKGROUND_STOP_LIMIT.as_secs(), "outbox or projector still running; stopping anyway");
    }
    // Session threads end (and release their GPU resources) before the process exits; their
    // commands are already stored, so they resume from their log at the next start.
    if let Some(h) = local_sessions {
        tokio::task::spawn_blocking(move || h.shutdown()).await?;
        tracing::info!(elapsed_ms = stopping.elapsed().as_millis(), "session threads ended");
    }
    // Every request has ended, so no connection should be checked out; one that is (a
    // background task mid-query) must not hold the database's shutdown forever.
    if tokio::time::timeout(POOL_CLOSE_LIMIT, pool.close()).await.is_err() {
        tracing::warn!(limit_s = POOL_CLOSE_LIMIT.as_secs(), "database connections still in use; stopping anyway");
    }
    tracing::info!(elapsed_ms = stopping.elapsed().as_millis(), "database pool closed");
    if let Some(c) = cluster {
        tokio::task::spawn_blocking(move || c.stop()).await??;
        tracing::info!(elapsed_ms = stopping.elapsed().as_millis(), "private cluster stopped");
    }
    served.context("HTTP server")
}

fn show_path(p: &Path) -> String {
    p.canonicalize().unwrap_or_else(|_| p.to_owned()).display().to_string()
}

/// How long open connections may keep the server up after SIGTERM/SIGINT (our choice: a
/// request of this platform takes well under a second; orchestrators wait 30 s before SIGKILL).
const DRAIN_LIMIT: Duration = Duration::from_secs(10);

/// How long the outbox workers and the xAPI projector may take to stop (our choice: they stop at
/// their next await; a delivery in flight is abandoned and sent again after the next start).
const BACKGROUND_STOP_LIMIT: Duration = Duration::from_secs(3);

/// How long closing the database pool may wait for checked-out connections (our choice).
const POOL_CLOSE_LIMIT: Duration = Duration::from_secs(5);

async fn shutdown_signal() {
    use tokio::signal::unix::{SignalKind, signal};
    let mut term = signal(SignalKind::terminate()).expect("installing the SIGTERM handler");
    let mut int = signal(SignalKind::interrupt()).expect("installing the SIGINT handler");
    tokio::select! {
        _ = term.recv() => tracing::info!("SIGTERM received"),
        _ = int.recv() => tracing::info!("SIGINT received"),
    }
}
