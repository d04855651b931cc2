//! Append-only engagement activity: clients report what the learner did (views, shots,
//! injections, page views) as it happens; the server stamps each event with its own clock and the
//! attempt. Reading a page is engagement, never completion. Server-side code (a live simulation
//! session, the opening of an attempt, a submission) records events too.

use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use sqlx::PgPool;
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::CurrentUser;
use super::authz::attempt_visible;
use super::extract::{ApiJson, ApiPath};
use super::schema;
use super::state::RecordsState;
use super::summary::visible_attempt;
use crate::error::ApiError;

/// Kinds of engagement events.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum ActivityKind {
    /// A live simulation session was launched for the attempt.
    SessionLaunched,
    /// The station was opened (recorded by the server when the attempt is created).
    StationOpened,
    /// A page (briefing, reading) was viewed: engagement, never completion.
    PageViewed,
    /// The imaging view changed (C-arm angle, probe pose).
    ViewChanged,
    /// An image was acquired (a fluoroscopy shot, an ultrasound capture).
    ImageAcquired,
    /// The needle was advanced, withdrawn or steered.
    NeedleAdjusted,
    /// Contrast or injectate was injected.
    Injection,
    /// Measurements were submitted (recorded by the server only).
    Submission,
}

impl ActivityKind {
    /// Every kind.
    pub const ALL: [ActivityKind; 8] = [
        ActivityKind::SessionLaunched,
        ActivityKind::StationOpened,
        ActivityKind::PageViewed,
        ActivityKind::ViewChanged,
        ActivityKind::ImageAcquired,
        ActivityKind::NeedleAdjusted,
        ActivityKind::Injection,
        ActivityKind::Submission,
    ];

    /// Stored name.
    pub fn as_str(self) -> &'static str {
        match self {
            ActivityKind::SessionLaunched => "session_launched",
            ActivityKind::StationOpened => "station_opened",
            ActivityKind::PageViewed => "page_viewed",
            ActivityKind::ViewChanged => "view_changed",
            ActivityKind::ImageAcquired => "image_acquired",
            ActivityKind::NeedleAdjusted => "needle_adjusted",
            ActivityKind::Injection => "injection",
            ActivityKind::Submission => "submission",
        }
    }

    /// Kinds only the server records (a client cannot claim them).
    pub fn server_only(self) -> bool {
        matches!(self, ActivityKind::StationOpened | ActivityKind::Submission)
    }
}

/// Largest `detail` object of an activity event, in bytes of JSON (an event describes one
/// interaction; bulk data belongs in the interaction log the result references).
pub const MAX_ACTIVITY_DETAIL_BYTES: usize = 4096;

/// An engagement event reported by a client.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewActivity {
    /// What happened (`station_opened` and `submission` are recorded by the server only).
    #[schema(schema_with = client_activity_kinds)]
    pub kind: ActivityKind,
    /// When the client saw it happen (kept for analysis; ordering uses the server's clock).
    #[serde(default, with = "time::serde::rfc3339::option")]
    #[schema(value_type = Option<String>, format = DateTime)]
    pub client_time: Option<OffsetDateTime>,
    /// Details (view angles, exposure, volume), a JSON object of at most 4 KiB.
    #[serde(default)]
    #[schema(schema_with = activity_detail)]
    pub detail: Option<serde_json::Value>,
}

/// The activity kinds a client may report (the others are recorded by the server).
fn client_activity_kinds() -> utoipa::openapi::schema::Schema {
    schema::one_of_strings(
        ActivityKind::ALL
            .iter()
            .filter(|k| !k.server_only())
            .map(|k| k.as_str()),
    )
    .description(Some(
        "What happened; `station_opened` and `submission` are recorded by the server only",
    ))
    .build()
    .into()
}

/// `detail` of a new activity event: absent, `null` or a JSON object whose strings and keys hold
/// no NUL (described three levels deep).
fn activity_detail() -> utoipa::openapi::schema::Schema {
    schema::object_without_nul(2, true)
        .description(Some(format!(
            "Details (view angles, exposure, volume): a JSON object of at most \
             {MAX_ACTIVITY_DETAIL_BYTES} bytes"
        )))
        .build()
        .into()
}

/// A recorded engagement event.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ActivityEvent {
    /// Id (increasing: the order of recording).
    pub id: i64,
    /// Attempt.
    pub attempt_id: Uuid,
    /// Who.
    pub user_id: Uuid,
    /// What.
    #[schema(value_type = ActivityKind)]
    pub kind: String,
    /// Server time of recording.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub recorded_at: OffsetDateTime,
    /// Client time, as reported.
    #[serde(with = "time::serde::rfc3339::option")]
    #[schema(value_type = Option<String>, format = DateTime)]
    pub client_time: Option<OffsetDateTime>,
    /// Details.
    #[schema(value_type = Object)]
    pub detail: serde_json::Value,
}

type ActivityRow = (
    i64,
    Uuid,
    Uuid,
    String,
    OffsetDateTime,
    Option<OffsetDateTime>,
    serde_json::Value,
);

/// Appends one activity event (also used by server-side sessions through [`record_activity`]).
pub(crate) async fn insert_activity<'e>(
    exec: impl sqlx::PgExecutor<'e>,
    attempt_id: Uuid,
    user_id: Uuid,
    kind: ActivityKind,
    client_time: Option<OffsetDateTime>,
    detail: serde_json::Value,
) -> Result<(i64, OffsetDateTime), sqlx::Error> {
    sqlx::query_as(
        "INSERT INTO activity_events (attempt_id, user_id, kind, client_time, detail) VALUES ($1, $2, $3, $4, $5)
         RETURNING id, recorded_at",
    )
    .bind(attempt_id)
    .bind(user_id)
    .bind(kind.as_str())
    .bind(client_time)
    .bind(detail)
    .fetch_one(exec)
    .await
}

/// Records an engagement event from server-side code (a live simulation session): the attempt
/// must belong to `user_id` and not be approved. Returns the event id.
pub async fn record_activity(
    pool: &PgPool,
    attempt_id: Uuid,
    user_id: Uuid,
    kind: ActivityKind,
    detail: serde_json::Value,
) -> Result<Option<i64>, sqlx::Error> {
    sqlx::query_scalar(
        "INSERT INTO activity_events (attempt_id, user_id, kind, detail)
         SELECT id, learner_id, $3, $4 FROM attempts WHERE id = $1 AND learner_id = $2 AND state <> 'approved'
         RETURNING id",
    )
    .bind(attempt_id)
    .bind(user_id)
    .bind(kind.as_str())
    .bind(detail)
    .fetch_optional(pool)
    .await
}

/// Record an engagement event on one's own attempt. The response (201) means it is committed.
#[utoipa::path(post, path = "/api/attempts/{attempt_id}/activity", tag = "attempts", request_body = NewActivity,
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 201, body = ActivityEvent), (status = 400), (status = 401), (status = 403, description = "Not the attempt's learner"), (status = 404), (status = 409, description = "Attempt approved: closed")))]
pub async fn post_activity(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(attempt_id): ApiPath<Uuid>,
    ApiJson(req): ApiJson<NewActivity>,
) -> Result<(StatusCode, axum::Json<ActivityEvent>), ApiError> {
    if req.kind.server_only() {
        return Err(ApiError::BadRequest(format!(
            "`{}` events are recorded by the server, not reported by clients",
            req.kind.as_str()
        )));
    }
    let detail = req.detail.unwrap_or_else(|| serde_json::json!({}));
    if !detail.is_object() {
        return Err(ApiError::BadRequest("detail must be a JSON object".into()));
    }
    if detail.to_string().len() > MAX_ACTIVITY_DETAIL_BYTES {
        return Err(ApiError::BadRequest(format!(
            "detail must be at most {MAX_ACTIVITY_DETAIL_BYTES} bytes of JSON"
        )));
    }
    let attempt = visible_attempt(&state, &user, attempt_id).await?;
    if attempt.learner_id != user.id {
        return Err(ApiError::Forbidden(
            "only the attempt's learner records activity on it".into(),
        ));
    }
    let row: Option<(i64, OffsetDateTime)> = sqlx::query_as(
        "INSERT INTO activity_events (attempt_id, user_id, kind, client_time, detail)
         SELECT id, learner_id, $3, $4, $5 FROM attempts WHERE id = $1 AND learner_id = $2 AND state <> 'approved'
         RETURNING id, recorded_at",
    )
    .bind(attempt_id)
    .bind(user.id)
    .bind(req.kind.as_str())
    .bind(req.client_time)
    .bind(&detail)
    .fetch_optional(&state.pool)
    .await?;
    let (id, recorded_at) =
        row.ok_or_else(|| ApiError::Conflict("the attempt is approved and closed".into()))?;
    Ok((
        StatusCode::CREATED,
        axum::Json(ActivityEvent {
            id,
            attempt_id,
            user_id: user.id,
            kind: req.kind.as_str().into(),
            recorded_at,
            client_time: req.client_time,
            detail,
        }),
    ))
}

/// The attempt's engagement events in recording order (visible to whoever sees the attempt).
#[utoipa::path(get, path = "/api/attempts/{attempt_id}/activity", tag = "attempts",
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 200, body = Vec<ActivityEvent>), (status = 400), (status = 401), (status = 404)))]
pub async fn list_activity(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(attempt_id): ApiPath<Uuid>,
) -> Result<axum::Json<Vec<ActivityEvent>>, ApiError> {
    let rows: Vec<ActivityRow> = sqlx::query_as(&format!(
        "SELECT e.id, e.attempt_id, e.user_id, e.kind, e.recorded_at, e.client_time, e.detail
         FROM activity_events e JOIN attempts a ON a.id = e.attempt_id
         WHERE a.id = $3 AND {} ORDER BY e.id",
        attempt_visible(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .bind(attempt_id)
    .fetch_all(&state.pool)
    .await?;
    if rows.is_empty() {
        // An attempt always has its `station_opened` event, so no rows means not visible.
        visible_attempt(&state, &user, attempt_id).await?;
    }
    Ok(axum::Json(
        rows.into_iter()
            .map(
                |(id, attempt_id, user_id, kind, recorded_at, client_time, detail)| ActivityEvent {
                    id,
                    attempt_id,
                    user_id,
                    kind,
                    recorded_at,
                    client_time,
                    detail,
                },
            )
            .collect(),
    ))
}
