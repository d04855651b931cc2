//! The start-up calibration through the real `server` binary: once the GPU settled and the
//! station's region is loaded, the server times its renderers on a real session, chooses one and
//! reports it in `/healthz` with the capacity it derived, which the in-process worker then takes
//! unless `PAINSIM_IN_PROCESS_CAPACITY` fixes it.

use std::time::{Duration, Instant};

use render_worker::session::demo::demo_station_toml;
use serde_json::Value;
use server::test_support::test_db;

use crate::server_process::{fast_auth_env, health, spawn_server};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_server_calibrates_its_renderer_and_capacity_at_start() {
    let db = test_db().await;
    let stations = tempfile::tempdir().unwrap();
    std::fs::write(
        stations.path().join("demo-station.toml"),
        demo_station_toml(&[]),
    )
    .unwrap();
    // No region folders: the demo region is built in memory.
    let assets = tempfile::tempdir().unwrap();
    for fixed in [None, Some(2usize)] {
        let data = tempfile::tempdir().unwrap();
        let mut env = fast_auth_env();
        env.push((
            "PAINSIM_STATIONS_DIR",
            stations.path().display().to_string(),
        ));
        env.push(("PAINSIM_ASSETS_DIR", assets.path().display().to_string()));
        if let Some(n) = fixed {
            env.push(("PAINSIM_IN_PROCESS_CAPACITY", n.to_string()));
        }
        let url = db.url.clone();
        let data_path = data.path().to_owned();
        let mut server =
            tokio::task::spawn_blocking(move || spawn_server(&data_path, Some(&url), &env))
                .await
                .unwrap();
        let addr = server.addr.clone();
        let began = Instant::now();
        let h = loop {
            let a = addr.clone();
            let h = tokio::task::spawn_blocking(move || health(&a))
                .await
                .unwrap();
            if h["render_worker"]["calibration"]["state"] != "pending" && h != Value::Null {
                break h;
            }
            assert!(
                began.elapsed() < Duration::from_secs(180),
                "no calibration after 180 s: {h}"
            );
            tokio::time::sleep(Duration::from_millis(200)).await;
        };
        let _ = server.child.kill();
        let _ = server.child.wait();
        let c = &h["render_worker"]["calibration"];
        assert_eq!(c["state"], "done", "{h:#}");
        assert_eq!(c["station"], "demo-station");
        let timings = c["timings"].as_array().expect("timings");
        // The GPU renderer (when an adapter opened; on a software adapter also with the
        // adapter's own L-buffer passes instead of the CPU's) and the CPU reference, all timed.
        let adapter = &h["render_worker"]["adapter"];
        let expected = if adapter.is_null() {
            1
        } else if adapter["is_software"] == true {
            3
        } else {
            2
        };
        assert_eq!(timings.len(), expected, "{c:#}");
        assert_eq!(timings.last().unwrap()["renderer"]["kind"], "cpu-reference");
        if expected == 3 {
            let device = |k: usize| timings[k]["renderer"]["device"].as_str().unwrap_or("");
            assert!(
                device(0).ends_with("L-buffer passes on the CPU")
                    && !device(1).contains("on the CPU"),
                "{c:#}"
            );
        }
        let chosen = &timings[c["chosen"].as_u64().expect("chosen") as usize];
        assert_eq!(chosen["renderer"], c["renderer"]);
        assert!(chosen["stopped"].is_null(), "{c:#}");
        for key in [
            "carm_moved_ms",
            "needle_moved_ms",
            "new_shot_ms",
            "learner_load",
        ] {
            let v = chosen[key].as_f64().unwrap_or(f64::NAN);
            assert!(v.is_finite() && v > 0.0, "{key}: {c:#}");
        }
        let calibrated = c["capacity"].as_u64().expect("capacity") as usize;
        assert_eq!(chosen["capacity"].as_u64(), Some(calibrated as u64));
        assert!(calibrated >= 1);
        assert_eq!(
            h["sessions"]["capacity"].as_u64(),
            Some(fixed.unwrap_or(calibrated) as u64),
            "{h:#}"
        );
    }
}
