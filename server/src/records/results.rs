//! Technical results: submitting measurements runs the rubric engine (`sim_core::rubric`)
//! against the station revision the attempt was opened with, stores the technical result with
//! its reproducibility record, records `submission`, and puts the attempt in the review queue.
//! None of this is approval: that is a faculty decision ([`super::reviews`]).

use std::collections::BTreeMap;

use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use sim_core::rubric::{Measurements, RubricResult, Station, TECHNICAL_RESULT_NOTICE};
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::activity::{ActivityKind, insert_activity};
use super::auth::CurrentUser;
use super::extract::{ApiJson, ApiPath};
use super::history::audit;
use super::state::RecordsState;
use super::summary::visible_attempt;
use crate::error::ApiError;

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
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewResult {
    /// Measurement key (e.g. `tip_to_target_mm`) to value. Yes/no observations are 1 or 0.
    pub measurements: BTreeMap<String, f64>,
    /// Reproducibility record.
    pub reproducibility: Reproducibility,
}

/// A `technical_results` row, as [`RESULT_COLUMNS`] selects it.
#[derive(sqlx::FromRow)]
pub(super) struct ResultRow {
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

/// The columns of [`ResultRow`].
pub(super) const RESULT_COLUMNS: &str = "id, seq, source, outcome, score, measured_weight_fraction, station_id, station_revision,
    rubric_revision, station_sha256, measurements, detail, code_revision, server_version, asset_hashes, device_profile,
    imaging_settings, interaction_log_ref, activity_upto_event_id, activity_event_count, created_at";

/// The API view of a stored result.
pub(super) fn result_view(r: ResultRow) -> TechnicalResultView {
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

/// Who submits: a client on the learner's behalf, or the simulation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ResultSource<'a> {
    /// Measurements reported by an authenticated client (checked with the rules for client
    /// input).
    Client,
    /// Measurements computed by a simulation session from its log. The server's evaluation of
    /// the stored station's rubric is the authority; the worker's own evaluation
    /// (`worker_rubric`) must equal it, else nothing is stored.
    Session {
        /// The rubric result the worker computed at submit.
        worker_rubric: &'a RubricResult,
    },
}

/// Scores measurements for an attempt of `learner_id` and stores the technical result; moves the
/// attempt to `submitted`. Used by the HTTP handler and by server-side sessions.
pub async fn submit_result_for(
    state: &RecordsState,
    learner_id: Uuid,
    attempt_id: Uuid,
    req: NewResult,
    source: ResultSource<'_>,
) -> Result<TechnicalResultView, ApiError> {
    if source == ResultSource::Client {
        check_reproducibility(&req.reproducibility)?;
    }
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
    let mut measurements: Measurements = req.measurements.clone();
    if let ResultSource::Session { .. } = source {
        // A session reports every measurement it can make; those no criterion reads are kept
        // with the result but are not typos to flag, so the rubric sees what it reads (as the
        // worker's evaluation did).
        measurements.retain(|k, _| station.rubric.criteria.iter().any(|c| &c.measurement == k));
    }
    let result = station.evaluate(&measurements);
    if let ResultSource::Session { worker_rubric } = source {
        if *worker_rubric != result {
            tracing::error!(attempt = %attempt_id, worker = ?worker_rubric, server = ?result, "the worker's rubric result differs from the server's");
            return Err(ApiError::Internal(
                "the worker's rubric result differs from the server's evaluation of the same measurements".into(),
            ));
        }
    }
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
        ResultSource::Session { .. } => "server",
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
