//! Every SQL statement on `live_sessions` and `live_session_commands`: the server's durable copy
//! of each session (its initial snapshot, its acknowledged commands, and what it ended with).
//! Nothing else in the server names these tables.

use render_worker::session::{LogEntry, SessionSnapshot};
use sqlx::PgPool;
use uuid::Uuid;

/// Records a new session of an attempt with its initial snapshot.
pub async fn insert_session(
    pool: &PgPool,
    id: Uuid,
    attempt_id: Uuid,
    learner_id: Uuid,
    station_id: &str,
    initial: &SessionSnapshot,
) -> Result<(), sqlx::Error> {
    let initial = serde_json::to_value(initial).map_err(|e| sqlx::Error::Encode(Box::new(e)))?;
    sqlx::query(
        "INSERT INTO live_sessions (id, attempt_id, learner_id, station_id, initial_snapshot)
         VALUES ($1, $2, $3, $4, $5)",
    )
    .bind(id)
    .bind(attempt_id)
    .bind(learner_id)
    .bind(station_id)
    .bind(initial)
    .execute(pool)
    .await?;
    Ok(())
}

/// The newest session of an attempt that was not submitted (to resume), with its stored
/// initial snapshot.
pub async fn resumable_session(
    pool: &PgPool,
    attempt_id: Uuid,
) -> Result<Option<(Uuid, serde_json::Value)>, sqlx::Error> {
    sqlx::query_as(
        "SELECT id, initial_snapshot FROM live_sessions
         WHERE attempt_id = $1 AND result_id IS NULL ORDER BY created_at DESC LIMIT 1",
    )
    .bind(attempt_id)
    .fetch_optional(pool)
    .await
}

/// A recorded session with what it ended with: id, station, initial snapshot, result id, final
/// state and frame hashes, and the stored result's score and outcome.
pub type RecordedSession = (
    Uuid,
    String,
    serde_json::Value,
    Option<Uuid>,
    Option<String>,
    Option<String>,
    Option<f64>,
    Option<String>,
);

/// The newest recorded session of an attempt, submitted ones first.
pub async fn newest_recorded(
    pool: &PgPool,
    attempt_id: Uuid,
) -> Result<Option<RecordedSession>, sqlx::Error> {
    sqlx::query_as(
        "SELECT s.id, s.station_id, s.initial_snapshot, s.result_id, s.final_state_sha256, s.final_frame_sha256, r.score, r.outcome
         FROM live_sessions s LEFT JOIN technical_results r ON r.id = s.result_id
         WHERE s.attempt_id = $1 ORDER BY (s.result_id IS NOT NULL) DESC, s.created_at DESC LIMIT 1",
    )
    .bind(attempt_id)
    .fetch_optional(pool)
    .await
}

/// Saves the hash of the last frame the browser was sent (kept when `frame` is `None`), by the
/// connection that holds the session at `epoch`, while it is not submitted (a replica that lost
/// the session, or a late connection after the submit, changes nothing).
pub async fn save_frame_hash(
    pool: &PgPool,
    id: Uuid,
    epoch: i64,
    frame: Option<&str>,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE live_sessions SET final_frame_sha256 = COALESCE($2, final_frame_sha256),
         updated_at = now() WHERE id = $1 AND epoch = $3 AND result_id IS NULL",
    )
    .bind(id)
    .bind(frame)
    .bind(epoch)
    .execute(pool)
    .await?;
    Ok(())
}

/// Marks a session submitted: its stored result, final state and last frame.
pub async fn save_submitted(
    pool: &PgPool,
    id: Uuid,
    result_id: Uuid,
    final_state_sha256: &str,
    frame: Option<&str>,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE live_sessions SET result_id = $2, final_state_sha256 = $3,
         final_frame_sha256 = $4, updated_at = now() WHERE id = $1",
    )
    .bind(id)
    .bind(result_id)
    .bind(final_state_sha256)
    .bind(frame)
    .execute(pool)
    .await?;
    Ok(())
}

/// Takes session `id` over for a new connection: bumps its epoch and returns the epoch it had
/// and the new one (`None`: no such session). Appends under the old epoch are refused from now
/// on (see [`append_commands`]); appends already in flight commit first (the bump waits for
/// their row lock), so the log read after this call holds all of them.
pub async fn take_over(pool: &PgPool, id: Uuid) -> Result<Option<(i64, i64)>, sqlx::Error> {
    let row: Option<(i64,)> = sqlx::query_as(
        "UPDATE live_sessions SET epoch = epoch + 1, updated_at = now() WHERE id = $1
         RETURNING epoch",
    )
    .bind(id)
    .fetch_optional(pool)
    .await?;
    Ok(row.map(|(e,)| (e - 1, e)))
}

/// Takes session `id` over for a new connection of the replica that holds it at `held`: bumps
/// the epoch only if it is still `held` (compare and swap); the new epoch, or `None` when
/// another connection took the session over since (or there is no such session).
pub async fn take_over_from(
    pool: &PgPool,
    id: Uuid,
    held: i64,
) -> Result<Option<i64>, sqlx::Error> {
    sqlx::query_scalar(
        "UPDATE live_sessions SET epoch = epoch + 1, updated_at = now()
         WHERE id = $1 AND epoch = $2 RETURNING epoch",
    )
    .bind(id)
    .bind(held)
    .fetch_optional(pool)
    .await
}

/// A stored session as a replica that does not hold it loads it: attempt, learner, course,
/// station, initial snapshot, and whether it was submitted.
pub type StoredSession = (Uuid, Uuid, Uuid, String, serde_json::Value, Option<Uuid>);

/// Session `id` with its attempt's course.
pub async fn stored_session(pool: &PgPool, id: Uuid) -> Result<Option<StoredSession>, sqlx::Error> {
    sqlx::query_as(
        "SELECT s.attempt_id, s.learner_id, a.course_id, s.station_id, s.initial_snapshot, s.result_id
         FROM live_sessions s JOIN attempts a ON a.id = s.attempt_id WHERE s.id = $1",
    )
    .bind(id)
    .fetch_optional(pool)
    .await
}

/// The epoch session `id` is held at now.
pub async fn epoch_of(pool: &PgPool, id: Uuid) -> Result<Option<i64>, sqlx::Error> {
    sqlx::query_scalar("SELECT epoch FROM live_sessions WHERE id = $1")
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// How many commands session `id` has logged, and the last one's sequence number (0 before the
/// first).
pub async fn log_extent(pool: &PgPool, id: Uuid) -> Result<(i64, i64), sqlx::Error> {
    sqlx::query_as(
        "SELECT count(*), COALESCE(max(seq), 0) FROM live_session_commands WHERE session_id = $1",
    )
    .bind(id)
    .fetch_one(pool)
    .await
}

/// SQLSTATE of an append refused because another connection took the session over
/// (`migrations/0901_cluster_state.sql`).
pub const FENCED_SQLSTATE: &str = "PF409";

/// Why a write of logged commands failed, and whether trying again can help.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WriteError {
    /// True when the same write can never succeed (the data is refused, not the connection):
    /// retrying would wedge the session, so it ends instead (see [`super::durable`]).
    pub permanent: bool,
    /// True when the write was refused because another connection (perhaps on another
    /// replica) took the session over: this copy of the session is stale.
    pub fenced: bool,
    /// What went wrong, in words.
    pub message: String,
}

impl std::fmt::Display for WriteError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl WriteError {
    fn permanent(message: impl Into<String>) -> WriteError {
        WriteError {
            permanent: true,
            fenced: false,
            message: message.into(),
        }
    }
}

/// Whether a database error may go away by itself. SQLSTATE classes (PostgreSQL manual,
/// appendix A): 08 connection exception, 25 invalid transaction state (a read-only standby
/// during failover), 40 transaction rollback (serialization, deadlock), 53 insufficient
/// resources (disk full, too many connections), 55 object not in prerequisite state (lock not
/// available), 57 operator intervention (shutdown, cancel), 58 system error (I/O). Every other
/// class (22 data exception, 23 integrity constraint, 42 syntax or access, P0 raised by a
/// trigger, ...) refuses the data itself. Errors outside the database (I/O, pool timeouts, TLS)
/// are transient.
pub fn is_transient(e: &sqlx::Error) -> bool {
    match e {
        sqlx::Error::Database(db) => {
            let code = db.code().map(|c| c.into_owned()).unwrap_or_default();
            matches!(
                code.get(..2),
                Some("08" | "25" | "40" | "53" | "55" | "57" | "58") | None
            )
        }
        sqlx::Error::Encode(_)
        | sqlx::Error::Decode(_)
        | sqlx::Error::ColumnDecode { .. }
        | sqlx::Error::TypeNotFound { .. }
        | sqlx::Error::ColumnNotFound(_)
        | sqlx::Error::ColumnIndexOutOfBounds { .. }
        | sqlx::Error::RowNotFound => false,
        _ => true,
    }
}

/// Why PostgreSQL's `jsonb` cannot store a JSON value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum JsonbError {
    /// A string value holds U+0000.
    #[error("a string holds U+0000, which jsonb cannot store")]
    NulInString,
    /// An object key holds U+0000.
    #[error("a key holds U+0000, which jsonb cannot store")]
    NulInKey,
}

/// Refuses a JSON value PostgreSQL's `jsonb` cannot store: a string (or key) holding U+0000.
/// (Non-finite numbers cannot occur: `serde_json` has no JSON form for them.)
pub fn jsonb_storable(v: &serde_json::Value) -> Result<(), JsonbError> {
    match v {
        serde_json::Value::String(s) if s.contains('\0') => Err(JsonbError::NulInString),
        serde_json::Value::Array(a) => a.iter().try_for_each(jsonb_storable),
        serde_json::Value::Object(o) => o.iter().try_for_each(|(k, v)| {
            if k.contains('\0') {
                return Err(JsonbError::NulInKey);
            }
            jsonb_storable(v)
        }),
        _ => Ok(()),
    }
}

/// Writes `entries` (consecutive, in order) of session `id` under `epoch`, the epoch the
/// writer's connection took the session at. Idempotent: a row that is already there (written
/// by another connection's writer) is kept as it is. Values the table cannot hold are refused
/// here, before the database, as permanent errors; an epoch that is no longer the session's is
/// refused by the database (`fenced`).
pub async fn append_commands(
    pool: &PgPool,
    id: Uuid,
    epoch: i64,
    entries: &[LogEntry],
) -> Result<(), WriteError> {
    if entries.is_empty() {
        return Ok(());
    }
    let mut seqs = Vec::with_capacity(entries.len());
    let mut times = Vec::with_capacity(entries.len());
    let mut commands = Vec::with_capacity(entries.len());
    for e in entries {
        seqs.push(
            i64::try_from(e.seq)
                .map_err(|_| WriteError::permanent(format!("seq {} out of range", e.seq)))?,
        );
        times.push(
            i64::try_from(e.t_ms)
                .map_err(|_| WriteError::permanent(format!("t_ms {} out of range", e.t_ms)))?,
        );
        let command = serde_json::to_value(&e.command)
            .map_err(|x| WriteError::permanent(format!("command {}: {x}", e.seq)))?;
        jsonb_storable(&command)
            .map_err(|x| WriteError::permanent(format!("command {}: {x}", e.seq)))?;
        commands.push(command);
    }
    sqlx::query(
        "INSERT INTO live_session_commands (session_id, seq, t_ms, command, epoch)
         SELECT $1, s, t, c, $5 FROM UNNEST($2::bigint[], $3::bigint[], $4::jsonb[]) AS u(s, t, c)
         ON CONFLICT (session_id, seq) DO NOTHING",
    )
    .bind(id)
    .bind(seqs)
    .bind(times)
    .bind(commands)
    .bind(epoch)
    .execute(pool)
    .await
    .map_err(|e| {
        let fenced = matches!(&e, sqlx::Error::Database(db) if db.code().as_deref() == Some(FENCED_SQLSTATE));
        WriteError {
            permanent: fenced || !is_transient(&e),
            fenced,
            message: e.to_string(),
        }
    })?;
    Ok(())
}

/// Why the stored log of a session could not be read back.
#[derive(Debug, thiserror::Error)]
pub enum LoadLogError {
    /// The query failed.
    #[error(transparent)]
    Database(#[from] sqlx::Error),
    /// A stored sequence number is negative.
    #[error("stored seq {0}")]
    Seq(i64),
    /// A stored simulation time is negative.
    #[error("stored t_ms {0}")]
    TimeMs(i64),
    /// A stored command no longer parses.
    #[error("stored command {seq}: {source}")]
    Command {
        /// Its sequence number.
        seq: i64,
        /// The parser's error.
        source: serde_json::Error,
    },
}

/// The logged commands of session `id`, in order.
pub async fn load_commands(pool: &PgPool, id: Uuid) -> Result<Vec<LogEntry>, LoadLogError> {
    let rows: Vec<(i64, i64, serde_json::Value)> = sqlx::query_as(
        "SELECT seq, t_ms, command FROM live_session_commands WHERE session_id = $1 ORDER BY seq",
    )
    .bind(id)
    .fetch_all(pool)
    .await?;
    rows.into_iter()
        .map(|(seq, t_ms, command)| {
            Ok(LogEntry {
                seq: u64::try_from(seq).map_err(|_| LoadLogError::Seq(seq))?,
                t_ms: u64::try_from(t_ms).map_err(|_| LoadLogError::TimeMs(t_ms))?,
                command: serde_json::from_value(command)
                    .map_err(|source| LoadLogError::Command { seq, source })?,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_jsonb_cannot_hold_are_refused_anywhere_in_the_command() {
        assert!(jsonb_storable(&serde_json::json!({ "a": [1.5, "x", { "b": null }] })).is_ok());
        for bad in [
            serde_json::json!("a\u{0}b"),
            serde_json::json!({ "label": "L4\u{0}" }),
            serde_json::json!([[{ "deep": ["\u{0}"] }]]),
            serde_json::json!({ "k\u{0}": 1 }),
        ] {
            assert!(jsonb_storable(&bad).is_err(), "{bad}");
        }
        assert_eq!(
            jsonb_storable(&serde_json::json!({ "k\u{0}": "v\u{0}" })),
            Err(JsonbError::NulInKey)
        );
        assert_eq!(
            jsonb_storable(&serde_json::json!(["ok", "v\u{0}"])),
            Err(JsonbError::NulInString)
        );
    }

    #[test]
    fn connection_trouble_is_transient_and_refused_data_is_not() {
        assert!(is_transient(&sqlx::Error::PoolTimedOut));
        assert!(is_transient(&sqlx::Error::Io(std::io::Error::other(
            "reset"
        ))));
        assert!(!is_transient(&sqlx::Error::RowNotFound));
        assert!(!is_transient(&sqlx::Error::Encode("bad".into())));
    }
}
