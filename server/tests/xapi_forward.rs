//! Forwarding to an external LRS across crashes: server A (the platform) produces records and
//! forwards their statements to server B (a second `server` process whose LRS plays the
//! institution's). B is killed with SIGKILL mid-stream and restarted, then A is; afterwards every
//! statement A produced is in B exactly once (by id).
//!
//! Needs B's Statement resource (`POST`/`PUT`/`GET /xapi/statements`, the statements helper's
//! work).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::Value;
use server::records::auth::Role;
use server::records::config::Argon2Cost;
use server::test_support::test_db;
use sha2::{Digest, Sha256};
use sqlx::PgPool;
use uuid::Uuid;

use crate::records_support::PASSWORD;
use crate::server_process::{ServerProcess, fast_auth_env, http, spawn_server};

const KEY: &str = "forwarding-test-key";
const SECRET: &str = "forwarding-test-secret-0123456789";

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

async fn spawn(
    data: &std::path::Path,
    url: &str,
    env: Vec<(&'static str, String)>,
) -> ServerProcess {
    let (data, url) = (data.to_owned(), url.to_owned());
    tokio::task::spawn_blocking(move || {
        let mut e = fast_auth_env();
        e.push(("PAINSIM_PREPARE_ANATOMY", "0".into()));
        e.extend(env);
        spawn_server(&data, Some(&url), &e)
    })
    .await
    .unwrap()
}

async fn delivered(pool: &PgPool) -> i64 {
    server::outbox::kind_status(pool, "xapi-forward")
        .await
        .unwrap()
        .delivered
}

/// Waits until 100 more statements are delivered, then kills `who` with SIGKILL.
async fn hundred_more_then_kill(
    pool: &PgPool,
    server: ServerProcess,
    who: &str,
    produced: &AtomicUsize,
) {
    let target = delivered(pool).await + 100;
    wait_for(
        "100 more statements delivered",
        Duration::from_secs(90),
        async || delivered(pool).await >= target,
    )
    .await;
    server.sigkill();
    eprintln!(
        "{who} killed after {} delivered; {} records produced",
        delivered(pool).await,
        produced.load(Ordering::SeqCst)
    );
    tokio::time::sleep(Duration::from_millis(500)).await;
}

async fn wait_for(what: &str, limit: Duration, mut f: impl AsyncFnMut() -> bool) {
    let start = Instant::now();
    while !f().await {
        assert!(start.elapsed() < limit, "{what}: not within {limit:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Every statement id in B's LRS, following `more`, as listed (duplicates kept).
fn lrs_ids(addr: &str) -> Vec<String> {
    let basic = base64::engine::general_purpose::STANDARD.encode(format!("{KEY}:{SECRET}"));
    let auth = format!("Basic {basic}");
    let mut ids = Vec::new();
    let mut next = "/xapi/statements?format=ids&limit=500".to_owned();
    loop {
        let (st, _, body) = http(
            addr,
            "GET",
            &next,
            &[
                ("Authorization", &auth),
                ("X-Experience-API-Version", "2.0.0"),
            ],
            "",
        )
        .unwrap();
        assert_eq!(st, 200, "{body}");
        let v: Value = serde_json::from_str(&body).unwrap();
        for s in v["statements"].as_array().unwrap() {
            ids.push(s["id"].as_str().unwrap().to_owned());
        }
        match v["more"].as_str() {
            Some(m) if !m.is_empty() => next = m.to_owned(),
            _ => return ids,
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_statement_is_lost_across_a_sigkill_of_either_side() {
    let (db_a, db_b) = (test_db().await, test_db().await);
    // B: an admin and the credential A forwards with.
    let admin_b = server::records::users::create_user(
        &db_b.pool,
        Argon2Cost::TEST_ONLY,
        "b@example.org",
        "B",
        Role::Admin,
        PASSWORD,
        false,
    )
    .await
    .unwrap()
    .id;
    sqlx::query(
        "INSERT INTO lrs_credentials (id, name, key, secret_sha256, can_read, can_write, authority, created_by)
         VALUES ($1, 'platform A', $2, $3, TRUE, TRUE, $4, $5)",
    )
    .bind(Uuid::new_v4())
    .bind(KEY)
    .bind(Sha256::digest(SECRET.as_bytes()).to_vec())
    .bind(serde_json::json!({"objectType": "Agent", "account": {"homePage": "http://b.example.org/xapi/", "name": KEY}}))
    .bind(admin_b)
    .execute(&db_b.pool)
    .await
    .unwrap();
    // A: a learner in a course, forwarding to B's fixed port.
    server::records::prepare(
        &db_a.pool,
        &crate::records_support::test_config(&[]).records,
        false,
    )
    .await
    .unwrap();
    let learner = server::records::users::create_user(
        &db_a.pool,
        Argon2Cost::TEST_ONLY,
        "fw@example.org",
        "F",
        Role::Learner,
        PASSWORD,
        false,
    )
    .await
    .unwrap()
    .id;
    let admin_a = server::records::users::create_user(
        &db_a.pool,
        Argon2Cost::TEST_ONLY,
        "fa@example.org",
        "A",
        Role::Admin,
        PASSWORD,
        false,
    )
    .await
    .unwrap()
    .id;
    let course = Uuid::new_v4();
    sqlx::query("INSERT INTO courses (id, code, title) VALUES ($1, 'FW', 'FW')")
        .bind(course)
        .execute(&db_a.pool)
        .await
        .unwrap();
    sqlx::query("INSERT INTO course_members (course_id, user_id, role) VALUES ($1, $2, 'learner')")
        .bind(course)
        .bind(learner)
        .execute(&db_a.pool)
        .await
        .unwrap();
    let port_b = free_port();
    sqlx::query(
        "INSERT INTO lrs_forwarding (endpoint, key, secret, updated_by) VALUES ($1, $2, $3, $4)",
    )
    .bind(format!("http://127.0.0.1:{port_b}/xapi/"))
    .bind(KEY)
    .bind(SECRET)
    .bind(admin_a)
    .execute(&db_a.pool)
    .await
    .unwrap();
    let (data_a, data_b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let env_b = || {
        vec![
            ("PAINSIM_BIND", format!("127.0.0.1:{port_b}")),
            ("PAINSIM_PUBLIC_URL", "http://b.example.org".to_owned()),
        ]
    };
    let env_a = || vec![("PAINSIM_PUBLIC_URL", "http://a.example.org".to_owned())];
    let b = spawn(data_b.path(), &db_b.url, env_b()).await;
    let a = spawn(data_a.path(), &db_a.url, env_a()).await;

    // The learner opens an attempt on A (records: station_opened).
    let (st, head, body) = http(
        &a.addr,
        "POST",
        "/api/auth/login",
        &[],
        &format!("{{\"email\":\"fw@example.org\",\"password\":\"{PASSWORD}\"}}"),
    )
    .unwrap();
    assert_eq!(st, 200, "{body}");
    let cookie = head
        .lines()
        .find_map(|l| l.strip_prefix("set-cookie: painsim_session="))
        .unwrap()
        .split(';')
        .next()
        .unwrap()
        .to_owned();
    let csrf = serde_json::from_str::<Value>(&body).unwrap()["csrf_token"]
        .as_str()
        .unwrap()
        .to_owned();
    let (st, _, body) = http(
        &a.addr,
        "POST",
        "/api/attempts",
        &[
            ("Cookie", &format!("painsim_session={cookie}")),
            ("X-CSRF-Token", &csrf),
        ],
        &format!("{{\"course_id\":\"{course}\",\"station_id\":\"l4-l5-left-facet\"}}"),
    )
    .unwrap();
    assert_eq!(st, 201, "{body}");
    let attempt: Uuid = serde_json::from_str::<Value>(&body).unwrap()["id"]
        .as_str()
        .unwrap()
        .parse()
        .unwrap();

    // Records keep coming (straight into A's database, as A's handlers would store them, so the
    // stream goes on while A is down too) until the end of the test.
    let stop = Arc::new(AtomicBool::new(false));
    let produced = Arc::new(AtomicUsize::new(0));
    let producer = tokio::spawn({
        let (pool, stop, produced) = (db_a.pool.clone(), stop.clone(), produced.clone());
        async move {
            while !stop.load(Ordering::SeqCst) {
                sqlx::query("INSERT INTO activity_events (attempt_id, user_id, kind, detail)
                             SELECT $1, $2, 'image_acquired', jsonb_build_object('n', g) FROM generate_series(1, 10) g")
                    .bind(attempt)
                    .bind(learner)
                    .execute(&pool)
                    .await
                    .unwrap();
                produced.fetch_add(10, Ordering::SeqCst);
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    });

    // SIGKILL B mid-stream, restart it on the same port.
    hundred_more_then_kill(&db_a.pool, b, "B", &produced).await;
    let b = spawn(data_b.path(), &db_b.url, env_b()).await;
    // SIGKILL A mid-stream, restart it.
    hundred_more_then_kill(&db_a.pool, a, "A", &produced).await;
    let a = spawn(data_a.path(), &db_a.url, env_a()).await;
    tokio::time::sleep(Duration::from_secs(1)).await;
    stop.store(true, Ordering::SeqCst);
    producer.await.unwrap();

    // Everything drains: the projection queue and the outbox are empty (a lease of the killed A
    // expires after 45 s, server::outbox::Timing::default).
    let started = Instant::now();
    wait_for("the backlog drains", Duration::from_secs(180), async || {
        let queued: i64 = sqlx::query_scalar("SELECT count(*) FROM xapi_projection_queue")
            .fetch_one(&db_a.pool)
            .await
            .unwrap();
        let st = server::outbox::kind_status(&db_a.pool, "xapi-forward")
            .await
            .unwrap();
        queued == 0 && st.pending == 0 && st.failed == 0
    })
    .await;
    eprintln!("drained {:?} after the producer stopped", started.elapsed());

    let expected: Vec<String> =
        sqlx::query_scalar("SELECT key FROM outbox WHERE kind = 'xapi-forward'")
            .fetch_all(&db_a.pool)
            .await
            .unwrap();
    let events: i64 = sqlx::query_scalar("SELECT count(*) FROM activity_events")
        .fetch_one(&db_a.pool)
        .await
        .unwrap();
    assert_eq!(
        i64::try_from(expected.len()).unwrap(),
        events,
        "one statement per activity event"
    );
    let got = lrs_ids(&b.addr);
    let unique: std::collections::HashSet<&String> = got.iter().collect();
    assert_eq!(unique.len(), got.len(), "a statement is in B twice");
    let missing: Vec<&String> = expected.iter().filter(|id| !unique.contains(id)).collect();
    eprintln!(
        "forwarding across SIGKILLs: {} records, {} statements produced, {} in B, {} missing, {} delivered (counted by A)",
        produced.load(Ordering::SeqCst) + 1,
        expected.len(),
        got.len(),
        missing.len(),
        delivered(&db_a.pool).await
    );
    assert!(missing.is_empty(), "lost: {missing:?}");
    assert_eq!(got.len(), expected.len(), "B holds only A's statements");
    a.sigterm_and_wait();
    b.sigterm_and_wait();
}

#[tokio::test]
async fn admins_set_see_and_stop_forwarding_and_the_secret_never_comes_back() {
    let lrs = crate::xapi_support::Lrs::new().await;
    let admin = Some(&lrs.admin);
    let get = async || {
        lrs.app
            .send(
                axum::http::Method::GET,
                "/api/admin/lrs-forwarding",
                admin,
                None,
            )
            .await
    };
    let r = get().await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["configured"], false);
    assert_eq!(r.json["status"]["pending"], 0);
    // Statements produced while nothing is configured wait in the backlog.
    let mut tx = lrs.app.pool().begin().await.unwrap();
    server::outbox::enqueue(
        &mut tx,
        "xapi-forward",
        "s1",
        serde_json::json!({"id": "s1"}),
    )
    .await
    .unwrap();
    tx.commit().await.unwrap();
    let r = get().await;
    assert_eq!(r.json["status"]["pending"], 1);
    assert!(r.json["status"]["oldest_pending_age_s"].as_f64().unwrap() >= 0.0);

    for bad in [
        serde_json::json!({ "endpoint": "ftp://lrs.example.org/", "key": "k", "secret": "s" }),
        serde_json::json!({ "endpoint": "https://user@lrs.example.org/", "key": "k", "secret": "s" }),
        serde_json::json!({ "endpoint": "https://lrs.example.org/x?y", "key": "k", "secret": "s" }),
        serde_json::json!({ "endpoint": "https://lrs.example.org/", "key": "a:b", "secret": "s" }),
        serde_json::json!({ "endpoint": "https://lrs.example.org/", "key": "k", "secret": "" }),
        serde_json::json!({ "endpoint": "https://lrs.example.org/", "key": "k" }),
    ] {
        let r = lrs
            .app
            .send(
                axum::http::Method::PUT,
                "/api/admin/lrs-forwarding",
                admin,
                Some(bad.clone()),
            )
            .await;
        assert_eq!(r.status, 400, "{bad}: {}", r.text);
    }
    let r = lrs
        .app
        .send(
            axum::http::Method::PUT,
            "/api/admin/lrs-forwarding",
            admin,
            Some(serde_json::json!({ "endpoint": "https://lrs.example.org/xapi", "key": "inst", "secret": "very-secret" })),
        )
        .await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["configured"], true);
    assert_eq!(r.json["endpoint"], "https://lrs.example.org/xapi/");
    assert_eq!(r.json["key"], "inst");
    assert!(!r.text.contains("very-secret"), "the secret is write-only");
    assert!(!get().await.text.contains("very-secret"));
    let audit: i64 = sqlx::query_scalar("SELECT count(*) FROM audit_events WHERE action = 'lrs_forwarding_set' AND NOT detail::text LIKE '%very-secret%'")
        .fetch_one(lrs.app.pool())
        .await
        .unwrap();
    assert_eq!(audit, 1);
    let r = lrs
        .app
        .send(
            axum::http::Method::DELETE,
            "/api/admin/lrs-forwarding",
            admin,
            None,
        )
        .await;
    assert_eq!(r.status, 204);
    let r = get().await;
    assert_eq!(r.json["configured"], false);
    assert_eq!(r.json["status"]["pending"], 1, "the backlog is kept");
}
