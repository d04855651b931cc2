//! The attempt as listed: the summary every attempt and review handler returns, the one query
//! shape that produces it, and the visibility-checked fetch of one attempt.

use serde::{Deserialize, Serialize};
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::CurrentUser;
use super::authz::attempt_visible;
use super::schema::one_of_strings;
use super::state::RecordsState;
use crate::error::ApiError;

/// States of an attempt (the `attempts.state` check of the schema migration).
pub const ATTEMPT_STATES: [&str; 4] = ["in_progress", "submitted", "returned", "approved"];

/// Modes an attempt runs in (the `attempts.mode` check of `1001_station_modes.sql`).
pub const ATTEMPT_MODES: [&str; 2] = ["practice", "assessment"];

/// Technical outcomes of a result (the `technical_results.outcome` check).
pub const OUTCOMES: [&str; 3] = ["met", "not_met", "incomplete"];

fn attempt_state() -> utoipa::openapi::schema::Schema {
    one_of_strings(ATTEMPT_STATES).build().into()
}

fn attempt_mode() -> utoipa::openapi::schema::Schema {
    one_of_strings(ATTEMPT_MODES).build().into()
}

fn latest_outcome() -> utoipa::openapi::schema::Schema {
    one_of_strings(OUTCOMES)
        .schema_type(utoipa::openapi::schema::SchemaType::from_iter([
            utoipa::openapi::schema::Type::String,
            utoipa::openapi::schema::Type::Null,
        ]))
        .build()
        .into()
}

/// A technical outcome (`met`, `not_met` or `incomplete`).
pub fn outcome() -> utoipa::openapi::schema::Schema {
    one_of_strings(OUTCOMES).build().into()
}

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
    /// How the station ran (`practice` or `assessment`), fixed when the attempt was opened.
    #[schema(schema_with = attempt_mode)]
    pub mode: String,
    /// `in_progress`, `submitted` (awaiting review), `returned` (to the learner) or `approved`.
    #[schema(schema_with = attempt_state)]
    pub state: String,
    /// Technical outcome of the latest result (`met`, `not_met`, `incomplete`), if any.
    #[schema(schema_with = latest_outcome)]
    pub latest_outcome: Option<String>,
    /// Score of the latest result, if any.
    pub latest_score: Option<f64>,
    /// Where the latest result came from (`server`: a simulation session; `client`: reported by
    /// a client before results came only from the simulation), if any.
    pub latest_source: Option<String>,
    /// The latest result's replay check (`pending`, `identical`, `differs`, `unavailable`), if
    /// there is a result.
    pub latest_replay_check: Option<String>,
    /// Opened.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub created_at: OffsetDateTime,
    /// Last change of state.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub updated_at: OffsetDateTime,
}

/// SELECT list producing an [`AttemptSummary`] from `attempts a` (columns named as the fields of
/// [`SummaryRow`]).
pub(crate) const SUMMARY_COLUMNS: &str = "a.id, a.learner_id, u.email, u.display_name, a.course_id, c.code, a.station_id,
    a.station_revision, a.rubric_revision, a.mode, a.state,
    (SELECT r.outcome FROM technical_results r WHERE r.attempt_id = a.id ORDER BY r.seq DESC LIMIT 1) AS latest_outcome,
    (SELECT r.score FROM technical_results r WHERE r.attempt_id = a.id ORDER BY r.seq DESC LIMIT 1) AS latest_score,
    (SELECT r.source FROM technical_results r WHERE r.attempt_id = a.id ORDER BY r.seq DESC LIMIT 1) AS latest_source,
    (SELECT COALESCE((SELECT c.verdict FROM result_replay_checks c WHERE c.result_id = r.id ORDER BY c.id DESC LIMIT 1), 'pending')
       FROM technical_results r WHERE r.attempt_id = a.id ORDER BY r.seq DESC LIMIT 1) AS latest_replay_check,
    a.created_at, a.updated_at";
/// FROM clause matching [`SUMMARY_COLUMNS`].
pub(crate) const SUMMARY_FROM: &str =
    "attempts a JOIN users u ON u.id = a.learner_id JOIN courses c ON c.id = a.course_id";

/// One row of [`SUMMARY_COLUMNS`].
#[derive(sqlx::FromRow)]
pub(crate) struct SummaryRow {
    id: Uuid,
    learner_id: Uuid,
    email: String,
    display_name: String,
    course_id: Uuid,
    code: String,
    station_id: String,
    station_revision: i32,
    rubric_revision: i32,
    mode: String,
    state: String,
    latest_outcome: Option<String>,
    latest_score: Option<f64>,
    latest_source: Option<String>,
    latest_replay_check: Option<String>,
    created_at: OffsetDateTime,
    updated_at: OffsetDateTime,
}

pub(crate) fn summary(r: SummaryRow) -> AttemptSummary {
    AttemptSummary {
        id: r.id,
        learner_id: r.learner_id,
        learner_email: r.email,
        learner_name: r.display_name,
        course_id: r.course_id,
        course_code: r.code,
        station_id: r.station_id,
        station_revision: r.station_revision,
        rubric_revision: r.rubric_revision,
        mode: r.mode,
        state: r.state,
        latest_outcome: r.latest_outcome,
        latest_score: r.latest_score,
        latest_source: r.latest_source,
        latest_replay_check: r.latest_replay_check,
        created_at: r.created_at,
        updated_at: r.updated_at,
    }
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
