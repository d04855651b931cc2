//! What one server replica tells the others through PostgreSQL (`LISTEN`/`NOTIFY`, the only
//! state they share): an account revoked there ([`super::revoke::CHANNEL`]: close its sessions
//! here too) and a session taken over there ([`super::cluster::TAKEOVER_CHANNEL`]: a copy held
//! here is stale, forget it at once so its worker slot is freed).

use std::sync::Weak;
use std::time::Duration;

use uuid::Uuid;

use super::Dispatcher;
use super::dispatcher::Inner;

/// How long a replica waits before listening again after its listening connection failed.
/// Simulator choice: a database restart takes seconds; login sessions are revoked in the
/// database regardless (a reconnect fails meanwhile), and a stale copy is also found by its
/// fenced writes and by the reaper.
const RELISTEN_AFTER: Duration = Duration::from_secs(1);

/// How often a listener with nothing to hear checks that its dispatcher still exists.
const ALIVE_CHECK: Duration = Duration::from_secs(5);

/// Listens (with a database attached and a tokio runtime) until the dispatcher is dropped.
pub(super) fn start(dispatcher: &Dispatcher) {
    let (Ok(rt), Some(pool)) = (tokio::runtime::Handle::try_current(), dispatcher.pool()) else {
        return;
    };
    rt.spawn(listen(pool, std::sync::Arc::downgrade(&dispatcher.inner)));
}

async fn listen(pool: sqlx::PgPool, weak: Weak<Inner>) {
    while weak.strong_count() > 0 {
        let listener = async {
            let mut l = sqlx::postgres::PgListener::connect_with(&pool).await?;
            l.listen_all([super::revoke::CHANNEL, super::cluster::TAKEOVER_CHANNEL])
                .await?;
            Ok::<_, sqlx::Error>(l)
        };
        let mut listener = match listener.await {
            Ok(l) => l,
            Err(sqlx::Error::PoolClosed) => return,
            Err(e) => {
                tracing::warn!("cannot listen to the other replicas: {e}");
                tokio::time::sleep(RELISTEN_AFTER).await;
                continue;
            }
        };
        loop {
            let note = tokio::select! {
                n = listener.recv() => n,
                () = tokio::time::sleep(ALIVE_CHECK) => {
                    if weak.strong_count() == 0 {
                        return;
                    }
                    continue;
                }
            };
            let note = match note {
                Ok(n) => n,
                Err(e) => {
                    tracing::warn!("listening to the other replicas failed: {e}");
                    break;
                }
            };
            let Some(inner) = weak.upgrade() else { return };
            let d = Dispatcher { inner };
            let Ok(id) = note.payload().parse::<Uuid>() else {
                continue;
            };
            if note.channel() == super::revoke::CHANNEL {
                super::revoke::close_sessions_of(&d, id).await;
            } else if let Some(s) = d.session(id)
                && let Err(e) = d.unless_stale(s).await
            {
                tracing::warn!(session = %id, "checking a copy after a takeover elsewhere failed: {e}");
            }
        }
        tokio::time::sleep(RELISTEN_AFTER).await;
    }
}
