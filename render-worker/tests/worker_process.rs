//! The `render-worker` binary as an operator runs it: it prepares its stations' anatomy, times
//! its renderers on them (the start-up calibration), renders with the chosen one, takes the
//! calibrated capacity unless `RENDER_WORKER_CAPACITY` fixes it, reports all of it at
//! `/healthz`, and announces the capacity it has now to the server it registers with.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use render_worker::session::demo::demo_station_toml;
use serde_json::Value;

/// Longest wait for the worker's calibration (the demo region is built in memory; the CPU
/// reference's and lavapipe's frames of it take tens of milliseconds each on 2 cores, so the
/// calibration takes seconds; a busy CI machine gets ample room).
const CALIBRATION_WAIT: Duration = Duration::from_secs(180);

/// A server's `/api/workers` stand-in: answers every request 204 and keeps each JSON body.
fn registration_sink() -> (String, Arc<Mutex<Vec<Value>>>) {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let url = format!("http://{}/api/workers", listener.local_addr().unwrap());
    let bodies = Arc::new(Mutex::new(Vec::new()));
    let kept = Arc::clone(&bodies);
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut stream) = stream else { continue };
            let mut reader = BufReader::new(stream.try_clone().expect("clone"));
            let mut length = 0usize;
            loop {
                let mut line = String::new();
                if reader.read_line(&mut line).unwrap_or(0) == 0 || line == "\r\n" {
                    break;
                }
                if let Some(v) = line.to_ascii_lowercase().strip_prefix("content-length:") {
                    length = v.trim().parse().unwrap_or(0);
                }
            }
            let mut body = vec![0u8; length];
            if reader.read_exact(&mut body).is_ok()
                && let Ok(v) = serde_json::from_slice(&body)
            {
                kept.lock().unwrap().push(v);
            }
            let _ = stream.write_all(b"HTTP/1.1 204 No Content\r\nConnection: close\r\n\r\n");
        }
    });
    (url, bodies)
}

/// `GET http://{addr}{path}` as JSON, with the cluster's own HTTP client.
fn get_json(addr: &str, path: &str) -> Value {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let url = format!("http://{addr}{path}");
    let r = rt
        .block_on(render_worker::cluster::request("GET", &url, None, None))
        .unwrap_or_else(|e| panic!("GET {url}: {e}"));
    assert_eq!(r.status, 200, "GET {url}");
    serde_json::from_slice(&r.body)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&r.body)))
}

/// A running worker over a temporary assets folder holding the demo station (its region is
/// the analytic demo region, built in memory), killed on drop.
struct Worker {
    child: Child,
    addr: String,
    _assets: tempfile::TempDir,
}

impl Drop for Worker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start_worker(register_url: &str, capacity: Option<&str>) -> Worker {
    let assets = tempfile::tempdir().expect("tempdir");
    std::fs::create_dir(assets.path().join("stations")).unwrap();
    std::fs::write(
        assets.path().join("stations/demo-station.toml"),
        demo_station_toml(&[]),
    )
    .unwrap();
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_render-worker"));
    cmd.env("RENDER_WORKER_BIND", "127.0.0.1:0")
        .env("RENDER_WORKER_ASSETS", assets.path())
        .env("RENDER_WORKER_REGISTER_URL", register_url)
        .env(
            "RENDER_WORKER_TOKEN",
            "a-cluster-token-of-enough-length-0123456789",
        )
        .env_remove("RENDER_WORKER_CAPACITY")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    if let Some(c) = capacity {
        cmd.env("RENDER_WORKER_CAPACITY", c);
    }
    let mut child = cmd.spawn().expect("start render-worker");
    let stdout = child.stdout.take().expect("stdout");
    let mut w = Worker {
        child,
        addr: String::new(),
        _assets: assets,
    };
    // The log goes to stdout too: read up to the line that gives the address, then keep
    // draining it so that the worker never blocks on a full pipe.
    let mut lines = BufReader::new(stdout).lines();
    let ready = lines
        .by_ref()
        .map_while(Result::ok)
        .find(|l| l.starts_with("render-worker ready at http://"))
        .expect("the worker's ready line");
    std::thread::spawn(move || lines.for_each(drop));
    // "render-worker ready at http://{addr}/healthz (stations: ...)"
    w.addr = ready
        .split("http://")
        .nth(1)
        .and_then(|r| r.split('/').next())
        .unwrap_or_else(|| panic!("no address in {ready:?}"))
        .to_string();
    w
}

/// Polls `/healthz` until it reports a calibration.
fn calibrated_health(w: &Worker) -> Value {
    let t0 = Instant::now();
    loop {
        let h = get_json(&w.addr, "/healthz");
        if !h["calibration"].is_null() {
            return h;
        }
        assert!(
            t0.elapsed() < CALIBRATION_WAIT,
            "no calibration after {CALIBRATION_WAIT:?}: {h}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn the_worker_binary_calibrates_and_announces_its_capacity() {
    let (url, bodies) = registration_sink();
    let w = start_worker(&url, None);
    let h = calibrated_health(&w);
    let c = &h["calibration"];
    let capacity = c["capacity"].as_u64().expect("a calibrated capacity");
    assert!(capacity >= 1, "{c}");
    assert_eq!(
        h["capacity"].as_u64(),
        Some(capacity),
        "the worker takes it: {h}"
    );
    assert_eq!(c["station"], "demo-station", "{c}");
    // The chosen candidate is the renderer reported (and used) from now on.
    let chosen = c["chosen"].as_u64().expect("chosen") as usize;
    assert_eq!(c["timings"][chosen]["renderer"], c["renderer"], "{c}");
    assert_eq!(h["renderer"], c["renderer"], "{h}");
    assert!(
        c["timings"].as_array().is_some_and(|t| !t.is_empty()),
        "{c}"
    );
    // The next heartbeat announces it (one every 5 s).
    let t0 = Instant::now();
    loop {
        let last = bodies.lock().unwrap().last().cloned();
        if let Some(r) = &last
            && r["capacity"].as_u64() == Some(capacity)
            && r["renderer"] == c["renderer"]
        {
            assert!(
                r["url"].as_str().is_some_and(|u| u.ends_with(&w.addr)),
                "{r}"
            );
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "no announcement of capacity {capacity}: {last:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

#[test]
fn a_fixed_capacity_stays_while_the_calibration_chooses_the_renderer() {
    let (url, bodies) = registration_sink();
    let w = start_worker(&url, Some("3"));
    let h = calibrated_health(&w);
    assert_eq!(h["capacity"].as_u64(), Some(3), "{h}");
    assert_eq!(h["renderer"], h["calibration"]["renderer"], "{h}");
    std::thread::sleep(render_worker::cluster::HEARTBEAT + Duration::from_secs(1));
    let all = bodies.lock().unwrap().clone();
    assert!(!all.is_empty(), "the worker registered");
    assert!(
        all.iter().all(|r| r["capacity"].as_u64() == Some(3)),
        "every announcement carries the fixed capacity: {all:?}"
    );
}
