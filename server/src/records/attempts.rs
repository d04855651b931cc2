//! Attempts: a learner opens an attempt at a station in a course they are enrolled in (the server
//! records `station_opened`), and lists the attempts they may see. What happens in an attempt is
//! recorded by [`super::activity`] (engagement) and [`super::results`] (technical results); the
//! faculty decision by [`super::reviews`]; [`super::detail`] shows it all.

use axum::extract::State;
use axum::http::StatusCode;
use serde::Deserialize;
use utoipa::ToSchema;
use uuid::Uuid;

use super::activity::{ActivityKind, insert_activity};
use super::auth::CurrentUser;
use super::authz::attempt_visible;
use super::extract::ApiJson;
use super::history::audit;
use super::state::RecordsState;
use super::summary::{AttemptSummary, SUMMARY_COLUMNS, SUMMARY_FROM, SummaryRow, summary};
use crate::error::ApiError;

/// Opening an attempt.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewAttempt {
    /// Course the attempt counts for (the caller must be enrolled as a learner).
    pub course_id: Uuid,
    /// Station id.
    #[schema(pattern = "^[^\\u0000]*$")]
    pub station_id: String,
}

/// Open an attempt at a station (learners of the course). Records `station_opened`.
#[utoipa::path(post, path = "/api/attempts", tag = "attempts", request_body = NewAttempt,
    responses((status = 201, body = AttemptSummary), (status = 400), (status = 401), (status = 403, description = "Not a learner of the course"), (status = 404, description = "Unknown course or station")))]
pub async fn create_attempt(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiJson(req): ApiJson<NewAttempt>,
) -> Result<(StatusCode, axum::Json<AttemptSummary>), ApiError> {
    let station = state
        .stations
        .get(&req.station_id)
        .ok_or_else(|| ApiError::NotFound(format!("station {:?}", req.station_id)))?;
    // Registering is idempotent; start-up has normally done it already.
    station
        .register(&state.pool)
        .await
        .map_err(|e| ApiError::Internal(format!("{e:#}")))?;
    let id = Uuid::new_v4();
    let mut tx = state.pool.begin().await?;
    let inserted = sqlx::query(
        "INSERT INTO attempts (id, learner_id, course_id, station_id, station_revision, rubric_revision, mode)
         SELECT $1, $2, $3, $4, $5, $6,
                COALESCE((SELECT mode FROM course_station_modes WHERE course_id = $3 AND station_id = $4), 'practice')
         WHERE EXISTS (SELECT 1 FROM course_members WHERE course_id = $3 AND user_id = $2 AND role = 'learner')",
    )
    .bind(id)
    .bind(user.id)
    .bind(req.course_id)
    .bind(&station.station.id)
    .bind(station.station.revision as i32)
    .bind(station.station.rubric.revision as i32)
    .execute(&mut *tx)
    .await?;
    if inserted.rows_affected() == 0 {
        let exists: bool =
            sqlx::query_scalar("SELECT EXISTS (SELECT 1 FROM courses WHERE id = $1)")
                .bind(req.course_id)
                .fetch_one(&mut *tx)
                .await?;
        return Err(if exists {
            ApiError::Forbidden(
                "only learners enrolled in the course can open attempts in it".into(),
            )
        } else {
            ApiError::NotFound("course".into())
        });
    }
    insert_activity(
        &mut *tx,
        id,
        user.id,
        ActivityKind::StationOpened,
        None,
        serde_json::json!({ "station_id": station.station.id }),
    )
    .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "attempt_created",
        "attempt",
        &id.to_string(),
        serde_json::json!({ "station_id": station.station.id, "course_id": req.course_id }),
    )
    .await?;
    let row: SummaryRow = sqlx::query_as(&format!(
        "SELECT {SUMMARY_COLUMNS} FROM {SUMMARY_FROM} WHERE a.id = $1"
    ))
    .bind(id)
    .fetch_one(&mut *tx)
    .await?;
    tx.commit().await?;
    Ok((StatusCode::CREATED, axum::Json(summary(row))))
}

/// Attempts visible to the caller (own; of courses taught; all for admins), newest first.
#[utoipa::path(get, path = "/api/attempts", tag = "attempts",
    responses((status = 200, body = Vec<AttemptSummary>), (status = 401)))]
pub async fn list_attempts(
    State(state): State<RecordsState>,
    user: CurrentUser,
) -> Result<axum::Json<Vec<AttemptSummary>>, ApiError> {
    let rows: Vec<SummaryRow> = sqlx::query_as(&format!(
        "SELECT {SUMMARY_COLUMNS} FROM {SUMMARY_FROM} WHERE {} ORDER BY a.created_at DESC, a.id LIMIT 1000",
        attempt_visible(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .fetch_all(&state.pool)
    .await?;
    Ok(axum::Json(rows.into_iter().map(summary).collect()))
}
