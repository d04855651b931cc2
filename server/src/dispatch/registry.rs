//! Registered render workers in the shared state (PostgreSQL): registration and heartbeats,
//! dead-marking, least-load choice, and the calls that create and restore sessions on them.

use std::sync::Arc;
use std::time::Duration;

use render_worker::cluster::{HttpError, HttpResponse, Registration, request};
use render_worker::session::{LogEntry, SessionSnapshot};
use serde::Serialize;
use sqlx::PgPool;

/// How often each replica sweeps the shared state: marks workers whose heartbeats stopped dead,
/// refreshes its own placement rows and removes those of replicas that stopped. Simulator
/// choice: a dead worker is noticed within [`DEAD_AFTER`] plus a second even when none of its
/// sessions is sending (a session that is sending notices at once, through its socket).
pub const SWEEP_INTERVAL: Duration = Duration::from_secs(1);

/// A worker whose last heartbeat is older than this is dead. Three heartbeats
/// ([`render_worker::cluster::HEARTBEAT`], 2 s): one lost packet or a slow answer is not a death.
pub const DEAD_AFTER: Duration = Duration::from_secs(6);

/// A placement row that its replica did not refresh for this long belongs to a replica that
/// stopped (it refreshes every [`SWEEP_INTERVAL`]); any replica removes it, so the live-session
/// count an autoscaler reads does not keep dead replicas' sessions. Simulator choice: 30 sweeps.
pub const PLACEMENT_STALE_AFTER: Duration = Duration::from_secs(30);

/// A worker as listed by `GET /api/workers` (from the shared state: every replica lists the
/// same).
#[derive(Debug, Clone, Serialize)]
pub struct WorkerView {
    /// Base URL.
    pub url: String,
    /// `alive`, `draining` (takes no new sessions) or `dead`.
    pub state: String,
    /// Capacity.
    pub capacity: usize,
    /// Sessions placed there (by any replica).
    pub sessions: usize,
    /// Sessions the worker reported in its last heartbeat.
    pub reported_sessions: usize,
    /// sessions / capacity.
    pub load: f64,
    /// `gpu` when an adapter is reported, else `software`.
    pub adapter_kind: &'static str,
    /// The adapter as reported.
    pub adapter: Option<serde_json::Value>,
    /// The renderer as reported.
    pub renderer: serde_json::Value,
    /// Seconds since its last heartbeat.
    pub last_seen_s: f64,
    /// The replica that marked it dead (the one that noticed first), when dead.
    pub marked_dead_by: Option<String>,
}

/// What a worker's heartbeat says beyond its registration.
#[derive(Debug, Clone, Copy, Default)]
pub struct Heartbeat {
    /// Sessions it holds.
    pub sessions: usize,
    /// True while it drains (it takes no new sessions).
    pub draining: bool,
}

/// The registered workers, in PostgreSQL (`render_workers`; `session_placements` for their
/// load): the same for every replica. Without a database attached (a dispatcher outside the
/// app) there are none.
#[derive(Debug, Clone, Default)]
pub struct Registry {
    pool: Arc<std::sync::OnceLock<PgPool>>,
}

type WorkerRow = (
    String,
    i32,
    i32,
    serde_json::Value,
    Option<serde_json::Value>,
    String,
    f64,
    Option<String>,
    i64,
);

impl Registry {
    /// Uses `pool` for the shared state (the first pool attached stays).
    pub fn attach(&self, pool: &PgPool) {
        let _ = self.pool.set(pool.clone());
    }

    fn pool(&self) -> Option<&PgPool> {
        self.pool.get()
    }

    /// Adds or refreshes a worker (by URL) from its registration or heartbeat.
    pub async fn register(&self, r: &Registration, beat: Heartbeat) -> Result<(), sqlx::Error> {
        let Some(pool) = self.pool() else {
            return Ok(());
        };
        let state = if beat.draining { "draining" } else { "alive" };
        let (previous,): (Option<String>,) = sqlx::query_as(
            "WITH old AS (SELECT state FROM render_workers WHERE url = $1)
             INSERT INTO render_workers (url, capacity, sessions, renderer, adapter, state)
             VALUES ($1, $2, $3, $4, $5, $6)
             ON CONFLICT (url) DO UPDATE SET capacity = EXCLUDED.capacity,
                 sessions = EXCLUDED.sessions, renderer = EXCLUDED.renderer,
                 adapter = EXCLUDED.adapter, state = EXCLUDED.state, last_seen = now(),
                 dead_since = NULL, marked_dead_by = NULL
             RETURNING (SELECT state FROM old)",
        )
        .bind(&r.url)
        .bind(i32::try_from(r.capacity).unwrap_or(i32::MAX))
        .bind(i32::try_from(beat.sessions).unwrap_or(i32::MAX))
        .bind(&r.renderer)
        .bind(&r.adapter)
        .bind(state)
        .fetch_one(pool)
        .await?;
        match previous.as_deref() {
            None => {
                tracing::info!(worker = %r.url, capacity = r.capacity, "render worker registered");
            }
            Some(p) if p != state => {
                tracing::info!(worker = %r.url, from = p, to = state, "render worker state changed");
            }
            _ => {}
        }
        Ok(())
    }

    /// Marks a worker dead (its socket failed) unless it is already; true for the replica whose
    /// update did it. Its next heartbeat revives it.
    pub async fn mark_dead(&self, url: &str, by: &str) -> bool {
        let Some(pool) = self.pool() else {
            return false;
        };
        let r = sqlx::query(
            "UPDATE render_workers SET state = 'dead', dead_since = now(), marked_dead_by = $2
             WHERE url = $1 AND state <> 'dead'",
        )
        .bind(url)
        .bind(by)
        .execute(pool)
        .await;
        match r {
            Ok(r) if r.rows_affected() == 1 => {
                tracing::warn!(worker = %url, "render worker marked dead (its socket failed)");
                true
            }
            Ok(_) => false,
            Err(e) => {
                tracing::error!(worker = %url, "marking a render worker dead failed: {e}");
                false
            }
        }
    }

    /// Marks dead every worker whose last heartbeat is older than [`DEAD_AFTER`]; returns the
    /// ones this replica (`by`) marked (another replica's sweep may win some).
    pub async fn sweep_dead(&self, by: &str) -> Result<Vec<String>, sqlx::Error> {
        let Some(pool) = self.pool() else {
            return Ok(Vec::new());
        };
        let rows: Vec<(String,)> = sqlx::query_as(
            "UPDATE render_workers SET state = 'dead', dead_since = now(), marked_dead_by = $1
             WHERE state <> 'dead' AND last_seen < now() - make_interval(secs => $2)
             RETURNING url",
        )
        .bind(by)
        .bind(DEAD_AFTER.as_secs_f64())
        .fetch_all(pool)
        .await?;
        for (url,) in &rows {
            tracing::warn!(worker = %url, replica = by, "render worker marked dead (no heartbeat)");
        }
        Ok(rows.into_iter().map(|(u,)| u).collect())
    }

    /// URLs of live workers with room, least loaded first (the sessions placed there by every
    /// replica, or the worker's own report when higher), leaving out `avoid`.
    pub async fn by_load(&self, avoid: Option<&str>) -> Vec<String> {
        let Some(pool) = self.pool() else {
            return Vec::new();
        };
        let rows: Result<Vec<(String,)>, _> = sqlx::query_as(
            "SELECT w.url FROM render_workers w
             LEFT JOIN (SELECT worker_url, count(*)::int AS n FROM session_placements
                        WHERE worker_url IS NOT NULL GROUP BY worker_url) p ON p.worker_url = w.url
             WHERE w.state = 'alive' AND w.last_seen >= now() - make_interval(secs => $2)
               AND w.url IS DISTINCT FROM $1
               AND GREATEST(COALESCE(p.n, 0), w.sessions) < w.capacity
             ORDER BY GREATEST(COALESCE(p.n, 0), w.sessions)::float8 / w.capacity, w.url",
        )
        .bind(avoid)
        .bind(DEAD_AFTER.as_secs_f64())
        .fetch_all(pool)
        .await;
        match rows {
            Ok(rows) => rows.into_iter().map(|(u,)| u).collect(),
            Err(e) => {
                tracing::error!("listing render workers failed: {e}");
                Vec::new()
            }
        }
    }

    /// The listing (every worker ever registered and not removed), by URL.
    pub async fn views(&self) -> Result<Vec<WorkerView>, sqlx::Error> {
        let Some(pool) = self.pool() else {
            return Ok(Vec::new());
        };
        let rows: Vec<WorkerRow> = sqlx::query_as(
            "SELECT w.url, w.capacity, w.sessions, w.renderer, w.adapter, w.state,
                    EXTRACT(EPOCH FROM (now() - w.last_seen))::float8, w.marked_dead_by,
                    COALESCE(p.n, 0)
             FROM render_workers w
             LEFT JOIN (SELECT worker_url, count(*) AS n FROM session_placements
                        WHERE worker_url IS NOT NULL GROUP BY worker_url) p ON p.worker_url = w.url
             ORDER BY w.url",
        )
        .fetch_all(pool)
        .await?;
        Ok(rows
            .into_iter()
            .map(
                |(url, capacity, reported, renderer, adapter, state, last_seen_s, by, placed)| {
                    let capacity = capacity.max(0) as usize;
                    let sessions = placed.max(0) as usize;
                    WorkerView {
                        url,
                        state,
                        capacity,
                        sessions,
                        reported_sessions: reported.max(0) as usize,
                        load: sessions as f64 / capacity.max(1) as f64,
                        adapter_kind: if adapter.as_ref().is_some_and(|a| !a.is_null()) {
                            "gpu"
                        } else {
                            "software"
                        },
                        adapter,
                        renderer,
                        last_seen_s,
                        marked_dead_by: by,
                    }
                },
            )
            .collect())
    }
}

/// Why a call that creates or restores a session on a registered worker failed.
#[derive(Debug, thiserror::Error)]
pub enum WorkerCallError {
    /// The request got no usable answer.
    #[error(transparent)]
    Http(#[from] HttpError),
    /// The worker answered with another status than the call expects.
    #[error("{call}: worker answered {status}: {body}")]
    Status {
        /// The call (`create`, `snapshot`, `restore`).
        call: &'static str,
        /// The HTTP status.
        status: u16,
        /// The answer's body, as text.
        body: String,
    },
    /// The answer lacks the new session's id.
    #[error("{0}: no session id in the answer")]
    NoSessionId(&'static str),
    /// The snapshot in the answer does not parse.
    #[error("snapshot: {0}")]
    Snapshot(#[source] serde_json::Error),
}

/// The errors of several workers tried in turn, in words, separated by `; `.
pub fn joined(errors: &[WorkerCallError]) -> String {
    errors
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

fn worker_error(call: &'static str, r: &HttpResponse) -> WorkerCallError {
    WorkerCallError::Status {
        call,
        status: r.status,
        body: String::from_utf8_lossy(&r.body).into_owned(),
    }
}

/// Creates a session on a worker; returns its id there and its initial snapshot.
pub async fn create_remote(
    url: &str,
    station_id: &str,
) -> Result<(String, SessionSnapshot), WorkerCallError> {
    let r = request(
        "POST",
        &format!("{url}/sessions"),
        Some(&serde_json::json!({ "station_id": station_id })),
        None,
    )
    .await?;
    if r.status != 201 {
        return Err(worker_error("create", &r));
    }
    let id = r.json()?["session"]["id"]
        .as_str()
        .ok_or(WorkerCallError::NoSessionId("create"))?
        .to_string();
    let r = request("GET", &format!("{url}/sessions/{id}/snapshot"), None, None).await?;
    if r.status != 200 {
        return Err(worker_error("snapshot", &r));
    }
    let snapshot: SessionSnapshot =
        serde_json::from_value(r.json()?["snapshot"].clone()).map_err(WorkerCallError::Snapshot)?;
    Ok((id, snapshot))
}

/// Restores a session on a worker from its initial snapshot and log; returns its id there.
pub async fn restore_remote(
    url: &str,
    snapshot: &SessionSnapshot,
    log: &[LogEntry],
) -> Result<String, WorkerCallError> {
    let body = serde_json::json!({ "snapshot": snapshot, "log": log });
    let r = request(
        "POST",
        &format!("{url}/sessions/restore"),
        Some(&body),
        None,
    )
    .await?;
    if r.status != 201 {
        return Err(worker_error("restore", &r));
    }
    Ok(r.json()?["session"]["id"]
        .as_str()
        .ok_or(WorkerCallError::NoSessionId("restore"))?
        .to_string())
}
