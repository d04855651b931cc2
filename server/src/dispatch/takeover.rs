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

    /// Takes `s`, held in this replica's memory, over for a new connection when the session's
    /// epoch is still this replica's (one compare-and-bump); otherwise the copy is stale: it is
    /// forgotten (its connections close with 4009, its worker session ends) and `Stale` says
    /// so, without fencing off whoever holds the session now.
    pub(super) async fn claim(&self, s: &Arc<LiveSession>) -> Result<Claim, TakeoverError> {
        let Some(pool) = self.pool() else {
            return Ok(Claim::Held);
        };
        let mut st = s.state.lock().await;
        match store::take_over_from(&pool, s.id, st.epoch).await? {
            Some(epoch) => {
                st.epoch = epoch;
                let record = st.clone();
                drop(st);
                self.record_placement(s.id, &record).await;
                Ok(Claim::Held)
            }
            None => {
                let held = st.epoch;
                drop(st);
                tracing::info!(session = %s.id, held, "the session was taken over elsewhere since: restoring it from the stored log");
                self.forget_taken_over(s.id, held).await;
                Ok(Claim::Stale)
            }
        }
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
    /// else the stored live session loaded from the database, restored on a worker and taken
    /// over ([`Dispatcher::adopt`]).
    pub(super) async fn session_for_connection(
        &self,
        id: Uuid,
        learner: Uuid,
    ) -> Result<Arc<LiveSession>, TakeoverError> {
        if let Some(s) = self.session(id) {
            if s.learner_id != learner {
                return Err(TakeoverError::NotFound);
            }
            if let Claim::Held = self.claim(&s).await? {
                return Ok(s);
            }
        }
        let pool = self.pool().ok_or(TakeoverError::NotFound)?;
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
        self.adopt(&pool, stored, true).await
    }

    /// Restores stored session `s` here, one restore per session at a time: when another
    /// request of this replica restored it meanwhile, that copy (claimed for a connection when
    /// `connecting`).
    pub(super) async fn adopt(
        &self,
        pool: &PgPool,
        s: Stored,
        connecting: bool,
    ) -> Result<Arc<LiveSession>, TakeoverError> {
        let lock = {
            let mut locks = self
                .inner
                .adopting
                .lock()
                .map_err(|_| TakeoverError::NotFound)?;
            locks.retain(|_, l| Arc::strong_count(l) > 1);
            locks.entry(s.id).or_default().clone()
        };
        let _one_at_a_time = lock.lock().await;
        if let Some(held) = self.session(s.id) {
            if !connecting {
                return Ok(held);
            }
            if let Claim::Held = self.claim(&held).await? {
                return Ok(held);
            }
        }
        self.restore_stored(pool, s).await
    }

    /// Restores a stored session on a worker by least load from its initial snapshot and
    /// durable log, then takes it over (its epoch bumped): a restore that fails fences off
    /// nobody. When the holder appended between the read and the bump (it cannot any more), the
    /// session is restored again from the final log. This replica then holds it, and the other
    /// replicas are told (a stale copy there is forgotten at once).
    async fn restore_stored(
        &self,
        pool: &PgPool,
        s: Stored,
    ) -> Result<Arc<LiveSession>, TakeoverError> {
        let started = std::time::Instant::now();
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
            epoch: 0,
        };
        record.placement = self.restore_anywhere(&record).await?;
        let taken = store::take_over(pool, s.id).await;
        let epoch = match taken {
            Ok(Some((_, epoch))) => epoch,
            Ok(None) | Err(_) => {
                self.end_in_background(record.placement.clone());
                return Err(match taken {
                    Err(e) => TakeoverError::Database(e),
                    _ => TakeoverError::NotFound,
                });
            }
        };
        record.epoch = epoch;
        let (logged, _) = store::log_extent(pool, s.id).await?;
        if usize::try_from(logged).ok() != Some(record.log.len()) {
            self.end_in_background(record.placement.clone());
            record.log = store::load_commands(pool, s.id).await?;
            record.durable_len = record.log.len();
            record.placement = self.restore_anywhere(&record).await?;
        }
        tracing::info!(session = %s.id, epoch, log = record.log.len(), worker = %record.placement.worker_label(),
            took_ms = started.elapsed().as_millis() as u64, "session taken over from the stored log");
        let session = Arc::new(LiveSession::new(
            s.id,
            s.attempt_id,
            s.course_id,
            s.learner_id,
            s.station_id,
            record.clone(),
        ));
        self.insert(session.clone());
        self.record_placement(s.id, &record).await;
        super::cluster::announce_takeover(pool, s.id).await;
        Ok(session)
    }

    /// Ends a worker session without waiting (a dead worker's request can take its timeout).
    fn end_in_background(&self, placement: Placement) {
        let me = self.clone();
        tokio::spawn(async move { me.end_on_worker(placement).await });
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
    /// epoch this replica still holds, or a claim found it stale): its connections here close
    /// with 4009, its worker session ends; the placement row is the new holder's. Nothing
    /// happens when this replica claimed it again since (the fenced writer was an older
    /// connection's).
    pub(super) async fn forget_taken_over(&self, id: Uuid, fenced_at: i64) {
        let Some(s) = self.session(id) else {
            return;
        };
        let placement = {
            // Under the state lock, so that no claim runs between the check and the removal.
            let st = s.state.lock().await;
            if st.epoch != fenced_at || !self.take_exact(&s) {
                return;
            }
            st.placement.clone()
        };
        // Its connections here close with the reason instead of restoring it elsewhere.
        s.end(
            super::CLOSE_TAKEN_OVER,
            "the session was opened in another connection",
        );
        self.end_on_worker(placement).await;
    }
}

/// What a claim found.
pub(super) enum Claim {
    /// This replica holds the session at the new epoch.
    Held,
    /// Another replica took it over since; this replica's copy was forgotten.
    Stale,
}
