//! Two server replicas over one PostgreSQL, the only state they share: any replica relays any
//! session (a connection takes the session over by bumping its epoch), a replica that lost a
//! session can no longer append to its log (fencing), workers are registered in the shared
//! state only with the cluster token, a well-formed body and an address they own, and every
//! replica lists the same workers.

use std::time::Duration;

use render_worker::cluster::request_with_headers;
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

use crate::dispatch_support::{
    Client, Received, acked, demo_server, disable_account, second_replica,
};

/// The stored log of a session: (seq, epoch) in order.
async fn stored_log(pool: &sqlx::PgPool, session: &str) -> Vec<(i64, i64)> {
    sqlx::query_as(
        "SELECT seq, epoch FROM live_session_commands WHERE session_id = $1::uuid ORDER BY seq",
    )
    .bind(session)
    .fetch_all(pool)
    .await
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failover_to_a_second_replica_takes_the_session_and_fences_off_the_first() {
    let srv = demo_server(true, None).await;
    let (addr_b, replica_b) = second_replica(&srv, "replica-b").await;
    let learner_a = Client::login(srv.addr, "learner@demo.invalid").await;
    // The login is a row of the shared database: the same cookie works on replica B.
    let learner_b = Client {
        addr: addr_b,
        ..learner_a.clone()
    };
    let (attempt, session) = learner_a.start_demo_attempt().await;
    let sid = session["session_id"].as_str().unwrap().to_string();
    let ws_path = session["ws"].as_str().unwrap().to_string();
    let mut ws_a = learner_a.websocket(&ws_path).await;
    let mut got_a = Received::default();
    let first = [
        json!({ "type": "carm_pose", "orbital_deg": 15, "angular_deg": 0 }),
        json!({ "type": "shot" }),
        json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [12, -80, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] }),
    ];
    for (i, c) in first.iter().enumerate() {
        ws_a.send(i as u64 + 1, c.clone()).await;
    }
    ws_a.until(&mut got_a, |r| acked(r).len() == 3).await;
    assert_eq!(
        stored_log(&srv.db.pool, &sid).await,
        vec![(1, 1), (2, 1), (3, 1)]
    );

    // The browser reconnects through replica B (a round-robin balancer would do this): B
    // takes the session over and restores it from the stored snapshot and log.
    let mut ws_b = learner_b.websocket(&ws_path).await;
    let mut got_b = Received::default();
    ws_b.until(&mut got_b, |r| !r.texts.is_empty()).await;
    assert_eq!(got_b.texts[0]["type"], "hello", "{:?}", got_b.texts);
    assert_eq!(
        got_b.texts[0]["last_seq"], 3,
        "restored up to the durable log"
    );
    assert_eq!(got_b.texts[0]["session"]["id"], sid.as_str());
    let placement: (String, i64, Option<String>) = sqlx::query_as(
        "SELECT replica, epoch, worker_url FROM session_placements WHERE session_id = $1::uuid",
    )
    .bind(&sid)
    .fetch_one(&srv.db.pool)
    .await
    .unwrap();
    assert_eq!(placement, ("replica-b".into(), 2, None));
    ws_b.send(4, json!({ "type": "needle_feed", "mm": 10 }))
        .await;
    ws_b.send(5, json!({ "type": "shot" })).await;
    ws_b.until(&mut got_b, |r| acked(r).len() == 2).await;

    // Replica A's old connection ends with 4009: B's takeover notice reached A (or, had it not,
    // A's next log append is refused by the database, fenced). A command sent there now is
    // never acknowledged.
    let late =
        json!({ "type": "command", "seq": 6, "command": { "type": "needle_feed", "mm": 3 } });
    let _ = futures::SinkExt::send(&mut ws_a.ws, Message::Text(late.to_string().into())).await;
    let code = ws_a
        .until_closed(&mut got_a, Duration::from_secs(30))
        .await
        .map(|(c, _)| c);
    assert_eq!(code, Some(4009), "{:?}", got_a.texts);
    assert_eq!(
        acked(&got_a),
        vec![1, 2, 3],
        "the fenced command was not acknowledged"
    );
    assert!(
        got_a.texts.iter().any(|t| t["code"] == "taken_over"),
        "{:?}",
        got_a.texts
    );
    assert!(
        srv.dispatcher.session(sid.parse().unwrap()).is_none(),
        "replica A forgot the session it lost"
    );
    assert_eq!(
        stored_log(&srv.db.pool, &sid).await,
        vec![(1, 1), (2, 1), (3, 1), (4, 2), (5, 2)],
        "every acknowledged command once, and nothing from the fenced replica"
    );
    // The database itself refuses an append at the old epoch.
    let refused = sqlx::query(
        "INSERT INTO live_session_commands (session_id, seq, t_ms, command, epoch)
         VALUES ($1::uuid, 6, 0, '{\"type\":\"shot\"}', 1)",
    )
    .bind(&sid)
    .execute(&srv.db.pool)
    .await
    .expect_err("an append at a superseded epoch");
    let code = refused
        .as_database_error()
        .and_then(|e| e.code())
        .map(|c| c.into_owned());
    assert_eq!(code.as_deref(), Some("PF409"), "{refused}");

    // Through replica A the session is B's: its view comes from the shared state, and asking
    // for the attempt's session there does not take it back.
    let (s, info) = learner_a
        .call("GET", &format!("/api/sessions/{sid}"), None)
        .await;
    assert_eq!(s, 200, "{info}");
    assert_eq!(info["worker"], "in-process (replica-b)", "{info}");
    assert_eq!(
        (info["log_len"].as_u64(), info["last_seq"].as_u64()),
        (Some(5), Some(5))
    );
    let (s, again) = learner_a.session_of(&attempt).await;
    assert_eq!(s, 200, "{again}");
    assert_eq!(again["session_id"], sid.as_str());
    let epoch: i64 = sqlx::query_scalar("SELECT epoch FROM live_sessions WHERE id = $1::uuid")
        .bind(&sid)
        .fetch_one(&srv.db.pool)
        .await
        .unwrap();
    assert_eq!(epoch, 2, "asking through A took nothing over");

    // The session goes on through B to a result, and the replay equals the live state.
    ws_b.send(6, json!({ "type": "submit" })).await;
    ws_b.until(&mut got_b, |r| {
        r.texts.iter().any(|t| t["type"] == "technical_result")
    })
    .await;
    let (s, replay) = learner_b
        .call("GET", &format!("/api/attempts/{attempt}/replay"), None)
        .await;
    assert_eq!(s, 200, "{replay}");
    assert_eq!(replay["timeline"].as_array().unwrap().len(), 6);
    assert_eq!(
        replay["recorded"]["final_state_sha256"], replay["replayed"]["final_state_sha256"],
        "{replay}"
    );
    // Once the browser leaves, B frees the submitted session and its placement.
    drop(ws_b);
    for _ in 0..100 {
        if replica_b.session(sid.parse().unwrap()).is_none() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(
        replica_b.session(sid.parse().unwrap()).is_none(),
        "a submitted session is freed"
    );
    // The replica forgets the session first and then removes its placement row
    // (`Dispatcher::close_taken`): the row goes shortly after.
    let mut placements = -1i64;
    for _ in 0..100 {
        placements = sqlx::query_scalar("SELECT count(*) FROM session_placements")
            .fetch_one(&srv.db.pool)
            .await
            .unwrap();
        if placements == 0 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert_eq!(placements, 0, "no live session is left in the shared state");
}

/// Every row of `render_workers` as JSON (the whole shared worker state).
async fn workers_table(pool: &sqlx::PgPool) -> Value {
    sqlx::query_scalar(
        "SELECT COALESCE(jsonb_agg(to_jsonb(w) ORDER BY url), '[]') FROM render_workers w",
    )
    .fetch_one(pool)
    .await
    .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_registrations_are_refused_and_change_nothing_and_replicas_agree() {
    let token = "a-cluster-token-of-some-length";
    let srv = demo_server(true, Some(token)).await;
    let (addr_b, replica_b) = second_replica(&srv, "replica-b").await;
    let register = format!("http://{}/api/workers", srv.addr);
    let auth = format!("Bearer {token}");
    let good = json!({ "url": "http://127.0.0.1:9", "capacity": 4, "renderer": {}, "adapter": null, "sessions": 1 });
    let post = |body: Value, bearer: String| {
        let register = register.clone();
        async move {
            request_with_headers(
                "POST",
                &register,
                Some(&body),
                &[("Authorization", bearer.as_str())],
            )
            .await
            .unwrap()
        }
    };
    let refused = [
        (
            good.clone(),
            "Bearer wrong-token-wrong-token".to_string(),
            401,
        ),
        (good.clone(), String::new(), 401),
        (json!({ "url": "http://127.0.0.1:9" }), auth.clone(), 400),
        (
            json!({ "url": "http://127.0.0.1:9", "capacity": "four", "renderer": {} }),
            auth.clone(),
            400,
        ),
        (
            json!({ "url": "http://127.0.0.1:9", "capacity": 0, "renderer": {} }),
            auth.clone(),
            400,
        ),
        (
            json!({ "url": "ftp://127.0.0.1:9", "capacity": 4, "renderer": {} }),
            auth.clone(),
            400,
        ),
        (
            json!({ "url": "http://127.0.0.1:0", "capacity": 4, "renderer": {} }),
            auth.clone(),
            400,
        ),
        (
            json!({ "url": "http://127.0.0.1:9/elsewhere", "capacity": 4, "renderer": {} }),
            auth.clone(),
            400,
        ),
        (json!([1, 2, 3]), auth.clone(), 400),
        // Addresses the caller (127.0.0.1) does not own.
        (
            json!({ "url": "http://10.20.30.40:8081", "capacity": 4, "renderer": {} }),
            auth.clone(),
            403,
        ),
        (
            json!({ "url": "http://worker.invalid:8081", "capacity": 4, "renderer": {} }),
            auth.clone(),
            403,
        ),
    ];
    for (body, bearer, status) in &refused {
        let r = post(body.clone(), bearer.clone()).await;
        assert_eq!(
            r.status,
            *status,
            "{body} -> {}",
            String::from_utf8_lossy(&r.body)
        );
        assert_eq!(
            workers_table(&srv.db.pool).await,
            json!([]),
            "{body} changed the shared state"
        );
    }
    let r = request_with_headers("POST", &register, None, &[("Authorization", auth.as_str())])
        .await
        .unwrap();
    assert_eq!(r.status, 400, "no body");
    // A good registration through replica A is seen by both replicas alike.
    assert_eq!(post(good.clone(), auth.clone()).await.status, 204);
    let before = workers_table(&srv.db.pool).await;
    assert_eq!(before.as_array().unwrap().len(), 1);
    let a = srv.dispatcher.workers().await.unwrap();
    let b = replica_b.workers().await.unwrap();
    assert_eq!(a.len(), 1);
    assert_eq!(
        serde_json::to_value(&a).unwrap()[0]["url"],
        serde_json::to_value(&b).unwrap()[0]["url"]
    );
    assert_eq!(a[0].state, "alive");
    assert_eq!(a[0].reported_sessions, 1);
    // Heartbeats for that worker that are refused leave its row exactly as it was.
    for (body, bearer) in [
        (
            json!({ "url": "http://127.0.0.1:9", "capacity": 9, "renderer": {}, "draining": true }),
            "Bearer wrong-token-wrong-token".to_string(),
        ),
        (
            json!({ "url": "http://127.0.0.1:9", "capacity": 9, "renderer": {}, "sessions": -1 }),
            auth.clone(),
        ),
        (
            json!({ "url": "http://127.0.0.1:9", "capacity": 20000, "renderer": {} }),
            auth.clone(),
        ),
    ] {
        let r = post(body.clone(), bearer).await;
        assert!((400..500).contains(&r.status), "{body}: {}", r.status);
        assert_eq!(
            workers_table(&srv.db.pool).await,
            before,
            "{body} changed the worker's row"
        );
    }
    // /healthz reads the same shared state on both replicas.
    let health = |addr: std::net::SocketAddr| async move {
        let r = request_with_headers("GET", &format!("http://{addr}/healthz"), None, &[])
            .await
            .unwrap();
        r.json().unwrap()["cluster"].clone()
    };
    let (ha, hb) = (health(srv.addr).await, health(addr_b).await);
    assert_eq!(ha["workers"], hb["workers"], "{ha} / {hb}");
    assert_eq!(ha["live_sessions"], hb["live_sessions"]);
    assert_eq!(ha["workers"]["alive"], 1, "{ha}");
    assert_eq!(
        (ha["replica"].as_str(), hb["replica"].as_str()),
        (Some("replica-a"), Some("replica-b"))
    );
    // An admin's GET /api/workers agrees across replicas (last_seen_s aside, which ticks).
    let admin_a = Client::login(srv.addr, "admin@demo.invalid").await;
    let admin_b = Client {
        addr: addr_b,
        ..admin_a.clone()
    };
    let strip = |mut v: Value| {
        for w in v["remote"].as_array_mut().unwrap() {
            w.as_object_mut().unwrap().remove("last_seen_s");
        }
        v["remote"].clone()
    };
    let (sa, la) = admin_a.call("GET", "/api/workers", None).await;
    let (sb, lb) = admin_b.call("GET", "/api/workers", None).await;
    assert_eq!((sa, sb), (200, 200));
    assert_eq!(strip(la), strip(lb));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silent_worker_is_marked_dead_by_exactly_one_replica() {
    let token = "a-cluster-token-of-some-length";
    let srv = demo_server(true, Some(token)).await;
    let (_addr_b, replica_b) = second_replica(&srv, "replica-b").await;
    let body = json!({ "url": "http://127.0.0.1:9", "capacity": 4, "renderer": {} });
    let r = request_with_headers(
        "POST",
        &format!("http://{}/api/workers", srv.addr),
        Some(&body),
        &[("Authorization", &format!("Bearer {token}"))],
    )
    .await
    .unwrap();
    assert_eq!(r.status, 204);
    // Its heartbeats stop: its last one is a minute old. Both replicas sweep at once.
    sqlx::query("UPDATE render_workers SET last_seen = now() - interval '1 minute'")
        .execute(&srv.db.pool)
        .await
        .unwrap();
    let (a, b) = tokio::join!(
        srv.dispatcher.registry().sweep_dead("replica-a"),
        replica_b.registry().sweep_dead("replica-b"),
    );
    let (a, b) = (a.unwrap(), b.unwrap());
    // Their own sweepers may have won too; in all, exactly one replica marked it.
    let (state, by): (String, Option<String>) =
        sqlx::query_as("SELECT state, marked_dead_by FROM render_workers")
            .fetch_one(&srv.db.pool)
            .await
            .unwrap();
    assert_eq!(state, "dead");
    let by = by.expect("the replica that marked it");
    assert!(a.len() + b.len() <= 1, "one winner: {a:?} {b:?}");
    if let Some(winner) = a
        .iter()
        .map(|_| "replica-a")
        .chain(b.iter().map(|_| "replica-b"))
        .next()
    {
        assert_eq!(by, winner);
    }
    assert!(["replica-a", "replica-b"].contains(&by.as_str()), "{by}");
    // A dead worker gets no sessions; its next heartbeat revives it.
    assert!(srv.dispatcher.registry().by_load(None).await.is_empty());
    let r = request_with_headers(
        "POST",
        &format!("http://{}/api/workers", srv.addr),
        Some(&body),
        &[("Authorization", &format!("Bearer {token}"))],
    )
    .await
    .unwrap();
    assert_eq!(r.status, 204);
    assert_eq!(
        srv.dispatcher.registry().by_load(None).await,
        vec!["http://127.0.0.1:9".to_string()]
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_account_revoked_on_one_replica_loses_its_session_on_another() {
    let srv = demo_server(true, None).await;
    let (addr_b, replica_b) = second_replica(&srv, "replica-b").await;
    let learner_a = Client::login(srv.addr, "learner@demo.invalid").await;
    let learner_b = Client {
        addr: addr_b,
        ..learner_a.clone()
    };
    let (_, session) = learner_a.start_demo_attempt().await;
    let sid: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    // The session is relayed by replica B.
    let mut ws = learner_b.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r).len() == 1).await;
    assert!(replica_b.session(sid).is_some());
    // An admin disables the learner through replica A: B closes the session with 4003.
    disable_account(srv.addr, &srv.db.pool, "learner@demo.invalid").await;
    let code = ws
        .until_closed(&mut got, Duration::from_secs(30))
        .await
        .map(|(c, _)| c);
    assert_eq!(
        code,
        Some(server::dispatch::CLOSE_REVOKED),
        "{:?}",
        got.texts
    );
    for _ in 0..100 {
        if replica_b.session(sid).is_none() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(
        replica_b.session(sid).is_none(),
        "replica B freed the session"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_replica_forgets_a_copy_that_another_replica_took_over() {
    let srv = demo_server(true, None).await;
    let (addr_b, _replica_b) = second_replica(&srv, "replica-b").await;
    // Replica A reaps every 2 s (a quarter of its 8 s idle limit).
    srv.dispatcher.set_session_idle(Duration::from_secs(8));
    let learner_a = Client::login(srv.addr, "learner@demo.invalid").await;
    let learner_b = Client {
        addr: addr_b,
        ..learner_a.clone()
    };
    let (_, session) = learner_a.start_demo_attempt().await;
    let sid: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    let mut ws_a = learner_a.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws_a.send(1, json!({ "type": "shot" })).await;
    ws_a.until(&mut got, |r| acked(r).len() == 1).await;
    drop(ws_a);
    // The learner comes back through replica B, which takes the session over.
    let mut ws_b = learner_b.websocket(session["ws"].as_str().unwrap()).await;
    let mut got_b = Received::default();
    ws_b.send(2, json!({ "type": "shot" })).await;
    ws_b.until(&mut got_b, |r| acked(r).len() == 1).await;
    // A holds a stale copy with nobody connected: its reaper forgets it (and frees its worker
    // slot) well before the idle limit.
    let start = std::time::Instant::now();
    while srv.dispatcher.session(sid).is_some() {
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "replica A still holds the session it lost"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(
        srv.dispatcher.local_capacity().map(|(live, _)| live),
        Some(0)
    );
}
