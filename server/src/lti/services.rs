//! LTI Advantage services from the tool side: OAuth 2 access tokens with a signed client
//! assertion (IMS Security Framework §4.1), Assignment and Grade Services score publication
//! through the durable outbox, and Names and Role Provisioning to fill a course.
//!
//! Scores: triggers on `technical_results` and `reviews` (migration 0805) queue the results of
//! learners who came through an LTI launch with a line item; [`spawn_score_pump`] moves the queue
//! into the outbox (kind [`SCORE_KIND`], key `<result id>:<stage>`: idempotent), and
//! [`ScoreDelivery`] posts each score: `Completed` + `PendingManual` when scored, `FullyGraded`
//! after faculty approval.

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::Json;
use axum::extract::State;
use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use time::OffsetDateTime;
use time::format_description::well_known::Rfc3339;
use utoipa::ToSchema;
use uuid::Uuid;

use super::error::LtiError;
use super::jws::random_hex;
use super::keys;
use super::launch::{TOOL_JWT_TTL_S, account, member};
use super::platforms::{self, Platform};
use super::state::LtiState;
use crate::error::ApiError;
use crate::outbox::{self, Deliver, DeliveryError, Outbox};
use crate::records::auth::{CurrentUser, Role};
use crate::records::extract::ApiPath;
use crate::records::history::audit;

/// Outbox kind of AGS score publications.
pub const SCORE_KIND: &str = "lti-ags-score";
/// AGS scope to post scores.
pub const SCOPE_SCORE: &str = "https://purl.imsglobal.org/spec/lti-ags/scope/score";
/// NRPS scope to read memberships.
pub const SCOPE_NRPS: &str =
    "https://purl.imsglobal.org/spec/lti-nrps/scope/contextmembership.readonly";
/// The scopes the tool asks for with scores (AGS: line items, scores, reading results back).
pub const SCOPES_AGS: &str = "https://purl.imsglobal.org/spec/lti-ags/scope/lineitem \
    https://purl.imsglobal.org/spec/lti-ags/scope/score \
    https://purl.imsglobal.org/spec/lti-ags/scope/result.readonly";
/// How often the score queue is looked at (our choice: a score reaches the outbox within half a
/// second of its result or approval, at one cheap query per tick).
pub const SCORE_PUMP_INTERVAL: Duration = Duration::from_millis(500);
/// Largest technical score sent (the line item's scoreMaximum: the rubric's 0..=1 in percent).
pub const SCORE_MAXIMUM: f64 = 100.0;
/// Most NRPS pages read in one fill (our choice: bounds a misbehaving platform's `next` links).
pub const NRPS_MAX_PAGES: usize = 200;
/// A token is renewed this long before the platform says it expires (our choice).
const TOKEN_MARGIN: Duration = Duration::from_secs(30);

/// Why no access token could be had from a platform's token endpoint.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    /// The tool's client assertion could not be signed (its key store failed).
    #[error("{0}")]
    Assertion(ApiError),
    /// The token request did not complete.
    #[error("token request: {0}")]
    Request(reqwest::Error),
    /// The answer is not JSON.
    #[error("token response ({status}): {source}")]
    Response {
        /// The answer's status.
        status: reqwest::StatusCode,
        /// Why its body does not parse.
        source: reqwest::Error,
    },
    /// The platform answered without a token (an error status, or no `access_token`).
    #[error("token endpoint answered {status}: {body}")]
    Refused {
        /// The answer's status.
        status: reqwest::StatusCode,
        /// Its body.
        body: Value,
    },
}

/// An access token for `scopes` at `platform` (cached until shortly before it expires).
pub async fn access_token(
    state: &LtiState,
    platform: &Platform,
    scopes: &str,
) -> Result<String, TokenError> {
    let key = (platform.id, scopes.to_owned());
    if let Some((t, until)) = state.tokens.lock().expect("token cache").get(&key)
        && *until > Instant::now()
    {
        return Ok(t.clone());
    }
    let now = OffsetDateTime::now_utc().unix_timestamp();
    let assertion = keys::sign(
        &state.pool,
        &json!({
            "iss": platform.client_id, "sub": platform.client_id, "aud": platform.token_url,
            "iat": now, "exp": now + TOOL_JWT_TTL_S, "jti": random_hex(16),
        }),
    )
    .await
    .map_err(TokenError::Assertion)?;
    let form = [
        ("grant_type", "client_credentials"),
        (
            "client_assertion_type",
            "urn:ietf:params:oauth:client-assertion-type:jwt-bearer",
        ),
        ("client_assertion", assertion.as_str()),
        ("scope", scopes),
    ];
    let resp = state
        .http
        .post(&platform.token_url)
        .form(&form)
        .send()
        .await
        .map_err(TokenError::Request)?;
    let status = resp.status();
    let body: Value = resp
        .json()
        .await
        .map_err(|source| TokenError::Response { status, source })?;
    let Some(token) = body["access_token"]
        .as_str()
        .filter(|_| status.is_success())
        .map(str::to_owned)
    else {
        return Err(TokenError::Refused { status, body });
    };
    let life = Duration::from_secs(body["expires_in"].as_u64().unwrap_or(3600));
    state.tokens.lock().expect("token cache").insert(
        key,
        (
            token.clone(),
            Instant::now() + life.saturating_sub(TOKEN_MARGIN),
        ),
    );
    Ok(token)
}

fn forget_token(state: &LtiState, platform: Uuid, scopes: &str) {
    state
        .tokens
        .lock()
        .expect("token cache")
        .remove(&(platform, scopes.to_owned()));
}

/// The `scores` URL of a line item (AGS §3.4: the line item URL with `/scores` appended to its
/// path, its query kept).
pub fn scores_url(lineitem: &str) -> Option<String> {
    let mut u = reqwest::Url::parse(lineitem).ok()?;
    let path = format!("{}/scores", u.path().trim_end_matches('/'));
    u.set_path(&path);
    Some(u.to_string())
}

/// Posts AGS scores from the outbox.
pub struct ScoreDelivery {
    state: LtiState,
}

impl ScoreDelivery {
    /// A deliverer over `state`.
    pub fn new(state: LtiState) -> Arc<ScoreDelivery> {
        Arc::new(ScoreDelivery { state })
    }

    async fn publish(&self, item: &Value) -> Result<(), DeliveryError> {
        let platform_id: Uuid = item["platform_id"]
            .as_str()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| DeliveryError::Permanent("no platform id".into()))?;
        let platform = platforms::get(&self.state.pool, platform_id)
            .await
            .map_err(|e| DeliveryError::Retry(e.to_string()))?
            .ok_or_else(|| DeliveryError::Permanent("the platform was removed".into()))?;
        let url = item["lineitem_url"]
            .as_str()
            .and_then(scores_url)
            .ok_or_else(|| DeliveryError::Permanent("bad line item URL".into()))?;
        let token = access_token(&self.state, &platform, SCOPES_AGS)
            .await
            .map_err(|e| DeliveryError::Retry(e.to_string()))?;
        let resp = self
            .state
            .http
            .post(&url)
            .bearer_auth(token)
            .header("content-type", "application/vnd.ims.lis.v1.score+json")
            .body(item["score"].to_string())
            .send()
            .await
            .map_err(|e| DeliveryError::Retry(format!("posting the score: {e}")))?;
        let status = resp.status();
        if status.is_success() {
            return Ok(());
        }
        let text = resp.text().await.unwrap_or_default();
        let msg = format!(
            "{url} answered {status}: {}",
            text.chars().take(500).collect::<String>()
        );
        match status.as_u16() {
            401 | 403 => {
                forget_token(&self.state, platform.id, SCOPES_AGS);
                Err(DeliveryError::Retry(msg))
            }
            400 | 404 | 405 | 410 | 422 => Err(DeliveryError::Permanent(msg)),
            _ => Err(DeliveryError::Retry(msg)),
        }
    }
}

impl Deliver for ScoreDelivery {
    fn kind(&self) -> &'static str {
        SCORE_KIND
    }

    fn deliver<'a>(&'a self, items: &'a [Value]) -> BoxFuture<'a, Result<(), DeliveryError>> {
        Box::pin(async move {
            for item in items {
                self.publish(item).await?;
            }
            Ok(())
        })
    }
}

type QueueRow = (
    i64,
    Uuid,
    String,
    OffsetDateTime,
    Option<f64>,
    String,
    Uuid,
    String,
    String,
);

/// Moves queued scores into the outbox; returns how many.
pub async fn pump_once(pool: &sqlx::PgPool) -> Result<usize, sqlx::Error> {
    let mut tx = pool.begin().await?;
    let rows: Vec<QueueRow> = sqlx::query_as(
        "SELECT q.id, q.result_id, q.stage, q.at, r.score, r.outcome, g.platform_id, g.lineitem_url, g.sub
         FROM lti_score_queue q
         JOIN technical_results r ON r.id = q.result_id
         JOIN attempts a ON a.id = r.attempt_id
         JOIN lti_grade_targets g
           ON g.user_id = a.learner_id AND g.course_id = a.course_id AND g.station_id = a.station_id
         ORDER BY q.id LIMIT 100 FOR UPDATE OF q SKIP LOCKED",
    )
    .fetch_all(&mut *tx)
    .await?;
    let mut ids = Vec::with_capacity(rows.len());
    for (id, result, stage, at, score, outcome, platform, lineitem, sub) in &rows {
        ids.push(*id);
        let mut s = json!({
            "userId": sub,
            "scoreMaximum": SCORE_MAXIMUM,
            "activityProgress": "Completed",
            "gradingProgress": if stage == "approved" { "FullyGraded" } else { "PendingManual" },
            "timestamp": at.format(&Rfc3339).unwrap_or_default(),
            "comment": match outcome.as_str() {
                "met" => "technical criteria met",
                "not_met" => "technical criteria not met",
                _ => "incomplete: some measurements missing",
            },
        });
        if let Some(v) = score {
            s["scoreGiven"] = json!((v * SCORE_MAXIMUM * 100.0).round() / 100.0);
        }
        let payload = json!({ "platform_id": platform, "lineitem_url": lineitem, "result_id": result, "score": s });
        outbox::enqueue(&mut tx, SCORE_KIND, &format!("{result}:{stage}"), payload).await?;
    }
    sqlx::query("DELETE FROM lti_score_queue WHERE id = ANY($1)")
        .bind(&ids)
        .execute(&mut *tx)
        .await?;
    tx.commit().await?;
    Ok(ids.len())
}

/// Registers the score deliverer with `outbox` and runs the score pump until `shutdown`.
pub fn spawn_score_pump(
    state: LtiState,
    outbox: Outbox,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> tokio::task::JoinHandle<()> {
    outbox.register(ScoreDelivery::new(state.clone()));
    tokio::spawn(async move {
        tokio::pin!(shutdown);
        loop {
            match pump_once(&state.pool).await {
                Ok(0) => {}
                Ok(_) => outbox.wake(),
                Err(e) => tracing::warn!(error = %e, "LTI score pump"),
            }
            tokio::select! {
                () = &mut shutdown => return,
                () = tokio::time::sleep(SCORE_PUMP_INTERVAL) => {}
            }
        }
    })
}

/// What a membership fill did.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct MembershipSync {
    /// Active members read from the platform.
    pub members: usize,
    /// Of these, accounts created now.
    pub accounts_created: usize,
    /// Members skipped (inactive, deleted, or without a user id).
    pub skipped: usize,
    /// Pages read.
    pub pages: usize,
}

fn next_link(headers: &reqwest::header::HeaderMap) -> Option<String> {
    headers
        .get_all(reqwest::header::LINK)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .find_map(|l| {
            let (url, params) = l.trim().split_once(';')?;
            params
                .split(';')
                .any(|p| {
                    matches!(
                        p.trim().replace(' ', "").as_str(),
                        "rel=\"next\"" | "rel=next"
                    )
                })
                .then(|| {
                    url.trim()
                        .trim_start_matches('<')
                        .trim_end_matches('>')
                        .to_owned()
                })
        })
}

/// Fill a course from its LMS context (Names and Role Provisioning Services): every active
/// member gets an account (created at first sight) and a membership with their role. Faculty
/// of the course or an admin.
#[utoipa::path(post, path = "/api/lti/courses/{id}/memberships/sync", tag = "lms",
    params(("id" = Uuid, Path, description = "Course id")),
    responses((status = 200, body = MembershipSync, description = "Filled"), (status = 401),
        (status = 403), (status = 404, description = "No such course, or it came from no LTI context"),
        (status = 502, description = "The platform failed")))]
pub async fn sync_memberships(
    State(state): State<LtiState>,
    user: CurrentUser,
    ApiPath(course): ApiPath<Uuid>,
) -> Result<Json<MembershipSync>, LtiError> {
    user.require(&[Role::Faculty, Role::Admin])?;
    if !user.is_admin() {
        let teaches: bool = sqlx::query_scalar(
            "SELECT EXISTS (SELECT 1 FROM course_members WHERE course_id = $1 AND user_id = $2 AND role = 'faculty')",
        )
        .bind(course)
        .bind(user.id)
        .fetch_one(&state.pool)
        .await?;
        if !teaches {
            return Err(ApiError::Forbidden(
                "only the course's faculty or an admin may fill it".into(),
            )
            .into());
        }
    }
    let link: Option<(Uuid, Option<String>)> = sqlx::query_as(
        "SELECT platform_id, memberships_url FROM lti_contexts WHERE course_id = $1 LIMIT 1",
    )
    .bind(course)
    .fetch_optional(&state.pool)
    .await?;
    let (platform_id, url) =
        link.ok_or_else(|| LtiError::Api(ApiError::NotFound("LTI course".into())))?;
    let platform = platforms::get(&state.pool, platform_id)
        .await?
        .ok_or_else(|| LtiError::Api(ApiError::NotFound("LTI platform".into())))?;
    let mut url = url.or(platform.memberships_url.clone()).ok_or_else(|| {
        LtiError::Api(ApiError::NotFound(
            "the course's NRPS memberships URL".into(),
        ))
    })?;
    let bad = LtiError::Platform;
    let token = access_token(&state, &platform, SCOPE_NRPS)
        .await
        .map_err(|e| bad(e.to_string()))?;
    let mut members = Vec::new();
    let mut pages = 0;
    loop {
        pages += 1;
        let resp = state
            .http
            .get(&url)
            .bearer_auth(&token)
            .header(
                "accept",
                "application/vnd.ims.lti-nrps.v2.membershipcontainer+json",
            )
            .send()
            .await
            .and_then(|r| r.error_for_status())
            .map_err(|e| bad(e.to_string()))?;
        let next = next_link(resp.headers());
        let body: Value = resp.json().await.map_err(|e| bad(e.to_string()))?;
        members.extend(body["members"].as_array().cloned().unwrap_or_default());
        match next {
            Some(n) if pages < NRPS_MAX_PAGES => url = n,
            _ => break,
        }
    }
    let mut tx = state.pool.begin().await?;
    let mut out = MembershipSync {
        members: 0,
        accounts_created: 0,
        skipped: 0,
        pages,
    };
    for m in &members {
        let active = m["status"].as_str().is_none_or(|s| s == "Active");
        let Some(sub) = m["user_id"].as_str().filter(|s| !s.is_empty() && active) else {
            out.skipped += 1;
            continue;
        };
        let roles: Vec<&str> = m["roles"]
            .as_array()
            .into_iter()
            .flatten()
            .filter_map(Value::as_str)
            .collect();
        let faculty = super::launch::is_faculty(&roles);
        let known: bool = sqlx::query_scalar(
            "SELECT EXISTS (SELECT 1 FROM lti_users WHERE issuer = $1 AND sub = $2)",
        )
        .bind(&platform.issuer)
        .bind(sub)
        .fetch_one(&mut *tx)
        .await?;
        let id = account(&mut tx, &platform.issuer, sub, m["name"].as_str(), faculty).await?;
        member(&mut tx, course, id, faculty).await?;
        out.members += 1;
        out.accounts_created += usize::from(!known);
    }
    audit(
        &mut *tx,
        Some(user.id),
        "lti_memberships_synced",
        "course",
        &course.to_string(),
        json!({ "members": out.members, "created": out.accounts_created }),
    )
    .await?;
    tx.commit().await?;
    Ok(Json(out))
}
