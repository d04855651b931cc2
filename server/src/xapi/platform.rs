//! The platform's own learning records as xAPI 2.0 statements.
//!
//! Triggers on the records tables (migration 0804) queue every new activity event, technical
//! result, review and non-reproducing replay check in `xapi_projection_queue`, in the transaction
//! that stores the record (the records module knows nothing of xAPI). The [`Projector`] turns
//! queued records into statements, stores them in the local LRS
//! ([`insert_statements`]) and enqueues each one in the durable outbox (kind
//! [`FORWARD_KIND`](super::forward::FORWARD_KIND)) in the transaction that deletes the queue rows:
//! a record becomes its statements exactly once, and every statement is forwarded.
//!
//! Statement ids are UUID v5 of the record (see [`statement_id`]), so projecting a record again
//! yields the same statements (idempotent in both LRSs).
//!
//! The mapping (verb IRIs from the ADL vocabulary, <http://adlnet.gov/expapi/verbs/>, and the
//! Activity Streams base schema, <http://activitystrea.ms/schema/1.0/>):
//! - `session_launched` -> `launched`; `station_opened` -> `initialized`; `view_changed`,
//!   `image_acquired`, `needle_adjusted`, `injection` -> `interacted`; `page_viewed` ->
//!   `experienced` (reading is engagement, never `completed`); `submission` -> `terminated` (the
//!   attempt's work ends with its submission). Object: the station (or the page, its parent the
//!   station); the event's kind and detail in context extensions.
//! - a technical result -> `scored`: `result.score` {scaled, raw, min 0, max 1} (the rubric's
//!   weighted credit, 0..1), `result.success` from the technical rubric's outcome only (absent when
//!   incomplete), the per-criterion results, the outcome and the incomplete flag in result
//!   extensions; the reproducibility record in context extensions.
//! - a review -> a separate statement by the faculty member: `approve` or `reject` (returned to the
//!   learner), object a StatementRef to the result's `scored` statement, the comment as
//!   `result.response`.
//! - a replay check that did not reproduce its result -> the result's statement is voided (verb
//!   `voided`, by the platform).
//!
//! Every statement's `context.registration` is the attempt id. The learner and faculty are Agents
//! with `account {homePage: public_url, name: user id}` (no name or e-mail leaves the platform).
//! Activity ids are IRIs under the public URL: `<public_url>/xapi/activities/station/<id>`,
//! `.../station/<id>/page/<page>`, `<public_url>/xapi/activities/course/<id>`.

use std::sync::Arc;
use std::time::Duration;

use serde_json::{Value, json};
use sha1::{Digest, Sha1};
use sqlx::PgPool;
use time::OffsetDateTime;
use time::format_description::well_known::Rfc3339;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use uuid::Uuid;

use super::forward::FORWARD_KIND;
use super::statements::query::percent_encode;
use super::statements::store::insert_statements;
use crate::error::ApiError;
use crate::outbox::{self, Outbox};

/// Namespace of the statement ids (UUID v5, RFC 9562 section 5.5): our choice, a fixed random
/// UUID, so the ids of the platform's statements never collide with another system's v5 ids.
pub const STATEMENT_NAMESPACE: Uuid = Uuid::from_u128(0x6f1d_1c2e_8b7a_4c55_9a37_2f0e_5d4b_3a21);

/// ADL verbs (<https://adlnet.gov/expapi/verbs/>, the ADL vocabulary registered for xAPI).
pub mod verbs {
    /// The learner launched the simulation session.
    pub const LAUNCHED: &str = "http://adlnet.gov/expapi/verbs/launched";
    /// The station was opened for the attempt.
    pub const INITIALIZED: &str = "http://adlnet.gov/expapi/verbs/initialized";
    /// Imaging, needle and injection actions.
    pub const INTERACTED: &str = "http://adlnet.gov/expapi/verbs/interacted";
    /// The attempt's work was submitted.
    pub const TERMINATED: &str = "http://adlnet.gov/expapi/verbs/terminated";
    /// A page was read (never `completed`).
    pub const EXPERIENCED: &str = "http://adlnet.gov/expapi/verbs/experienced";
    /// The technical result.
    pub const SCORED: &str = "http://adlnet.gov/expapi/verbs/scored";
    /// A correction: the target statement no longer holds (xAPI 2.0, Voided Statements).
    pub const VOIDED: &str = "http://adlnet.gov/expapi/verbs/voided";
    /// Faculty approval (Activity Streams 1.0 base schema, "approve").
    pub const APPROVE: &str = "http://activitystrea.ms/schema/1.0/approve";
    /// Faculty returned the attempt (Activity Streams 1.0 base schema, "reject").
    pub const REJECT: &str = "http://activitystrea.ms/schema/1.0/reject";
}

/// ADL activity types (<http://adlnet.gov/expapi/activities/>).
mod activity_types {
    pub const SIMULATION: &str = "http://adlnet.gov/expapi/activities/simulation";
    pub const COURSE: &str = "http://adlnet.gov/expapi/activities/course";
    pub const MODULE: &str = "http://adlnet.gov/expapi/activities/module";
}

/// The deterministic id of the statement a record becomes: UUID v5 of `<source>:<record id>`
/// (`part` distinguishes several statements of one record).
pub fn statement_id(source: &str, record_id: &str) -> Uuid {
    let mut h = Sha1::new();
    h.update(STATEMENT_NAMESPACE.as_bytes());
    h.update(source.as_bytes());
    h.update(b":");
    h.update(record_id.as_bytes());
    let digest = h.finalize();
    let mut bytes = [0u8; 16];
    bytes.copy_from_slice(&digest[..16]);
    uuid::Builder::from_sha1_bytes(bytes).into_uuid()
}

/// Builds statements from records under one public URL.
#[derive(Clone)]
pub struct Vocabulary {
    public_url: Arc<str>,
}

impl Vocabulary {
    /// Statements for a server reached at `public_url` (no trailing slash).
    pub fn new(public_url: &str) -> Vocabulary {
        Vocabulary {
            public_url: public_url.trim_end_matches('/').into(),
        }
    }

    /// An extension IRI under the public URL.
    pub fn extension(&self, name: &str) -> String {
        format!("{}/xapi/extensions/{name}", self.public_url)
    }

    /// The authority of the platform's statements (and the actor of its voiding statements).
    pub fn platform_agent(&self) -> Value {
        json!({
            "objectType": "Agent",
            "name": "pain-sim platform",
            "account": { "homePage": format!("{}/xapi/", self.public_url), "name": "platform" },
        })
    }

    /// A user of the platform as an Agent.
    pub fn user_agent(&self, user: Uuid) -> Value {
        json!({
            "objectType": "Agent",
            "account": { "homePage": self.public_url.as_ref(), "name": user.to_string() },
        })
    }

    /// The station as an Activity.
    pub fn station(&self, station_id: &str, title: Option<&str>) -> Value {
        let mut definition = json!({ "type": activity_types::SIMULATION });
        if let Some(t) = title {
            definition["name"] = json!({ "en-US": t });
        }
        json!({
            "objectType": "Activity",
            "id": format!("{}/xapi/activities/station/{}", self.public_url, percent_encode(station_id)),
            "definition": definition,
        })
    }

    fn page(&self, station_id: &str, page: &str) -> Value {
        json!({
            "objectType": "Activity",
            "id": format!("{}/xapi/activities/station/{}/page/{}", self.public_url, percent_encode(station_id), percent_encode(page)),
            "definition": { "type": activity_types::MODULE, "name": { "en-US": page } },
        })
    }

    fn course(&self, course: Uuid) -> Value {
        json!({
            "objectType": "Activity",
            "id": format!("{}/xapi/activities/course/{course}", self.public_url),
            "definition": { "type": activity_types::COURSE },
        })
    }
}

fn verb(id: &str, display: &str) -> Value {
    json!({ "id": id, "display": { "en-US": display } })
}

fn rfc3339(t: OffsetDateTime) -> String {
    t.format(&Rfc3339).unwrap_or_default()
}

/// What an attempt contributes to every statement about it.
struct AttemptInfo {
    learner: Uuid,
    course: Uuid,
    station_id: String,
    title: Option<String>,
}

async fn attempt_info(
    conn: &mut sqlx::PgConnection,
    attempt: Uuid,
) -> Result<AttemptInfo, sqlx::Error> {
    let (learner, course, station_id, title): (Uuid, Uuid, String, Option<String>) =
        sqlx::query_as(
            "SELECT a.learner_id, a.course_id, a.station_id, s.definition->>'title'
             FROM attempts a JOIN station_revisions s ON s.station_id = a.station_id
                  AND s.revision = a.station_revision AND s.rubric_revision = a.rubric_revision
             WHERE a.id = $1",
        )
        .bind(attempt)
        .fetch_one(conn)
        .await?;
    Ok(AttemptInfo {
        learner,
        course,
        station_id,
        title,
    })
}

impl Vocabulary {
    fn context(&self, attempt: Uuid, info: &AttemptInfo, extensions: Value) -> Value {
        json!({
            "registration": attempt,
            "platform": "pain-sim",
            "contextActivities": { "grouping": [self.course(info.course)] },
            "extensions": extensions,
        })
    }

    /// The statement of one activity event.
    pub async fn activity_event(
        &self,
        conn: &mut sqlx::PgConnection,
        id: i64,
    ) -> Result<Vec<Value>, sqlx::Error> {
        type Row = (
            Uuid,
            Uuid,
            String,
            OffsetDateTime,
            Option<OffsetDateTime>,
            Value,
        );
        let (attempt, user, kind, recorded_at, client_time, detail): Row = sqlx::query_as(
            "SELECT attempt_id, user_id, kind, recorded_at, client_time, detail
             FROM activity_events WHERE id = $1",
        )
        .bind(id)
        .fetch_one(&mut *conn)
        .await?;
        let info = attempt_info(conn, attempt).await?;
        let station = self.station(&info.station_id, info.title.as_deref());
        let (verb_iri, display) = match kind.as_str() {
            "session_launched" => (verbs::LAUNCHED, "launched"),
            "station_opened" => (verbs::INITIALIZED, "initialized"),
            "page_viewed" => (verbs::EXPERIENCED, "experienced"),
            "submission" => (verbs::TERMINATED, "terminated"),
            _ => (verbs::INTERACTED, "interacted"),
        };
        let page = detail
            .get("page")
            .and_then(Value::as_str)
            .filter(|p| kind == "page_viewed" && !p.is_empty());
        let mut extensions = json!({
            self.extension("event-kind"): kind,
            self.extension("event-id"): id,
            self.extension("event-detail"): detail,
        });
        if let Some(t) = client_time {
            extensions[self.extension("client-time")] = json!(rfc3339(t));
        }
        let mut context = self.context(attempt, &info, extensions);
        let object = match page {
            Some(p) => {
                context["contextActivities"]["parent"] = json!([station]);
                self.page(&info.station_id, p)
            }
            None => station,
        };
        Ok(vec![json!({
            "id": statement_id("activity_event", &id.to_string()),
            "actor": self.user_agent(user),
            "verb": verb(verb_iri, display),
            "object": object,
            "context": context,
            "timestamp": rfc3339(recorded_at),
        })])
    }

    /// The `scored` statement of one technical result.
    pub async fn technical_result(
        &self,
        conn: &mut sqlx::PgConnection,
        id: Uuid,
    ) -> Result<Vec<Value>, sqlx::Error> {
        #[derive(sqlx::FromRow)]
        struct Row {
            attempt_id: Uuid,
            seq: i32,
            submitted_by: Uuid,
            source: String,
            outcome: String,
            score: Option<f64>,
            measured_weight_fraction: f64,
            station_revision: i32,
            rubric_revision: i32,
            station_sha256: String,
            measurements: Value,
            detail: Value,
            code_revision: String,
            server_version: String,
            asset_hashes: Value,
            device_profile: Value,
            imaging_settings: Value,
            interaction_log_ref: Option<String>,
            created_at: OffsetDateTime,
        }
        let r: Row = sqlx::query_as(
            "SELECT attempt_id, seq, submitted_by, source, outcome, score, measured_weight_fraction,
                    station_revision, rubric_revision, station_sha256, measurements, detail,
                    code_revision, server_version, asset_hashes, device_profile, imaging_settings,
                    interaction_log_ref, created_at
             FROM technical_results WHERE id = $1",
        )
        .bind(id)
        .fetch_one(&mut *conn)
        .await?;
        let info = attempt_info(conn, r.attempt_id).await?;
        let incomplete = r.outcome == "incomplete";
        let mut result = json!({
            "extensions": {
                self.extension("outcome"): r.outcome,
                self.extension("incomplete"): incomplete,
                self.extension("incomplete-criteria"): r.detail.get("incomplete_criteria").cloned().unwrap_or(json!([])),
                self.extension("critical-failures"): r.detail.get("critical_failures").cloned().unwrap_or(json!([])),
                self.extension("measured-weight-fraction"): r.measured_weight_fraction,
                self.extension("pass-threshold"): r.detail.get("pass_threshold").cloned().unwrap_or(Value::Null),
                self.extension("criteria"): r.detail.get("criteria").cloned().unwrap_or(json!([])),
                self.extension("measurements"): r.measurements,
            }
        });
        // The rubric's credit is a weighted mean in 0..=1 (sim-core's RubricResult::score).
        if let Some(s) = r.score.filter(|s| s.is_finite()) {
            let s = s.clamp(0.0, 1.0);
            result["score"] = json!({ "scaled": s, "raw": s, "min": 0.0, "max": 1.0 });
        }
        if !incomplete {
            result["success"] = json!(r.outcome == "met");
        }
        let extensions = json!({
            self.extension("result-id"): id,
            self.extension("result-seq"): r.seq,
            self.extension("result-source"): r.source,
            self.extension("reproducibility"): {
                "code_revision": r.code_revision,
                "server_version": r.server_version,
                "asset_hashes": r.asset_hashes,
                "device_profile": r.device_profile,
                "imaging_settings": r.imaging_settings,
                "station_sha256": r.station_sha256,
                "station_revision": r.station_revision,
                "rubric_revision": r.rubric_revision,
                "interaction_log_ref": r.interaction_log_ref,
            },
        });
        Ok(vec![json!({
            "id": statement_id("technical_result", &id.to_string()),
            "actor": self.user_agent(r.submitted_by),
            "verb": verb(verbs::SCORED, "scored"),
            "object": self.station(&info.station_id, info.title.as_deref()),
            "result": result,
            "context": self.context(r.attempt_id, &info, extensions),
            "timestamp": rfc3339(r.created_at),
        })])
    }

    /// The faculty member's statement about a result.
    pub async fn review(
        &self,
        conn: &mut sqlx::PgConnection,
        id: Uuid,
    ) -> Result<Vec<Value>, sqlx::Error> {
        let (attempt, result_id, reviewer, decision, comment, created_at): (
            Uuid,
            Uuid,
            Uuid,
            String,
            String,
            OffsetDateTime,
        ) = sqlx::query_as(
            "SELECT attempt_id, result_id, reviewer_id, decision, comment, created_at
             FROM reviews WHERE id = $1",
        )
        .bind(id)
        .fetch_one(&mut *conn)
        .await?;
        let info = attempt_info(conn, attempt).await?;
        let (verb_iri, display) = if decision == "approved" {
            (verbs::APPROVE, "approved")
        } else {
            (verbs::REJECT, "returned")
        };
        let mut statement = json!({
            "id": statement_id("review", &id.to_string()),
            "actor": self.user_agent(reviewer),
            "verb": verb(verb_iri, display),
            "object": {
                "objectType": "StatementRef",
                "id": statement_id("technical_result", &result_id.to_string()),
            },
            "context": {
                "registration": attempt,
                "contextActivities": {
                    "parent": [self.station(&info.station_id, info.title.as_deref())],
                    "grouping": [self.course(info.course)],
                },
                "extensions": {
                    self.extension("review-id"): id,
                    self.extension("result-id"): result_id,
                    self.extension("decision"): decision,
                    self.extension("learner"): self.user_agent(info.learner),
                },
            },
            "timestamp": rfc3339(created_at),
        });
        if !comment.trim().is_empty() {
            statement["result"] = json!({ "response": comment });
        }
        Ok(vec![statement])
    }

    /// The voiding of a result whose replay did not reproduce it.
    pub async fn replay_check(
        &self,
        conn: &mut sqlx::PgConnection,
        id: i64,
    ) -> Result<Vec<Value>, sqlx::Error> {
        let (result_id, checked_at): (Uuid, OffsetDateTime) =
            sqlx::query_as("SELECT result_id, checked_at FROM result_replay_checks WHERE id = $1")
                .bind(id)
                .fetch_one(&mut *conn)
                .await?;
        Ok(vec![json!({
            "id": statement_id("replay_check", &id.to_string()),
            "actor": self.platform_agent(),
            "verb": verb(verbs::VOIDED, "voided"),
            "object": {
                "objectType": "StatementRef",
                "id": statement_id("technical_result", &result_id.to_string()),
            },
            "timestamp": rfc3339(checked_at),
        })])
    }

    /// The statements of one queued record.
    pub async fn record(
        &self,
        conn: &mut sqlx::PgConnection,
        source: &str,
        record_id: &str,
    ) -> Result<Vec<Value>, ApiError> {
        let bad = |e: &dyn std::fmt::Display| {
            ApiError::Internal(format!("record {source} {record_id}: {e}"))
        };
        match source {
            "activity_event" => {
                let id = record_id.parse().map_err(|e| bad(&e))?;
                Ok(self.activity_event(conn, id).await?)
            }
            "technical_result" => {
                let id = record_id.parse().map_err(|e| bad(&e))?;
                Ok(self.technical_result(conn, id).await?)
            }
            "review" => {
                let id = record_id.parse().map_err(|e| bad(&e))?;
                Ok(self.review(conn, id).await?)
            }
            "replay_check" => {
                let id = record_id.parse().map_err(|e| bad(&e))?;
                Ok(self.replay_check(conn, id).await?)
            }
            other => Err(bad(&format!("unknown source {other}"))),
        }
    }
}

/// Queued records per projector transaction (our choice: a few hundred statements' work, short
/// enough that a transaction holds its locks for milliseconds).
const PROJECTION_BATCH: i64 = 100;

/// Longest the projector sleeps without looking at the queue (our choice; notifications wake it
/// at once).
const PROJECTION_POLL: Duration = Duration::from_secs(2);

/// Turns queued records into statements (local LRS + outbox).
#[derive(Clone)]
pub struct Projector {
    pool: PgPool,
    vocabulary: Vocabulary,
    outbox: Option<Outbox>,
}

impl Projector {
    /// A projector for `pool`'s records, statements under `public_url`; `outbox` (if any) is
    /// woken after each batch.
    pub fn new(pool: PgPool, public_url: &str, outbox: Option<Outbox>) -> Projector {
        Projector {
            pool,
            vocabulary: Vocabulary::new(public_url),
            outbox,
        }
    }

    /// Projects one batch of queued records; returns how many queue rows it settled (projected
    /// or marked failed), 0 when the queue is empty.
    pub async fn project_batch(&self) -> Result<usize, ApiError> {
        let mut tx = self.pool.begin().await?;
        let rows: Vec<(i64, String, String)> = sqlx::query_as(
            "SELECT id, source, record_id FROM xapi_projection_queue WHERE failed_at IS NULL
             ORDER BY id LIMIT $1 FOR UPDATE SKIP LOCKED",
        )
        .bind(PROJECTION_BATCH)
        .fetch_all(&mut *tx)
        .await?;
        if rows.is_empty() {
            tx.commit().await?;
            return Ok(0);
        }
        match self.project(&mut tx, &rows).await {
            Ok(()) => {
                tx.commit().await?;
                Ok(rows.len())
            }
            Err(batch_error) => {
                drop(tx);
                // One bad record must not hold up the others: project them one by one, and keep
                // the bad one with its error.
                tracing::warn!(error = %batch_error, "xAPI projection batch failed; retrying record by record");
                for row in &rows {
                    let mut tx = self.pool.begin().await?;
                    let locked: Option<i64> = sqlx::query_scalar(
                        "SELECT id FROM xapi_projection_queue WHERE id = $1 AND failed_at IS NULL
                         FOR UPDATE SKIP LOCKED",
                    )
                    .bind(row.0)
                    .fetch_optional(&mut *tx)
                    .await?;
                    if locked.is_none() {
                        continue;
                    }
                    match self.project(&mut tx, std::slice::from_ref(row)).await {
                        Ok(()) => tx.commit().await?,
                        Err(e) => {
                            drop(tx);
                            tracing::error!(source = %row.1, record = %row.2, error = %e, "xAPI projection of a record failed");
                            sqlx::query(
                                "UPDATE xapi_projection_queue SET failed_at = now(), last_error = $2
                                 WHERE id = $1",
                            )
                            .bind(row.0)
                            .bind(format!("{e:?}"))
                            .execute(&self.pool)
                            .await?;
                        }
                    }
                }
                Ok(rows.len())
            }
        }
    }

    async fn project(
        &self,
        tx: &mut sqlx::PgConnection,
        rows: &[(i64, String, String)],
    ) -> Result<(), ApiError> {
        let mut statements = Vec::new();
        for (_, source, record_id) in rows {
            statements.extend(self.vocabulary.record(tx, source, record_id).await?);
        }
        if !statements.is_empty() {
            insert_statements(tx, statements.clone(), &self.vocabulary.platform_agent()).await?;
        }
        for s in statements {
            let key = s["id"].as_str().unwrap_or_default().to_owned();
            outbox::enqueue(tx, FORWARD_KIND, &key, s).await?;
        }
        let ids: Vec<i64> = rows.iter().map(|r| r.0).collect();
        sqlx::query("DELETE FROM xapi_projection_queue WHERE id = ANY($1)")
            .bind(ids)
            .execute(&mut *tx)
            .await?;
        Ok(())
    }

    /// Projects until the queue is empty.
    pub async fn drain(&self) -> Result<usize, ApiError> {
        let mut total = 0;
        loop {
            let n = self.project_batch().await?;
            if n == 0 {
                return Ok(total);
            }
            total += n;
            if let Some(o) = &self.outbox {
                o.wake();
            }
        }
    }

    /// Runs until `shutdown` completes: drains the queue whenever a record is queued (`NOTIFY
    /// xapi_projection`) and every [`PROJECTION_POLL`].
    pub fn spawn(
        self,
        shutdown: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> JoinHandle<()> {
        let (stop_tx, mut stop) = watch::channel(false);
        tokio::spawn(async move {
            tokio::spawn(async move {
                shutdown.await;
                let _ = stop_tx.send(true);
            });
            let mut listener = None;
            loop {
                if listener.is_none() {
                    listener = match sqlx::postgres::PgListener::connect_with(&self.pool).await {
                        Ok(mut l) => l.listen("xapi_projection").await.ok().map(|()| l),
                        Err(_) => None,
                    };
                }
                let drained = tokio::select! {
                    _ = stop.wait_for(|s| *s) => return,
                    r = self.drain() => r,
                };
                if let Err(e) = drained {
                    tracing::warn!(error = %e, "xAPI projection failed; retrying");
                }
                let wait = async {
                    match listener.as_mut() {
                        Some(l) => l.recv().await.map(|_| ()),
                        None => std::future::pending().await,
                    }
                };
                tokio::select! {
                    _ = stop.wait_for(|s| *s) => return,
                    r = tokio::time::timeout(PROJECTION_POLL, wait) => {
                        if let Ok(Err(_)) = r {
                            listener = None;
                        }
                    }
                }
            }
        })
    }
}
