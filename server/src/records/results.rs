//! Technical results: measurements a simulation session computed from its log are scored by the
//! rubric engine (`sim_core::rubric`) against the station revision the attempt was opened with,
//! stored with their reproducibility record, recorded as `submission`, and the attempt joins the
//! review queue. None of this is approval: that is a faculty decision ([`super::reviews`]).
//!
//! Architecture invariant: technical results come only from the simulation. No route accepts
//! measurements from a client; [`store_session_result`] is called by the session relay with the
//! worker's own rubric evaluation, and every stored result is later re-checked by replaying its
//! logged session ([`record_replay_check`]; the verdict travels with the result everywhere it is
//! shown: detail, review queue, CSV export).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use sim_core::rubric::{Measurements, RubricResult, Station, TECHNICAL_RESULT_NOTICE};
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::activity::{ActivityKind, insert_activity};
use super::history::audit;
use super::state::RecordsState;
use crate::error::ApiError;

/// Where a result came from (the `technical_results.source` check).
fn result_source() -> utoipa::openapi::schema::Schema {
    super::schema::one_of_strings(["server", "client"])
        .build()
        .into()
}

/// A stored technical result.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct TechnicalResultView {
    /// Id.
    pub id: Uuid,
    /// 1 for the first submission of the attempt, 2 for the next, ...
    pub seq: i32,
    /// `server` (computed by a simulation session from its log, the only source now) or `client`
    /// (reported by a client before results came only from the simulation; never replayable).
    #[schema(schema_with = result_source)]
    pub source: String,
    /// The newest replay check of this result.
    pub replay_check: ReplayCheck,
    /// `met`, `not_met` or `incomplete`: a technical outcome, not a competency judgement.
    #[schema(schema_with = super::summary::outcome)]
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

/// The outcome of replaying a result's logged session.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ReplayCheck {
    /// `pending` (not checked yet), `identical` (the replay reproduced the stored measurements,
    /// score, outcome, final state and final image exactly), `differs`, or `unavailable` (no log
    /// to replay).
    #[schema(example = "identical")]
    pub verdict: String,
    /// When it was checked (absent while pending).
    #[serde(default, with = "time::serde::rfc3339::option")]
    #[schema(value_type = Option<String>, format = DateTime)]
    pub checked_at: Option<OffsetDateTime>,
    /// What was compared, and what differed.
    #[schema(value_type = Object)]
    pub detail: serde_json::Value,
}

/// The verdicts a replay check can store ([`ReplayCheck::verdict`] is also `pending`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplayVerdict {
    /// Reproduced exactly.
    Identical,
    /// Not reproduced.
    Differs,
    /// Nothing to replay.
    Unavailable,
}

impl ReplayVerdict {
    /// The stored word.
    pub fn as_str(self) -> &'static str {
        match self {
            ReplayVerdict::Identical => "identical",
            ReplayVerdict::Differs => "differs",
            ReplayVerdict::Unavailable => "unavailable",
        }
    }
}

/// Appends a replay check of `result_id` (the newest check is the result's verdict).
pub async fn record_replay_check(
    pool: &sqlx::PgPool,
    result_id: Uuid,
    verdict: ReplayVerdict,
    detail: &serde_json::Value,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO result_replay_checks (result_id, verdict, detail) VALUES ($1, $2, $3)",
    )
    .bind(result_id)
    .bind(verdict.as_str())
    .bind(detail)
    .execute(pool)
    .await?;
    Ok(())
}

/// Measurements a simulation session computed, to score.
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
    replay_verdict: Option<String>,
    replay_checked_at: Option<OffsetDateTime>,
    replay_detail: Option<serde_json::Value>,
}

/// The columns of [`ResultRow`].
pub(super) const RESULT_COLUMNS: &str = "id, seq, source, outcome, score, measured_weight_fraction, station_id, station_revision,
    rubric_revision, station_sha256, measurements, detail, code_revision, server_version, asset_hashes, device_profile,
    imaging_settings, interaction_log_ref, activity_upto_event_id, activity_event_count, created_at,
    (SELECT c.verdict FROM result_replay_checks c WHERE c.result_id = technical_results.id ORDER BY c.id DESC LIMIT 1) AS replay_verdict,
    (SELECT c.checked_at FROM result_replay_checks c WHERE c.result_id = technical_results.id ORDER BY c.id DESC LIMIT 1) AS replay_checked_at,
    (SELECT c.detail FROM result_replay_checks c WHERE c.result_id = technical_results.id ORDER BY c.id DESC LIMIT 1) AS replay_detail";

/// The API view of a stored result.
pub(super) fn result_view(r: ResultRow) -> TechnicalResultView {
    TechnicalResultView {
        id: r.id,
        seq: r.seq,
        source: r.source,
        replay_check: ReplayCheck {
            verdict: r.replay_verdict.unwrap_or_else(|| "pending".into()),
            checked_at: r.replay_checked_at,
            detail: r.replay_detail.unwrap_or_else(|| serde_json::json!({})),
        },
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

/// Scores measurements that a simulation session computed from its log for an attempt of
/// `learner_id`, stores the technical result and moves the attempt to `submitted`. The server's
/// evaluation of the stored station's rubric is the authority; the worker's own evaluation
/// (`worker_rubric`) must equal it, else nothing is stored. Measurements outside their physical
/// range are refused (`sim_core::rubric::check_measurements`).
pub async fn store_session_result(
    state: &RecordsState,
    learner_id: Uuid,
    attempt_id: Uuid,
    req: NewResult,
    worker_rubric: &RubricResult,
) -> Result<TechnicalResultView, ApiError> {
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
    sim_core::rubric::check_measurements(&req.measurements)
        .map_err(|e| ApiError::BadRequest(format!("measurements: {e}")))?;
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
    // A session reports every measurement it can make; those no criterion reads are kept with
    // the result but are not typos to flag, so the rubric sees what it reads (as the worker's
    // evaluation did).
    measurements.retain(|k, _| station.rubric.criteria.iter().any(|c| &c.measurement == k));
    let result = station.evaluate(&measurements);
    if *worker_rubric != result {
        tracing::error!(attempt = %attempt_id, worker = ?worker_rubric, server = ?result, "the worker's rubric result differs from the server's");
        return Err(ApiError::Internal(
            "the worker's rubric result differs from the server's evaluation of the same measurements".into(),
        ));
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
    .bind("server")
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
