//! Durability of acknowledged session commands: the real `server` binary runs a live session
//! (the analytic demo station, in-process), a client streams commands over the websocket, and
//! the server is killed with SIGKILL in the middle of the stream. Every command whose
//! acknowledgement reached the client must be in `live_session_commands` at once; after a
//! restart on the same database the attempt resumes with all of them, the client re-sends what
//! it never saw acknowledged (as `web-client/session.js` does), and the submitted session
//! equals a reference session fed the same commands.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use render_worker::cluster::request_with_headers;
use render_worker::session::{Command, LogEntry, Session, SessionSnapshot};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

use crate::dispatch::{Client, demo_host};
use crate::server_process::{demo_deployment, spawn_on};

/// Commands of the scripted stream (sequence numbers 1..=N); the submit comes after them.
const SCRIPT_LEN: u64 = 400;
/// Acknowledgements to see before the kill: enough for several group commits to have happened.
const ACKS_BEFORE_KILL: usize = 60;

/// Command number `seq` of the script: C-arm moves, a shot every ten, the needle placed at 2
/// and fed 0.2 mm every ten (8 mm in all, well short of bone on the demo region's path).
fn scripted(seq: u64) -> Value {
    if seq == 2 {
        return json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [12, -80, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] });
    }
    match seq % 10 {
        0 => json!({ "type": "shot" }),
        5 if seq > 2 => json!({ "type": "needle_feed", "mm": 0.2 }),
        _ => json!({
            "type": "carm_pose",
            "orbital_deg": (seq * 7 % 41) as f64 - 20.0,
            "angular_deg": (seq * 3 % 21) as f64 - 10.0,
        }),
    }
}

/// Command `seq` as the session reads it (defaults filled in), in its canonical JSON form.
fn canonical(command: Value) -> Value {
    let c: Command = serde_json::from_value(command).expect("a valid command");
    serde_json::to_value(c).unwrap()
}

fn command_text(seq: u64, command: &Value) -> String {
    json!({ "type": "command", "seq": seq, "command": command }).to_string()
}

/// `POST /api/attempts/{id}/session`, retried while the server answers 503 (anatomy being
/// prepared) for up to 60 s; returns (status, body).
async fn open_session(c: &Client, attempt: &str) -> (u16, Value) {
    let start = Instant::now();
    loop {
        let r = request_with_headers(
            "POST",
            &format!("http://{}/api/attempts/{attempt}/session", c.addr),
            None,
            &[("Cookie", &c.cookie), ("X-CSRF-Token", &c.csrf)],
        )
        .await
        .expect("session request");
        if r.status != 503 || start.elapsed() > Duration::from_secs(60) {
            return (r.status, r.json().unwrap_or(Value::Null));
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

async fn websocket(c: &Client, path: &str) -> Socket {
    let mut req = format!("ws://{}{path}", c.addr)
        .into_client_request()
        .unwrap();
    req.headers_mut()
        .insert("Cookie", c.cookie.parse().unwrap());
    tokio_tungstenite::connect_async(req)
        .await
        .expect("websocket through the server")
        .0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_mid_session_loses_no_acknowledged_command() {
    let deployment = demo_deployment().await;
    let (db, env) = (&deployment.db, deployment.env.clone());
    let data = tempfile::tempdir().unwrap();

    let server = spawn_on(data.path(), &db.url, &env).await;
    let addr: SocketAddr = server.addr.parse().unwrap();
    let learner = Client::login(addr, "learner@demo.invalid").await;
    let (s, courses) = learner.call("GET", "/api/courses", None).await;
    assert_eq!(s, 200);
    let course = courses
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["code"] == "DEMO-101")
        .expect("demo course")["id"]
        .clone();
    let (s, attempt) = learner
        .call(
            "POST",
            "/api/attempts",
            Some(json!({ "course_id": course, "station_id": "demo-station" })),
        )
        .await;
    assert_eq!(s, 201, "{attempt}");
    let attempt = attempt["id"].as_str().unwrap().to_string();
    let (s, session) = open_session(&learner, &attempt).await;
    assert_eq!(s, 201, "{session}");
    let session_id: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();

    // Stream the script; collect acknowledgements (seq -> t_ms) until the socket dies.
    let (mut tx, mut rx) = websocket(&learner, session["ws"].as_str().unwrap())
        .await
        .split();
    let acks: Arc<Mutex<BTreeMap<u64, u64>>> = Arc::default();
    let reader = tokio::spawn({
        let acks = acks.clone();
        async move {
            while let Some(Ok(m)) = rx.next().await {
                if let Message::Text(t) = m {
                    let v: Value = serde_json::from_str(&t).unwrap();
                    assert_ne!(v["type"], "error", "{v}");
                    if v["type"] == "ack" {
                        let (seq, t_ms) = (v["seq"].as_u64().unwrap(), v["t_ms"].as_u64().unwrap());
                        acks.lock().unwrap().insert(seq, t_ms);
                    }
                }
            }
        }
    });
    let killed = Arc::new(AtomicBool::new(false));
    let writer = tokio::spawn({
        let killed = killed.clone();
        async move {
            let mut sent = 0;
            for seq in 1..=SCRIPT_LEN {
                if killed.load(Ordering::SeqCst)
                    || tx
                        .send(Message::Text(command_text(seq, &scripted(seq)).into()))
                        .await
                        .is_err()
                {
                    break;
                }
                sent = seq;
                // A steady stream (a learner dragging the C-arm), not one burst.
                tokio::time::sleep(Duration::from_millis(2)).await;
            }
            sent
        }
    });
    let deadline = Instant::now() + Duration::from_secs(60);
    while acks.lock().unwrap().len() < ACKS_BEFORE_KILL {
        assert!(
            Instant::now() < deadline,
            "only {} acks in 60 s",
            acks.lock().unwrap().len()
        );
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    tokio::task::spawn_blocking(move || server.sigkill())
        .await
        .unwrap();
    killed.store(true, Ordering::SeqCst);
    let sent = writer.await.unwrap();
    tokio::time::timeout(Duration::from_secs(30), reader)
        .await
        .expect("the socket of a killed server ends")
        .expect("no error message from the session");
    let acked_before = acks.lock().unwrap().clone();
    let last_acked = *acked_before.keys().last().unwrap();
    assert_eq!(
        acked_before.keys().copied().collect::<Vec<_>>(),
        (1..=last_acked).collect::<Vec<_>>(),
        "acknowledgements arrive in order, none skipped"
    );

    // Straight after the kill, before any restart: every acknowledged command is stored, with
    // the time it was applied at and exactly the command sent.
    let stored: Vec<(i64, i64, Value)> = sqlx::query_as(
        "SELECT seq, t_ms, command FROM live_session_commands WHERE session_id = $1 ORDER BY seq",
    )
    .bind(session_id)
    .fetch_all(&db.pool)
    .await
    .unwrap();
    let stored: BTreeMap<u64, (u64, Value)> = stored
        .into_iter()
        .map(|(s, t, c)| (s as u64, (t as u64, c)))
        .collect();
    let lost: Vec<u64> = acked_before
        .iter()
        .filter(|(seq, t_ms)| {
            stored
                .get(seq)
                .is_none_or(|(t, c)| t != *t_ms || *c != canonical(scripted(**seq)))
        })
        .map(|(seq, _)| *seq)
        .collect();
    eprintln!(
        "session SIGKILL test: {sent} commands sent, {} acknowledged before the kill, {} stored",
        acked_before.len(),
        stored.len()
    );
    assert!(
        lost.is_empty(),
        "acknowledged but not stored (or stored differently): {lost:?}"
    );
    assert!(
        stored.keys().copied().eq(1..=stored.len() as u64),
        "the stored log is a gap-free prefix: {:?}",
        stored.keys().collect::<Vec<_>>()
    );

    // Restart on the same database; the login session survives in PostgreSQL.
    let server = spawn_on(data.path(), &db.url, &env).await;
    let learner = Client {
        addr: server.addr.parse().unwrap(),
        ..learner
    };
    let (s, resumed) = open_session(&learner, &attempt).await;
    assert_eq!(s, 200, "{resumed}");
    assert_eq!(resumed["session_id"], session_id.to_string());
    let resumed_seq = resumed["last_seq"].as_u64().unwrap();
    assert!(
        resumed_seq >= last_acked,
        "resumed at {resumed_seq}, acknowledged {last_acked}"
    );

    // The client re-sends every command it never saw acknowledged, then the rest, then submits.
    let mut ws = websocket(&learner, resumed["ws"].as_str().unwrap()).await;
    let submit_seq = SCRIPT_LEN + 1;
    for seq in (last_acked + 1)..=SCRIPT_LEN {
        ws.send(Message::Text(command_text(seq, &scripted(seq)).into()))
            .await
            .unwrap();
    }
    ws.send(Message::Text(
        command_text(submit_seq, &json!({ "type": "submit" })).into(),
    ))
    .await
    .unwrap();
    let mut hello_seq = None;
    let mut answered = std::collections::BTreeSet::new();
    let mut duplicates = 0;
    let mut result = None;
    while result.is_none() {
        let m = tokio::time::timeout(Duration::from_secs(60), ws.next())
            .await
            .expect("a message within 60 s")
            .expect("open")
            .expect("ok");
        let Message::Text(t) = m else { continue };
        let v: Value = serde_json::from_str(&t).unwrap();
        match v["type"].as_str() {
            Some("hello") => hello_seq = v["last_seq"].as_u64(),
            Some("ack") => {
                answered.insert(v["seq"].as_u64().unwrap());
                duplicates += usize::from(v["duplicate"] == true);
            }
            Some("technical_result") => result = Some(v["result"].clone()),
            Some("error" | "technical_result_error") => panic!("{v}"),
            _ => {}
        }
    }
    assert_eq!(
        hello_seq,
        Some(resumed_seq),
        "the resumed session starts where it was stored"
    );
    assert_eq!(
        answered,
        ((last_acked + 1)..=submit_seq).collect(),
        "every re-sent command answered once"
    );
    assert_eq!(
        duplicates as u64,
        resumed_seq - last_acked,
        "commands stored but not yet acknowledged when the server died come back as duplicates"
    );

    // The recorded timeline is the whole script, each command once, in order, and a replay of it
    // reproduces the submitted result.
    let (s, replay) = learner
        .call("GET", &format!("/api/attempts/{attempt}/replay"), None)
        .await;
    assert_eq!(s, 200, "{}", replay["error"]);
    let timeline: Vec<LogEntry> = serde_json::from_value(replay["timeline"].clone()).unwrap();
    assert_eq!(
        timeline.iter().map(|e| e.seq).collect::<Vec<_>>(),
        (1..=submit_seq).collect::<Vec<_>>()
    );
    for e in &timeline {
        let sent = if e.seq == submit_seq {
            json!({ "type": "submit" })
        } else {
            scripted(e.seq)
        };
        assert_eq!(
            serde_json::to_value(&e.command).unwrap(),
            canonical(sent),
            "command {}",
            e.seq
        );
        if let Some(t_ms) = acked_before.get(&e.seq) {
            assert_eq!(
                e.t_ms, *t_ms,
                "command {} keeps the time it was acknowledged with",
                e.seq
            );
        }
    }
    // (Frames are not compared: the resumed session may render on the CPU reference while the
    // server's GPU is still starting, and the replay on the GPU; see dispatch::InProcessBackend.)
    assert_eq!(
        replay["replayed"]["final_state_sha256"], replay["recorded"]["final_state_sha256"],
        "recorded {} replayed {}",
        replay["recorded"], replay["replayed"]
    );
    assert_eq!(replay["replayed"]["score"], replay["recorded"]["score"]);

    // A reference session fed the same commands (at the logged times) ends in the same state.
    let initial: Value =
        sqlx::query_scalar("SELECT initial_snapshot FROM live_sessions WHERE id = $1")
            .bind(session_id)
            .fetch_one(&db.pool)
            .await
            .unwrap();
    let initial: SessionSnapshot = serde_json::from_value(initial).unwrap();
    let reference_log: Vec<LogEntry> = timeline
        .iter()
        .map(|e| {
            let sent = if e.seq == submit_seq {
                json!({ "type": "submit" })
            } else {
                scripted(e.seq)
            };
            LogEntry {
                seq: e.seq,
                t_ms: e.t_ms,
                command: serde_json::from_value(sent).unwrap(),
            }
        })
        .collect();
    let env_ref = demo_host(1).env_for("demo-station").unwrap();
    let reference = Session::restore(env_ref, &initial, &reference_log).unwrap();
    let reference_state = &reference
        .result()
        .expect("the reference was submitted")
        .record
        .final_state_sha256;
    assert_eq!(
        replay["recorded"]["final_state_sha256"].as_str(),
        Some(reference_state.as_str()),
        "the live session's final state is the reference's"
    );
    assert!(result.is_some());
    server.sigterm_and_wait();
}
