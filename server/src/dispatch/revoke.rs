//! Revoked accounts lose their live sessions: when the learning records revoke an account
//! (disabled by an admin, or its password reset), every live simulation session of that learner
//! is closed on its worker, which ends an open websocket relay; a reconnect then fails
//! authentication, since the account's login sessions were revoked with it.
//!
//! Every server replica closes its own: a revocation on one replica is announced to all of them
//! through PostgreSQL (`NOTIFY` on [`CHANNEL`]), the state they share.

use tokio::sync::broadcast::{Receiver, error::RecvError};
use uuid::Uuid;

use super::Dispatcher;

/// The PostgreSQL notification channel of revoked accounts (payload: the user id).
pub const CHANNEL: &str = "painsim_account_revoked";

/// Closes the live sessions of every account announced on `revocations` (this replica's), and
/// announces each to the other replicas through PostgreSQL (`super::notices` listens), until
/// the dispatcher is dropped or the records' sender is gone. Does nothing outside a tokio
/// runtime.
pub(super) fn start_listener(mut revocations: Receiver<Uuid>, dispatcher: &Dispatcher) {
    let Ok(rt) = tokio::runtime::Handle::try_current() else {
        return;
    };
    let weak = std::sync::Arc::downgrade(&dispatcher.inner);
    rt.spawn(async move {
        loop {
            let user = match revocations.recv().await {
                Ok(user) => Some(user),
                // Missed announcements cannot be recovered here. Their login sessions are revoked
                // regardless, so a reconnect fails, and idle sessions close on their own.
                Err(RecvError::Lagged(n)) => {
                    tracing::warn!(missed = n, "missed account revocations");
                    None
                }
                Err(RecvError::Closed) => return,
            };
            let Some(inner) = weak.upgrade() else { return };
            let d = Dispatcher { inner };
            let Some(user) = user else { continue };
            if let Some(pool) = d.pool() {
                let notified = sqlx::query("SELECT pg_notify($1, $2)")
                    .bind(CHANNEL)
                    .bind(user.to_string())
                    .execute(&pool)
                    .await;
                if let Err(e) = notified {
                    tracing::error!(user = %user, "announcing a revoked account to the other replicas failed: {e}");
                }
            }
            close_sessions_of(&d, user).await;
        }
    });
}

/// Ends (with [`super::CLOSE_REVOKED`]) and closes every live session of `user` held here.
pub(super) async fn close_sessions_of(d: &Dispatcher, user: Uuid) {
    let sessions: Vec<std::sync::Arc<super::LiveSession>> = d
        .inner
        .sessions
        .lock()
        .map(|m| {
            m.values()
                .filter(|s| s.learner_id == user)
                .cloned()
                .collect()
        })
        .unwrap_or_default();
    for s in sessions {
        tracing::info!(session = %s.id, user = %user, "closing the session of a revoked account");
        // Ended, not just closed: its relay closes the socket with the reason instead of
        // restoring the session on another worker.
        s.end(
            super::CLOSE_REVOKED,
            "the account was disabled or its password reset: log in again",
        );
        d.close(s.id).await;
    }
}
