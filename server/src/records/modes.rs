//! How each station runs in a course: practice (the session may give hints such as "needle in
//! the scan plane") or assessment (no hints, and the technical result stays off the session's
//! socket until the attempt is over). The course's faculty set it; an attempt keeps the mode it
//! was opened in (`attempts.mode`), so changing the setting never changes an attempt under way.
//!
//! What a session tells the browser in each mode is `dispatch::disclosure`'s business; this
//! module only stores the setting.

use axum::extract::State;
use serde::{Deserialize, Serialize};
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::CurrentUser;
use super::extract::{ApiJson, ApiPath};
use super::history::audit;
use super::state::RecordsState;
use crate::error::ApiError;

/// How a station runs in a course.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum StationMode {
    /// Hints allowed; the result is shown at the end of the session.
    #[default]
    Practice,
    /// No hints; the result is read from the attempt once it is submitted.
    Assessment,
}

impl StationMode {
    /// The database and wire spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            StationMode::Practice => "practice",
            StationMode::Assessment => "assessment",
        }
    }

    /// From the database spelling; anything unknown is assessment (the mode that tells less).
    pub fn from_db(s: &str) -> StationMode {
        match s {
            "practice" => StationMode::Practice,
            _ => StationMode::Assessment,
        }
    }
}

/// The mode an attempt was opened in. A database failure answers assessment: a session whose
/// mode cannot be read tells the learner less, never more.
pub async fn mode_of_attempt(pool: &sqlx::PgPool, attempt_id: Uuid) -> StationMode {
    match sqlx::query_scalar::<_, String>("SELECT mode FROM attempts WHERE id = $1")
        .bind(attempt_id)
        .fetch_optional(pool)
        .await
    {
        Ok(Some(m)) => StationMode::from_db(&m),
        Ok(None) => StationMode::Assessment,
        Err(e) => {
            tracing::warn!(%attempt_id, "reading the attempt's mode failed (assessment assumed): {e}");
            StationMode::Assessment
        }
    }
}

/// One station's mode in a course.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct StationModeSetting {
    /// Station id.
    pub station_id: String,
    /// Its mode in the course.
    pub mode: StationMode,
    /// Who set it last (absent: never set, so practice).
    pub set_by: Option<Uuid>,
    /// When it was set last.
    #[serde(with = "time::serde::rfc3339::option")]
    #[schema(value_type = Option<String>, format = DateTime)]
    pub set_at: Option<OffsetDateTime>,
}

/// Setting a station's mode.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StationModeRequest {
    /// The new mode.
    pub mode: StationMode,
}

/// Whether the caller may see the course (member or admin) and may set its modes (its faculty
/// or an admin); 404 when the course does not exist or is not visible.
pub(crate) async fn course_access(
    state: &RecordsState,
    user: &CurrentUser,
    course_id: Uuid,
) -> Result<bool, ApiError> {
    let role: Option<Option<String>> = sqlx::query_scalar(
        "SELECT (SELECT m.role FROM course_members m WHERE m.course_id = c.id AND m.user_id = $2)
         FROM courses c WHERE c.id = $1",
    )
    .bind(course_id)
    .bind(user.id)
    .fetch_optional(&state.pool)
    .await?;
    match role {
        None => Err(ApiError::NotFound("course".into())),
        Some(_) if user.is_admin() => Ok(true),
        Some(Some(r)) => Ok(r == "faculty"),
        Some(None) => Err(ApiError::NotFound("course".into())),
    }
}

/// Every station of the catalog with its mode in the course (members and admins).
#[utoipa::path(get, path = "/api/courses/{course_id}/station-modes", tag = "courses",
    params(("course_id" = Uuid, Path, description = "Course id")),
    responses((status = 200, body = Vec<StationModeSetting>), (status = 401), (status = 404)))]
pub async fn list_station_modes(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(course_id): ApiPath<Uuid>,
) -> Result<axum::Json<Vec<StationModeSetting>>, ApiError> {
    course_access(&state, &user, course_id).await?;
    let rows: Vec<(String, String, Option<Uuid>, OffsetDateTime)> = sqlx::query_as(
        "SELECT station_id, mode, set_by, set_at FROM course_station_modes WHERE course_id = $1",
    )
    .bind(course_id)
    .fetch_all(&state.pool)
    .await?;
    let mut out: Vec<StationModeSetting> = state
        .stations
        .stations
        .keys()
        .map(|id| {
            let row = rows.iter().find(|r| &r.0 == id);
            StationModeSetting {
                station_id: id.clone(),
                mode: row.map_or(StationMode::Practice, |r| StationMode::from_db(&r.1)),
                set_by: row.and_then(|r| r.2),
                set_at: row.map(|r| r.3),
            }
        })
        .collect();
    out.sort_by(|a, b| a.station_id.cmp(&b.station_id));
    Ok(axum::Json(out))
}

/// Set how a station runs in the course (its faculty, or an admin). Attempts already opened
/// keep their mode; the change is in the audit trail.
#[utoipa::path(put, path = "/api/courses/{course_id}/station-modes/{station_id}", tag = "courses",
    request_body = StationModeRequest,
    params(("course_id" = Uuid, Path, description = "Course id"), ("station_id" = String, Path, description = "Station id")),
    responses((status = 200, body = StationModeSetting), (status = 400), (status = 401),
        (status = 403, description = "Not faculty of the course"), (status = 404, description = "Unknown course or station")))]
pub async fn put_station_mode(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath((course_id, station_id)): ApiPath<(Uuid, String)>,
    ApiJson(req): ApiJson<StationModeRequest>,
) -> Result<axum::Json<StationModeSetting>, ApiError> {
    if !course_access(&state, &user, course_id).await? {
        return Err(ApiError::Forbidden(
            "only the course's faculty (or an admin) set how its stations run".into(),
        ));
    }
    if state.stations.get(&station_id).is_none() {
        return Err(ApiError::NotFound(format!("station {station_id:?}")));
    }
    let mut tx = state.pool.begin().await?;
    let set_at: OffsetDateTime = sqlx::query_scalar(
        "INSERT INTO course_station_modes (course_id, station_id, mode, set_by) VALUES ($1, $2, $3, $4)
         ON CONFLICT (course_id, station_id)
         DO UPDATE SET mode = EXCLUDED.mode, set_by = EXCLUDED.set_by, set_at = now()
         RETURNING set_at",
    )
    .bind(course_id)
    .bind(&station_id)
    .bind(req.mode.as_str())
    .bind(user.id)
    .fetch_one(&mut *tx)
    .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "station_mode_set",
        "course",
        &course_id.to_string(),
        serde_json::json!({ "station_id": station_id, "mode": req.mode.as_str() }),
    )
    .await?;
    tx.commit().await?;
    Ok(axum::Json(StationModeSetting {
        station_id,
        mode: req.mode,
        set_by: Some(user.id),
        set_at: Some(set_at),
    }))
}
