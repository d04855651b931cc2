//! The durable outbox (`server::outbox`): idempotent enqueue, retries with exponential backoff,
//! permanent failures, resumption after a restart and after a crashed worker's lease, and two
//! workers on one database delivering every item exactly once.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::future::BoxFuture;
use serde_json::{Value, json};
use server::outbox::{self, Deliver, DeliveryError, Outbox, Timing};
use server::test_support::test_db;
use sqlx::PgPool;

/// Short timings for tests (our choice: milliseconds instead of seconds, same ratios as the
/// defaults: lease longer than the delivery timeout).
fn fast() -> Timing {
    Timing {
        backoff_base: Duration::from_millis(100),
        backoff_max: Duration::from_secs(2),
        delivery_timeout: Duration::from_millis(800),
        lease: Duration::from_millis(1200),
        poll: Duration::from_millis(100),
    }
}

/// A deliverer that answers with a script of outcomes (then `Ok`), and logs every call.
struct Scripted {
    kind: &'static str,
    batch: usize,
    script: Mutex<Vec<Result<(), DeliveryError>>>,
    calls: Mutex<Vec<(Instant, Vec<Value>)>>,
    delay: Duration,
    hang: bool,
}

impl Scripted {
    fn new(kind: &'static str, script: Vec<Result<(), DeliveryError>>) -> Arc<Scripted> {
        Arc::new(Scripted {
            kind,
            batch: 1,
            script: Mutex::new(script),
            calls: Mutex::default(),
            delay: Duration::ZERO,
            hang: false,
        })
    }
    fn calls(&self) -> Vec<(Instant, Vec<Value>)> {
        self.calls.lock().unwrap().clone()
    }
}

impl Deliver for Scripted {
    fn kind(&self) -> &'static str {
        self.kind
    }
    fn batch_size(&self) -> usize {
        self.batch
    }
    fn deliver<'a>(&'a self, items: &'a [Value]) -> BoxFuture<'a, Result<(), DeliveryError>> {
        Box::pin(async move {
            self.calls
                .lock()
                .unwrap()
                .push((Instant::now(), items.to_vec()));
            if self.hang {
                std::future::pending::<()>().await;
            }
            tokio::time::sleep(self.delay).await;
            let mut s = self.script.lock().unwrap();
            if s.is_empty() { Ok(()) } else { s.remove(0) }
        })
    }
}

async fn enqueue_n(pool: &PgPool, kind: &str, n: usize) {
    let mut tx = pool.begin().await.unwrap();
    for i in 0..n {
        outbox::enqueue(&mut tx, kind, &format!("k{i}"), json!({ "n": i }))
            .await
            .unwrap();
    }
    tx.commit().await.unwrap();
}

async fn wait_until(limit: Duration, mut f: impl AsyncFnMut() -> bool) {
    let start = Instant::now();
    while !f().await {
        assert!(
            start.elapsed() < limit,
            "condition not met within {limit:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Waits (at most `limit`) until `n` items of `kind` are delivered.
async fn wait_delivered(pool: &PgPool, kind: &str, n: i64, limit: Duration) {
    wait_until(limit, async || {
        outbox::kind_status(pool, kind).await.unwrap().delivered == n
    })
    .await;
}

fn stopper() -> (
    tokio::sync::oneshot::Sender<()>,
    impl Future<Output = ()> + Send + 'static,
) {
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    (tx, async move {
        let _ = rx.await;
    })
}

#[tokio::test]
async fn enqueue_is_idempotent_by_kind_and_key_and_transactional() {
    let db = test_db().await;
    let mut tx = db.pool.begin().await.unwrap();
    outbox::enqueue(&mut tx, "t", "a", json!(1)).await.unwrap();
    outbox::enqueue(&mut tx, "t", "a", json!(2)).await.unwrap();
    outbox::enqueue(&mut tx, "u", "a", json!(3)).await.unwrap();
    tx.commit().await.unwrap();
    // A rolled-back transaction leaves nothing.
    let mut tx = db.pool.begin().await.unwrap();
    outbox::enqueue(&mut tx, "t", "b", json!(4)).await.unwrap();
    tx.rollback().await.unwrap();
    let rows: Vec<(String, String, Value)> =
        sqlx::query_as("SELECT kind, key, payload FROM outbox ORDER BY id")
            .fetch_all(&db.pool)
            .await
            .unwrap();
    assert_eq!(
        rows,
        vec![
            ("t".into(), "a".into(), json!(1)),
            ("u".into(), "a".into(), json!(3))
        ]
    );
    let st = outbox::kind_status(&db.pool, "t").await.unwrap();
    assert_eq!((st.pending, st.delivered, st.failed), (1, 0, 0));
    assert!(st.oldest_pending_age_s.unwrap() >= 0.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn retries_back_off_exponentially_then_deliver() {
    let db = test_db().await;
    let d = Scripted::new(
        "retry",
        vec![
            Err(DeliveryError::Retry("down 1".into())),
            Err(DeliveryError::Retry("down 2".into())),
            Err(DeliveryError::Retry("down 3".into())),
        ],
    );
    let ob = Outbox::with_timing(db.pool.clone(), fast());
    ob.register(d.clone());
    let (stop, stopped) = stopper();
    let task = ob.spawn(stopped);
    enqueue_n(&db.pool, "retry", 1).await;
    wait_delivered(&db.pool, "retry", 1, Duration::from_secs(10)).await;
    let calls = d.calls();
    assert_eq!(calls.len(), 4, "three failures, then the delivery");
    // Attempt k failed -> the next one waits backoff(k) in [base*2^(k-1)/2, base*2^(k-1)]
    // (equal jitter), i.e. at least 50, 100, 200 ms with base 100 ms.
    for (k, w) in calls.windows(2).enumerate() {
        let gap = w[1].0 - w[0].0;
        let floor = Duration::from_millis(50 << k);
        eprintln!("retry gap {k}: {gap:?} (floor {floor:?})");
        assert!(gap >= floor, "gap {k} {gap:?} < {floor:?}");
    }
    let st = outbox::kind_status(&db.pool, "retry").await.unwrap();
    assert_eq!((st.pending, st.delivered, st.failed), (0, 1, 0));
    assert_eq!(st.last_error.as_deref(), Some("down 3"));
    let attempts: i32 = sqlx::query_scalar("SELECT attempts FROM outbox WHERE kind = 'retry'")
        .fetch_one(&db.pool)
        .await
        .unwrap();
    assert_eq!(attempts, 4);
    stop.send(()).unwrap();
    tokio::time::timeout(Duration::from_secs(5), task)
        .await
        .expect("the outbox stops")
        .unwrap();
}

#[test]
fn backoff_is_capped_and_jittered_within_the_upper_half() {
    // Samples per attempt count. With uniform jitter the chance that all of them miss the lowest
    // (or highest) quarter of the range is 0.75^400, about 1e-50, and the sample mean's standard
    // deviation is range / sqrt(12 * 400), about 1.4 % of the range, so the 10 % bound on the
    // mean below is a 7-sigma margin: a correct implementation fails neither by chance.
    const SAMPLES: usize = 400;
    let t = fast();
    let mut previous_max = Duration::ZERO;
    let mut previous_full = Duration::ZERO;
    for attempts in 1..40 {
        let full = (t.backoff_base * 2u32.pow(u32::try_from(attempts - 1).unwrap().min(30)))
            .min(t.backoff_max);
        let half = full / 2;
        let range = full - half;
        let drawn: Vec<Duration> = (0..SAMPLES).map(|_| t.backoff(attempts)).collect();
        for b in &drawn {
            assert!(
                *b >= half && *b <= full,
                "attempt {attempts}: {b:?} vs {full:?}"
            );
        }
        // Jittered: the delays for one attempt spread over the whole upper half, centred on its
        // middle, instead of being one constant value inside it.
        let min = *drawn.iter().min().unwrap();
        let max = *drawn.iter().max().unwrap();
        assert!(
            min < half + range / 4 && max > full - range / 4,
            "attempt {attempts}: delays span only {min:?}..{max:?} of {half:?}..{full:?}"
        );
        let mean = drawn.iter().sum::<Duration>() / u32::try_from(SAMPLES).unwrap();
        let middle = half + range / 2;
        let off = mean.abs_diff(middle);
        assert!(
            off < range / 10,
            "attempt {attempts}: mean {mean:?} is {off:?} from the middle {middle:?}"
        );
        // Exponential until the cap: while the full delay doubles, no delay of this attempt is
        // shorter than any of the previous one (its upper half starts where the previous range
        // ends).
        if full == previous_full * 2 {
            assert!(
                min >= previous_max,
                "attempt {attempts}: {min:?} < the previous attempt's {previous_max:?}"
            );
        }
        previous_full = full;
        previous_max = max;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn permanent_errors_are_never_retried() {
    let db = test_db().await;
    let d = Scripted::new(
        "perm",
        vec![Err(DeliveryError::Permanent("rejected".into()))],
    );
    let ob = Outbox::with_timing(db.pool.clone(), fast());
    ob.register(d.clone());
    let (stop, stopped) = stopper();
    let task = ob.spawn(stopped);
    enqueue_n(&db.pool, "perm", 1).await;
    wait_until(Duration::from_secs(10), async || {
        outbox::kind_status(&db.pool, "perm").await.unwrap().failed == 1
    })
    .await;
    // Several backoff periods later it has still been tried once.
    tokio::time::sleep(Duration::from_millis(800)).await;
    assert_eq!(d.calls().len(), 1);
    let st = outbox::kind_status(&db.pool, "perm").await.unwrap();
    assert_eq!((st.pending, st.delivered, st.failed), (0, 0, 1));
    assert_eq!(st.last_error.as_deref(), Some("permanent: rejected"));
    stop.send(()).unwrap();
    task.await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_resumes_and_a_crashed_workers_items_are_delivered_again() {
    let db = test_db().await;
    // Items enqueued while no outbox runs (a server that is down) wait in the table.
    enqueue_n(&db.pool, "resume", 5).await;
    // The first worker claims items and "crashes" mid-delivery (it never answers and its task is
    // dropped): nothing is marked delivered.
    let hung = Arc::new(Scripted {
        kind: "resume",
        batch: 5,
        script: Mutex::default(),
        calls: Mutex::default(),
        delay: Duration::ZERO,
        hang: true,
    });
    let timing = Timing {
        delivery_timeout: Duration::from_secs(60),
        lease: Duration::from_millis(1500),
        ..fast()
    };
    let first = Outbox::with_timing(db.pool.clone(), timing);
    first.register(hung.clone());
    let (stop1, stopped1) = stopper();
    let task1 = first.spawn(stopped1);
    wait_until(Duration::from_secs(10), async || !hung.calls().is_empty()).await;
    stop1.send(()).unwrap();
    task1.await.unwrap();
    let claimed_at = Instant::now();
    // A second process starts: it delivers them once the lease ends, not before.
    let d = Scripted::new("resume", vec![]);
    let second = Outbox::with_timing(db.pool.clone(), fast());
    second.register(d.clone());
    let (stop2, stopped2) = stopper();
    let task2 = second.spawn(stopped2);
    wait_delivered(&db.pool, "resume", 5, Duration::from_secs(10)).await;
    let first_redelivery = d.calls()[0].0;
    eprintln!(
        "redelivered {:?} after the crash (lease 1.5 s)",
        first_redelivery - claimed_at
    );
    // The lease was taken before `claimed_at`, so its end can come a little sooner; 1 s of the
    // 1.5 s lease is a safe floor.
    assert!(first_redelivery - claimed_at >= Duration::from_millis(1000));
    let delivered: Vec<i64> = d
        .calls()
        .iter()
        .flat_map(|c| c.1.iter().map(|v| v["n"].as_i64().unwrap()))
        .collect();
    assert_eq!(delivered, vec![0, 1, 2, 3, 4]);
    stop2.send(()).unwrap();
    task2.await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_workers_deliver_every_item_exactly_once() {
    let db = test_db().await;
    let n = 400;
    enqueue_n(&db.pool, "pair", n).await;
    let seen: Arc<Mutex<HashMap<i64, usize>>> = Arc::default();
    let mut stops = Vec::new();
    let mut tasks = Vec::new();
    let mut deliverers = Vec::new();
    for _ in 0..2 {
        let d = Arc::new(Scripted {
            kind: "pair",
            batch: 7,
            script: Mutex::default(),
            calls: Mutex::default(),
            delay: Duration::from_millis(5),
            hang: false,
        });
        let ob = Outbox::with_timing(db.pool.clone(), fast());
        ob.register(d.clone());
        let (stop, stopped) = stopper();
        tasks.push(ob.spawn(stopped));
        stops.push(stop);
        deliverers.push(d);
    }
    wait_delivered(
        &db.pool,
        "pair",
        i64::try_from(n).unwrap(),
        Duration::from_secs(60),
    )
    .await;
    for d in &deliverers {
        for (_, items) in d.calls() {
            for v in items {
                *seen
                    .lock()
                    .unwrap()
                    .entry(v["n"].as_i64().unwrap())
                    .or_default() += 1;
            }
        }
    }
    let seen = seen.lock().unwrap().clone();
    let per_worker: Vec<usize> = deliverers
        .iter()
        .map(|d| d.calls().iter().map(|c| c.1.len()).sum())
        .collect();
    eprintln!("two workers: {per_worker:?} items of {n}");
    assert_eq!(seen.len(), n);
    assert!(
        seen.values().all(|&c| c == 1),
        "an item was delivered twice"
    );
    for s in stops {
        s.send(()).unwrap();
    }
    for t in tasks {
        t.await.unwrap();
    }
}

/// Claim passes of `ob` over `wait` (after the start's own wakes have settled).
async fn passes_over(ob: &Outbox, wait: Duration) -> u64 {
    tokio::time::sleep(Duration::from_millis(300)).await;
    let before = ob.claim_passes();
    tokio::time::sleep(wait).await;
    ob.claim_passes() - before
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_outbox_sleeps_between_polls() {
    let db = test_db().await;
    let ob = Outbox::with_timing(db.pool.clone(), fast());
    ob.register(Scripted::new("idle", vec![]));
    let (stop, stopped) = stopper();
    let task = ob.spawn(stopped);
    // Nothing pending: a pass per poll (100 ms), so about 15 in 1.5 s; a worker that does not
    // sleep makes thousands (an empty table's `min` is NULL, not "due now").
    let wait = Duration::from_millis(1500);
    let empty = passes_over(&ob, wait).await;
    // An item due in an hour: the same.
    let mut tx = db.pool.begin().await.unwrap();
    outbox::enqueue(&mut tx, "idle", "later", json!({}))
        .await
        .unwrap();
    sqlx::query(
        "UPDATE outbox SET next_attempt_at = now() + interval '1 hour' WHERE key = 'later'",
    )
    .execute(&mut *tx)
    .await
    .unwrap();
    tx.commit().await.unwrap();
    let later = passes_over(&ob, wait).await;
    // An item that falls due while another transaction holds its row (as a second worker's
    // claim holds it until it commits): the claim skips it, and the worker looks again after
    // its shortest nap (25 ms), not at once.
    sqlx::query(
        "UPDATE outbox SET next_attempt_at = now() + interval '400 milliseconds' WHERE key = 'later'",
    )
    .execute(&db.pool)
    .await
    .unwrap();
    let mut holder = db.pool.begin().await.unwrap();
    sqlx::query("SELECT id FROM outbox WHERE key = 'later' FOR UPDATE")
        .execute(&mut *holder)
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(400)).await;
    let locked = passes_over(&ob, wait).await;
    assert_eq!(
        outbox::kind_status(&db.pool, "idle")
            .await
            .unwrap()
            .delivered,
        0
    );
    holder.rollback().await.unwrap();
    // Released, it is delivered within a few naps.
    wait_delivered(&db.pool, "idle", 1, Duration::from_secs(2)).await;
    eprintln!("claim passes in {wait:?}: empty {empty}, due in an hour {later}, locked {locked}");
    // Bounds: 1.5 s / 100 ms = 15 passes, plus a few wakes; 1.5 s / 25 ms = 60 when locked.
    assert!(
        empty <= 25,
        "idle outbox made {empty} claim passes in {wait:?}"
    );
    assert!(
        later <= 25,
        "outbox with a later item made {later} passes in {wait:?}"
    );
    assert!(
        locked <= 80,
        "outbox with a locked due item made {locked} passes in {wait:?}"
    );
    assert!(empty >= 5, "the worker still polls ({empty} passes)");
    stop.send(()).unwrap();
    task.await.unwrap();
}
