//! The durable outbox: deliveries to the outside world (xAPI statements to an institution's LRS,
//! LTI grade passback) that must happen at least once, whatever crashes in between.
//!
//! A producer calls [`enqueue`] in the transaction that records the cause (a statement, a score),
//! so an item exists exactly when its cause was committed. [`Outbox`] workers (one per registered
//! [`Deliver`] kind, in every server process on the database) claim due items with
//! `FOR UPDATE SKIP LOCKED` for a lease, deliver them outside any transaction, and then mark them
//! delivered, or schedule a retry with exponential backoff and jitter, or record a permanent
//! failure. The rows are the truth (table `outbox`, migration 0804): a restart resumes from them; a
//! worker that dies mid-delivery leaves its lease to expire and the item is delivered again, so
//! receivers must be idempotent by the item's key.
//!
//! A commit that enqueued items wakes the workers at once (a trigger sends `NOTIFY outbox`, which
//! PostgreSQL delivers at commit); [`Outbox::wake`] does the same from inside the process, and the
//! workers also poll, so a lost notification only delays an item by [`Timing::poll`].

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use futures::future::BoxFuture;
use rand::Rng;
use serde::{Deserialize, Serialize};
use sqlx::PgPool;
use time::OffsetDateTime;
use tokio::sync::watch;
use tokio::task::JoinHandle;
use utoipa::ToSchema;

/// Enqueues one item in the caller's transaction; (kind, key) is unique: a second enqueue of the
/// same key does nothing (idempotent producers).
pub async fn enqueue(
    conn: &mut sqlx::PgConnection,
    kind: &str,
    key: &str,
    payload: serde_json::Value,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO outbox (kind, key, payload) VALUES ($1, $2, $3) ON CONFLICT (kind, key) DO NOTHING",
    )
    .bind(kind)
    .bind(key)
    .bind(payload)
    .execute(conn)
    .await?;
    Ok(())
}

/// Why a delivery failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeliveryError {
    /// Try again later (network down, receiver busy or failing, not configured yet).
    #[error("retry: {0}")]
    Retry(String),
    /// Never try these items again (the receiver rejects them as they are).
    #[error("permanent: {0}")]
    Permanent(String),
}

/// A deliverer of one kind of item.
pub trait Deliver: Send + Sync + 'static {
    /// The kind it delivers (as given to [`enqueue`]).
    fn kind(&self) -> &'static str;
    /// Items per delivery call (1 for AGS scores; more for xAPI batches).
    fn batch_size(&self) -> usize {
        1
    }
    /// Delivers `items` (payloads, oldest first). `Ok` means every one of them arrived.
    fn deliver<'a>(
        &'a self,
        items: &'a [serde_json::Value],
    ) -> BoxFuture<'a, Result<(), DeliveryError>>;
}

/// The outbox's clock: backoff, lease and polling.
#[derive(Debug, Clone, Copy)]
pub struct Timing {
    /// Delay before the first retry; doubled at each further attempt (our choice: 1 s).
    pub backoff_base: Duration,
    /// Longest delay between attempts (our choice: 5 min, so a receiver back from an outage is
    /// caught up within minutes).
    pub backoff_max: Duration,
    /// Longest a delivery call may take before it counts as a retryable failure (our choice:
    /// 30 s, a generous HTTP round trip for a batch).
    pub delivery_timeout: Duration,
    /// How long a claim holds items: longer than `delivery_timeout`, so a live worker's items are
    /// never claimed by another one; after a crash its items are delivered again once it expires
    /// (our choice: 45 s).
    pub lease: Duration,
    /// Longest a worker sleeps without looking for due items (our choice: 2 s; notifications
    /// normally wake it sooner).
    pub poll: Duration,
}

impl Default for Timing {
    fn default() -> Timing {
        Timing {
            backoff_base: Duration::from_secs(1),
            backoff_max: Duration::from_secs(300),
            delivery_timeout: Duration::from_secs(30),
            lease: Duration::from_secs(45),
            poll: Duration::from_secs(2),
        }
    }
}

impl Timing {
    /// The delay before attempt `attempts + 1` after `attempts` failed ones: exponential,
    /// capped, with "equal jitter" (uniform in the upper half), so receivers coming back from an
    /// outage are not hit by every sender at the same instant.
    pub fn backoff(&self, attempts: i32) -> Duration {
        let exp = u32::try_from(attempts.saturating_sub(1).clamp(0, 30)).unwrap_or(30);
        let full = self
            .backoff_base
            .saturating_mul(2u32.saturating_pow(exp))
            .min(self.backoff_max);
        let half = full / 2;
        half + full
            .saturating_sub(half)
            .mul_f64(rand::rng().random::<f64>())
    }
}

/// The outbox workers of this process. Cheap to clone.
#[derive(Clone)]
pub struct Outbox {
    inner: Arc<Inner>,
}

struct Inner {
    pool: PgPool,
    timing: Timing,
    deliverers: Mutex<Vec<Arc<dyn Deliver>>>,
    wake: watch::Sender<u64>,
    /// Times this process's workers looked for due items (see [`Outbox::claim_passes`]).
    passes: AtomicU64,
}

impl Outbox {
    /// An outbox on `pool` with the default [`Timing`] and no deliverers yet.
    pub fn new(pool: PgPool) -> Outbox {
        Outbox::with_timing(pool, Timing::default())
    }

    /// An outbox with its own timing (tests use short backoffs and leases).
    pub fn with_timing(pool: PgPool, timing: Timing) -> Outbox {
        Outbox {
            inner: Arc::new(Inner {
                pool,
                timing,
                deliverers: Mutex::new(Vec::new()),
                wake: watch::channel(0).0,
                passes: AtomicU64::new(0),
            }),
        }
    }

    /// Registers the deliverer of one kind; call before [`Outbox::spawn`].
    pub fn register(&self, deliverer: Arc<dyn Deliver>) {
        self.inner
            .deliverers
            .lock()
            .expect("outbox deliverers")
            .push(deliverer);
    }

    /// How many times this process's workers have looked for due items. An idle outbox looks
    /// about once per [`Timing::poll`] and per wake, not continuously.
    pub fn claim_passes(&self) -> u64 {
        self.inner.passes.load(Ordering::Relaxed)
    }

    /// Wakes every worker to look for due items now (e.g. after a commit that enqueued some, or
    /// after a deliverer's settings changed).
    pub fn wake(&self) {
        self.inner.wake.send_modify(|n| *n = n.wrapping_add(1));
    }

    /// Starts one worker per registered kind and the listener of `NOTIFY outbox`; they stop when
    /// `shutdown` completes (a delivery in flight is abandoned: its lease expires and it is
    /// delivered again later). The handle ends when all of them have stopped.
    pub fn spawn(
        &self,
        shutdown: impl std::future::Future<Output = ()> + Send + 'static,
    ) -> JoinHandle<()> {
        let (stop_tx, stop_rx) = watch::channel(false);
        let mut tasks = Vec::new();
        let deliverers = self
            .inner
            .deliverers
            .lock()
            .expect("outbox deliverers")
            .clone();
        for d in deliverers {
            tasks.push(tokio::spawn(worker(self.clone(), d, stop_rx.clone())));
        }
        tasks.push(tokio::spawn(listener(self.clone(), stop_rx)));
        tokio::spawn(async move {
            shutdown.await;
            let _ = stop_tx.send(true);
            for t in tasks {
                let _ = t.await;
            }
        })
    }
}

/// Resolves when `stop` says so (or its sender is gone).
async fn stopped(stop: &mut watch::Receiver<bool>) {
    let _ = stop.wait_for(|s| *s).await;
}

/// Listens for `NOTIFY outbox` and wakes the workers; reconnects after an error.
async fn listener(outbox: Outbox, mut stop: watch::Receiver<bool>) {
    loop {
        tokio::select! {
            () = stopped(&mut stop) => return,
            r = listen(&outbox) => if let Err(e) = r {
                tracing::debug!(error = %e, "outbox listener stopped; retrying");
            },
        }
        tokio::select! {
            () = stopped(&mut stop) => return,
            () = tokio::time::sleep(outbox.inner.timing.poll) => {}
        }
    }
}

/// Wakes the workers at each notification until the connection fails.
async fn listen(outbox: &Outbox) -> Result<(), sqlx::Error> {
    let mut l = sqlx::postgres::PgListener::connect_with(&outbox.inner.pool).await?;
    l.listen("outbox").await?;
    // Items committed while no listener was up are found by this wake's claim.
    outbox.wake();
    loop {
        l.recv().await?;
        outbox.wake();
    }
}

/// One kind's worker: claim, deliver, record the outcome; sleep when nothing is due.
async fn worker(outbox: Outbox, deliverer: Arc<dyn Deliver>, mut stop: watch::Receiver<bool>) {
    let timing = outbox.inner.timing;
    let pool = &outbox.inner.pool;
    let kind = deliverer.kind();
    let mut wake = outbox.inner.wake.subscribe();
    loop {
        if *stop.borrow() {
            return;
        }
        wake.mark_unchanged();
        outbox.inner.passes.fetch_add(1, Ordering::Relaxed);
        let claimed = claim(pool, kind, deliverer.batch_size().max(1), timing.lease).await;
        let items = match claimed {
            Ok(items) => items,
            Err(e) => {
                tracing::warn!(kind, error = %e, "outbox: claiming items failed");
                Vec::new()
            }
        };
        if items.is_empty() {
            let nap = next_due_in(pool, kind)
                .await
                .unwrap_or(timing.poll)
                .clamp(MIN_NAP, timing.poll.max(MIN_NAP));
            tokio::select! {
                () = stopped(&mut stop) => return,
                _ = wake.changed() => {}
                () = tokio::time::sleep(nap) => {}
            }
            continue;
        }
        let payloads: Vec<serde_json::Value> = items.iter().map(|i| i.payload.clone()).collect();
        let outcome = tokio::select! {
            () = stopped(&mut stop) => return,
            r = tokio::time::timeout(timing.delivery_timeout, deliverer.deliver(&payloads)) => match r {
                Ok(r) => r,
                Err(_) => Err(DeliveryError::Retry(format!("no answer within {:?}", timing.delivery_timeout))),
            },
        };
        let recorded = match &outcome {
            Ok(()) => mark_delivered(pool, kind, &items).await,
            Err(DeliveryError::Retry(e)) => schedule_retry(pool, kind, &items, e, &timing).await,
            Err(DeliveryError::Permanent(e)) => mark_failed(pool, kind, &items, e).await,
        };
        if let Err(e) = &outcome {
            tracing::warn!(kind, items = items.len(), error = %e, "outbox: delivery failed");
        }
        if let Err(e) = recorded {
            // The lease expires and the items are delivered again: at-least-once holds.
            tracing::warn!(kind, error = %e, "outbox: recording a delivery's outcome failed");
            tokio::select! {
                () = stopped(&mut stop) => return,
                () = tokio::time::sleep(timing.poll) => {}
            }
        }
    }
}

struct Claimed {
    id: i64,
    attempts: i32,
    payload: serde_json::Value,
}

/// Claims up to `limit` due items of `kind`, oldest first, for `lease`.
async fn claim(
    pool: &PgPool,
    kind: &str,
    limit: usize,
    lease: Duration,
) -> Result<Vec<Claimed>, sqlx::Error> {
    let rows: Vec<(i64, i32, serde_json::Value)> = sqlx::query_as(
        "UPDATE outbox SET attempts = attempts + 1,
                next_attempt_at = now() + make_interval(secs => $3)
         WHERE id IN (SELECT id FROM outbox
                      WHERE kind = $1 AND delivered_at IS NULL AND failed_at IS NULL
                        AND next_attempt_at <= now()
                      ORDER BY id LIMIT $2 FOR UPDATE SKIP LOCKED)
         RETURNING id, attempts, payload",
    )
    .bind(kind)
    .bind(i64::try_from(limit).unwrap_or(i64::MAX))
    .bind(lease.as_secs_f64())
    .fetch_all(pool)
    .await?;
    let mut items: Vec<Claimed> = rows
        .into_iter()
        .map(|(id, attempts, payload)| Claimed {
            id,
            attempts,
            payload,
        })
        .collect();
    items.sort_by_key(|i| i.id);
    Ok(items)
}

/// Shortest sleep of a worker whose claim found nothing. An item can be due yet not claimable
/// (another worker's claim holds its row until that transaction commits, which then moves it a
/// lease ahead); the worker looks again after this instead of at once. Our choice: 25 ms, short
/// against any backoff, long against a claim's round trip.
const MIN_NAP: Duration = Duration::from_millis(25);

/// Time until the next undelivered item of `kind` is due (zero when one is overdue; `None`: none
/// pending). `min` over no row is NULL, which stays `None` here (SQL's `greatest(NULL, 0)` would
/// be 0, and an idle worker would never sleep).
async fn next_due_in(pool: &PgPool, kind: &str) -> Option<Duration> {
    let secs: Option<f64> = sqlx::query_scalar(
        "SELECT extract(epoch FROM min(next_attempt_at) - now())::float8 FROM outbox
         WHERE kind = $1 AND delivered_at IS NULL AND failed_at IS NULL",
    )
    .bind(kind)
    .fetch_one(pool)
    .await
    .ok()
    .flatten();
    secs.and_then(|s| Duration::try_from_secs_f64(s.max(0.0)).ok())
}

fn ids(items: &[Claimed]) -> Vec<i64> {
    items.iter().map(|i| i.id).collect()
}

async fn mark_delivered(pool: &PgPool, kind: &str, items: &[Claimed]) -> Result<(), sqlx::Error> {
    let mut tx = pool.begin().await?;
    // A row another worker delivered after this one's lease expired is counted once.
    let n = sqlx::query(
        "UPDATE outbox SET delivered_at = now() WHERE id = ANY($1) AND delivered_at IS NULL",
    )
    .bind(ids(items))
    .execute(&mut *tx)
    .await?
    .rows_affected();
    sqlx::query(
        "INSERT INTO outbox_kind_stats (kind, delivered, last_delivered_at) VALUES ($1, $2, now())
         ON CONFLICT (kind) DO UPDATE SET delivered = outbox_kind_stats.delivered + $2,
             last_delivered_at = now()",
    )
    .bind(kind)
    .bind(i64::try_from(n).unwrap_or(i64::MAX))
    .execute(&mut *tx)
    .await?;
    tx.commit().await
}

async fn record_error(
    conn: &mut sqlx::PgConnection,
    kind: &str,
    error: &str,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO outbox_kind_stats (kind, last_error, last_error_at) VALUES ($1, $2, now())
         ON CONFLICT (kind) DO UPDATE SET last_error = $2, last_error_at = now()",
    )
    .bind(kind)
    .bind(error)
    .execute(conn)
    .await?;
    Ok(())
}

/// Longest error text kept (our choice: enough for a receiver's error message).
const MAX_ERROR_CHARS: usize = 2000;

fn clip(e: &str) -> String {
    e.chars().take(MAX_ERROR_CHARS).collect()
}

async fn schedule_retry(
    pool: &PgPool,
    kind: &str,
    items: &[Claimed],
    error: &str,
    timing: &Timing,
) -> Result<(), sqlx::Error> {
    let error = clip(error);
    let delays: Vec<f64> = items
        .iter()
        .map(|i| timing.backoff(i.attempts).as_secs_f64())
        .collect();
    let mut tx = pool.begin().await?;
    sqlx::query(
        "UPDATE outbox o SET next_attempt_at = now() + make_interval(secs => d.delay_s),
                last_error = $3, last_error_at = now()
         FROM unnest($1::bigint[], $2::float8[]) AS d(id, delay_s)
         WHERE o.id = d.id AND o.delivered_at IS NULL",
    )
    .bind(ids(items))
    .bind(delays)
    .bind(&error)
    .execute(&mut *tx)
    .await?;
    record_error(&mut tx, kind, &error).await?;
    tx.commit().await
}

async fn mark_failed(
    pool: &PgPool,
    kind: &str,
    items: &[Claimed],
    error: &str,
) -> Result<(), sqlx::Error> {
    let error = clip(error);
    let mut tx = pool.begin().await?;
    sqlx::query(
        "UPDATE outbox SET failed_at = now(), last_error = $2, last_error_at = now()
         WHERE id = ANY($1) AND delivered_at IS NULL",
    )
    .bind(ids(items))
    .bind(&error)
    .execute(&mut *tx)
    .await?;
    record_error(&mut tx, kind, &format!("permanent: {error}")).await?;
    tx.commit().await
}

/// The state of one kind of item.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct KindStatus {
    /// The kind.
    pub kind: String,
    /// Items not delivered yet that will be tried (again).
    pub pending: i64,
    /// When the oldest pending item was enqueued.
    #[serde(with = "time::serde::rfc3339::option")]
    pub oldest_pending_at: Option<OffsetDateTime>,
    /// Its age in seconds.
    pub oldest_pending_age_s: Option<f64>,
    /// Items given up on after a permanent error.
    pub failed: i64,
    /// Items delivered so far.
    pub delivered: i64,
    /// When an item was last delivered.
    #[serde(with = "time::serde::rfc3339::option")]
    pub last_delivered_at: Option<OffsetDateTime>,
    /// The last delivery error (retryable or permanent), if any.
    pub last_error: Option<String>,
    /// When it happened.
    #[serde(with = "time::serde::rfc3339::option")]
    pub last_error_at: Option<OffsetDateTime>,
}

type StatusRow = (
    String,
    i64,
    Option<OffsetDateTime>,
    Option<f64>,
    i64,
    i64,
    Option<OffsetDateTime>,
    Option<String>,
    Option<OffsetDateTime>,
);

/// The state of every kind that has items or history: backlog, failures, deliveries, last error.
pub async fn status(pool: &PgPool) -> Result<Vec<KindStatus>, sqlx::Error> {
    let rows: Vec<StatusRow> = sqlx::query_as(
        "WITH p AS (
             SELECT kind, count(*) FILTER (WHERE failed_at IS NULL) AS pending,
                    min(created_at) FILTER (WHERE failed_at IS NULL) AS oldest,
                    count(*) FILTER (WHERE failed_at IS NOT NULL) AS failed
             FROM outbox WHERE delivered_at IS NULL GROUP BY kind)
         SELECT k.kind, coalesce(p.pending, 0), p.oldest,
                extract(epoch FROM now() - p.oldest)::float8, coalesce(p.failed, 0),
                coalesce(s.delivered, 0), s.last_delivered_at, s.last_error, s.last_error_at
         FROM (SELECT kind FROM p UNION SELECT kind FROM outbox_kind_stats) k
         LEFT JOIN p USING (kind) LEFT JOIN outbox_kind_stats s USING (kind)
         ORDER BY k.kind",
    )
    .fetch_all(pool)
    .await?;
    Ok(rows
        .into_iter()
        .map(|r| KindStatus {
            kind: r.0,
            pending: r.1,
            oldest_pending_at: r.2,
            oldest_pending_age_s: r.3,
            failed: r.4,
            delivered: r.5,
            last_delivered_at: r.6,
            last_error: r.7,
            last_error_at: r.8,
        })
        .collect())
}

/// The state of one kind (zeros when it never had an item).
pub async fn kind_status(pool: &PgPool, kind: &str) -> Result<KindStatus, sqlx::Error> {
    Ok(status(pool)
        .await?
        .into_iter()
        .find(|s| s.kind == kind)
        .unwrap_or(KindStatus {
            kind: kind.to_owned(),
            pending: 0,
            oldest_pending_at: None,
            oldest_pending_age_s: None,
            failed: 0,
            delivered: 0,
            last_delivered_at: None,
            last_error: None,
            last_error_at: None,
        }))
}
