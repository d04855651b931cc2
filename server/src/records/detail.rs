//! One attempt with everything recorded about it: technical results, faculty reviews, the audit
//! trail and the amount of engagement. It reads what the other modules write, so it sits above
//! them all (and neither attempts nor reviews need each other).

use axum::extract::State;
use serde::{Deserialize, Serialize};
use sim_core::rubric::TECHNICAL_RESULT_NOTICE;
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::CurrentUser;
use super::extract::ApiPath;
use super::history::{AuditEntry, audit_of};
use super::results::{RESULT_COLUMNS, ResultRow, TechnicalResultView, result_view};
use super::reviews::{ReviewView, reviews_of};
use super::state::RecordsState;
use super::summary::{AttemptSummary, visible_attempt};
use crate::error::ApiError;

/// The attempt with results, reviews, audit trail and activity count.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct AttemptDetail {
    /// Summary.
    pub attempt: AttemptSummary,
    /// Technical results, oldest first.
    pub results: Vec<TechnicalResultView>,
    /// Faculty reviews, oldest first.
    pub reviews: Vec<ReviewView>,
    /// Audit trail of the attempt, oldest first.
    pub audit: Vec<AuditEntry>,
    /// Number of engagement events.
    pub activity_events: i64,
    /// "Met" is not a certification of clinical competency; approval is a faculty decision.
    pub notice: String,
}

/// One attempt with its results, reviews and audit trail (its learner, faculty of its course,
/// admins; 404 for everyone else).
#[utoipa::path(get, path = "/api/attempts/{attempt_id}", tag = "attempts",
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 200, body = AttemptDetail), (status = 400), (status = 401), (status = 404)))]
pub async fn get_attempt(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(attempt_id): ApiPath<Uuid>,
) -> Result<axum::Json<AttemptDetail>, ApiError> {
    let attempt = visible_attempt(&state, &user, attempt_id).await?;
    let results: Vec<ResultRow> = sqlx::query_as(&format!(
        "SELECT {RESULT_COLUMNS} FROM technical_results WHERE attempt_id = $1 ORDER BY seq"
    ))
    .bind(attempt_id)
    .fetch_all(&state.pool)
    .await?;
    let reviews = reviews_of(&state.pool, attempt_id).await?;
    let audit = audit_of(&state.pool, "attempt", &attempt_id.to_string()).await?;
    let activity_events: i64 =
        sqlx::query_scalar("SELECT count(*) FROM activity_events WHERE attempt_id = $1")
            .bind(attempt_id)
            .fetch_one(&state.pool)
            .await?;
    Ok(axum::Json(AttemptDetail {
        attempt,
        results: results.into_iter().map(result_view).collect(),
        reviews,
        audit,
        activity_events,
        notice: TECHNICAL_RESULT_NOTICE.into(),
    }))
}
