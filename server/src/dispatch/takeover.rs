//! Taking a session over: any replica relays any session.
//!
//! Every browser connection takes its session over by bumping the session's epoch in the
//! database ([`store::take_over`]); the log is appended under the epoch its writer holds, and
//! the database refuses an older one, so a replica that lost a session can never append again.
//!
//! - A session this replica holds, and whose epoch nobody bumped since this replica's last
//!   takeover, keeps its worker session (the fast path of a reconnect to the same replica).
//! - A session this replica does not hold, or holds at an epoch that another replica bumped
//!   since (its copy is stale), is loaded from the database and always restored on a worker from
//!   its initial snapshot and its durable log: the worker that ran it may be ahead of the
//!   durable log by commands no browser saw acknowledged, which the browser sends again.

use std::sync::Arc;

use sqlx::PgPool;
use uuid::Uuid;

use super::{Dispatcher, LiveSession, Placement, RestoreError, SessionRecord, store};

/// Why a session could not be taken over.
#[derive(Debug, thiserror::Error)]
pub enum TakeoverError {
    /// No such live session (or not the caller's, or submitted).
    #[error("no such live session")]
    NotFound,
    /// The shared state could not be read or written.
    #[error(transparent)]
    Database(#[from] sqlx::Error),
    /// The stored log no longer parses.
    #[error("stored log: {0}")]
    Log(#[from] store::LoadLogError),
    /// The stored initial snapshot no longer parses.
    #[error("stored snapshot: {0}")]
    Snapshot(#[from] serde_json::Error),
    /// No worker could restore it.
    #[error(transparent)]
    Restore(#[from] RestoreError),
}

/// A stored session to restore: the id and what its row holds.
pub struct Stored {
    /// Session id.
    pub id: Uuid,
    /// Its attempt.
    pub attempt_id: Uuid,
    /// The attempt's course.
    pub course_id: Uuid,
    /// Its learner.
    pub learner_id: Uuid,
    /// Its station.
    pub station_id: String,
    /// The initial snapshot as stored.
    pub initial: serde_json::Value,
}

impl Dispatcher {
    /// The shared state in numbers (`/healthz`); an error without a database attached.
    pub async fn cluster_status(&self) -> Result<super::ClusterStatus, sqlx::Error> {
        let pool = self.pool().ok_or(sqlx::Error::PoolClosed)?;
        super::cluster::status(&pool, &self.replica()).await
    }

    /// Takes `s`, held in this replica's memory, over for a new connection: the fast path when
    /// the epoch is still this replica's, else the stale copy is reloaded from the database
    /// and restored on a worker (its old worker session is ended in the background).
    pub(super) async fn claim(&self, s: &LiveSession) -> Result<(), TakeoverError> {
        let Some(pool) = self.pool() else {
            return Ok(());
        };
        let mut st = s.state.lock().await;
        let (previous, epoch) = store::take_over(&pool, s.id)
            .await?
            .ok_or(TakeoverError::NotFound)?;
        if previous != st.epoch {
            tracing::info!(session = %s.id, held = st.epoch, now = epoch,
                "the session was taken over elsewhere since: restoring it from the stored log");
            let stale = st.placement.clone();
            st.log = store::load_commands(&pool, s.id).await?;
            st.durable_len = st.log.len();
            st.epoch = epoch;
            st.placement = self.restore_anywhere(&st).await?;
            let me = self.clone();
            tokio::spawn(async move { me.end_on_worker(stale).await });
        } else {
            st.epoch = epoch;
        }
        let record = st.clone();
        drop(st);
        self.record_placement(s.id, &record).await;
        Ok(())
    }

    /// Live, unsubmitted sessions of `user` and of `course` in the whole deployment, leaving out
    /// `attempt`'s; `None` when the shared state cannot be read (the caller counts its own).
    pub(super) async fn live_sessions_elsewhere(
        &self,
        user: Uuid,
        course: Uuid,
        attempt: Uuid,
    ) -> Option<(usize, usize)> {
        let pool = self.pool()?;
        match super::cluster::live_sessions_of(&pool, user, course, attempt).await {
            Ok((u, c)) => Some((u.max(0) as usize, c.max(0) as usize)),
            Err(e) => {
                tracing::error!("counting live sessions in the shared state failed: {e}");
                None
            }
        }
    }

    /// Whether `learner` may connect to session `id`: a live session of theirs, held here or
    /// stored and not submitted.
    pub(super) async fn may_connect(&self, id: Uuid, learner: Uuid) -> Result<bool, sqlx::Error> {
        if let Some(s) = self.session(id) {
            return Ok(s.learner_id == learner);
        }
        let Some(pool) = self.pool() else {
            return Ok(false);
        };
        Ok(store::stored_session(&pool, id)
            .await?
            .is_some_and(|(_, l, _, _, _, result)| l == learner && result.is_none()))
    }

    /// Session `id` for a new connection of `learner`: the one this replica holds (claimed),
    /// else the stored live session loaded from the database, taken over and restored on a
    /// worker ([`Dispatcher::restore_stored`]).
    pub(super) async fn session_for_connection(
        &self,
        id: Uuid,
        learner: Uuid,
    ) -> Result<Arc<LiveSession>, TakeoverError> {
        if let Some(s) = self.session(id) {
            if s.learner_id != learner {
                return Err(TakeoverError::NotFound);
            }
            self.claim(&s).await?;
            return Ok(s);
        }
        let pool = self.pool().ok_or(TakeoverError::NotFound)?;
        let lock = {
            let mut locks = self
                .inner
                .adopting
                .lock()
                .map_err(|_| TakeoverError::NotFound)?;
            locks.retain(|_, l| Arc::strong_count(l) > 1);
            locks.entry(id).or_default().clone()
        };
        let one_at_a_time = lock.lock().await;
        if let Some(s) = self.session(id) {
            drop(one_at_a_time);
            if s.learner_id != learner {
                return Err(TakeoverError::NotFound);
            }
            self.claim(&s).await?;
            return Ok(s);
        }
        let (attempt_id, learner_id, course_id, station_id, initial, result) =
            store::stored_session(&pool, id)
                .await?
                .ok_or(TakeoverError::NotFound)?;
        if learner_id != learner || result.is_some() {
            return Err(TakeoverError::NotFound);
        }
        let stored = Stored {
            id,
            attempt_id,
            course_id,
            learner_id,
            station_id,
            initial,
        };
        self.restore_stored(&pool, stored).await
    }

    /// Takes a stored session over (its epoch bumped), loads its durable log and restores it on
    /// a worker by least load; this replica then holds it.
    pub(super) async fn restore_stored(
        &self,
        pool: &PgPool,
        s: Stored,
    ) -> Result<Arc<LiveSession>, TakeoverError> {
        let started = std::time::Instant::now();
        let (_, epoch) = store::take_over(pool, s.id)
            .await?
            .ok_or(TakeoverError::NotFound)?;
        let initial = serde_json::from_value(s.initial)?;
        let log = store::load_commands(pool, s.id).await?;
        let mut record = SessionRecord {
            placement: Placement::Local {
                worker_session: String::new(),
            },
            initial,
            durable_len: log.len(),
            log,
            last_frame_sha256: None,
            result_id: None,
            failovers: 0,
            epoch,
        };
        record.placement = self.restore_anywhere(&record).await?;
        tracing::info!(session = %s.id, epoch, log = record.log.len(), worker = %record.placement.worker_label(),
            took_ms = started.elapsed().as_millis() as u64, "session taken over from the stored log");
        self.record_placement(s.id, &record).await;
        let session = Arc::new(LiveSession::new(
            s.id,
            s.attempt_id,
            s.course_id,
            s.learner_id,
            s.station_id,
            record,
        ));
        self.insert(session.clone());
        Ok(session)
    }

    /// The live session of `attempt` that this replica holds, unless another connection took it
    /// over since (then this replica's stale copy is forgotten and ended on its worker).
    pub(super) async fn current_session_of_attempt(
        &self,
        attempt: Uuid,
    ) -> Result<Option<Arc<LiveSession>>, sqlx::Error> {
        let Some(s) = self.session_of_attempt(attempt).await else {
            return Ok(None);
        };
        self.unless_stale(s).await
    }

    /// `s`, unless the shared state holds it at a newer epoch than this replica (then the stale
    /// copy is forgotten and ended on its worker).
    pub(super) async fn unless_stale(
        &self,
        s: Arc<LiveSession>,
    ) -> Result<Option<Arc<LiveSession>>, sqlx::Error> {
        let Some(pool) = self.pool() else {
            return Ok(Some(s));
        };
        let held = s.state.lock().await.epoch;
        if store::epoch_of(&pool, s.id).await? == Some(held) {
            return Ok(Some(s));
        }
        self.forget_taken_over(s.id, held).await;
        Ok(None)
    }

    /// Forgets a session that another replica took over (its log writer was fenced off at the
    /// epoch this replica still holds): ends it on its worker; the placement row is the new
    /// holder's.
    pub(super) async fn forget_taken_over(&self, id: Uuid, fenced_at: i64) {
        let Some(s) = self.session(id) else {
            return;
        };
        if s.state.lock().await.epoch != fenced_at {
            return; // Claimed again since: the fenced writer was an older connection's.
        }
        if let Some(s) = self.take(id) {
            // Its connections here close with the reason instead of restoring it elsewhere.
            s.end(
                super::CLOSE_TAKEN_OVER,
                "the session was opened in another connection",
            );
            let placement = s.state.lock().await.placement.clone();
            self.end_on_worker(placement).await;
        }
    }
}
