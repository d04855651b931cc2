//! TEMP placeholder of the durable outbox, with exactly the shared plan's API, so that the LTI
//! grade passback can be built and tested before the outbox helper's module lands on main. The
//! real module replaces this file (and `migrations/0804_outbox.sql`) at merge.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures::future::BoxFuture;
use serde_json::Value;
use sqlx::PgPool;
use tokio::sync::Notify;

/// Enqueues one item in the caller's transaction; (kind, key) is unique: a second enqueue of the
/// same key does nothing (idempotent producers).
pub async fn enqueue(
    conn: &mut sqlx::PgConnection,
    kind: &str,
    key: &str,
    payload: Value,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO outbox_items (kind, key, payload) VALUES ($1, $2, $3)
         ON CONFLICT (kind, key) DO NOTHING",
    )
    .bind(kind)
    .bind(key)
    .bind(payload)
    .execute(conn)
    .await?;
    Ok(())
}

/// Why a delivery failed.
#[derive(Debug)]
pub enum DeliveryError {
    /// Try again later.
    Retry(String),
    /// Never try again.
    Permanent(String),
}

/// A receiver of one kind of item.
pub trait Deliver: Send + Sync + 'static {
    /// The kind it delivers.
    fn kind(&self) -> &'static str;
    /// Items per delivery call.
    fn batch_size(&self) -> usize {
        1
    }
    /// Delivers the items (all or none).
    fn deliver<'a>(&'a self, items: &'a [Value]) -> BoxFuture<'a, Result<(), DeliveryError>>;
}

/// The delivery loop's handle. Cheap to clone.
#[derive(Clone)]
pub struct Outbox {
    pool: PgPool,
    deliverers: Arc<Mutex<HashMap<&'static str, Arc<dyn Deliver>>>>,
    wake: Arc<Notify>,
}

/// The backlog of one kind.
#[derive(Debug, Clone, serde::Serialize)]
pub struct KindStatus {
    /// Kind.
    pub kind: String,
    /// Items not delivered yet.
    pub pending: i64,
    /// Delivered items.
    pub delivered: i64,
    /// The last error, if any.
    pub last_error: Option<String>,
}

impl Outbox {
    /// A loop over `pool`'s outbox.
    pub fn new(pool: PgPool) -> Outbox {
        Outbox {
            pool,
            deliverers: Arc::default(),
            wake: Arc::new(Notify::new()),
        }
    }

    /// Adds the deliverer of a kind.
    pub fn register(&self, d: Arc<dyn Deliver>) {
        self.deliverers
            .lock()
            .expect("outbox lock")
            .insert(d.kind(), d);
    }

    /// Looks for work now.
    pub fn wake(&self) {
        self.wake.notify_one();
    }

    /// Runs the delivery loop until `shutdown` completes.
    pub fn spawn(
        &self,
        shutdown: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> tokio::task::JoinHandle<()> {
        let me = self.clone();
        tokio::spawn(async move {
            tokio::pin!(shutdown);
            loop {
                let worked = me.round().await.unwrap_or_else(|e| {
                    tracing::warn!(error = %e, "outbox round failed");
                    false
                });
                if worked {
                    continue;
                }
                tokio::select! {
                    () = &mut shutdown => return,
                    () = me.wake.notified() => {}
                    () = tokio::time::sleep(Duration::from_millis(200)) => {}
                }
            }
        })
    }

    async fn round(&self) -> Result<bool, sqlx::Error> {
        let row: Option<(i64, String, Value, i32)> = sqlx::query_as(
            "SELECT id, kind, payload, attempts FROM outbox_items
             WHERE delivered_at IS NULL AND failed_at IS NULL AND next_attempt_at <= now()
             ORDER BY id LIMIT 1",
        )
        .fetch_optional(&self.pool)
        .await?;
        let Some((id, kind, payload, attempts)) = row else {
            return Ok(false);
        };
        let d = self
            .deliverers
            .lock()
            .expect("outbox lock")
            .get(kind.as_str())
            .cloned();
        let Some(d) = d else {
            sqlx::query("UPDATE outbox_items SET next_attempt_at = now() + interval '1 second' WHERE id = $1")
                .bind(id)
                .execute(&self.pool)
                .await?;
            return Ok(false);
        };
        match d.deliver(std::slice::from_ref(&payload)).await {
            Ok(()) => {
                sqlx::query(
                    "UPDATE outbox_items SET delivered_at = now(), last_error = NULL WHERE id = $1",
                )
                .bind(id)
                .execute(&self.pool)
                .await?;
            }
            Err(DeliveryError::Retry(e)) => {
                let backoff_s = (0.1 * 2f64.powi(attempts.min(8))).min(30.0);
                sqlx::query(
                    "UPDATE outbox_items SET attempts = attempts + 1, last_error = $2,
                     next_attempt_at = now() + make_interval(secs => $3) WHERE id = $1",
                )
                .bind(id)
                .bind(e)
                .bind(backoff_s)
                .execute(&self.pool)
                .await?;
            }
            Err(DeliveryError::Permanent(e)) => {
                sqlx::query(
                    "UPDATE outbox_items SET failed_at = now(), last_error = $2 WHERE id = $1",
                )
                .bind(id)
                .bind(e)
                .execute(&self.pool)
                .await?;
            }
        }
        Ok(true)
    }
}

/// The backlog of every kind.
pub async fn status(pool: &PgPool) -> Result<Vec<KindStatus>, sqlx::Error> {
    let rows: Vec<(String, i64, i64, Option<String>)> = sqlx::query_as(
        "SELECT kind, count(*) FILTER (WHERE delivered_at IS NULL),
                count(*) FILTER (WHERE delivered_at IS NOT NULL),
                (array_agg(last_error ORDER BY id DESC) FILTER (WHERE last_error IS NOT NULL))[1]
         FROM outbox_items GROUP BY kind ORDER BY kind",
    )
    .fetch_all(pool)
    .await?;
    Ok(rows
        .into_iter()
        .map(|(kind, pending, delivered, last_error)| KindStatus {
            kind,
            pending,
            delivered,
            last_error,
        })
        .collect())
}
