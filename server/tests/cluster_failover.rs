//! The whole deployment shape on loopback: PostgreSQL, two `server` binaries (replicas, no
//! in-process sessions), three render-worker processes, and a plain round-robin TCP balancer in
//! front of the replicas (no stickiness; the workers heartbeat through it too). Six scripted
//! learners stream commands through the balancer while one replica and one worker are SIGKILLed,
//! then a second worker. Each learner does what `web-client/session.js` does: on a lost socket
//! it reconnects (through the balancer) and sends again what the `hello`'s `last_seq` does not
//! cover. Checked: every session goes on within 5 s of each kill (from when the killed processes
//! are gone); every acknowledged command is
//! in the log exactly once; each session's replay equals its live state; no session is lost.

use std::collections::BTreeSet;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

use crate::dispatch::{WorkerProcesses, process_listens_on, spawn_worker};
use crate::dispatch_support::Client;
use crate::server_process::{demo_deployment, spawn_on};

/// Commands each learner sends before the submit.
const SCRIPT_LEN: u64 = 240;
/// Pause between a learner's commands: the streams span every kill below.
const PACE: Duration = Duration::from_millis(40);
/// How soon a session must go on after a kill: a learner who waits longer than a few seconds
/// thinks the simulator froze (simulator choice, the deployment's stated bound).
const CONTINUE_WITHIN: Duration = Duration::from_secs(5);

/// A round-robin TCP balancer on loopback: each new connection goes to the next backend that
/// accepts it (a dead one is skipped), bytes copied both ways. No stickiness of any kind.
async fn balancer(backends: Vec<String>) -> SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let next = Arc::new(AtomicUsize::new(0));
    tokio::spawn(async move {
        loop {
            let Ok((mut inbound, _)) = listener.accept().await else {
                continue;
            };
            let (backends, next) = (backends.clone(), next.clone());
            tokio::spawn(async move {
                let start = next.fetch_add(1, Ordering::SeqCst);
                for i in 0..backends.len() {
                    let b = &backends[(start + i) % backends.len()];
                    if let Ok(mut outbound) = tokio::net::TcpStream::connect(b).await {
                        let _ = tokio::io::copy_bidirectional(&mut inbound, &mut outbound).await;
                        return;
                    }
                }
            });
        }
    });
    addr
}

/// Command `seq` of a learner's script: C-arm moves, a shot every eight, the needle placed at 2
/// and fed 0.25 mm every eight after that (well short of bone on the demo region's path).
fn scripted(seq: u64) -> Value {
    if seq == 2 {
        return json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [12, -80, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] });
    }
    match seq % 8 {
        0 => json!({ "type": "shot" }),
        4 if seq > 2 => json!({ "type": "needle_feed", "mm": 0.25 }),
        _ => {
            json!({ "type": "carm_pose", "orbital_deg": (seq * 7 % 41) as f64 - 20.0, "angular_deg": 0 })
        }
    }
}

/// What one learner saw.
#[derive(Debug, Default)]
struct Seen {
    /// Acknowledged sequence numbers (duplicates included, in arrival order).
    acks: Vec<(u64, Instant)>,
    /// Times the socket was lost and opened again.
    reconnects: usize,
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// Opens the session's socket through the balancer, retrying for up to 10 s (a connection may
/// land on a replica as it dies); returns the socket and the `hello`'s `last_seq`.
async fn connect(c: &Client, path: &str) -> (Socket, u64) {
    let start = Instant::now();
    loop {
        let mut req = format!("ws://{}{path}", c.addr)
            .into_client_request()
            .unwrap();
        req.headers_mut()
            .insert("Cookie", c.cookie.parse().unwrap());
        let attempt = async {
            let (mut ws, _) = tokio_tungstenite::connect_async(req).await.ok()?;
            loop {
                match tokio::time::timeout(Duration::from_secs(5), ws.next())
                    .await
                    .ok()??
                {
                    Ok(Message::Text(t)) => {
                        let v: Value = serde_json::from_str(&t).ok()?;
                        if v["type"] == "hello" {
                            return Some((ws, v["last_seq"].as_u64()?));
                        }
                    }
                    Ok(_) => {}
                    Err(_) => return None,
                }
            }
        };
        if let Some(ok) = attempt.await {
            return ok;
        }
        assert!(
            start.elapsed() < Duration::from_secs(10),
            "reconnected within 10 s"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// One learner: streams the script, reconnecting and re-sending as the browser client does,
/// then submits.
async fn learner(c: Client, path: String, seen: Arc<Mutex<Seen>>) {
    let (mut ws, mut last_seq) = connect(&c, &path).await;
    let mut acked: BTreeSet<u64> = BTreeSet::new();
    let mut next = 1u64;
    let mut tick = tokio::time::interval(PACE);
    loop {
        // Done once the submit is acknowledged (its result is stored before that).
        acked.extend(1..=last_seq);
        if acked.contains(&(SCRIPT_LEN + 1)) {
            return;
        }
        let lost = tokio::select! {
            _ = tick.tick(), if next <= SCRIPT_LEN + 1 => {
                let command = if next == SCRIPT_LEN + 1 { json!({ "type": "submit" }) } else { scripted(next) };
                let text = json!({ "type": "command", "seq": next, "command": command }).to_string();
                next += 1;
                ws.send(Message::Text(text.into())).await.is_err()
            }
            m = ws.next() => match m {
                Some(Ok(Message::Text(t))) => {
                    let v: Value = serde_json::from_str(&t).unwrap();
                    if v["type"] == "ack" {
                        let seq = v["seq"].as_u64().unwrap();
                        acked.insert(seq);
                        seen.lock().unwrap().acks.push((seq, Instant::now()));
                    }
                    false
                }
                Some(Ok(Message::Close(_))) | Some(Err(_)) | None => true,
                Some(Ok(_)) => false,
            },
        };
        if lost {
            seen.lock().unwrap().reconnects += 1;
            let (socket, last) = connect(&c, &path).await;
            ws = socket;
            last_seq = last;
            acked.extend(1..=last_seq);
            // Send again, in order, what was sent and is not known to be applied.
            for seq in 1..next {
                if !acked.contains(&seq) {
                    let command = if seq == SCRIPT_LEN + 1 {
                        json!({ "type": "submit" })
                    } else {
                        scripted(seq)
                    };
                    let text =
                        json!({ "type": "command", "seq": seq, "command": command }).to_string();
                    if ws.send(Message::Text(text.into())).await.is_err() {
                        break;
                    }
                }
            }
        }
    }
}

/// The first acknowledgement each learner got after `t`, as a delay from `t`.
fn resumed_after(seen: &[Arc<Mutex<Seen>>], t: Instant) -> Vec<Option<Duration>> {
    seen.iter()
        .map(|s| {
            let s = s.lock().unwrap();
            s.acks.iter().find(|(_, at)| *at > t).map(|(_, at)| *at - t)
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failover_of_a_replica_and_workers_loses_no_session_and_no_command() {
    let token = "failover-whole-system-cluster-token";
    let deployment = demo_deployment().await;
    let db = &deployment.db;
    let mut env = deployment.env.clone();
    env.extend([
        ("PAINSIM_IN_PROCESS_CAPACITY", "0".into()),
        ("PAINSIM_WORKER_TOKEN", token.into()),
        ("PAINSIM_SESSIONS_PER_USER", "10".into()),
        ("PAINSIM_SESSIONS_PER_COURSE", "10".into()),
    ]);
    let data = [tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap()];
    let mut replicas = Vec::new();
    for (i, d) in data.iter().enumerate() {
        let mut env = env.clone();
        env.push(("PAINSIM_REPLICA_ID", format!("replica-{i}")));
        replicas.push(spawn_on(d.path(), &db.url, &env).await);
    }
    let front = balancer(replicas.iter().map(|r| r.addr.clone()).collect()).await;
    let register = format!("http://{front}/api/workers");
    // Killed when the test ends, passed or failed (the replicas are too: `ServerProcess`).
    let mut workers = WorkerProcesses((0..3).map(|_| spawn_worker(&register, token)).collect());
    async {
        let alive: i64 = loop {
            let n: i64 =
                sqlx::query_scalar("SELECT count(*) FROM render_workers WHERE state = 'alive'")
                    .fetch_one(&db.pool)
                    .await
                    .unwrap();
            if n == 3 {
                break n;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        assert_eq!(alive, 3);
        // Six learners' sessions, opened through the balancer.
        let mut sessions = Vec::new();
        for _ in 0..6 {
            let c = Client::login(front, "learner@demo.invalid").await;
            let (id, (s, session)) = c.try_demo_attempt().await;
            assert_eq!(s, 201, "{session}");
            sessions.push((c, id, session));
        }
        let seen: Vec<Arc<Mutex<Seen>>> = (0..6).map(|_| Arc::default()).collect();
        let drivers: Vec<_> = sessions
            .iter()
            .zip(&seen)
            .map(|((c, _, s), seen)| {
                tokio::spawn(learner(
                    c.clone(),
                    s["ws"].as_str().unwrap().to_string(),
                    seen.clone(),
                ))
            })
            .collect();
        // Mid-stream: SIGKILL replica 0 and the worker with the most sessions.
        tokio::time::sleep(Duration::from_millis(1500)).await;
        let busiest: (String, i64) = sqlx::query_as(
            "SELECT worker_url, count(*) FROM session_placements GROUP BY worker_url ORDER BY 2 DESC, 1 LIMIT 1",
        )
        .fetch_one(&db.pool)
        .await
        .unwrap();
        let port: u16 = busiest.0.rsplit(':').next().unwrap().parse().unwrap();
        let i = workers
            .iter()
            .position(|w| process_listens_on(w.id(), port))
            .expect("the busiest worker");
        let mut replica = replicas.remove(0);
        let mut worker = workers.remove(i);
        replica.child.kill().unwrap();
        worker.kill().unwrap();
        let signalled = Instant::now();
        replica.child.wait().unwrap();
        worker.wait().unwrap();
        // Timed from when both are gone: the kernel takes a while (1.6 s measured here) to tear
        // a SIGKILLed server down, and its sockets stay open until then.
        let first_kill = Instant::now();
        let teardown = first_kill - signalled;
        tokio::time::sleep(Duration::from_millis(3000)).await;
        // Then a second worker, whichever holds a session now.
        let second: String = sqlx::query_scalar(
            "SELECT worker_url FROM session_placements ORDER BY worker_url LIMIT 1",
        )
        .fetch_one(&db.pool)
        .await
        .unwrap();
        let port: u16 = second.rsplit(':').next().unwrap().parse().unwrap();
        let i = workers
            .iter()
            .position(|w| process_listens_on(w.id(), port))
            .expect("a worker with sessions");
        let mut worker = workers.remove(i);
        worker.kill().unwrap();
        worker.wait().unwrap();
        let second_kill = Instant::now();
        for d in drivers {
            tokio::time::timeout(Duration::from_secs(120), d)
                .await
                .expect("every learner finishes within 2 minutes")
                .expect("learner task");
        }
        let after_first = resumed_after(&seen, first_kill);
        let after_second = resumed_after(&seen, second_kill);
        let ms = |v: &[Option<Duration>]| -> Vec<String> {
            v.iter()
                .map(|d| d.map_or("none".into(), |d| format!("{} ms", d.as_millis())))
                .collect()
        };
        println!(
            "failover: sessions went on after the replica + worker kill in {:?} (teardown of the killed processes {} ms before), after the second worker kill in {:?}; reconnects {:?}",
            ms(&after_first),
            teardown.as_millis(),
            ms(&after_second),
            seen.iter()
                .map(|s| s.lock().unwrap().reconnects)
                .collect::<Vec<_>>()
        );
        for (i, d) in after_first.iter().chain(&after_second).enumerate() {
            let d = d.unwrap_or_else(|| panic!("learner {} went on after the kill", i % 6));
            assert!(
                d < CONTINUE_WITHIN,
                "learner {} went on {d:?} after a kill",
                i % 6
            );
        }
        for ((c, attempt, session), seen) in sessions.iter().zip(&seen) {
            let sid = session["session_id"].as_str().unwrap();
            let seqs: Vec<i64> = sqlx::query_scalar(
                "SELECT seq FROM live_session_commands WHERE session_id = $1::uuid ORDER BY seq",
            )
            .bind(sid)
            .fetch_all(&db.pool)
            .await
            .unwrap();
            assert_eq!(
                seqs,
                (1..=SCRIPT_LEN as i64 + 1).collect::<Vec<_>>(),
                "session {sid}: every command logged once"
            );
            let acked: BTreeSet<u64> = seen.lock().unwrap().acks.iter().map(|(s, _)| *s).collect();
            assert!(
                acked.iter().all(|s| *s >= 1 && *s <= SCRIPT_LEN + 1),
                "{acked:?}"
            );
            let (s, replay) = c
                .call("GET", &format!("/api/attempts/{attempt}/replay"), None)
                .await;
            assert_eq!(s, 200, "{replay}");
            assert_eq!(
                replay["recorded"]["final_state_sha256"], replay["replayed"]["final_state_sha256"],
                "session {sid}: the replay equals the live state"
            );
            assert_eq!(
                replay["timeline"].as_array().unwrap().len() as u64,
                SCRIPT_LEN + 1
            );
        }
    }
    .await;
}
