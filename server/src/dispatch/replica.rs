//! This replica in the shared state: its name, its database, and the placement rows it writes
//! for the sessions it holds (see [`super::cluster`] for the statements).

use uuid::Uuid;

use super::{Dispatcher, Placement, SessionRecord};

impl Dispatcher {
    /// The live sessions this replica holds, for its sweep (a placement only where the state
    /// is not locked by a request at the moment).
    pub(super) fn held(&self) -> Vec<super::cluster::Held> {
        self.all_sessions()
            .iter()
            .map(|s| {
                let row = s.state.try_lock().ok().map(|st| {
                    let (url, worker_session) = match &st.placement {
                        Placement::Local { worker_session } => (None, worker_session.clone()),
                        Placement::Remote {
                            worker_url,
                            worker_session,
                        } => (Some(worker_url.clone()), worker_session.clone()),
                    };
                    (st.epoch, url, worker_session)
                });
                (s.id, row)
            })
            .collect()
    }

    /// The database of the shared state, once attached.
    pub(super) fn pool(&self) -> Option<sqlx::PgPool> {
        self.records().map(|r| r.pool)
    }

    /// This replica's name in the shared state.
    pub fn replica(&self) -> String {
        self.inner
            .replica
            .lock()
            .map(|r| r.clone())
            .unwrap_or_default()
    }

    /// Names this replica (`PAINSIM_REPLICA_ID`); call before the routes are built.
    pub fn set_replica(&self, id: &str) {
        if let Ok(mut r) = self.inner.replica.lock() {
            *r = id.to_string();
        }
    }

    /// Records where `session` runs now (at `record`'s epoch), for every replica to see.
    pub(super) async fn record_placement(&self, session: Uuid, record: &SessionRecord) {
        let Some(pool) = self.pool() else {
            return;
        };
        let replica = self.replica();
        let (worker_url, worker_session) = match &record.placement {
            Placement::Local { worker_session } => (None, worker_session.as_str()),
            Placement::Remote {
                worker_url,
                worker_session,
            } => (Some(worker_url.as_str()), worker_session.as_str()),
        };
        let row = super::cluster::PlacementRow {
            session,
            epoch: record.epoch,
            replica: &replica,
            worker_url,
            worker_session,
        };
        if let Err(e) = super::cluster::place(&pool, &row).await {
            tracing::error!(session = %session, "recording the session's placement failed: {e}");
        }
    }
}
