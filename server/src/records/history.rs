//! The audit trail: its one writer ([`audit`], called inside the transaction of every change it
//! records) and its readers (one object's trail, and the admin's `/api/audit`).

use axum::extract::State;
use serde::{Deserialize, Serialize};
use sqlx::PgPool;
use time::OffsetDateTime;
use utoipa::{IntoParams, ToSchema};
use uuid::Uuid;

use super::auth::{CurrentUser, Role};
use super::extract::ApiQuery;
use super::state::RecordsState;
use crate::error::ApiError;

/// Writes one audit event.
pub async fn audit<'e>(
    exec: impl sqlx::PgExecutor<'e>,
    actor: Option<Uuid>,
    action: &str,
    object_type: &str,
    object_id: &str,
    detail: serde_json::Value,
) -> Result<(), sqlx::Error> {
    sqlx::query("INSERT INTO audit_events (actor_id, action, object_type, object_id, detail) VALUES ($1, $2, $3, $4, $5)")
        .bind(actor)
        .bind(action)
        .bind(object_type)
        .bind(object_id)
        .bind(detail)
        .execute(exec)
        .await?;
    Ok(())
}

/// One audit-trail entry: who did what, when, to which object.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct AuditEntry {
    /// Id (increasing).
    pub id: i64,
    /// When (server clock).
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub at: OffsetDateTime,
    /// Who (none for the command line).
    pub actor_id: Option<Uuid>,
    /// Their e-mail.
    pub actor_email: Option<String>,
    /// What (`attempt_created`, `result_submitted`, `attempt_returned`, `attempt_approved`, ...).
    pub action: String,
    /// Object type.
    pub object_type: String,
    /// Object id.
    pub object_id: String,
    /// Details.
    #[schema(value_type = Object)]
    pub detail: serde_json::Value,
}

type AuditRow = (
    i64,
    OffsetDateTime,
    Option<Uuid>,
    Option<String>,
    String,
    String,
    String,
    serde_json::Value,
);

fn audit_entry(
    (id, at, actor_id, actor_email, action, object_type, object_id, detail): AuditRow,
) -> AuditEntry {
    AuditEntry {
        id,
        at,
        actor_id,
        actor_email,
        action,
        object_type,
        object_id,
        detail,
    }
}

pub(crate) async fn audit_of(
    pool: &PgPool,
    object_type: &str,
    object_id: &str,
) -> Result<Vec<AuditEntry>, sqlx::Error> {
    let rows: Vec<AuditRow> = sqlx::query_as(
        "SELECT e.id, e.at, e.actor_id, u.email, e.action, e.object_type, e.object_id, e.detail
         FROM audit_events e LEFT JOIN users u ON u.id = e.actor_id
         WHERE e.object_type = $1 AND e.object_id = $2 ORDER BY e.id",
    )
    .bind(object_type)
    .bind(object_id)
    .fetch_all(pool)
    .await?;
    Ok(rows.into_iter().map(audit_entry).collect())
}

/// Filters of the audit trail.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct AuditFilter {
    /// Only this object type (`attempt`, `user`, `course`).
    #[param(pattern = "^[^\\u0000]*$")]
    pub object_type: Option<String>,
    /// Only this object id.
    #[param(pattern = "^[^\\u0000]*$")]
    pub object_id: Option<String>,
    /// At most this many entries (default 500, at most 5000), newest last.
    #[param(minimum = 1, maximum = 5000, default = 500)]
    pub limit: Option<i64>,
}

/// The audit trail (admin).
#[utoipa::path(get, path = "/api/audit", tag = "reviews", params(AuditFilter),
    responses((status = 200, body = Vec<AuditEntry>), (status = 400), (status = 401), (status = 403)))]
pub async fn audit_trail(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiQuery(f): ApiQuery<AuditFilter>,
) -> Result<axum::Json<Vec<AuditEntry>>, ApiError> {
    user.require(&[Role::Admin])?;
    let limit = f.limit.unwrap_or(500);
    if !(1..=5000).contains(&limit) {
        return Err(ApiError::BadRequest("limit must lie in 1..=5000".into()));
    }
    let rows: Vec<AuditRow> = sqlx::query_as(
        "SELECT * FROM (SELECT e.id, e.at, e.actor_id, u.email, e.action, e.object_type, e.object_id, e.detail
           FROM audit_events e LEFT JOIN users u ON u.id = e.actor_id
           WHERE ($1::text IS NULL OR e.object_type = $1) AND ($2::text IS NULL OR e.object_id = $2)
           ORDER BY e.id DESC LIMIT $3) t ORDER BY id",
    )
    .bind(&f.object_type)
    .bind(&f.object_id)
    .bind(limit)
    .fetch_all(&state.pool)
    .await?;
    Ok(axum::Json(rows.into_iter().map(audit_entry).collect()))
}
