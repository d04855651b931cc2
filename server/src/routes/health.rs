//! `GET /healthz`: is the database reachable and migrated, and is a render worker ready?

use std::time::Duration;

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use serde::Serialize;

use crate::state::AppState;
use crate::workers::WorkerStatus;
use render_worker::session::host::RegionReadiness;

/// Database part of the health report.
#[derive(Debug, Serialize)]
pub struct DatabaseStatus {
    /// True when a query against the migrated schema succeeded.
    pub ready: bool,
    /// True for the embedded private cluster.
    pub embedded: bool,
    /// Installation id (kept across restarts).
    pub installation_id: Option<uuid::Uuid>,
}

/// The health report.
#[derive(Debug, Serialize)]
pub struct Health {
    /// `ok` when everything is ready, else `unavailable`.
    pub status: &'static str,
    /// Server version.
    pub version: &'static str,
    /// Database readiness.
    pub database: DatabaseStatus,
    /// Render worker readiness.
    pub render_worker: WorkerStatus,
    /// The in-process worker's anatomy (absent when the server has no in-process worker).
    pub anatomy: Option<AnatomyStatus>,
    /// The in-process worker's session slots (absent without one).
    pub sessions: Option<SessionCapacity>,
    /// What every server replica shares (PostgreSQL): the registered workers and the live
    /// sessions of the whole deployment, the same from every replica. Absent when the shared
    /// state could not be read.
    pub cluster: Option<crate::dispatch::ClusterStatus>,
}

/// Session slots of the in-process worker.
#[derive(Debug, Serialize)]
pub struct SessionCapacity {
    /// Sessions it holds now.
    pub live: usize,
    /// Most sessions it holds.
    pub capacity: usize,
    /// `capacity - live`: new sessions it can take.
    pub free: usize,
    /// Most live sessions one user may hold.
    pub per_user_limit: usize,
    /// Most live sessions one course may hold.
    pub per_course_limit: usize,
    /// A session without a command for this long is closed, open socket or not.
    pub idle_close_s: u64,
}

/// Anatomy part of the health report. Not part of `status`: the server serves while the anatomy
/// is prepared, and session requests meanwhile get 503 with `Retry-After`.
#[derive(Debug, Serialize)]
pub struct AnatomyStatus {
    /// True when every region the stations use is loaded.
    pub ready: bool,
    /// Each region: `not_started`, `building` (stage, fraction, elapsed and remaining seconds),
    /// `ready`, or `failed` with the reason.
    pub regions: std::collections::BTreeMap<String, RegionReadiness>,
}

/// 200 with the report when database and render worker are ready, 503 with it otherwise.
pub async fn healthz(State(state): State<AppState>) -> (StatusCode, Json<Health>) {
    let query = sqlx::query_scalar::<_, uuid::Uuid>("SELECT id FROM installation")
        .fetch_optional(&state.pool);
    let installation_id = match tokio::time::timeout(Duration::from_secs(2), query).await {
        Ok(Ok(id)) => id,
        Ok(Err(e)) => {
            tracing::warn!(error = %e, "health check: database query failed");
            None
        }
        Err(_) => {
            tracing::warn!("health check: database query timed out");
            None
        }
    };
    let database = DatabaseStatus {
        ready: installation_id.is_some(),
        embedded: state.embedded_db,
        installation_id,
    };
    let render_worker = state.workers.status();
    let anatomy = state
        .dispatcher
        .clone()
        .filter(|d| d.local_host().is_some())
        .map(|d| {
            let regions = d.anatomy();
            AnatomyStatus {
                ready: regions
                    .values()
                    .all(|r| matches!(r, RegionReadiness::Ready { .. })),
                regions,
            }
        });
    let sessions = state.dispatcher.as_ref().and_then(|d| {
        d.local_capacity().map(|(live, capacity)| SessionCapacity {
            live,
            capacity,
            free: capacity.saturating_sub(live),
            per_user_limit: d.sessions_per_user(),
            per_course_limit: d.sessions_per_course(),
            idle_close_s: d.session_idle().as_secs(),
        })
    });
    let cluster = match &state.dispatcher {
        Some(d) => match tokio::time::timeout(Duration::from_secs(2), d.cluster_status()).await {
            Ok(Ok(c)) => Some(c),
            Ok(Err(e)) => {
                tracing::warn!(error = %e, "health check: reading the shared state failed");
                None
            }
            Err(_) => None,
        },
        None => None,
    };
    // Sessions can run when the in-process worker is ready or a registered worker is alive.
    let remote_ready = cluster.as_ref().is_some_and(|c| c.workers.alive > 0);
    let ok = database.ready && (render_worker.ready || remote_ready);
    let status = if ok {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (
        status,
        Json(Health {
            status: if ok { "ok" } else { "unavailable" },
            version: env!("CARGO_PKG_VERSION"),
            database,
            render_worker,
            anatomy,
            sessions,
            cluster,
        }),
    )
}
