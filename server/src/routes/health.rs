//! `GET /healthz`: is the database reachable and migrated, and is a render worker ready?

use std::time::Duration;

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use serde::Serialize;

use crate::AppState;
use crate::workers::WorkerStatus;

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
}

/// 200 with the report when database and render worker are ready, 503 with it otherwise.
pub async fn healthz(State(state): State<AppState>) -> (StatusCode, Json<Health>) {
    let query = sqlx::query_scalar::<_, uuid::Uuid>("SELECT id FROM installation").fetch_optional(&state.pool);
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
    let database = DatabaseStatus { ready: installation_id.is_some(), embedded: state.embedded_db, installation_id };
    let render_worker = state.workers.status();
    let ok = database.ready && render_worker.ready;
    let status = if ok { StatusCode::OK } else { StatusCode::SERVICE_UNAVAILABLE };
    (status, Json(Health { status: if ok { "ok" } else { "unavailable" }, version: env!("CARGO_PKG_VERSION"), database, render_worker }))
}
