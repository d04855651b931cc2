//! Loopback load benchmark of live sessions through the server.
//!
//! N learners' sessions run at once on the in-process worker, each over a real websocket through
//! the server's relay (`/api/sessions/{id}/ws`), exactly as browsers use it. Each session turns
//! live fluoroscopy on (30 pulses per second) and then moves the C-arm at 20 Hz (a scripted
//! drag); every pose command makes a new image. Reported per N: input-to-frame latency (from
//! sending a pose command to receiving the first frame that reflects it, by the frame header's
//! input sequence) at p50, p99 and max, and frames per second per session. Frames are 512 x 512
//! fluoroscopy of the analytic demo region, rendered by the GPU renderer (a real adapter, or
//! lavapipe) and by the f64 CPU reference.
//!
//! `BENCH_QUICK=1`: GPU N = 1, 4, 8 and CPU N = 1, 4 s each (under a minute with start-up).

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use render_worker::cluster::request_with_headers;
use render_worker::gpu::GpuContext;
use render_worker::session::demo::{demo_region, demo_station, demo_station_toml};
use render_worker::session::frame::EncodedFrame;
use render_worker::session::{Backends, SessionConfig, SessionHost};
use serde_json::{Value, json};
use server::dispatch::Dispatcher;
use server::records::config::Argon2Cost;
use server::{AppState, Config, app, workers::Workers};
use sim_core::stats::{percentile_of_sorted, sorted};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

/// Pose command interval, ms. Simulator choice: 20 Hz, the web client's drag throttle.
const POSE_INTERVAL_MS: u64 = 50;

struct Login {
    cookie: String,
    csrf: String,
}

async fn call(addr: &str, login: &Login, method: &str, path: &str, body: Option<Value>) -> Value {
    let headers = [
        ("Cookie", login.cookie.as_str()),
        ("X-CSRF-Token", login.csrf.as_str()),
    ];
    let r = request_with_headers(
        method,
        &format!("http://{addr}{path}"),
        body.as_ref(),
        &headers,
    )
    .await
    .expect("request");
    assert!(
        (200..300).contains(&r.status),
        "{method} {path}: {} {}",
        r.status,
        String::from_utf8_lossy(&r.body)
    );
    r.json().unwrap_or(Value::Null)
}

/// One session's figures.
#[derive(Default)]
struct SessionFigures {
    latencies_ms: Vec<f64>,
    frames: usize,
    seconds: f64,
}

async fn run_session(
    addr: String,
    login: Arc<Login>,
    course: Value,
    run_for: Duration,
    start_at: Instant,
) -> SessionFigures {
    let attempt = call(
        &addr,
        &login,
        "POST",
        "/api/attempts",
        Some(json!({ "course_id": course, "station_id": "demo-station" })),
    )
    .await;
    let session = call(
        &addr,
        &login,
        "POST",
        &format!("/api/attempts/{}/session", attempt["id"].as_str().unwrap()),
        None,
    )
    .await;
    let mut req = format!("ws://{addr}{}", session["ws"].as_str().unwrap())
        .into_client_request()
        .unwrap();
    req.headers_mut()
        .insert("Cookie", login.cookie.parse().unwrap());
    // Nagle's algorithm off, as browsers have it.
    let (ws, _) = tokio_tungstenite::connect_async_with_config(req, None, true)
        .await
        .expect("websocket");
    let (mut tx, mut rx) = ws.split();
    let send = |seq: u64, c: Value| {
        Message::Text(
            json!({ "type": "command", "seq": seq, "command": c })
                .to_string()
                .into(),
        )
    };
    // Live fluoroscopy at 30 pulses per second, the most demanding rate: with poses every
    // 50 ms each lands in a pulse of its own and makes a new image.
    tx.send(send(1, json!({ "type": "pulse_rate", "pps": 30.0 })))
        .await
        .unwrap();
    tx.send(send(2, json!({ "type": "live", "on": true })))
        .await
        .unwrap();
    let mut sent_at: HashMap<u64, Instant> = HashMap::new();
    let mut figures = SessionFigures::default();
    let mut seq = 2u64;
    let mut newest_reflected = 0u64;
    tokio::time::sleep_until(start_at.into()).await;
    let began = Instant::now();
    let mut tick = tokio::time::interval(Duration::from_millis(POSE_INTERVAL_MS));
    loop {
        tokio::select! {
            _ = tick.tick() => {
                if began.elapsed() >= run_for {
                    break;
                }
                seq += 1;
                // A back-and-forth drag between 10 and 30 degrees LAO.
                let orbital = 10.0 + 20.0 * ((seq as f64 * 0.15).sin() * 0.5 + 0.5);
                sent_at.insert(seq, Instant::now());
                tx.send(send(seq, json!({ "type": "carm_pose", "orbital_deg": orbital, "angular_deg": 0 }))).await.unwrap();
            }
            m = rx.next() => match m {
                Some(Ok(Message::Binary(b))) => {
                    let f = EncodedFrame::parse(&b).expect("frame");
                    let now = Instant::now();
                    figures.frames += 1;
                    for s in (newest_reflected + 1)..=f.input_seq {
                        if let Some(t) = sent_at.remove(&s) {
                            figures.latencies_ms.push((now - t).as_secs_f64() * 1e3);
                        }
                    }
                    newest_reflected = newest_reflected.max(f.input_seq);
                }
                Some(Ok(_)) => {}
                _ => break,
            }
        }
    }
    figures.seconds = began.elapsed().as_secs_f64();
    let _ = tx.send(Message::Close(None)).await;
    figures
}

/// Runs the rows of one renderer: a server whose in-process worker renders with `backends`.
async fn bench_backend(name: &str, backends: Backends, counts: &[usize], run_for: Duration) {
    let stations = tempfile::tempdir().expect("stations folder");
    std::fs::write(
        stations.path().join("demo-station.toml"),
        demo_station_toml(&[]),
    )
    .unwrap();
    let dir = stations.path().display().to_string();
    let mut config = Config::from_lookup(|k| match k {
        "PAINSIM_STATIONS_DIR" => Some(dir.clone()),
        "PAINSIM_AUTH_RATE_PER_MINUTE" | "PAINSIM_AUTH_BURST" => Some("100000".into()),
        // The simulated learners share one account: lift its write limit too.
        "PAINSIM_WRITE_RATE_PER_MINUTE" | "PAINSIM_WRITE_BURST" => Some("1000000".into()),
        _ => None,
    })
    .expect("configuration");
    config.records.argon2 = Argon2Cost::TEST_ONLY;
    let db = server::test_support::test_db().await;
    server::records::prepare(&db.pool, &config.records, true)
        .await
        .expect("demo accounts");
    let capacity = counts.iter().sum::<usize>() + 1;
    let host = SessionHost::with_regions(
        vec![demo_station(&[])],
        vec![Arc::new(demo_region())],
        backends,
        capacity,
        SessionConfig::default(),
    );
    let sessions_host = host.clone();
    let dispatcher = Dispatcher::new(Some(host.clone()), host, None);
    // Every simulated learner logs in as the same demo account, in the same course.
    dispatcher.set_sessions_per_user(capacity);
    dispatcher.set_sessions_per_course(capacity);
    let state = AppState {
        pool: db.pool.clone(),
        embedded_db: true,
        workers: workers(),
        dispatcher: Some(dispatcher),
        config,
    };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    tokio::spawn(async move { axum::serve(listener, app(state)).await });
    let r = request_with_headers(
        "POST",
        &format!("http://{addr}/api/auth/login"),
        Some(&json!({ "email": "learner@demo.invalid", "password": server::records::demo::DEMO_PASSWORD })),
        &[],
    )
    .await
    .unwrap();
    let cookie = r
        .headers
        .iter()
        .filter(|(k, _)| k == "set-cookie")
        .filter_map(|(_, v)| v.split(';').next())
        .find(|c| c.starts_with("painsim_session="))
        .unwrap()
        .to_string();
    let login = Arc::new(Login {
        cookie,
        csrf: r.json().unwrap()["csrf_token"]
            .as_str()
            .unwrap()
            .to_string(),
    });
    let courses = call(&addr, &login, "GET", "/api/courses", None).await;
    let course = courses
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["code"] == "DEMO-101")
        .unwrap()["id"]
        .clone();
    for &n in counts {
        let start_at = Instant::now() + Duration::from_millis(500 + 100 * n as u64);
        let tasks: Vec<_> = (0..n)
            .map(|_| {
                tokio::spawn(run_session(
                    addr.clone(),
                    login.clone(),
                    course.clone(),
                    run_for,
                    start_at,
                ))
            })
            .collect();
        let mut all = Vec::new();
        let (mut frames, mut fps) = (0usize, 0.0);
        for t in tasks {
            let f = t.await.expect("session task");
            frames += f.frames;
            fps += f.frames as f64 / f.seconds.max(1e-9);
            all.extend(f.latencies_ms);
        }
        // A row whose poses never showed measured nothing: the live path is broken, not slow.
        assert!(
            !all.is_empty(),
            "{name}, {n} sessions: no pose was ever shown ({frames} frames in all)"
        );
        let all = sorted(all);
        println!(
            "| {name} | {n} | {} | {frames} | {:.1} | {:.1} | {:.1} | {:.1} |",
            all.len(),
            fps / n as f64,
            percentile_of_sorted(&all, 50.0),
            percentile_of_sorted(&all, 99.0),
            percentile_of_sorted(&all, 100.0)
        );
    }
    // Session threads release their GPU resources before the process exits.
    tokio::task::spawn_blocking(move || sessions_host.shutdown())
        .await
        .expect("session shutdown");
}

/// The server's worker status (its GPU check), shared by both renderers' servers.
fn workers() -> Workers {
    let w = Workers::start_in_process();
    w.wait_until_settled(Duration::from_secs(120));
    w
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    // The CPU reference renders a 512 x 512 frame in hundreds of milliseconds on 2 cores, so
    // quick mode runs it with one session only.
    let (cpu_counts, gpu_counts, run_for): (&[usize], &[usize], Duration) = if quick {
        (&[1], &[1, 4, 8], Duration::from_secs(4))
    } else {
        (&[1, 2, 4], &[1, 2, 4, 8, 16], Duration::from_secs(10))
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async move {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        println!("## Live sessions through the server (loopback websockets, {cores} cores)\n");
        println!(
            "512 x 512 fluoroscopy of the demo region, live fluoroscopy with a C-arm move every {POSE_INTERVAL_MS} ms per session, {} s per row.\n",
            run_for.as_secs()
        );
        println!("| renderer | sessions | pose inputs | frames | frames/s per session | latency p50 (ms) | p99 (ms) | max (ms) |");
        println!("|---|---:|---:|---:|---:|---:|---:|---:|");
        match GpuContext::new_headless() {
            Ok(ctx) => {
                let name = format!("gpu: {}", ctx.summary.name);
                bench_backend(&name, Backends::gpu(ctx), gpu_counts, run_for).await;
            }
            Err(e) => println!("| gpu | - | - | - | - | - | - | no adapter: {e} |"),
        }
        bench_backend("cpu-reference", Backends::cpu(0), cpu_counts, run_for).await;
        println!(
            "\nLatency covers relay, queueing, rendering, JPEG encoding and delivery; a pose superseded before it was rendered counts until the frame that reflects a later one arrives."
        );
    });
}
