//! Replay checks: every technical result a session stored is re-computed by restoring the session
//! from its initial snapshot and replaying its durable log on the replay host, and the verdict is
//! appended to `result_replay_checks` (shown with the result in the attempt's detail, the review
//! queue and the CSV export).
//!
//! What must be reproduced exactly (bit for bit, no tolerance: the simulation is deterministic
//! and the log carries its clock): every measurement, the score, the outcome, the final state
//! hash and the hash of the final image the learner was shown.
//!
//! The checker runs in the background ([`start_verifier`]), a few results per round, oldest first,
//! so that a burst of submits never holds a request; `GET /api/attempts/{id}/replay` runs the same
//! comparison on demand ([`compare`]).

use std::collections::BTreeSet;
use std::time::Duration;

use render_worker::session::{
    HostError, LogEntry, Session, SessionEnv, SessionHost, SessionSnapshot, ViewId,
};
use serde_json::json;
use uuid::Uuid;

use super::Dispatcher;
use crate::error::ApiError;
use crate::records::RecordsState;
use crate::records::results::{ReplayVerdict, record_replay_check};

/// How often the background checker looks for unchecked results. Our choice: a learner sees the
/// verdict within seconds of a submit, and an idle server costs one small query per round.
pub const VERIFY_EVERY: Duration = Duration::from_secs(2);

/// Results checked per round at most (each replay is a whole session on the replay host).
const PER_ROUND: i64 = 4;

/// A stored result whose session never linked it (the server stopped between storing the result
/// and linking its session) has no log to replay; after this long it is marked `unavailable`.
const UNLINKED_AFTER_S: i64 = 600;

/// Runs `f` with the environment of `station_id`'s sessions on `host`, off the async runtime.
/// Never holds a request for an anatomy build: answers 503 (come back later) instead.
pub(super) async fn on_replay_host<T: Send + 'static>(
    host: SessionHost,
    station_id: String,
    f: impl FnOnce(SessionEnv) -> Result<T, ApiError> + Send + 'static,
) -> Result<T, ApiError> {
    if let Err(HostError::Preparing { .. }) = host.check_ready(&station_id) {
        return Err(ApiError::Unavailable(
            "anatomy (being prepared; retry shortly)",
        ));
    }
    tokio::task::spawn_blocking(move || {
        let env = host
            .env_for(&station_id)
            .map_err(|e| ApiError::Internal(e.to_string()))?;
        f(env)
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?
}

/// A session restored from `initial` with `log` replayed, a failure as an internal error.
pub(super) fn restore(
    env: SessionEnv,
    initial: &SessionSnapshot,
    log: &[LogEntry],
) -> Result<Session, ApiError> {
    Session::restore(env, initial, log).map_err(|e| ApiError::Internal(format!("replay: {e}")))
}

/// Restores `initial` on `host`, replays `log`, and renders what the learner saw last: the
/// session and the JPEG of its `view` (if it has one), or with `draft` the draft of that view
/// that a live session shows before it (none where the view has no draft).
pub(super) async fn replay_on(
    host: SessionHost,
    station_id: String,
    initial: SessionSnapshot,
    log: Vec<LogEntry>,
    view: ViewId,
    draft: bool,
) -> Result<(Session, Option<Vec<u8>>), ApiError> {
    on_replay_host(host, station_id, move |env| {
        let mut s = restore(env, &initial, &log)?;
        let views = if draft {
            s.replay_draft(view).map(|d| d.into_iter().collect())
        } else {
            let visible: BTreeSet<ViewId> = s.views().into_iter().collect();
            s.render_dirty(&visible)
        }
        .map_err(|e| ApiError::Internal(format!("replay render: {e}")))?;
        let jpeg = match views.into_iter().find(|v| v.view == view) {
            Some(v) => Some(
                render_worker::session::frame::encode_jpeg(&v.image)
                    .map_err(|e| ApiError::Internal(e.to_string()))?,
            ),
            None => None,
        };
        Ok((s, jpeg))
    })
    .await
}

/// What a result recorded, to compare a replay with.
#[derive(Debug, Clone)]
pub(super) struct Recorded {
    /// The stored measurements (every one the session reported).
    pub measurements: serde_json::Value,
    /// Stored score.
    pub score: Option<f64>,
    /// Stored outcome.
    pub outcome: Option<String>,
    /// Final state hash recorded at submit.
    pub final_state_sha256: Option<String>,
    /// Hash of the last image the learner was sent.
    pub final_frame_sha256: Option<String>,
}

/// Compares a replayed session with what was recorded: the verdict and a detail object naming
/// both sides of every compared item and the measurement keys that differ.
pub(super) fn compare(
    recorded: &Recorded,
    replayed: &Session,
    jpeg: Option<&[u8]>,
) -> (ReplayVerdict, serde_json::Value) {
    let result = replayed.result();
    let measurements = result
        .map(|r| serde_json::to_value(&r.measurements).unwrap_or_default())
        .unwrap_or(serde_json::Value::Null);
    let mut differing: Vec<String> = Vec::new();
    if let (Some(a), Some(b)) = (recorded.measurements.as_object(), measurements.as_object()) {
        let keys: BTreeSet<&String> = a.keys().chain(b.keys()).collect();
        differing = keys
            .into_iter()
            .filter(|k| a.get(*k) != b.get(*k))
            .cloned()
            .collect();
    }
    let score = result.and_then(|r| r.rubric.score);
    let outcome = result.map(|r| r.rubric.outcome.as_str().to_owned());
    let state = result.map(|r| r.record.final_state_sha256.clone());
    let frame = jpeg.map(render_worker::session::sha256_hex);
    let identical = result.is_some()
        && measurements.is_object()
        && differing.is_empty()
        && recorded.measurements == measurements
        && score == recorded.score
        && outcome == recorded.outcome
        && state == recorded.final_state_sha256
        && frame == recorded.final_frame_sha256;
    let detail = json!({
        "measurements": { "recorded": recorded.measurements, "replayed": measurements, "differing_keys": differing },
        "score": { "recorded": recorded.score, "replayed": score },
        "outcome": { "recorded": recorded.outcome, "replayed": outcome },
        "final_state_sha256": { "recorded": recorded.final_state_sha256, "replayed": state },
        "final_frame_sha256": { "recorded": recorded.final_frame_sha256, "replayed": frame },
    });
    let verdict = if identical {
        ReplayVerdict::Identical
    } else {
        ReplayVerdict::Differs
    };
    (verdict, detail)
}

/// A result waiting for its check, with its session.
type Unchecked = (
    Uuid,
    String,
    serde_json::Value,
    Uuid,
    serde_json::Value,
    Option<f64>,
    String,
    Option<String>,
    Option<String>,
);

/// Checks one stored result; `None` when the replay host is not ready (try again later).
async fn check_one(
    records: &RecordsState,
    host: &SessionHost,
    row: Unchecked,
) -> Option<(ReplayVerdict, serde_json::Value)> {
    let (_result_id, station_id, initial, session_id, measurements, score, outcome, state, frame) =
        row;
    let recorded = Recorded {
        measurements,
        score,
        outcome: Some(outcome),
        final_state_sha256: state,
        final_frame_sha256: frame,
    };
    let initial: SessionSnapshot = match serde_json::from_value(initial) {
        Ok(s) => s,
        Err(e) => {
            return Some((
                ReplayVerdict::Differs,
                json!({ "error": format!("the stored initial snapshot cannot be read: {e}") }),
            ));
        }
    };
    let log = match super::store::load_commands(&records.pool, session_id).await {
        Ok(l) => l,
        Err(e) => {
            tracing::warn!(session = %session_id, "loading a log for its replay check failed: {e}");
            return None;
        }
    };
    match replay_on(
        host.clone(),
        station_id,
        initial,
        log,
        ViewId::FLUOROSCOPY,
        false,
    )
    .await
    {
        Ok((s, jpeg)) => Some(compare(&recorded, &s, jpeg.as_deref())),
        Err(ApiError::Unavailable(_)) => None,
        Err(e) => Some((
            ReplayVerdict::Differs,
            json!({ "error": format!("the logged session does not replay: {e}") }),
        )),
    }
}

/// One round of the checker: results with a linked session and no check yet, oldest first, and
/// long-unlinked ones marked `unavailable`. Returns how many verdicts it stored.
pub async fn verify_round(
    records: &RecordsState,
    host: &SessionHost,
) -> Result<usize, sqlx::Error> {
    let rows: Vec<Unchecked> = sqlx::query_as(
        "SELECT r.id, s.station_id, s.initial_snapshot, s.id, r.measurements, r.score, r.outcome,
                s.final_state_sha256, s.final_frame_sha256
         FROM technical_results r JOIN live_sessions s ON s.result_id = r.id
         WHERE r.source = 'server'
           AND NOT EXISTS (SELECT 1 FROM result_replay_checks c WHERE c.result_id = r.id)
         ORDER BY r.created_at, r.id LIMIT $1",
    )
    .bind(PER_ROUND)
    .fetch_all(&records.pool)
    .await?;
    let mut stored = 0;
    for row in rows {
        let result_id = row.0;
        if let Some((verdict, detail)) = check_one(records, host, row).await {
            if verdict != ReplayVerdict::Identical {
                tracing::warn!(result = %result_id, %detail, "a stored result does not replay");
            }
            record_replay_check(&records.pool, result_id, verdict, &detail).await?;
            stored += 1;
        }
    }
    let unlinked: Vec<Uuid> = sqlx::query_scalar(
        "SELECT r.id FROM technical_results r
         WHERE NOT EXISTS (SELECT 1 FROM result_replay_checks c WHERE c.result_id = r.id)
           AND NOT EXISTS (SELECT 1 FROM live_sessions s WHERE s.result_id = r.id)
           AND r.created_at < now() - make_interval(secs => $1)
         ORDER BY r.created_at LIMIT $2",
    )
    .bind(UNLINKED_AFTER_S as f64)
    .bind(PER_ROUND)
    .fetch_all(&records.pool)
    .await?;
    for id in unlinked {
        let detail = json!({ "reason": "no recorded session is linked to this result" });
        record_replay_check(&records.pool, id, ReplayVerdict::Unavailable, &detail).await?;
        stored += 1;
    }
    Ok(stored)
}

/// Starts the background checker for `dispatcher`'s replay host: a round every `every`, until the
/// dispatcher is dropped. Does nothing outside a tokio runtime.
pub fn start_verifier(records: RecordsState, dispatcher: &Dispatcher, every: Duration) {
    let Ok(rt) = tokio::runtime::Handle::try_current() else {
        return;
    };
    let weak = std::sync::Arc::downgrade(&dispatcher.inner);
    rt.spawn(async move {
        loop {
            tokio::time::sleep(every).await;
            let Some(inner) = weak.upgrade() else { return };
            let host = inner.replay.clone();
            drop(inner);
            if let Err(e) = verify_round(&records, &host).await {
                tracing::warn!("a replay-check round failed: {e}");
            }
        }
    });
}
