//! Attempts, append-only engagement activity, and technical results.
//!
//! A learner opens an attempt at a station in a course they are enrolled in; the server records
//! `station_opened`. Clients report engagement (views, shots, injections, page views) as it
//! happens; the server stamps each event with its own clock and the attempt. Submitting
//! measurements runs the rubric engine (`sim_core::rubric`) against the station revision the
//! attempt was opened with, stores the technical result with its reproducibility record, records
//! `submission`, and puts the attempt in the review queue. None of this is approval: that is a
//! faculty decision ([`super::reviews`]).

use std::collections::BTreeMap;

use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use sim_core::rubric::{Measurements, Station, TECHNICAL_RESULT_NOTICE};
use sqlx::PgPool;
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::RecordsState;
use super::auth::{CurrentUser, audit};
use super::authz::attempt_visible;
use super::extract::{ApiJson, ApiPath};
use crate::ApiError;

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

/// An attempt as listed.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct AttemptSummary {
    /// Id.
    pub id: Uuid,
    /// Learner id.
    pub learner_id: Uuid,
    /// Learner e-mail.
    pub learner_email: String,
    /// Learner name.
    pub learner_name: String,
    /// Course id.
    pub course_id: Uuid,
    /// Course code.
    pub course_code: String,
    /// Station id.
    pub station_id: String,
    /// Station revision in force when the attempt was opened.
    pub station_revision: i32,
    /// Rubric revision in force when the attempt was opened.
    pub rubric_revision: i32,
    /// `in_progress`, `submitted` (awaiting review), `returned` (to the learner) or `approved`.
    pub state: String,
    /// Technical outcome of the latest result (`met`, `not_met`, `incomplete`), if any.
    pub latest_outcome: Option<String>,
    /// Score of the latest result, if any.
    pub latest_score: Option<f64>,
    /// Opened.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub created_at: OffsetDateTime,
    /// Last change of state.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub updated_at: OffsetDateTime,
}

/// SELECT list producing an [`AttemptSummary`] from `attempts a`.
pub(crate) const SUMMARY_COLUMNS: &str = "a.id, a.learner_id, u.email, u.display_name, a.course_id, c.code, a.station_id,
    a.station_revision, a.rubric_revision, a.state,
    (SELECT r.outcome FROM technical_results r WHERE r.attempt_id = a.id ORDER BY r.seq DESC LIMIT 1),
    (SELECT r.score FROM technical_results r WHERE r.attempt_id = a.id ORDER BY r.seq DESC LIMIT 1),
    a.created_at, a.updated_at";
/// FROM clause matching [`SUMMARY_COLUMNS`].
pub(crate) const SUMMARY_FROM: &str =
    "attempts a JOIN users u ON u.id = a.learner_id JOIN courses c ON c.id = a.course_id";

pub(crate) type SummaryRow = (
    Uuid,
    Uuid,
    String,
    String,
    Uuid,
    String,
    String,
    i32,
    i32,
    String,
    Option<String>,
    Option<f64>,
    OffsetDateTime,
    OffsetDateTime,
);

pub(crate) fn summary(r: SummaryRow) -> AttemptSummary {
    AttemptSummary {
        id: r.0,
        learner_id: r.1,
        learner_email: r.2,
        learner_name: r.3,
        course_id: r.4,
        course_code: r.5,
        station_id: r.6,
        station_revision: r.7,
        rubric_revision: r.8,
        state: r.9,
        latest_outcome: r.10,
        latest_score: r.11,
        created_at: r.12,
        updated_at: r.13,
    }
}

/// Opening an attempt.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewAttempt {
    /// Course the attempt counts for (the caller must be enrolled as a learner).
    pub course_id: Uuid,
    /// Station id.
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
        "INSERT INTO attempts (id, learner_id, course_id, station_id, station_revision, rubric_revision)
         SELECT $1, $2, $3, $4, $5, $6
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

/// A stored technical result.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct TechnicalResultView {
    /// Id.
    pub id: Uuid,
    /// 1 for the first submission of the attempt, 2 for the next, ...
    pub seq: i32,
    /// `client` (reported by an authenticated client) or `server` (computed by a server session).
    pub source: String,
    /// `met`, `not_met` or `incomplete`: a technical outcome, not a competency judgement.
    pub outcome: String,
    /// Weighted score over measured criteria.
    pub score: Option<f64>,
    /// Share of rubric weight that was measured.
    pub measured_weight_fraction: f64,
    /// Station id, revision and rubric revision used.
    pub station_id: String,
    /// Station revision used.
    pub station_revision: i32,
    /// Rubric revision used.
    pub rubric_revision: i32,
    /// SHA-256 of the station file used.
    pub station_sha256: String,
    /// The measurements as submitted.
    #[schema(value_type = Object)]
    pub measurements: serde_json::Value,
    /// Full rubric-engine output with per-criterion detail.
    #[schema(value_type = Object)]
    pub detail: serde_json::Value,
    /// Reproducibility record.
    pub reproducibility: Reproducibility,
    /// Stored.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub created_at: OffsetDateTime,
    /// "Met" is not a certification of clinical competency.
    pub notice: String,
}

/// What is needed to reproduce the attempt's images and measurements.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct Reproducibility {
    /// Code revision of the simulator that produced the measurements (e.g. a git commit).
    pub code_revision: String,
    /// SHA-256 (hex) of each region asset file, by file name.
    pub asset_hashes: BTreeMap<String, String>,
    /// Device profile (detector, probe, display), as a JSON object.
    #[schema(value_type = Object)]
    pub device_profile: serde_json::Value,
    /// C-arm or probe settings (kVp, mA, angles, depth, gain), as a JSON object.
    #[schema(value_type = Object)]
    pub imaging_settings: serde_json::Value,
    /// Reference to an external ordered interaction log, if any (the server's own activity
    /// range is recorded in `activity_upto_event_id` regardless).
    #[serde(default)]
    pub interaction_log_ref: Option<String>,
    /// Server version that stored the result (set by the server).
    #[serde(default)]
    pub server_version: Option<String>,
    /// Last activity event of this attempt before the submission (set by the server): the
    /// ordered interaction history is `activity_events` of the attempt with id up to this.
    #[serde(default)]
    pub activity_upto_event_id: Option<i64>,
    /// Number of activity events up to the submission (set by the server).
    #[serde(default)]
    pub activity_event_count: Option<i64>,
}

/// Measurements to score.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewResult {
    /// Measurement key (e.g. `tip_to_target_mm`) to value. Yes/no observations are 1 or 0.
    pub measurements: BTreeMap<String, f64>,
    /// Reproducibility record.
    pub reproducibility: Reproducibility,
}

/// The attempt with results, reviews, audit trail and activity count.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct AttemptDetail {
    /// Summary.
    pub attempt: AttemptSummary,
    /// Technical results, oldest first.
    pub results: Vec<TechnicalResultView>,
    /// Faculty reviews, oldest first.
    pub reviews: Vec<super::reviews::ReviewView>,
    /// Audit trail of the attempt, oldest first.
    pub audit: Vec<super::reviews::AuditEntry>,
    /// Number of engagement events.
    pub activity_events: i64,
    /// "Met" is not a certification of clinical competency; approval is a faculty decision.
    pub notice: String,
}

/// Fetches a visible attempt's summary or 404.
pub(crate) async fn visible_attempt(
    state: &RecordsState,
    user: &CurrentUser,
    attempt_id: Uuid,
) -> Result<AttemptSummary, ApiError> {
    let row: Option<SummaryRow> = sqlx::query_as(&format!(
        "SELECT {SUMMARY_COLUMNS} FROM {SUMMARY_FROM} WHERE a.id = $3 AND {}",
        attempt_visible(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .bind(attempt_id)
    .fetch_optional(&state.pool)
    .await?;
    row.map(summary)
        .ok_or_else(|| ApiError::NotFound("attempt".into()))
}

#[derive(sqlx::FromRow)]
struct ResultRow {
    id: Uuid,
    seq: i32,
    source: String,
    outcome: String,
    score: Option<f64>,
    measured_weight_fraction: f64,
    station_id: String,
    station_revision: i32,
    rubric_revision: i32,
    station_sha256: String,
    measurements: serde_json::Value,
    detail: serde_json::Value,
    code_revision: String,
    server_version: String,
    asset_hashes: serde_json::Value,
    device_profile: serde_json::Value,
    imaging_settings: serde_json::Value,
    interaction_log_ref: Option<String>,
    activity_upto_event_id: Option<i64>,
    activity_event_count: i64,
    created_at: OffsetDateTime,
}

const RESULT_COLUMNS: &str = "id, seq, source, outcome, score, measured_weight_fraction, station_id, station_revision,
    rubric_revision, station_sha256, measurements, detail, code_revision, server_version, asset_hashes, device_profile,
    imaging_settings, interaction_log_ref, activity_upto_event_id, activity_event_count, created_at";

fn result_view(r: ResultRow) -> TechnicalResultView {
    TechnicalResultView {
        id: r.id,
        seq: r.seq,
        source: r.source,
        outcome: r.outcome,
        score: r.score,
        measured_weight_fraction: r.measured_weight_fraction,
        station_id: r.station_id,
        station_revision: r.station_revision,
        rubric_revision: r.rubric_revision,
        station_sha256: r.station_sha256,
        measurements: r.measurements,
        detail: r.detail,
        reproducibility: Reproducibility {
            code_revision: r.code_revision,
            server_version: Some(r.server_version),
            asset_hashes: serde_json::from_value(r.asset_hashes).unwrap_or_default(),
            device_profile: r.device_profile,
            imaging_settings: r.imaging_settings,
            interaction_log_ref: r.interaction_log_ref,
            activity_upto_event_id: r.activity_upto_event_id,
            activity_event_count: Some(r.activity_event_count),
        },
        created_at: r.created_at,
        notice: TECHNICAL_RESULT_NOTICE.into(),
    }
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
    let reviews = super::reviews::reviews_of(&state.pool, attempt_id).await?;
    let audit = super::reviews::audit_of(&state.pool, "attempt", &attempt_id.to_string()).await?;
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

/// An engagement event reported by a client.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewActivity {
    /// What happened (`station_opened` and `submission` are recorded by the server only).
    pub kind: ActivityKind,
    /// When the client saw it happen (kept for analysis; ordering uses the server's clock).
    #[serde(default, with = "time::serde::rfc3339::option")]
    #[schema(value_type = Option<String>, format = DateTime)]
    pub client_time: Option<OffsetDateTime>,
    /// Details (view angles, exposure, volume), a JSON object of at most 4 KiB.
    #[serde(default)]
    #[schema(value_type = Object)]
    pub detail: Option<serde_json::Value>,
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

fn check_reproducibility(r: &Reproducibility) -> Result<(), ApiError> {
    let bad = |m: String| Err(ApiError::BadRequest(format!("reproducibility: {m}")));
    if r.code_revision.trim().is_empty() || r.code_revision.len() > 100 {
        return bad("code_revision needs 1 to 100 characters".into());
    }
    if r.asset_hashes.is_empty() || r.asset_hashes.len() > 200 {
        return bad("asset_hashes needs 1 to 200 entries".into());
    }
    for (name, h) in &r.asset_hashes {
        if name.is_empty()
            || name.len() > 200
            || h.len() != 64
            || !h
                .bytes()
                .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())
        {
            return bad(format!(
                "asset_hashes[{name:?}] must be a lower-case hex SHA-256"
            ));
        }
    }
    for (field, v) in [
        ("device_profile", &r.device_profile),
        ("imaging_settings", &r.imaging_settings),
    ] {
        if !v.is_object() {
            return bad(format!("{field} must be a JSON object"));
        }
        if v.to_string().len() > 16 * 1024 {
            return bad(format!("{field} must be at most 16 KiB of JSON"));
        }
    }
    if r.interaction_log_ref
        .as_ref()
        .is_some_and(|s| s.is_empty() || s.len() > 500)
    {
        return bad("interaction_log_ref needs 1 to 500 characters when given".into());
    }
    if r.server_version.is_some()
        || r.activity_upto_event_id.is_some()
        || r.activity_event_count.is_some()
    {
        return bad(
            "server_version, activity_upto_event_id and activity_event_count are set by the server"
                .into(),
        );
    }
    Ok(())
}

/// Who submits: a client on the learner's behalf, or server-side code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResultSource {
    /// Measurements reported by an authenticated client.
    Client,
    /// Measurements computed by the server's own simulation session.
    Server,
}

/// Scores measurements for an attempt of `learner_id` and stores the technical result; moves the
/// attempt to `submitted`. Used by the HTTP handler and by server-side sessions.
pub async fn submit_result_for(
    state: &RecordsState,
    learner_id: Uuid,
    attempt_id: Uuid,
    req: NewResult,
    source: ResultSource,
) -> Result<TechnicalResultView, ApiError> {
    check_reproducibility(&req.reproducibility)?;
    if req.measurements.len() > 200
        || req
            .measurements
            .keys()
            .any(|k| k.is_empty() || k.len() > 100)
    {
        return Err(ApiError::BadRequest(
            "measurements: at most 200 keys of 1 to 100 characters".into(),
        ));
    }
    let mut tx = state.pool.begin().await?;
    let row: Option<(Uuid, String, String, i32, i32, serde_json::Value, String)> = sqlx::query_as(
        "SELECT a.learner_id, a.state, a.station_id, a.station_revision, a.rubric_revision, s.definition, s.file_sha256
         FROM attempts a JOIN station_revisions s
           ON s.station_id = a.station_id AND s.revision = a.station_revision AND s.rubric_revision = a.rubric_revision
         WHERE a.id = $1 AND a.learner_id = $2 FOR UPDATE OF a",
    )
    .bind(attempt_id)
    .bind(learner_id)
    .fetch_optional(&mut *tx)
    .await?;
    let Some((
        _,
        attempt_state,
        station_id,
        station_revision,
        rubric_revision,
        definition,
        station_sha256,
    )) = row
    else {
        return Err(ApiError::NotFound("attempt".into()));
    };
    if !["in_progress", "returned"].contains(&attempt_state.as_str()) {
        return Err(ApiError::Conflict(format!(
            "the attempt is {attempt_state}; results can be submitted while it is in progress or returned"
        )));
    }
    let station: Station = serde_json::from_value(definition)
        .map_err(|e| ApiError::Internal(format!("stored station {station_id}: {e}")))?;
    let measurements: Measurements = req.measurements.clone();
    let result = station.evaluate(&measurements);
    let (upto, count): (Option<i64>, i64) =
        sqlx::query_as("SELECT max(id), count(*) FROM activity_events WHERE attempt_id = $1")
            .bind(attempt_id)
            .fetch_one(&mut *tx)
            .await?;
    let seq: i32 = sqlx::query_scalar(
        "SELECT COALESCE(max(seq), 0) + 1 FROM technical_results WHERE attempt_id = $1",
    )
    .bind(attempt_id)
    .fetch_one(&mut *tx)
    .await?;
    let id = Uuid::new_v4();
    let r = &req.reproducibility;
    let detail = serde_json::to_value(&result).map_err(|e| ApiError::Internal(e.to_string()))?;
    let row: ResultRow = sqlx::query_as(&format!(
        "INSERT INTO technical_results (id, attempt_id, seq, submitted_by, source, outcome, score, measured_weight_fraction,
            station_id, station_revision, rubric_revision, station_sha256, measurements, detail, code_revision, server_version,
            asset_hashes, device_profile, imaging_settings, interaction_log_ref, activity_upto_event_id, activity_event_count)
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14, $15, $16, $17, $18, $19, $20, $21, $22)
         RETURNING {RESULT_COLUMNS}"
    ))
    .bind(id)
    .bind(attempt_id)
    .bind(seq)
    .bind(learner_id)
    .bind(match source {
        ResultSource::Client => "client",
        ResultSource::Server => "server",
    })
    .bind(result.outcome.as_str())
    .bind(result.score)
    .bind(result.measured_weight_fraction)
    .bind(&station_id)
    .bind(station_revision)
    .bind(rubric_revision)
    .bind(&station_sha256)
    .bind(serde_json::to_value(&req.measurements).map_err(|e| ApiError::Internal(e.to_string()))?)
    .bind(&detail)
    .bind(r.code_revision.trim())
    .bind(env!("CARGO_PKG_VERSION"))
    .bind(serde_json::to_value(&r.asset_hashes).map_err(|e| ApiError::Internal(e.to_string()))?)
    .bind(&r.device_profile)
    .bind(&r.imaging_settings)
    .bind(&r.interaction_log_ref)
    .bind(upto)
    .bind(count)
    .fetch_one(&mut *tx)
    .await?;
    insert_activity(
        &mut *tx,
        attempt_id,
        learner_id,
        ActivityKind::Submission,
        None,
        serde_json::json!({ "result_id": id, "seq": seq }),
    )
    .await?;
    sqlx::query("UPDATE attempts SET state = 'submitted', updated_at = now() WHERE id = $1")
        .bind(attempt_id)
        .execute(&mut *tx)
        .await?;
    audit(
        &mut *tx,
        Some(learner_id),
        "result_submitted",
        "attempt",
        &attempt_id.to_string(),
        serde_json::json!({ "result_id": id, "seq": seq, "outcome": result.outcome.as_str(), "score": result.score }),
    )
    .await?;
    tx.commit().await?;
    Ok(result_view(row))
}

/// Submit measurements for one's own attempt: runs the rubric engine, stores the technical
/// result, and queues the attempt for faculty review.
#[utoipa::path(post, path = "/api/attempts/{attempt_id}/results", tag = "attempts", request_body = NewResult,
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 201, body = TechnicalResultView), (status = 400), (status = 401), (status = 403, description = "Not the attempt's learner"), (status = 404), (status = 409, description = "Attempt submitted or approved")))]
pub async fn submit_result(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(attempt_id): ApiPath<Uuid>,
    ApiJson(req): ApiJson<NewResult>,
) -> Result<(StatusCode, axum::Json<TechnicalResultView>), ApiError> {
    let attempt = visible_attempt(&state, &user, attempt_id).await?;
    if attempt.learner_id != user.id {
        return Err(ApiError::Forbidden(
            "only the attempt's learner submits results for it".into(),
        ));
    }
    let view = submit_result_for(&state, user.id, attempt_id, req, ResultSource::Client).await?;
    Ok((StatusCode::CREATED, axum::Json(view)))
}
