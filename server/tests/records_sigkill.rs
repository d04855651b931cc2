//! Durability of acknowledged activity writes: the real `server` binary runs against a test
//! database, several clients stream activity events, and the server is killed with SIGKILL in
//! the middle of the stream, several times. Every event whose 201 reached a client must be in the
//! database afterwards (a 201 is sent only after the transaction committed).

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use server::records::auth::Role;
use server::records::config::Argon2Cost;
use server::test_support::test_db;
use uuid::Uuid;

use crate::records_support::PASSWORD;
use crate::server_process::{fast_auth_env, http, spawn_server};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_mid_stream_loses_no_acknowledged_activity() {
    let db = test_db().await;
    server::records::prepare(
        &db.pool,
        &crate::records_support::test_config(&[]).records,
        false,
    )
    .await
    .unwrap();
    let learner = server::records::users::create_user(
        &db.pool,
        Argon2Cost::TEST_ONLY,
        "k@example.org",
        "K",
        Role::Learner,
        PASSWORD,
        false,
    )
    .await
    .unwrap()
    .id;
    let course = Uuid::new_v4();
    sqlx::query("INSERT INTO courses (id, code, title) VALUES ($1, 'K', 'K')")
        .bind(course)
        .execute(&db.pool)
        .await
        .unwrap();
    sqlx::query("INSERT INTO course_members (course_id, user_id, role) VALUES ($1, $2, 'learner')")
        .bind(course)
        .bind(learner)
        .execute(&db.pool)
        .await
        .unwrap();
    let data = tempfile::tempdir().unwrap();
    let url = db.url.clone();

    let acked: Arc<Mutex<Vec<i64>>> = Arc::default();
    let rounds = 5;
    let acked_per_round = 40;
    let mut attempt = String::new();
    let mut cookie = String::new();
    let mut csrf = String::new();
    for round in 0..rounds {
        let server = tokio::task::spawn_blocking({
            let (url, data) = (url.clone(), data.path().to_owned());
            move || {
                // No session here: leave the anatomy (a phantom build) to the first session.
                let mut env = fast_auth_env();
                env.push(("PAINSIM_PREPARE_ANATOMY", "0".into()));
                spawn_server(&data, Some(&url), &env)
            }
        })
        .await
        .unwrap();
        let addr = server.addr.clone();
        if round == 0 {
            // Log in and open the attempt once: the session lives in PostgreSQL and survives the kills.
            let (st, head, body) = http(
                &addr,
                "POST",
                "/api/auth/login",
                &[],
                &format!("{{\"email\":\"k@example.org\",\"password\":\"{PASSWORD}\"}}"),
            )
            .unwrap();
            assert_eq!(st, 200, "{body}");
            cookie = head
                .lines()
                .find_map(|l| l.strip_prefix("set-cookie: painsim_session="))
                .unwrap()
                .split(';')
                .next()
                .unwrap()
                .to_owned();
            csrf = serde_json::from_str::<serde_json::Value>(&body).unwrap()["csrf_token"]
                .as_str()
                .unwrap()
                .to_owned();
            let (st, _, body) = http(
                &addr,
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
            attempt = serde_json::from_str::<serde_json::Value>(&body).unwrap()["id"]
                .as_str()
                .unwrap()
                .to_owned();
        }
        // Four clients stream events until the kill.
        let stop = Arc::new(AtomicBool::new(false));
        let round_acks = Arc::new(AtomicUsize::new(0));
        let mut clients = Vec::new();
        for c in 0..4 {
            let (addr, stop, round_acks, acked) = (
                addr.clone(),
                stop.clone(),
                round_acks.clone(),
                acked.clone(),
            );
            let (cookie, csrf, attempt) = (cookie.clone(), csrf.clone(), attempt.clone());
            clients.push(std::thread::spawn(move || {
                let mut n = 0;
                while !stop.load(Ordering::SeqCst) {
                    n += 1;
                    let body = format!("{{\"kind\":\"image_acquired\",\"detail\":{{\"round\":{round},\"client\":{c},\"n\":{n}}}}}");
                    let Ok((st, _, resp)) = http(&addr, "POST", &format!("/api/attempts/{attempt}/activity"), &[("Cookie", &format!("painsim_session={cookie}")), ("X-CSRF-Token", &csrf)], &body) else {
                        continue; // connection refused or cut by the kill: not acknowledged
                    };
                    if st == 201 {
                        let id = serde_json::from_str::<serde_json::Value>(&resp).ok().and_then(|v| v["id"].as_i64());
                        if let Some(id) = id {
                            acked.lock().unwrap().push(id);
                            round_acks.fetch_add(1, Ordering::SeqCst);
                        }
                    } else if st != 0 {
                        panic!("unexpected status {st}: {resp}");
                    }
                }
            }));
        }
        let deadline = Instant::now() + Duration::from_secs(60);
        while round_acks.load(Ordering::SeqCst) < acked_per_round {
            assert!(
                Instant::now() < deadline,
                "round {round}: only {} writes acknowledged",
                round_acks.load(Ordering::SeqCst)
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        // SIGKILL while the clients are still writing.
        server.sigkill();
        stop.store(true, Ordering::SeqCst);
        for c in clients {
            c.join().unwrap();
        }
    }

    let acked = acked.lock().unwrap().clone();
    let stored: Vec<i64> = sqlx::query_scalar(
        "SELECT id FROM activity_events WHERE attempt_id = $1::uuid AND kind = 'image_acquired'",
    )
    .bind(&attempt)
    .fetch_all(&db.pool)
    .await
    .unwrap();
    let stored: std::collections::HashSet<i64> = stored.into_iter().collect();
    let lost: Vec<_> = acked.iter().filter(|id| !stored.contains(id)).collect();
    eprintln!(
        "SIGKILL test: {rounds} kills, {} acknowledged writes, {} stored, {} lost",
        acked.len(),
        stored.len(),
        lost.len()
    );
    assert!(acked.len() >= rounds * acked_per_round);
    assert!(lost.is_empty(), "acknowledged but missing: {lost:?}");
}
