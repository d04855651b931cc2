//! What server replicas share about live sessions, in PostgreSQL (`session_placements`): where
//! each live session runs and which replica relays it at which epoch, and the sweep each
//! replica runs over the shared state. Nothing else in the server names that table.
//!
//! Architecture invariant: PostgreSQL is the only state replicas share. A replica's memory
//! holds the sessions it relays (and their logs beyond what is durable, which no browser saw
//! acknowledged); anything another replica needs to take a session over is in the database.

use std::time::Duration;

use sqlx::PgPool;
use uuid::Uuid;

use super::registry::{PLACEMENT_STALE_AFTER, Registry, SWEEP_INTERVAL};

/// A replica name when `PAINSIM_REPLICA_ID` is unset: the host name and the process id.
pub fn default_replica_id() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "server".into());
    format!("{host}-{}", std::process::id())
}

/// The PostgreSQL notification channel of sessions taken over (payload: the session id).
pub const TAKEOVER_CHANNEL: &str = "painsim_session_taken_over";

/// Tells every replica that session `id` was taken over (a copy held elsewhere is stale).
pub async fn announce_takeover(pool: &PgPool, id: Uuid) {
    let r = sqlx::query("SELECT pg_notify($1, $2)")
        .bind(TAKEOVER_CHANNEL)
        .bind(id.to_string())
        .execute(pool)
        .await;
    if let Err(e) = r {
        tracing::warn!(session = %id, "announcing a takeover to the other replicas failed: {e}");
    }
}

/// Where a session is placed, as stored.
pub struct PlacementRow<'a> {
    /// The session.
    pub session: Uuid,
    /// The epoch the relaying replica holds it at.
    pub epoch: i64,
    /// That replica.
    pub replica: &'a str,
    /// The worker's URL; `None` for the replica's in-process worker.
    pub worker_url: Option<&'a str>,
    /// The session's id on the worker.
    pub worker_session: &'a str,
}

/// Records (or moves) a session's placement. A row held at a newer epoch (another replica
/// took the session over since) is left as it is.
pub async fn place(pool: &PgPool, p: &PlacementRow<'_>) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO session_placements (session_id, epoch, replica, worker_url, worker_session)
         VALUES ($1, $2, $3, $4, $5)
         ON CONFLICT (session_id) DO UPDATE SET epoch = EXCLUDED.epoch,
             replica = EXCLUDED.replica, worker_url = EXCLUDED.worker_url,
             worker_session = EXCLUDED.worker_session, placed_at = now(), seen_at = now()
         WHERE session_placements.epoch <= EXCLUDED.epoch",
    )
    .bind(p.session)
    .bind(p.epoch)
    .bind(p.replica)
    .bind(p.worker_url)
    .bind(p.worker_session)
    .execute(pool)
    .await?;
    Ok(())
}

/// Removes a session's placement when it ends on the replica that holds it at `epoch` (a row of
/// a newer epoch belongs to the replica that took the session over, and stays).
pub async fn release(pool: &PgPool, session: Uuid, epoch: i64) -> Result<(), sqlx::Error> {
    sqlx::query("DELETE FROM session_placements WHERE session_id = $1 AND epoch <= $2")
        .bind(session)
        .bind(epoch)
        .execute(pool)
        .await?;
    Ok(())
}

/// Where session `id` runs, if a replica holds it live: (replica, worker URL or `None` for that
/// replica's in-process worker).
pub async fn placement_of(
    pool: &PgPool,
    id: Uuid,
) -> Result<Option<(String, Option<String>)>, sqlx::Error> {
    sqlx::query_as("SELECT replica, worker_url FROM session_placements WHERE session_id = $1")
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// Live, unsubmitted sessions of `user`, and of attempts in `course`, in the whole deployment
/// (every replica's placements), leaving out the attempt `except` (whose own session is being
/// resumed, which adds none).
pub async fn live_sessions_of(
    pool: &PgPool,
    user: Uuid,
    course: Uuid,
    except: Uuid,
) -> Result<(i64, i64), sqlx::Error> {
    sqlx::query_as(
        "SELECT count(*) FILTER (WHERE s.learner_id = $1), count(*) FILTER (WHERE a.course_id = $2)
         FROM session_placements p
         JOIN live_sessions s ON s.id = p.session_id
         JOIN attempts a ON a.id = s.attempt_id
         WHERE s.result_id IS NULL AND s.attempt_id <> $3",
    )
    .bind(user)
    .bind(course)
    .bind(except)
    .fetch_one(pool)
    .await
}

/// The shared state in numbers, as `/healthz` reports it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ClusterStatus {
    /// The replica that answered.
    pub replica: String,
    /// Live sessions of the whole deployment (placement rows: what an autoscaler counts).
    pub live_sessions: i64,
    /// Registered workers by state.
    pub workers: WorkerCounts,
}

/// Registered workers by state.
#[derive(Debug, Clone, Copy, serde::Serialize)]
pub struct WorkerCounts {
    /// Alive (taking sessions).
    pub alive: i64,
    /// Draining before they exit.
    pub draining: i64,
    /// Marked dead.
    pub dead: i64,
    /// Sum of the alive workers' capacities.
    pub alive_capacity: i64,
}

/// Reads [`ClusterStatus`] (one query).
pub async fn status(pool: &PgPool, replica: &str) -> Result<ClusterStatus, sqlx::Error> {
    let (live_sessions, alive, draining, dead, alive_capacity): (i64, i64, i64, i64, i64) =
        sqlx::query_as(
            "SELECT (SELECT count(*) FROM session_placements),
                    count(*) FILTER (WHERE state = 'alive'),
                    count(*) FILTER (WHERE state = 'draining'),
                    count(*) FILTER (WHERE state = 'dead'),
                    COALESCE(sum(capacity) FILTER (WHERE state = 'alive'), 0)::bigint
             FROM render_workers",
        )
        .fetch_one(pool)
        .await?;
    Ok(ClusterStatus {
        replica: replica.to_string(),
        live_sessions,
        workers: WorkerCounts {
            alive,
            draining,
            dead,
            alive_capacity,
        },
    })
}

/// A live session this replica holds, as its sweep sees it: the id, and its placement row when
/// the session's state could be read without waiting (`None` while a request holds it).
pub type Held = (Uuid, Option<(i64, Option<String>, String)>);

/// How old a placement row must be before a sweep removes it for not being held: a row written
/// just before its session entered the replica's memory is not removed.
const NOT_HELD_GRACE_S: f64 = 5.0;

/// Dead workers are forgotten this long after they died (a pod's address changes with every
/// scaling step, so their rows would pile up), once no placement names them.
const DEAD_WORKER_KEPT_S: f64 = 3600.0;

/// One sweep of a replica: the workers whose heartbeats stopped marked dead (one winner per
/// worker, by the database) and long-dead ones forgotten; this replica's placements made
/// exactly what it holds (refreshed, written again if a database outage let them lapse, and
/// rows it no longer holds removed: a session forgotten, or a previous process under the same
/// replica name); and the placements of replicas that stopped refreshing theirs removed.
pub async fn sweep(
    pool: &PgPool,
    registry: &Registry,
    replica: &str,
    held: &[Held],
) -> Result<(), sqlx::Error> {
    registry.sweep_dead(replica).await?;
    sqlx::query(
        "DELETE FROM render_workers w WHERE state = 'dead'
           AND dead_since < now() - make_interval(secs => $1)
           AND NOT EXISTS (SELECT 1 FROM session_placements p WHERE p.worker_url = w.url)",
    )
    .bind(DEAD_WORKER_KEPT_S)
    .execute(pool)
    .await?;
    let ids: Vec<Uuid> = held.iter().map(|(id, _)| *id).collect();
    sqlx::query(
        "UPDATE session_placements SET seen_at = now()
         WHERE replica = $1 AND session_id = ANY($2)",
    )
    .bind(replica)
    .bind(&ids)
    .execute(pool)
    .await?;
    sqlx::query(
        "DELETE FROM session_placements WHERE replica = $1 AND NOT (session_id = ANY($2))
           AND placed_at < now() - make_interval(secs => $3)",
    )
    .bind(replica)
    .bind(&ids)
    .bind(NOT_HELD_GRACE_S)
    .execute(pool)
    .await?;
    let (mut sessions, mut epochs, mut urls, mut worker_sessions) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (id, row) in held {
        if let Some((epoch, url, worker_session)) = row {
            sessions.push(*id);
            epochs.push(*epoch);
            urls.push(url.clone());
            worker_sessions.push(worker_session.clone());
        }
    }
    // Rows that lapsed (an outage longer than the stale limit) come back; existing rows, this
    // replica's or a newer holder's, are left as they are.
    sqlx::query(
        "INSERT INTO session_placements (session_id, epoch, replica, worker_url, worker_session)
         SELECT s, e, $1, u, w FROM UNNEST($2::uuid[], $3::bigint[], $4::text[], $5::text[])
             AS t(s, e, u, w)
         WHERE EXISTS (SELECT 1 FROM live_sessions l WHERE l.id = s AND l.epoch = e)
         ON CONFLICT (session_id) DO NOTHING",
    )
    .bind(replica)
    .bind(&sessions)
    .bind(&epochs)
    .bind(&urls)
    .bind(&worker_sessions)
    .execute(pool)
    .await?;
    let gone = sqlx::query(
        "DELETE FROM session_placements WHERE seen_at < now() - make_interval(secs => $1)",
    )
    .bind(PLACEMENT_STALE_AFTER.as_secs_f64())
    .execute(pool)
    .await?;
    if gone.rows_affected() > 0 {
        tracing::warn!(
            removed = gone.rows_affected(),
            "removed the placements of a replica that stopped"
        );
    }
    Ok(())
}

/// Runs [`sweep`] every [`SWEEP_INTERVAL`] with what `held` says this replica holds, until
/// `held` answers `None` (the dispatcher is gone).
pub fn start_sweeper(
    pool: PgPool,
    registry: Registry,
    replica: String,
    held: impl Fn() -> Option<Vec<Held>> + Send + 'static,
) {
    let Ok(rt) = tokio::runtime::Handle::try_current() else {
        return;
    };
    rt.spawn(async move {
        loop {
            tokio::time::sleep(SWEEP_INTERVAL).await;
            let Some(held) = held() else {
                return;
            };
            let round = tokio::time::timeout(
                Duration::from_secs(5),
                sweep(&pool, &registry, &replica, &held),
            );
            match round.await {
                Ok(Ok(())) => {}
                Ok(Err(e)) => tracing::warn!("sweeping the shared state failed: {e}"),
                Err(_) => tracing::warn!("sweeping the shared state timed out"),
            }
        }
    });
}
