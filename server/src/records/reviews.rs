//! Faculty review: the queue, approve or return with a comment, bulk approval, CSV export, and
//! the audit trail. Approval is a person's decision recorded next to, never instead of, the
//! technical result; nobody approves their own attempt.

use axum::extract::State;
use axum::http::header::{CONTENT_DISPOSITION, CONTENT_TYPE};
use axum::response::IntoResponse;
use serde::{Deserialize, Serialize};
use sqlx::PgPool;
use time::OffsetDateTime;
use utoipa::{IntoParams, ToSchema};
use uuid::Uuid;

use super::auth::{CurrentUser, Role};
use super::authz::attempt_reviewer;
use super::extract::{ApiJson, ApiPath, ApiQuery};
use super::history::audit;
use super::schema::{self, NO_NUL, NOT_BLANK};
use super::state::RecordsState;
use super::summary::{AttemptSummary, SUMMARY_COLUMNS, SUMMARY_FROM, SummaryRow, summary};
use crate::error::ApiError;

/// Longest review comment.
pub const MAX_COMMENT_CHARS: usize = 4000;
/// Most attempts in one bulk approval.
pub const MAX_BULK: usize = 200;

/// A review decision.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    /// Approve the attempt (final).
    Approve,
    /// Return it to the learner with a comment (they may submit again).
    Return,
}

/// A review to record (its schema, written by hand below, says a returned attempt needs a
/// comment).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReviewRequest {
    /// Approve or return.
    pub decision: Decision,
    /// Comment to the learner; required when returning.
    #[serde(default)]
    pub comment: String,
}

/// `approve` with an optional comment, or `return` with a comment that is not blank; comments
/// have at most [`MAX_COMMENT_CHARS`] characters after trimming ([`check_comment`]).
impl utoipa::PartialSchema for ReviewRequest {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{AdditionalProperties, ObjectBuilder, OneOfBuilder};
        // The names of `Decision`'s variants as serde reads them.
        let branch = |decision: &str, comment_pattern: &str, comment_required: bool| {
            let b = ObjectBuilder::new()
                .property("decision", schema::one_of_strings([decision]))
                .property(
                    "comment",
                    schema::text(comment_pattern)
                        .max_length(Some(MAX_COMMENT_CHARS))
                        .description(Some("Comment to the learner; required when returning")),
                )
                .required("decision")
                .additional_properties(Some(AdditionalProperties::FreeForm(false)));
            if comment_required {
                b.required("comment")
            } else {
                b
            }
        };
        let one_of = OneOfBuilder::new()
            .item(branch("approve", NO_NUL, false))
            .item(branch("return", NOT_BLANK, true))
            .description(Some(
                "A review to record: approve, or return with a comment",
            ))
            .build();
        utoipa::openapi::RefOr::T(one_of.into())
    }
}

impl utoipa::ToSchema for ReviewRequest {}

/// A recorded review.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ReviewView {
    /// Id.
    pub id: Uuid,
    /// Attempt.
    pub attempt_id: Uuid,
    /// The technical result the reviewer looked at.
    pub result_id: Uuid,
    /// Reviewer.
    pub reviewer_id: Uuid,
    /// Reviewer name.
    pub reviewer_name: String,
    /// `approved` or `returned`.
    #[schema(schema_with = recorded_decision)]
    pub decision: String,
    /// Comment.
    pub comment: String,
    /// When.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub created_at: OffsetDateTime,
}

type ReviewRow = (
    Uuid,
    Uuid,
    Uuid,
    Uuid,
    String,
    String,
    String,
    OffsetDateTime,
);

pub(crate) async fn reviews_of(
    pool: &PgPool,
    attempt_id: Uuid,
) -> Result<Vec<ReviewView>, sqlx::Error> {
    let rows: Vec<ReviewRow> = sqlx::query_as(
        "SELECT r.id, r.attempt_id, r.result_id, r.reviewer_id, u.display_name, r.decision, r.comment, r.created_at
         FROM reviews r JOIN users u ON u.id = r.reviewer_id WHERE r.attempt_id = $1 ORDER BY r.created_at, r.id",
    )
    .bind(attempt_id)
    .fetch_all(pool)
    .await?;
    Ok(rows
        .into_iter()
        .map(
            |(
                id,
                attempt_id,
                result_id,
                reviewer_id,
                reviewer_name,
                decision,
                comment,
                created_at,
            )| ReviewView {
                id,
                attempt_id,
                result_id,
                reviewer_id,
                reviewer_name,
                decision,
                comment,
                created_at,
            },
        )
        .collect())
}

fn check_reviewer(state: &RecordsState, user: &CurrentUser) -> Result<(), ApiError> {
    user.require(&[Role::Faculty, Role::Admin])?;
    if state.config.require_totp_for_approval && !user.mfa {
        return Err(ApiError::Forbidden(
            "reviewing needs a session opened with a TOTP code: enrol at /api/auth/totp/enroll, then log in again with a code".into(),
        ));
    }
    Ok(())
}

/// Records one decision inside `tx`; the caller has checked role and TOTP.
async fn decide(
    tx: &mut sqlx::Transaction<'static, sqlx::Postgres>,
    user: &CurrentUser,
    attempt_id: Uuid,
    decision: Decision,
    comment: &str,
) -> Result<ReviewView, ApiError> {
    let row: Option<(Uuid, String)> = sqlx::query_as(&format!(
        "SELECT a.learner_id, a.state FROM attempts a WHERE a.id = $3 AND {} FOR UPDATE OF a",
        attempt_reviewer(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .bind(attempt_id)
    .fetch_optional(&mut **tx)
    .await?;
    let (learner_id, attempt_state) =
        row.ok_or_else(|| ApiError::NotFound(format!("attempt {attempt_id}")))?;
    if learner_id == user.id {
        return Err(ApiError::Forbidden(
            "nobody approves or returns their own attempt".into(),
        ));
    }
    if attempt_state != "submitted" {
        return Err(ApiError::Conflict(format!(
            "attempt {attempt_id} is {attempt_state}; only submitted attempts can be reviewed"
        )));
    }
    let result_id: Uuid = sqlx::query_scalar(
        "SELECT id FROM technical_results WHERE attempt_id = $1 ORDER BY seq DESC LIMIT 1",
    )
    .bind(attempt_id)
    .fetch_one(&mut **tx)
    .await?;
    let (decided, new_state, action) = match decision {
        Decision::Approve => ("approved", "approved", "attempt_approved"),
        Decision::Return => ("returned", "returned", "attempt_returned"),
    };
    let id = Uuid::new_v4();
    let created_at: OffsetDateTime = sqlx::query_scalar(
        "INSERT INTO reviews (id, attempt_id, result_id, reviewer_id, decision, comment) VALUES ($1, $2, $3, $4, $5, $6) RETURNING created_at",
    )
    .bind(id)
    .bind(attempt_id)
    .bind(result_id)
    .bind(user.id)
    .bind(decided)
    .bind(comment)
    .fetch_one(&mut **tx)
    .await?;
    // The state guard repeats the checks in the statement that changes the row.
    let changed = sqlx::query(&format!(
        "UPDATE attempts a SET state = $4, updated_at = now()
         WHERE a.id = $3 AND a.state = 'submitted' AND a.learner_id <> $1 AND {}",
        attempt_reviewer(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .bind(attempt_id)
    .bind(new_state)
    .execute(&mut **tx)
    .await?;
    if changed.rows_affected() != 1 {
        return Err(ApiError::Conflict(format!(
            "attempt {attempt_id} changed meanwhile"
        )));
    }
    audit(
        &mut **tx,
        Some(user.id),
        action,
        "attempt",
        &attempt_id.to_string(),
        serde_json::json!({ "review_id": id, "result_id": result_id, "comment": comment }),
    )
    .await?;
    Ok(ReviewView {
        id,
        attempt_id,
        result_id,
        reviewer_id: user.id,
        reviewer_name: user.display_name.clone(),
        decision: decided.into(),
        comment: comment.into(),
        created_at,
    })
}

fn check_comment(decision: Decision, comment: &str) -> Result<String, ApiError> {
    let c = comment.trim();
    if c.chars().count() > MAX_COMMENT_CHARS {
        return Err(ApiError::BadRequest(format!(
            "comment must have at most {MAX_COMMENT_CHARS} characters"
        )));
    }
    if decision == Decision::Return && c.is_empty() {
        return Err(ApiError::BadRequest(
            "returning an attempt needs a comment for the learner".into(),
        ));
    }
    Ok(c.to_owned())
}

/// Approve or return a submitted attempt (faculty of its course, or an admin; never one's own).
#[utoipa::path(post, path = "/api/attempts/{attempt_id}/review", tag = "reviews", request_body = ReviewRequest,
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 200, body = ReviewView), (status = 400), (status = 401), (status = 403, description = "Not a reviewer, own attempt, or no TOTP session"), (status = 404), (status = 409, description = "Not awaiting review")))]
pub async fn review_attempt(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(attempt_id): ApiPath<Uuid>,
    ApiJson(req): ApiJson<ReviewRequest>,
) -> Result<axum::Json<ReviewView>, ApiError> {
    check_reviewer(&state, &user)?;
    let comment = check_comment(req.decision, &req.comment)?;
    let mut tx = state.pool.begin().await?;
    let view = decide(&mut tx, &user, attempt_id, req.decision, &comment).await?;
    tx.commit().await?;
    Ok(axum::Json(view))
}

/// Approving several attempts at once.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct BulkApproveRequest {
    /// Attempts to approve (1 to 200, no repeats).
    #[schema(schema_with = bulk_attempt_ids)]
    pub attempt_ids: Vec<Uuid>,
    /// Comment recorded with each approval (at most 4000 characters after trimming).
    #[serde(default)]
    #[schema(max_length = 4000, pattern = "^[^\\u0000]*$")]
    pub comment: String,
}

/// Result of a bulk approval.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct BulkApproveResponse {
    /// The reviews recorded, in request order.
    pub approved: Vec<ReviewView>,
}

/// Approve several submitted attempts, all or nothing: if any one cannot be approved by the
/// caller, nothing is recorded and the error names it.
#[utoipa::path(post, path = "/api/reviews/bulk-approve", tag = "reviews", request_body = BulkApproveRequest,
    responses((status = 200, body = BulkApproveResponse), (status = 400), (status = 401), (status = 403), (status = 404), (status = 409)))]
pub async fn bulk_approve(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiJson(req): ApiJson<BulkApproveRequest>,
) -> Result<axum::Json<BulkApproveResponse>, ApiError> {
    check_reviewer(&state, &user)?;
    let comment = check_comment(Decision::Approve, &req.comment)?;
    if req.attempt_ids.is_empty() || req.attempt_ids.len() > MAX_BULK {
        return Err(ApiError::BadRequest(format!(
            "attempt_ids needs 1 to {MAX_BULK} ids"
        )));
    }
    let mut seen = std::collections::HashSet::new();
    if let Some(dup) = req.attempt_ids.iter().find(|id| !seen.insert(**id)) {
        return Err(ApiError::BadRequest(format!(
            "attempt {dup} is listed twice"
        )));
    }
    let mut tx = state.pool.begin().await?;
    let mut approved = Vec::with_capacity(req.attempt_ids.len());
    for id in &req.attempt_ids {
        approved.push(decide(&mut tx, &user, *id, Decision::Approve, &comment).await?);
    }
    tx.commit().await?;
    Ok(axum::Json(BulkApproveResponse { approved }))
}

/// `attempt_ids` of a bulk approval: 1 to [`MAX_BULK`] attempt ids, no repeats.
fn bulk_attempt_ids() -> utoipa::openapi::schema::Schema {
    use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, Type};
    use utoipa::openapi::{KnownFormat, SchemaFormat};
    ArrayBuilder::new()
        .items(
            ObjectBuilder::new()
                .schema_type(Type::String)
                .format(Some(SchemaFormat::KnownFormat(KnownFormat::Uuid))),
        )
        .min_items(Some(1))
        .max_items(Some(MAX_BULK))
        .unique_items(true)
        .description(Some("Attempts to approve (no repeats)"))
        .build()
        .into()
}

/// A recorded decision (the `reviews.decision` check).
fn recorded_decision() -> utoipa::openapi::schema::Schema {
    schema::one_of_strings(["approved", "returned"])
        .build()
        .into()
}

/// States the review queue filters by.
pub const QUEUE_STATES: [&str; 5] = ["submitted", "returned", "approved", "in_progress", "any"];

/// The review queue's `state` filter.
fn queue_state() -> utoipa::openapi::schema::Schema {
    schema::one_of_strings(QUEUE_STATES)
        .default(Some("submitted".into()))
        .build()
        .into()
}

/// Filters of the review queue and its CSV export.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct QueueFilter {
    /// Only this station.
    #[param(pattern = "^[^\\u0000]*$")]
    pub station_id: Option<String>,
    /// Only this course.
    pub course_id: Option<Uuid>,
    /// `submitted` (default), `returned`, `approved`, `in_progress` or `any`.
    #[param(schema_with = queue_state)]
    pub state: Option<String>,
}

async fn queue_rows(
    state: &RecordsState,
    user: &CurrentUser,
    f: &QueueFilter,
) -> Result<Vec<AttemptSummary>, ApiError> {
    user.require(&[Role::Faculty, Role::Admin])?;
    let wanted = f.state.as_deref().unwrap_or("submitted");
    if !QUEUE_STATES.contains(&wanted) {
        return Err(ApiError::BadRequest(format!(
            "state {wanted:?} is not one of submitted, returned, approved, in_progress, any"
        )));
    }
    let rows: Vec<SummaryRow> = sqlx::query_as(&format!(
        "SELECT {SUMMARY_COLUMNS} FROM {SUMMARY_FROM}
         WHERE {} AND ($3::text IS NULL OR a.station_id = $3) AND ($4::uuid IS NULL OR a.course_id = $4)
           AND ($5 = 'any' OR a.state = $5)
         ORDER BY a.updated_at, a.id LIMIT 5000",
        attempt_reviewer(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .bind(&f.station_id)
    .bind(f.course_id)
    .bind(wanted)
    .fetch_all(&state.pool)
    .await?;
    Ok(rows.into_iter().map(summary).collect())
}

/// The review queue: attempts of the courses the caller teaches (all for admins), oldest first.
#[utoipa::path(get, path = "/api/reviews", tag = "reviews", params(QueueFilter),
    responses((status = 200, body = Vec<AttemptSummary>), (status = 400), (status = 401), (status = 403)))]
pub async fn review_queue(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiQuery(f): ApiQuery<QueueFilter>,
) -> Result<axum::Json<Vec<AttemptSummary>>, ApiError> {
    Ok(axum::Json(queue_rows(&state, &user, &f).await?))
}

/// One CSV field, quoted per RFC 4180, with a leading `'` on text a spreadsheet would run as a
/// formula (OWASP "CSV injection").
pub fn csv_field(s: &str) -> String {
    let s = if s.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        format!("'{s}")
    } else {
        s.to_owned()
    };
    format!("\"{}\"", s.replace('"', "\"\""))
}

/// The review queue as CSV (same filters), with the latest decision of each attempt.
#[utoipa::path(get, path = "/api/reviews/export.csv", tag = "reviews", params(QueueFilter),
    responses((status = 200, description = "CSV, one row per attempt", content_type = "text/csv"), (status = 400), (status = 401), (status = 403)))]
pub async fn export_csv(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiQuery(f): ApiQuery<QueueFilter>,
) -> Result<axum::response::Response, ApiError> {
    let rows = queue_rows(&state, &user, &f).await?;
    let mut out = String::from(
        "attempt_id,learner_email,learner_name,course_code,station_id,station_revision,rubric_revision,state,\
         technical_outcome,technical_score,result_source,replay_check,updated_at,last_decision,last_reviewer,\
         last_review_at,last_comment\r\n",
    );
    // The latest review of every listed attempt, in one query.
    let ids: Vec<Uuid> = rows.iter().map(|a| a.id).collect();
    let latest: std::collections::HashMap<Uuid, (String, String, OffsetDateTime, String)> =
        sqlx::query_as::<_, (Uuid, String, String, OffsetDateTime, String)>(
            "SELECT DISTINCT ON (r.attempt_id) r.attempt_id, r.decision, u.email, r.created_at, r.comment
             FROM reviews r JOIN users u ON u.id = r.reviewer_id
             WHERE r.attempt_id = ANY($1) ORDER BY r.attempt_id, r.created_at DESC, r.id DESC",
        )
        .bind(&ids)
        .fetch_all(&state.pool)
        .await?
        .into_iter()
        .map(|(id, d, r, t, c)| (id, (d, r, t, c)))
        .collect();
    let rfc = |t: OffsetDateTime| {
        t.format(&time::format_description::well_known::Rfc3339)
            .unwrap_or_default()
    };
    for a in rows {
        let last = latest.get(&a.id).cloned();
        let (decision, reviewer, at, comment) = last
            .map(|(d, r, t, c)| (d, r, rfc(t), c))
            .unwrap_or_default();
        let fields = [
            a.id.to_string(),
            a.learner_email,
            a.learner_name,
            a.course_code,
            a.station_id,
            a.station_revision.to_string(),
            a.rubric_revision.to_string(),
            a.state,
            a.latest_outcome.unwrap_or_default(),
            a.latest_score
                .map(|s| format!("{s:.4}"))
                .unwrap_or_default(),
            a.latest_source.unwrap_or_default(),
            a.latest_replay_check.unwrap_or_default(),
            rfc(a.updated_at),
            decision,
            reviewer,
            at,
            comment,
        ];
        out.push_str(
            &fields
                .iter()
                .map(|s| csv_field(s))
                .collect::<Vec<_>>()
                .join(","),
        );
        out.push_str("\r\n");
    }
    Ok((
        [
            (CONTENT_TYPE, "text/csv; charset=utf-8"),
            (
                CONTENT_DISPOSITION,
                "attachment; filename=\"review-queue.csv\"",
            ),
        ],
        out,
    )
        .into_response())
}

#[cfg(test)]
mod tests {
    use super::csv_field;

    #[test]
    fn csv_fields_are_quoted_and_formula_safe() {
        assert_eq!(csv_field("plain"), "\"plain\"");
        assert_eq!(csv_field("a \"b\", c"), "\"a \"\"b\"\", c\"");
        assert_eq!(csv_field("=HYPERLINK(1)"), "\"'=HYPERLINK(1)\"");
        assert_eq!(csv_field("-1+1"), "\"'-1+1\"");
        assert_eq!(csv_field("line\r\nbreak"), "\"line\r\nbreak\"");
    }
}
