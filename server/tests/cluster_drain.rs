//! A render worker asked to stop (SIGTERM, as Kubernetes does on scale-down or a rollout) drains:
//! it takes no new sessions at once (the shared state says `draining`), its live sessions go on
//! until its drain time is up, then it hands them back and the servers restore them on another
//! worker from snapshot and log: none lost, no command acknowledged twice.

use std::time::{Duration, Instant};

use serde_json::json;

use crate::dispatch::{
    WorkerProcesses, process_listens_on, spawn_worker_draining, wait_for_workers,
};
use crate::dispatch_support::{Client, Received, acked, demo_server};

/// The state of worker `url` in the shared state.
async fn worker_state(pool: &sqlx::PgPool, url: &str) -> Option<String> {
    sqlx::query_scalar("SELECT state FROM render_workers WHERE url = $1")
        .bind(url)
        .fetch_optional(pool)
        .await
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn failover_by_drain_a_worker_sent_sigterm_moves_its_sessions_without_loss() {
    let token = "drain-test-cluster-token";
    let srv = demo_server(false, Some(token)).await;
    let register = format!("http://{}/api/workers", srv.addr);
    let drain = Duration::from_secs(3);
    // Killed when the test ends, passed or failed.
    let mut workers = WorkerProcesses(vec![
        spawn_worker_draining(&register, token, drain),
        spawn_worker_draining(&register, token, drain),
    ]);
    async {
        wait_for_workers(&srv.dispatcher, 2).await;
        let learner = Client::login(srv.addr, "learner@demo.invalid").await;
        let (attempt, session) = learner.start_demo_attempt().await;
        let placed = session["worker"].as_str().unwrap().to_string();
        let sid = session["session_id"].as_str().unwrap().to_string();
        let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
        let mut got = Received::default();
        let mut seq = 0u64;
        let mut send = async |ws: &mut crate::dispatch_support::Ws, c: serde_json::Value| {
            seq += 1;
            ws.send(seq, c).await;
        };
        send(
            &mut ws,
            json!({ "type": "carm_pose", "orbital_deg": 20, "angular_deg": 0 }),
        )
        .await;
        send(&mut ws, json!({ "type": "shot" })).await;
        send(&mut ws, json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [12, -80, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] })).await;
        ws.until(&mut got, |r| acked(r).len() == 3).await;

        // SIGTERM the worker that runs the session.
        let port: u16 = placed.rsplit(':').next().unwrap().parse().unwrap();
        let pid = workers
            .iter()
            .map(|w| w.id())
            .find(|pid| process_listens_on(*pid, port))
            .expect("the process listening on the session's worker port");
        let terminated = Instant::now();
        let status = std::process::Command::new("kill")
            .args(["-TERM", &pid.to_string()])
            .status()
            .expect("kill -TERM");
        assert!(status.success());
        // Its next heartbeat (sent at once) says it drains: no replica places a session there.
        loop {
            if worker_state(&srv.db.pool, &placed).await.as_deref() == Some("draining") {
                break;
            }
            assert!(
                terminated.elapsed() < Duration::from_secs(3),
                "draining within 3 s"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let draining_after = terminated.elapsed();
        let elsewhere = srv.dispatcher.registry().by_load(None).await;
        assert!(!elsewhere.contains(&placed), "{elsewhere:?}");
        assert_eq!(elsewhere.len(), 1, "the other worker still takes sessions");
        // The session goes on on the draining worker meanwhile.
        send(&mut ws, json!({ "type": "needle_feed", "mm": 10 })).await;
        send(&mut ws, json!({ "type": "shot" })).await;
        ws.until(&mut got, |r| acked(r).len() == 5).await;
        // Then, with the drain time up, it is handed back and restored on the other worker:
        // keep sending without waiting, across the move.
        tokio::time::sleep(drain.saturating_sub(terminated.elapsed())).await;
        for mm in [1, 2, 3, 4] {
            send(&mut ws, json!({ "type": "needle_feed", "mm": mm })).await;
            tokio::time::sleep(Duration::from_millis(150)).await;
        }
        ws.until(&mut got, |r| acked(r).len() == 9).await;
        assert_eq!(
            acked(&got),
            (1..=9).collect::<Vec<u64>>(),
            "each command acknowledged once, in order"
        );
        let duplicates = got
            .texts
            .iter()
            .filter(|t| t["type"] == "ack" && t["duplicate"] == true)
            .count();
        let (_, info) = learner
            .call("GET", &format!("/api/sessions/{sid}"), None)
            .await;
        assert_eq!(info["failovers"], 1, "{info}");
        assert_ne!(info["worker"], placed.as_str(), "{info}");
        // The drained worker exits by itself once its sessions are handed back.
        let drained = workers
            .iter_mut()
            .find(|w| w.id() == pid)
            .expect("the drained worker");
        let exit = loop {
            if let Some(status) = drained.try_wait().expect("wait") {
                break status;
            }
            assert!(
                terminated.elapsed() < drain + Duration::from_secs(15),
                "the drained worker exits"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        };
        assert!(exit.success(), "{exit:?}");
        let exited_after = terminated.elapsed();
        // Every acknowledged command is in the log once; the replay equals the live state.
        ws.send(10, json!({ "type": "submit" })).await;
        ws.until(&mut got, |r| {
            r.texts.iter().any(|t| t["type"] == "technical_result")
        })
        .await;
        let seqs: Vec<i64> = sqlx::query_scalar(
            "SELECT seq FROM live_session_commands WHERE session_id = $1::uuid ORDER BY seq",
        )
        .bind(&sid)
        .fetch_all(&srv.db.pool)
        .await
        .unwrap();
        assert_eq!(seqs, (1..=10).collect::<Vec<i64>>());
        let (s, replay) = learner
            .call("GET", &format!("/api/attempts/{attempt}/replay"), None)
            .await;
        assert_eq!(s, 200, "{replay}");
        assert_eq!(
            replay["recorded"]["final_state_sha256"], replay["replayed"]["final_state_sha256"],
            "{replay}"
        );
        println!(
            "drain: draining in the shared state {:.0} ms after SIGTERM, worker exited after {:.1} s, {duplicates} re-sent commands answered as duplicates",
            draining_after.as_secs_f64() * 1e3,
            exited_after.as_secs_f64()
        );
    }
    .await;
}
