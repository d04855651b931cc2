//! Dispatch of live sessions: the server's websocket relay, authorization, engagement events,
//! the submit hand-off to the learning records, exact replay, and failover after a render
//! worker process is killed. The fixtures are in `dispatch_support` (re-exported here, where the
//! other modules have always found them).

use std::net::SocketAddr;
use std::time::Duration;

use futures::{SinkExt, StreamExt};
use render_worker::cluster::request_with_headers;
use serde_json::json;
use server::dispatch::Dispatcher;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

pub use crate::dispatch_support::{
    Client, DemoServer, Received, Ws, acked, base_workers, demo_host, demo_server, demo_server_for,
    demo_server_with,
};

/// Entry point of a worker process for the failover test: the test binary runs itself with
/// `PAINSIM_TEST_WORKER_REGISTER` set, and this "test" then serves the demo host over the
/// render worker's HTTP and websocket surface and registers with the server, until killed.
/// Without the variable it returns at once (it is ignored in normal runs).
#[test]
#[ignore = "entry point of the worker processes spawned by `failover_after_worker_process_is_killed`"]
fn worker_process_entry() {
    let Ok(register) = std::env::var("PAINSIM_TEST_WORKER_REGISTER") else {
        return;
    };
    let token = std::env::var("PAINSIM_TEST_WORKER_TOKEN").expect("token");
    let drain_ms: u64 = std::env::var("PAINSIM_TEST_WORKER_DRAIN_MS")
        .ok()
        .and_then(|d| d.parse().ok())
        .unwrap_or(25_000);
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    rt.block_on(async move {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .expect("bind");
        let addr = listener.local_addr().unwrap();
        println!("worker {addr} ready");
        // The binary's own serving loop: heartbeats, and the drain on SIGTERM.
        let serving = render_worker::cluster::Serving {
            register: Some((register, token)),
            public_url: None,
            drain: Duration::from_millis(drain_ms),
        };
        render_worker::cluster::serve_until_drained(
            listener,
            demo_host(8),
            serving,
            render_worker::cluster::stop_signal(),
        )
        .await
        .expect("serve");
    });
}

pub(crate) fn spawn_worker(register: &str, token: &str) -> std::process::Child {
    spawn_worker_draining(register, token, Duration::from_secs(25))
}

/// A worker process that drains for `drain` after SIGTERM.
pub(crate) fn spawn_worker_draining(
    register: &str,
    token: &str,
    drain: Duration,
) -> std::process::Child {
    std::process::Command::new(std::env::current_exe().expect("test binary"))
        .args([
            "--exact",
            "dispatch::worker_process_entry",
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env("PAINSIM_TEST_WORKER_REGISTER", register)
        .env("PAINSIM_TEST_WORKER_TOKEN", token)
        .env(
            "PAINSIM_TEST_WORKER_DRAIN_MS",
            drain.as_millis().to_string(),
        )
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("spawn a worker process")
}

/// Worker processes of a test, killed and reaped when it ends, whether it passed or panicked.
pub(crate) struct WorkerProcesses(pub Vec<std::process::Child>);

impl std::ops::Deref for WorkerProcesses {
    type Target = Vec<std::process::Child>;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl std::ops::DerefMut for WorkerProcesses {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.0
    }
}

impl Drop for WorkerProcesses {
    fn drop(&mut self) {
        for w in &mut self.0 {
            let _ = w.kill();
            let _ = w.wait();
        }
    }
}

pub(crate) async fn wait_for_workers(d: &Dispatcher, n: usize) {
    for _ in 0..600 {
        let alive = d.workers().await.expect("workers from the shared state");
        if alive.iter().filter(|w| w.state == "alive").count() >= n {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!(
        "{n} workers did not register within 60 s: {:?}",
        d.workers().await
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn in_process_session_records_activity_result_and_replays_exactly() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    assert_eq!(session["worker"], "in-process");
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.until(&mut got, |r| !r.texts.is_empty()).await;
    assert_eq!(got.texts[0]["type"], "hello");
    assert_eq!(
        got.texts[0]["session"]["id"], session["session_id"],
        "the browser sees the server's session id"
    );
    let commands = [
        json!({ "type": "shot" }),
        json!({ "type": "carm_pose", "orbital_deg": 25, "angular_deg": -5 }),
        json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [12, -80, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] }),
        json!({ "type": "needle_feed", "mm": 20 }),
        json!({ "type": "shot" }),
    ];
    for (i, c) in commands.iter().enumerate() {
        ws.send(i as u64 + 1, c.clone()).await;
    }
    ws.until(&mut got, |r| {
        acked(r).len() == 5 && r.frames.last() == Some(&5)
    })
    .await;
    assert_eq!(acked(&got), vec![1, 2, 3, 4, 5]);
    ws.send(6, json!({ "type": "submit" })).await;
    ws.until(&mut got, |r| {
        r.texts.iter().any(|t| t["type"] == "technical_result")
    })
    .await;
    let result = got
        .texts
        .iter()
        .find(|t| t["type"] == "technical_result")
        .unwrap()["result"]
        .clone();
    assert_eq!(result["source"], "server");
    drop(ws);

    // The attempt is submitted with the result and the engagement events of the session.
    let (s, detail) = learner
        .call("GET", &format!("/api/attempts/{attempt}"), None)
        .await;
    assert_eq!(s, 200);
    assert_eq!(detail["attempt"]["state"], "submitted");
    assert_eq!(detail["results"][0]["id"], result["id"]);
    let (_, events) = learner
        .call("GET", &format!("/api/attempts/{attempt}/activity"), None)
        .await;
    let kinds: Vec<&str> = events
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap())
        .collect();
    for k in [
        "station_opened",
        "session_launched",
        "image_acquired",
        "view_changed",
        "needle_adjusted",
        "submission",
    ] {
        assert!(kinds.contains(&k), "{k} missing from {kinds:?}");
    }
    // Activity is recorded asynchronously; shots: 2 by the end.
    for _ in 0..50 {
        let (_, events) = learner
            .call("GET", &format!("/api/attempts/{attempt}/activity"), None)
            .await;
        if events
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| e["kind"] == "image_acquired")
            .count()
            == 2
        {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // Faculty replay: the timeline is the log, and the full replay reproduces score, final
    // state and final frame exactly.
    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    let (s, replay) = faculty
        .call("GET", &format!("/api/attempts/{attempt}/replay"), None)
        .await;
    assert_eq!(s, 200, "{replay}");
    assert_eq!(replay["timeline"].as_array().unwrap().len(), 6);
    assert_eq!(replay["recorded"]["score"], replay["replayed"]["score"]);
    assert_eq!(
        replay["recorded"]["final_state_sha256"],
        replay["replayed"]["final_state_sha256"]
    );
    assert!(
        replay["recorded"]["final_frame_sha256"].is_string(),
        "{replay}"
    );
    assert_eq!(replay["identical"], true, "{replay}");
    // The stored measurements are exactly those of the replay (every one, bit for bit).
    assert!(
        replay["recorded"]["measurements"]
            .as_object()
            .is_some_and(|m| !m.is_empty()),
        "{replay}"
    );
    assert_eq!(
        replay["recorded"]["measurements"],
        replay["replayed"]["measurements"]
    );
    assert_eq!(replay["recorded"]["measurements"], result["measurements"]);
    assert_eq!(replay["differing_measurements"], json!([]));
    // The background checker replays the stored result on its own and records the verdict,
    // which travels with the result: detail, review queue and CSV export show source and check.
    let mut verdict = serde_json::Value::Null;
    for _ in 0..600 {
        let (_, d) = faculty
            .call("GET", &format!("/api/attempts/{attempt}"), None)
            .await;
        verdict = d["results"][0]["replay_check"].clone();
        if verdict["verdict"] != "pending" {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(verdict["verdict"], "identical", "{verdict}");
    assert_eq!(
        verdict["detail"]["measurements"]["differing_keys"],
        json!([]),
        "{verdict}"
    );
    let (_, d) = faculty
        .call("GET", &format!("/api/attempts/{attempt}"), None)
        .await;
    assert_eq!(d["results"][0]["source"], "server");
    let (s, queue) = faculty
        .call("GET", "/api/reviews?state=submitted", None)
        .await;
    assert_eq!(s, 200, "{queue}");
    let row = queue
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["id"] == attempt.to_string().as_str())
        .expect("queued");
    assert_eq!(
        (
            row["latest_source"].as_str(),
            row["latest_replay_check"].as_str()
        ),
        (Some("server"), Some("identical")),
        "{row}"
    );
    let r = request_with_headers(
        "GET",
        &format!("http://{}/api/reviews/export.csv?state=submitted", srv.addr),
        None,
        &[("Cookie", &faculty.cookie)],
    )
    .await
    .unwrap();
    let csv = String::from_utf8_lossy(&r.body).into_owned();
    assert!(
        csv.lines()
            .next()
            .unwrap()
            .contains("result_source,replay_check"),
        "{csv}"
    );
    assert!(csv.contains("\"server\",\"identical\""), "{csv}");
    let r = request_with_headers(
        "GET",
        &format!(
            "http://{}/api/attempts/{attempt}/replay/frame?step=1",
            srv.addr
        ),
        None,
        &[("Cookie", &faculty.cookie)],
    )
    .await
    .unwrap();
    assert_eq!(r.status, 200);
    assert_eq!(&r.body[..2], &[0xFF, 0xD8], "a JPEG");
    let r = request_with_headers(
        "GET",
        &format!(
            "http://{}/api/attempts/{attempt}/replay/frame?step=0",
            srv.addr
        ),
        None,
        &[("Cookie", &faculty.cookie)],
    )
    .await
    .unwrap();
    assert_eq!(r.status, 204, "no image before the first shot");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_learner_drives_and_workers_need_the_token() {
    let srv = demo_server(true, Some("a-cluster-token-of-some-length")).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let sid = session["session_id"].as_str().unwrap();
    // Another learner of the same course: cannot see the attempt, open or join its session.
    let other = Client::login(srv.addr, "learner2@demo.invalid").await;
    assert_eq!(
        other
            .call("POST", &format!("/api/attempts/{attempt}/session"), None)
            .await
            .0,
        404
    );
    assert_eq!(
        other
            .call("GET", &format!("/api/sessions/{sid}"), None)
            .await
            .0,
        404
    );
    assert_eq!(
        handshake_status(srv.addr, sid, &other.cookie, None).await,
        404
    );
    // Faculty can read the replay but cannot drive the session.
    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    assert_eq!(
        faculty
            .call("POST", &format!("/api/attempts/{attempt}/session"), None)
            .await
            .0,
        403
    );
    assert_eq!(
        faculty
            .call("GET", &format!("/api/sessions/{sid}"), None)
            .await
            .0,
        404
    );
    // A cross-site handshake with the learner's cookie is refused.
    assert_eq!(
        handshake_status(srv.addr, sid, &learner.cookie, Some("http://evil.example")).await,
        403
    );
    let own_origin = format!("http://{}", srv.addr);
    assert_eq!(
        handshake_status(srv.addr, sid, &learner.cookie, Some(&own_origin)).await,
        101,
        "the learner, same origin"
    );
    // Registration needs the cluster token.
    let reg =
        json!({ "url": "http://127.0.0.1:1", "capacity": 4, "renderer": {}, "adapter": null });
    let r = request_with_headers(
        "POST",
        &format!("http://{}/api/workers", srv.addr),
        Some(&reg),
        &[("Authorization", "Bearer wrong-token-wrong-token")],
    )
    .await
    .unwrap();
    assert_eq!(r.status, 401);
    assert!(srv.dispatcher.workers().await.unwrap().is_empty());
    let r = request_with_headers(
        "POST",
        &format!("http://{}/api/workers", srv.addr),
        Some(&reg),
        &[("Authorization", "Bearer a-cluster-token-of-some-length")],
    )
    .await
    .unwrap();
    assert_eq!(r.status, 204);
    assert_eq!(srv.dispatcher.workers().await.unwrap().len(), 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failover_after_worker_process_is_killed() {
    let token = "failover-test-cluster-token";
    let srv = demo_server(false, Some(token)).await;
    let register = format!("http://{}/api/workers", srv.addr);
    // Killed when the test ends, passed or failed.
    let mut workers = WorkerProcesses(vec![
        spawn_worker(&register, token),
        spawn_worker(&register, token),
    ]);
    async {
        wait_for_workers(&srv.dispatcher, 2).await;
        let learner = Client::login(srv.addr, "learner@demo.invalid").await;
        let (attempt, session) = learner.start_demo_attempt().await;
        let first_worker = session["worker"].as_str().unwrap().to_string();
        assert!(
            first_worker.starts_with("http://127.0.0.1:"),
            "placed on a registered worker: {session}"
        );
        let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
        let mut got = Received::default();
        let before = [
            json!({ "type": "carm_pose", "orbital_deg": 20, "angular_deg": 0 }),
            json!({ "type": "shot" }),
            json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [12, -80, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] }),
            json!({ "type": "needle_feed", "mm": 10 }),
        ];
        for (i, c) in before.iter().enumerate() {
            ws.send(i as u64 + 1, c.clone()).await;
        }
        ws.until(&mut got, |r| acked(r).len() == 4).await;
        // Kill the worker that runs the session, then keep sending without waiting.
        let placed_port: u16 = first_worker.rsplit(':').next().unwrap().parse().unwrap();
        let mut killed = false;
        // The process handle does not know its port: find the process listening on it (Linux).
        for w in workers.iter_mut() {
            if process_listens_on(w.id(), placed_port) {
                w.kill().expect("kill the worker process");
                w.wait().expect("reap it");
                killed = true;
            }
        }
        assert!(killed, "found the process listening on {placed_port}");
        let after = [
            json!({ "type": "needle_feed", "mm": 5 }),
            json!({ "type": "carm_pose", "orbital_deg": 30, "angular_deg": 0 }),
            json!({ "type": "shot" }),
            json!({ "type": "needle_feed", "mm": 2 }),
        ];
        for (i, c) in after.iter().enumerate() {
            ws.send(i as u64 + 5, c.clone()).await;
        }
        ws.until(&mut got, |r| acked(r).len() == 8).await;
        assert_eq!(
            acked(&got),
            (1..=8).collect::<Vec<u64>>(),
            "every input applied once, in order"
        );
        assert!(
            got.texts.iter().all(|t| t["type"] != "error"),
            "{:?}",
            got.texts
        );
        assert!(
            got.texts.iter().any(|t| t["type"] == "notice"),
            "the browser is told about the move"
        );
        let (_, info) = learner
            .call(
                "GET",
                &format!("/api/sessions/{}", session["session_id"].as_str().unwrap()),
                None,
            )
            .await;
        assert_eq!(info["failovers"], 1, "{info}");
        assert_ne!(info["worker"], first_worker);
        ws.send(9, json!({ "type": "submit" })).await;
        ws.until(&mut got, |r| {
            r.texts.iter().any(|t| t["type"] == "technical_result")
        })
        .await;
        // The replay of the whole log (restored on the server) reproduces the submitted result.
        let (s, replay) = learner
            .call("GET", &format!("/api/attempts/{attempt}/replay"), None)
            .await;
        assert_eq!(s, 200, "{replay}");
        assert_eq!(replay["timeline"].as_array().unwrap().len(), 9);
        assert_eq!(
            replay["recorded"]["final_state_sha256"], replay["replayed"]["final_state_sha256"],
            "{replay}"
        );
        assert_eq!(replay["recorded"]["score"], replay["replayed"]["score"]);
    }
    .await;
}

/// HTTP status of a websocket handshake to a session (101 when it upgrades).
pub(crate) async fn handshake_status(
    addr: SocketAddr,
    sid: &str,
    cookie: &str,
    origin: Option<&str>,
) -> u16 {
    let mut req = format!("ws://{addr}/api/sessions/{sid}/ws")
        .into_client_request()
        .unwrap();
    req.headers_mut().insert("Cookie", cookie.parse().unwrap());
    if let Some(o) = origin {
        req.headers_mut().insert("Origin", o.parse().unwrap());
    }
    match tokio_tungstenite::connect_async(req).await {
        Ok((_, resp)) => resp.status().as_u16(),
        Err(tokio_tungstenite::tungstenite::Error::Http(resp)) => resp.status().as_u16(),
        Err(e) => panic!("handshake failed without an HTTP answer: {e}"),
    }
}

/// Whether process `pid` has a listening TCP socket on `port` (reads /proc).
pub(crate) fn process_listens_on(pid: u32, port: u16) -> bool {
    let Ok(tcp) = std::fs::read_to_string("/proc/net/tcp") else {
        return false;
    };
    let inodes: Vec<String> = tcp
        .lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            let local_port = u16::from_str_radix(f.get(1)?.rsplit(':').next()?, 16).ok()?;
            (local_port == port && *f.get(3)? == "0A").then(|| f.get(9).map(|s| s.to_string()))?
        })
        .collect();
    let Ok(fds) = std::fs::read_dir(format!("/proc/{pid}/fd")) else {
        return false;
    };
    fds.flatten().any(|fd| {
        std::fs::read_link(fd.path()).is_ok_and(|l| {
            inodes
                .iter()
                .any(|i| l.to_string_lossy() == format!("socket:[{i}]"))
        })
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_the_server_no_longer_holds_resumes_from_its_recorded_log() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let sid = session["session_id"].as_str().unwrap().to_string();
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    for (seq, c) in [
        (
            1,
            json!({ "type": "carm_pose", "orbital_deg": 15, "angular_deg": 0 }),
        ),
        (2, json!({ "type": "shot" })),
        (
            3,
            json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [12, -80, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] }),
        ),
    ] {
        ws.send(seq, c).await;
    }
    ws.until(&mut got, |r| acked(r).len() == 3).await;
    drop(ws);
    // Every acknowledged command is stored before its acknowledgement is sent on: nothing to
    // wait for. Then the server forgets the session (as after a restart).
    let id: uuid::Uuid = sid.parse().unwrap();
    let saved: Vec<i64> = sqlx::query_scalar(
        "SELECT seq FROM live_session_commands WHERE session_id = $1 ORDER BY seq",
    )
    .bind(id)
    .fetch_all(&srv.db.pool)
    .await
    .unwrap();
    assert_eq!(saved, [1, 2, 3], "the acknowledged commands are stored");
    srv.dispatcher.close(id).await;
    assert!(srv.dispatcher.session(id).is_none());
    // Opening the attempt again continues the same session at the same point.
    let (s, resumed) = learner
        .call("POST", &format!("/api/attempts/{attempt}/session"), None)
        .await;
    assert_eq!(s, 200, "{resumed}");
    assert_eq!(resumed["session_id"], sid.as_str());
    assert_eq!(resumed["last_seq"], 3);
    let mut ws = learner.websocket(resumed["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.until(&mut got, |r| !r.texts.is_empty()).await;
    assert_eq!(got.texts[0]["last_seq"], 3, "{:?}", got.texts);
    ws.send(4, json!({ "type": "needle_feed", "mm": 5 })).await;
    ws.until(&mut got, |r| acked(r) == [4]).await;
    let depth = got.texts.iter().find(|t| t["type"] == "ack").unwrap()["outcome"]["depth_mm"]
        .as_f64()
        .unwrap();
    assert!(
        depth > 0.0,
        "the needle placed before the restart is still there: depth {depth}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_sessions_are_closed_only_without_a_connection_and_then_resume() {
    let srv = demo_server(true, None).await;
    // A short idle limit for the test (production: dispatch::IDLE_CLOSE).
    srv.dispatcher.start_reaper(Duration::from_millis(400));
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let id: uuid::Uuid = session["session_id"].as_str().unwrap().parse().unwrap();
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == [1]).await;
    // Connected for several idle limits: kept.
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert!(
        srv.dispatcher.session(id).is_some(),
        "a connected session is never closed as idle"
    );
    drop(ws);
    let mut closed = false;
    for _ in 0..100 {
        if srv.dispatcher.session(id).is_none() {
            closed = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(closed, "the session was closed once nobody was connected");
    let (s, resumed) = learner
        .call("POST", &format!("/api/attempts/{attempt}/session"), None)
        .await;
    assert_eq!(
        (s, resumed["last_seq"].as_u64()),
        (200, Some(1)),
        "{resumed}"
    );
}

/// A browser message over the relay's limit closes the socket with 1009 and a reason (the
/// library default accepted 64 MiB), nothing of it is applied, and a reconnect
/// carries on with the same session.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversized_message_closes_the_socket_with_1009_and_the_session_goes_on() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_attempt, session) = learner.start_demo_attempt().await;
    let ws_path = session["ws"].as_str().unwrap().to_string();
    let mut ws = learner.websocket(&ws_path).await;
    let mut got = Received::default();
    ws.until(&mut got, |r| !r.texts.is_empty()).await;
    let label = "x".repeat(server::dispatch::MAX_CLIENT_MESSAGE_BYTES);
    let big = json!({ "type": "command", "seq": 1, "command": { "type": "annotate", "pixel": [1, 1], "label": label } });
    ws.ws
        .send(Message::Text(big.to_string().into()))
        .await
        .expect("send");
    let close = loop {
        let m = tokio::time::timeout(Duration::from_secs(30), ws.ws.next())
            .await
            .expect("an answer within 30 s");
        match m {
            Some(Ok(Message::Close(frame))) => break frame,
            Some(Ok(_)) => continue,
            other => panic!("expected a close frame, got {other:?}"),
        }
    };
    let frame = close.expect("a close frame with a code");
    assert_eq!(u16::from(frame.code), 1009, "{frame:?}");
    assert!(frame.reason.contains("too large"), "{frame:?}");
    // The session is intact: a new connection greets with nothing applied and takes commands.
    let mut ws = learner.websocket(&ws_path).await;
    let mut got = Received::default();
    ws.until(&mut got, |r| !r.texts.is_empty()).await;
    assert_eq!(got.texts[0]["type"], "hello");
    assert_eq!(got.texts[0]["last_seq"], 0);
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == vec![1]).await;
}

/// One learner cannot take the render worker from everyone: a third live
/// session is refused with 429 naming the limit, the running ones are still returned, another
/// learner still gets a session, and `/healthz` reports the free slots.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_user_holds_at_most_the_per_user_limit_of_sessions() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (first, _) = learner.start_demo_attempt().await;
    learner.start_demo_attempt().await;
    let (_, (status, body)) = learner.try_demo_attempt().await;
    assert_eq!(status, 429, "{body}");
    assert_eq!(body["error"]["code"], "session_limit");
    assert_eq!(body["error"]["limit"], 2);
    assert!(
        body["error"]["message"]
            .as_str()
            .unwrap()
            .contains("at most 2")
    );
    // Asking again for a running session is not a new one.
    let (s, again) = learner
        .call("POST", &format!("/api/attempts/{first}/session"), None)
        .await;
    assert_eq!(s, 200, "{again}");
    // Everyone else is unaffected.
    let other = Client::login(srv.addr, "learner2@demo.invalid").await;
    other.start_demo_attempt().await;
    // (The per-test database has no installation row, so the status itself is 503 here.)
    let (_, health) = learner.call("GET", "/healthz", None).await;
    let sessions = &health["sessions"];
    assert_eq!(sessions["live"], 3, "{health}");
    assert_eq!(
        sessions["free"].as_u64().unwrap() + 3,
        sessions["capacity"].as_u64().unwrap(),
        "{health}"
    );
    assert_eq!(sessions["per_user_limit"], 2);
    assert_eq!(sessions["per_course_limit"], 6, "{health}");
    assert_eq!(sessions["idle_close_s"], 600, "{health}");
}
