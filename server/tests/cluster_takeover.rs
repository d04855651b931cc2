//! Takeovers between two replicas over one database, in the cases that are easy to get wrong: a
//! replica whose copy went stale getting a new connection, a session nobody holds resumed past
//! the limits, placements a replica no longer holds, and a worker URL spelled with a slash.

use std::time::Duration;

use render_worker::cluster::request_with_headers;
use serde_json::json;

use crate::dispatch::handshake_status;
use crate::dispatch_support::{Client, Received, acked, demo_server, second_replica};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stale_copy_that_gets_a_new_connection_is_replaced_not_reused() {
    let srv = demo_server(true, None).await;
    let (addr_b, _b) = second_replica(&srv, "replica-b").await;
    let learner_a = Client::login(srv.addr, "learner@demo.invalid").await;
    let learner_b = Client {
        addr: addr_b,
        ..learner_a.clone()
    };
    let (_, session) = learner_a.start_demo_attempt().await;
    let sid = session["session_id"].as_str().unwrap().to_string();
    let path = session["ws"].as_str().unwrap().to_string();
    // Tab 1 on replica A, idle after one command.
    let mut tab1 = learner_a.websocket(&path).await;
    let mut got1 = Received::default();
    tab1.send(1, json!({ "type": "shot" })).await;
    tab1.until(&mut got1, |r| acked(r).len() == 1).await;
    // Tab 2 through replica B takes the session over and goes on.
    let mut tab2 = learner_b.websocket(&path).await;
    let mut got2 = Received::default();
    for seq in 2..=4 {
        tab2.send(
            seq,
            json!({ "type": "carm_pose", "orbital_deg": seq * 5, "angular_deg": 0 }),
        )
        .await;
    }
    tab2.until(&mut got2, |r| acked(r).len() == 3).await;
    // Tab 3 back on replica A: A's copy is stale, so it is replaced by one restored from the
    // stored log (B's commands included), and tab 1 is closed with 4009.
    let mut tab3 = learner_a.websocket(&path).await;
    let mut got3 = Received::default();
    tab3.until(&mut got3, |r| !r.texts.is_empty()).await;
    assert_eq!(got3.texts[0]["type"], "hello");
    assert_eq!(got3.texts[0]["last_seq"], 4, "{:?}", got3.texts[0]);
    let code = tab1
        .until_closed(&mut got1, Duration::from_secs(30))
        .await
        .map(|(c, _)| c);
    assert_eq!(code, Some(4009));
    tab3.send(5, json!({ "type": "shot" })).await;
    tab3.until(&mut got3, |r| acked(r).len() == 1).await;
    let seqs: Vec<(i64, i64)> = sqlx::query_as(
        "SELECT seq, epoch FROM live_session_commands WHERE session_id = $1::uuid ORDER BY seq",
    )
    .bind(&sid)
    .fetch_all(&srv.db.pool)
    .await
    .unwrap();
    assert_eq!(
        seqs.iter().map(|(s, _)| *s).collect::<Vec<_>>(),
        vec![1, 2, 3, 4, 5]
    );
    assert!(
        seqs[4].1 > seqs[3].1,
        "tab 3 writes under a newer epoch: {seqs:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resuming_a_session_nobody_holds_through_its_socket_obeys_the_limits() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_, first) = learner.start_demo_attempt().await;
    let first_id = first["session_id"].as_str().unwrap().to_string();
    // The first session closes (nobody holds it); a second one is live.
    assert!(srv.dispatcher.close(first_id.parse().unwrap()).await);
    let (_, _second) = learner.start_demo_attempt().await;
    srv.dispatcher.set_sessions_per_user(1);
    assert_eq!(
        handshake_status(srv.addr, &first_id, &learner.cookie, None).await,
        429,
        "its socket would make a second live session"
    );
    srv.dispatcher.set_sessions_per_user(2);
    assert_eq!(
        handshake_status(srv.addr, &first_id, &learner.cookie, None).await,
        101
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replica_sweeps_away_placements_it_does_not_hold() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_, session) = learner.start_demo_attempt().await;
    let sid: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    assert!(srv.dispatcher.close(sid).await);
    // A row under this replica's name for a session it does not hold (left by a previous
    // process with the same name, or a release that failed).
    sqlx::query(
        "INSERT INTO session_placements (session_id, epoch, replica, worker_session, placed_at)
         VALUES ($1, 0, 'replica-a', 'gone', now() - interval '1 minute')",
    )
    .bind(sid)
    .execute(&srv.db.pool)
    .await
    .unwrap();
    let start = std::time::Instant::now();
    loop {
        let n: i64 = sqlx::query_scalar("SELECT count(*) FROM session_placements")
            .fetch_one(&srv.db.pool)
            .await
            .unwrap();
        if n == 0 {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "the row is still there"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_worker_url_with_a_trailing_slash_is_the_same_worker() {
    let token = "a-cluster-token-of-some-length";
    let srv = demo_server(true, Some(token)).await;
    let auth = format!("Bearer {token}");
    for url in [
        "http://127.0.0.1:9",
        "http://127.0.0.1:9/",
        "http://localhost:9",
    ] {
        let r = request_with_headers(
            "POST",
            &format!("http://{}/api/workers", srv.addr),
            Some(&json!({ "url": url, "capacity": 4, "renderer": {} })),
            &[("Authorization", auth.as_str())],
        )
        .await
        .unwrap();
        assert_eq!(r.status, 204, "{url}: {}", String::from_utf8_lossy(&r.body));
    }
    let urls: Vec<String> = sqlx::query_scalar("SELECT url FROM render_workers ORDER BY url")
        .fetch_all(&srv.db.pool)
        .await
        .unwrap();
    assert_eq!(urls, vec!["http://127.0.0.1:9", "http://localhost:9"]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_takeover_whose_notice_is_lost_still_fences_the_old_writer() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_, session) = learner.start_demo_attempt().await;
    let sid = session["session_id"].as_str().unwrap().to_string();
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r).len() == 1).await;
    // Another replica's takeover, as the database sees it, with no notice sent.
    sqlx::query("UPDATE live_sessions SET epoch = epoch + 1 WHERE id = $1::uuid")
        .bind(&sid)
        .execute(&srv.db.pool)
        .await
        .unwrap();
    // The next command reaches the worker, but its append is refused: never acknowledged,
    // never logged, and the connection closes with 4009 after a `taken_over` notice.
    ws.send(2, json!({ "type": "shot" })).await;
    let code = ws
        .until_closed(&mut got, Duration::from_secs(30))
        .await
        .map(|(c, _)| c);
    assert_eq!(code, Some(4009), "{:?}", got.texts);
    assert_eq!(acked(&got), vec![1]);
    assert!(
        got.texts.iter().any(|t| t["code"] == "taken_over"),
        "{:?}",
        got.texts
    );
    let logged: i64 = sqlx::query_scalar(
        "SELECT count(*) FROM live_session_commands WHERE session_id = $1::uuid",
    )
    .bind(&sid)
    .fetch_one(&srv.db.pool)
    .await
    .unwrap();
    assert_eq!(logged, 1);
    assert!(
        srv.dispatcher.session(sid.parse().unwrap()).is_none(),
        "the replica forgot it"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn workers_dead_for_an_hour_are_forgotten_unless_a_session_names_them() {
    let token = "a-cluster-token-of-some-length";
    let srv = demo_server(true, Some(token)).await;
    let auth = format!("Bearer {token}");
    for port in [9, 10] {
        let r = request_with_headers(
            "POST",
            &format!("http://{}/api/workers", srv.addr),
            Some(&json!({ "url": format!("http://127.0.0.1:{port}"), "capacity": 4, "renderer": {} })),
            &[("Authorization", auth.as_str())],
        )
        .await
        .unwrap();
        assert_eq!(r.status, 204);
    }
    // Both died two hours ago; a (stored) session is still placed on the second.
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_, session) = learner.start_demo_attempt().await;
    let sid: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    sqlx::query(
        "UPDATE render_workers SET state = 'dead', dead_since = now() - interval '2 hours',
         last_seen = now() - interval '2 hours'",
    )
    .execute(&srv.db.pool)
    .await
    .unwrap();
    sqlx::query(
        "UPDATE session_placements SET worker_url = 'http://127.0.0.1:10' WHERE session_id = $1",
    )
    .bind(sid)
    .execute(&srv.db.pool)
    .await
    .unwrap();
    let start = std::time::Instant::now();
    loop {
        let urls: Vec<String> = sqlx::query_scalar("SELECT url FROM render_workers ORDER BY url")
            .fetch_all(&srv.db.pool)
            .await
            .unwrap();
        if urls == ["http://127.0.0.1:10"] {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(5), "{urls:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}
