//! The durable half of the server's copy of a session: every acknowledged command is a row of
//! `live_session_commands` (through [`super::store`]), written before its acknowledgement
//! reaches the browser.
//!
//! # The rule
//! The relay passes no text message (acknowledgement, error, hello, notice, result) to the
//! browser until every command logged in memory before it was committed to the database. So a
//! browser never holds an acknowledgement that a restarted server has forgotten: if the server
//! process dies, whatever the browser saw acknowledged is in the table, and whatever it did not
//! see acknowledged it sends again after reconnecting (`web-client/session.js` re-sends
//! unacknowledged commands; the resumed session acknowledges a sequence number it already has
//! as a duplicate). Frames are not held back: they only show state, and losing the state they
//! show loses no input the browser considers delivered.
//!
//! # Group commit
//! One [`LogWriter`] task per browser connection writes what the in-memory log holds beyond
//! the session's durable length, in one `INSERT ... UNNEST` per round: commands acknowledged
//! while a write is in flight go together in the next one, so a fast stream of commands costs
//! one commit per round trip, not one per command. The relay never blocks on the write except
//! at submit, where the stored result must follow its logged command.
//!
//! # Writes that can never succeed
//! A transient failure (the connection, a restarting database) is retried with back-off for as
//! long as the connection is open. A permanent one (the database refuses the data itself; see
//! [`store::is_transient`]) is not: retrying would hold every later acknowledgement back for
//! ever. The writer stops and keeps the reason ([`LogWriter::failure`]); the relay then ends the
//! session with a close code and an audit entry and frees its worker slot. Nothing of the
//! refused write was acknowledged to the browser, and the session resumes from what is durable.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use sqlx::PgPool;
use tokio::sync::{mpsc, watch};

use super::LiveSession;
use super::store;

/// First wait after a failed write; doubled on each failure up to [`RETRY_MAX`]. Simulator
/// choice: a database restart or failover takes seconds, and the relay meanwhile only holds
/// acknowledgements back.
const RETRY_FIRST: Duration = Duration::from_millis(50);
/// Longest wait between retries.
const RETRY_MAX: Duration = Duration::from_secs(2);
/// Attempts left to flush the log once the connection ended; what is still not written then
/// stays in memory and is written by the session's next connection (or lost with the process,
/// but none of it was acknowledged to the browser).
const FINAL_ATTEMPTS: u32 = 5;

/// Why a writer stopped for good.
#[derive(Debug, Clone)]
pub struct Failure {
    /// In words.
    pub message: String,
    /// Set when the database refused the epoch the writer held (another connection, perhaps on
    /// another replica, took the session over): that epoch.
    pub fenced_at: Option<i64>,
}

/// The writer task of one browser connection.
pub struct LogWriter {
    kick: mpsc::Sender<()>,
    /// How many log entries of the session are known to be in the database.
    pub durable: watch::Receiver<usize>,
    /// Why the writer stopped for good (a permanent write error), once it did.
    failure: Arc<Mutex<Option<Failure>>>,
    task: tokio::task::JoinHandle<()>,
}

impl LogWriter {
    /// Starts the writer of `session` (it first writes anything an earlier connection left).
    pub fn start(pool: PgPool, session: Arc<LiveSession>, durable_now: usize) -> LogWriter {
        let (kick, mut kicks) = mpsc::channel::<()>(1);
        let (durable_tx, durable) = watch::channel(durable_now);
        let failure = Arc::new(Mutex::new(None));
        let failed = failure.clone();
        let task = tokio::spawn(async move {
            let stop = |reason: Failure| {
                if let Ok(mut f) = failed.lock() {
                    *f = Some(reason);
                }
            };
            loop {
                if let Err(reason) = flush(&pool, &session, &durable_tx).await {
                    return stop(reason);
                }
                if durable_tx.is_closed() || kicks.recv().await.is_none() {
                    // The connection ended: one last flush of what it pushed last.
                    if let Err(reason) = flush(&pool, &session, &durable_tx).await {
                        stop(reason);
                    }
                    return;
                }
            }
        });
        let w = LogWriter {
            kick,
            durable,
            failure,
            task,
        };
        w.kick();
        w
    }

    /// Asks for a write of whatever is new (never waits; a pending request covers later pushes).
    pub fn kick(&self) {
        let _ = self.kick.try_send(());
    }

    /// The durable length now.
    pub fn durable_len(&self) -> usize {
        *self.durable.borrow()
    }

    /// Waits until at least `len` entries are durable (false if the writer stopped first).
    pub async fn wait_durable(&mut self, len: usize) -> bool {
        self.kick();
        self.durable.wait_for(|d| *d >= len).await.is_ok()
    }

    /// Why the writer stopped for good: a write the database can never accept.
    pub fn failure(&self) -> Option<Failure> {
        self.failure.lock().ok().and_then(|f| f.clone())
    }

    /// Ends the writer after a last flush (a few attempts at most).
    pub async fn finish(self) {
        let LogWriter {
            kick,
            durable,
            task,
            ..
        } = self;
        drop((kick, durable));
        let _ = task.await;
    }
}

/// Writes the log beyond the session's durable length until nothing is left (retrying with
/// back-off while the connection is open, at most [`FINAL_ATTEMPTS`] times once it ended), under
/// the epoch the session is held at. Err with the reason when a write can never succeed.
async fn flush(
    pool: &PgPool,
    session: &LiveSession,
    durable_tx: &watch::Sender<usize>,
) -> Result<(), Failure> {
    let mut wait = RETRY_FIRST;
    let mut failures = 0u32;
    loop {
        let (from, batch, epoch) = {
            let st = session.state.lock().await;
            let from = st.durable_len.min(st.log.len());
            (from, st.log[from..].to_vec(), st.epoch)
        };
        if batch.is_empty() {
            return Ok(());
        }
        match store::append_commands(pool, session.id, epoch, &batch).await {
            Ok(()) => {
                let mut st = session.state.lock().await;
                st.durable_len = st.durable_len.max(from + batch.len());
                let now = st.durable_len;
                drop(st);
                durable_tx.send_replace(now);
                wait = RETRY_FIRST;
                failures = 0;
            }
            Err(e) if e.fenced => {
                // A connection of this replica that took the session over since holds a newer
                // epoch: write under it. Otherwise another replica holds the session now.
                if session.state.lock().await.epoch != epoch {
                    continue;
                }
                tracing::warn!(session = %session.id, epoch, "another connection took the session over; this copy stops writing");
                return Err(Failure {
                    message: e.message,
                    fenced_at: Some(epoch),
                });
            }
            Err(e) if e.permanent => {
                tracing::error!(session = %session.id, entries = batch.len(), "the database refuses the session's commands; the session ends: {e}");
                return Err(Failure {
                    message: e.message,
                    fenced_at: None,
                });
            }
            Err(e) => {
                failures += 1;
                tracing::error!(session = %session.id, entries = batch.len(), failures, "writing acknowledged commands failed: {e}");
                if durable_tx.is_closed() && failures >= FINAL_ATTEMPTS {
                    return Ok(());
                }
                tokio::time::sleep(wait).await;
                wait = (wait * 2).min(RETRY_MAX);
            }
        }
    }
}
