//! The first session never waits inside its request for the anatomy: while a station's region
//! is loaded or built, `POST /api/attempts/{id}/session` answers at once with 503, `Retry-After`
//! and the progress (code `anatomy_preparing`), `/healthz` reports the region's state, and once
//! it is ready the same request creates the session. A region that cannot be prepared is
//! reported as failed with the reason.
//!
//! The phantom here is the real procedural lumbar phantom built by the real pipeline, at 4 mm
//! voxels (seconds) instead of the default resolution (about 18 s on 2 cores), through the
//! host's region loader.

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use render_worker::cluster::request_with_headers;
use render_worker::session::loader::RegionLoadError;
use render_worker::session::region::Region;
use render_worker::session::{Backends, HostConfig, SessionConfig, SessionHost, sha256_hex};
use serde_json::{Value, json};
use server::dispatch::Dispatcher;
use server::test_support::{TestDb, test_db};
use server::{AppState, app};
use sim_core::anatomy::phantom::{self, PhantomParams};
use sim_core::anatomy::pipeline::Progress;

use crate::dispatch::{Client, base_workers};
use crate::records_support::test_config;

/// A server over `host` whose learning records read stations from `stations_dir`.
pub(crate) async fn server_with(host: SessionHost, stations_dir: &Path) -> (SocketAddr, TestDb) {
    let config = test_config(&[("PAINSIM_STATIONS_DIR", &stations_dir.display().to_string())]);
    let db = test_db().await;
    server::records::prepare(&db.pool, &config.records, true)
        .await
        .expect("stations and demo accounts");
    let dispatcher = Dispatcher::new(Some(host.clone()), host, None);
    let state = AppState {
        pool: db.pool.clone(),
        embedded_db: true,
        workers: base_workers(),
        dispatcher: Some(dispatcher),
        config,
    };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let router = app(state);
    tokio::spawn(async move { axum::serve(listener, router).await });
    (addr, db)
}

/// A host over `stations` whose region, the lumbar phantom at 4 mm voxels, the real pipeline
/// builds under `root` on first use (seconds; CPU reference renderer, 4 sessions). With a
/// non-zero `pace` every progress report of the build waits that long first: the build then
/// lasts about as long as the default phantom's on a busy machine (the 4 mm build alone can end
/// within one of the page's one-second polls), and what a learner sees during a long
/// preparation can be observed.
pub(crate) fn phantom_building_host(
    stations: Vec<(sim_core::rubric::Station, String)>,
    root: &Path,
    pace: Duration,
) -> SessionHost {
    let root = root.to_owned();
    SessionHost::with_loader(
        stations,
        move |name: &str, progress: &mut dyn FnMut(&Progress)| {
            assert_eq!(name, phantom::REGION_NAME);
            let mut paced = |p: &Progress| {
                std::thread::sleep(pace);
                progress(p);
            };
            let asset = phantom::ensure_built_with(
                &root.join(name),
                &PhantomParams::with_voxel_mm(4.0),
                &mut paced,
            )
            .map_err(|source| RegionLoadError::Asset {
                name: name.to_string(),
                source,
            })?;
            Ok(Region::from_asset(&asset))
        },
        Backends::cpu(0),
        4,
        SessionConfig::default(),
    )
}

/// An attempt of the demo learner at `station` in the demo course.
async fn attempt_at(learner: &Client, station: &str) -> String {
    let (_, courses) = learner.call("GET", "/api/courses", None).await;
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
            Some(json!({ "course_id": course, "station_id": station })),
        )
        .await;
    assert_eq!(s, 201, "{attempt}");
    attempt["id"].as_str().unwrap().to_string()
}

/// `POST .../session`: (status, Retry-After, body). A request held for more than 10 s fails the
/// test (the point is that none is held for a build).
async fn request_session(c: &Client, attempt: &str) -> (u16, Option<u64>, Value) {
    let r = tokio::time::timeout(
        Duration::from_secs(10),
        request_with_headers(
            "POST",
            &format!("http://{}/api/attempts/{attempt}/session", c.addr),
            None,
            &[("Cookie", &c.cookie), ("X-CSRF-Token", &c.csrf)],
        ),
    )
    .await
    .expect("the session request was answered, not held")
    .expect("request");
    let retry = r
        .headers
        .iter()
        .find(|(k, _)| k.eq_ignore_ascii_case("retry-after"))
        .and_then(|(_, v)| v.trim().parse().ok());
    (r.status, retry, r.json().unwrap_or(Value::Null))
}

async fn anatomy_health(addr: SocketAddr) -> Value {
    let r = request_with_headers("GET", &format!("http://{addr}/healthz"), None, &[])
        .await
        .expect("healthz");
    r.json().unwrap()["anatomy"].clone()
}

fn repo_stations() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn first_session_request_answers_at_once_while_the_phantom_builds() {
    let assets = tempfile::tempdir().unwrap();
    // The lumbar phantom's stations only: this host builds that one phantom (the cervical
    // stations' region is another build, and the real-CT region `lumbar-ct` loads from files;
    // neither is what this test watches).
    let stations = sim_core::rubric::load_station_dir(&repo_stations())
        .unwrap()
        .into_iter()
        .filter(|f| f.station.region_asset() == phantom::REGION_NAME)
        .map(|f| (f.station, sha256_hex(f.text.as_bytes())))
        .collect();
    let host = phantom_building_host(stations, assets.path(), Duration::ZERO);
    let (addr, _db) = server_with(host, &repo_stations()).await;
    let health = anatomy_health(addr).await;
    assert_eq!(health["ready"], false, "{health}");
    assert_eq!(
        health["regions"]["lumbar-phantom"]["state"], "not_started",
        "{health}"
    );

    let learner = Client::login(addr, "learner@demo.invalid").await;
    let attempt = attempt_at(&learner, "l4-l5-left-facet").await;
    // Nobody prepared the region yet: the first request starts it and is answered at once.
    let (status, retry, body) = request_session(&learner, &attempt).await;
    assert_eq!(status, 503, "{body}");
    assert_eq!(body["error"]["code"], "anatomy_preparing", "{body}");
    assert_eq!(body["error"]["region"], "lumbar-phantom");
    assert_eq!(body["error"]["readiness"]["state"], "building", "{body}");
    let retry = retry.expect("a Retry-After header");
    assert!(
        (1..=3).contains(&retry),
        "Retry-After {retry} s within 1 s and render_worker::session::host::MAX_RETRY_AFTER_S"
    );
    assert_eq!(body["error"]["retry_after_s"], retry);

    // /healthz follows the build: fractions never go back, then ready.
    let start = Instant::now();
    let mut fractions = Vec::new();
    let ready = loop {
        let h = anatomy_health(addr).await;
        let region = h["regions"]["lumbar-phantom"].clone();
        match region["state"].as_str() {
            Some("building") => {
                let f = region["fraction"].as_f64().unwrap();
                assert!((0.0..=1.0).contains(&f), "{region}");
                assert!(region["remaining_s"].as_f64().unwrap() >= 0.0, "{region}");
                fractions.push((region["stage"].as_str().unwrap().to_string(), f));
            }
            Some("ready") => break h,
            other => panic!("unexpected state {other:?}: {h}"),
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "not ready in 120 s"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    let mut seen: Vec<(String, f64, usize)> = Vec::new();
    for (stage, f) in &fractions {
        match seen.last_mut() {
            Some((s, g, n)) if s == stage && g == f => *n += 1,
            _ => seen.push((stage.clone(), *f, 1)),
        }
    }
    eprintln!(
        "4 mm phantom preparation seen by /healthz every 20 ms, (stage, fraction, polls): {seen:?}; then {}",
        ready["regions"]
    );
    assert!(
        fractions.windows(2).all(|w| w[0].1 <= w[1].1),
        "progress never goes back: {fractions:?}"
    );
    assert_eq!(ready["ready"], true);
    assert!(
        ready["regions"]["lumbar-phantom"]["prepare_s"]
            .as_f64()
            .unwrap()
            > 0.0
    );

    // Now the same request creates the session.
    let (status, _, session) = request_session(&learner, &attempt).await;
    assert_eq!(status, 201, "{session}");
    assert_eq!(session["station_id"], "l4-l5-left-facet");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_region_that_cannot_be_prepared_is_reported_with_the_reason() {
    let stations = tempfile::tempdir().unwrap();
    let text = render_worker::session::demo::demo_station_toml(&[])
        .replace("region = \"demo-region\"", "region = \"missing-region\"");
    assert!(text.contains("missing-region"));
    std::fs::write(stations.path().join("demo-station.toml"), text).unwrap();
    let assets = tempfile::tempdir().unwrap();
    // The production loader: a region folder that does not exist.
    let host = SessionHost::new(
        HostConfig {
            assets_root: assets.path().to_owned(),
            stations_dir: stations.path().to_owned(),
            capacity: 4,
            session: SessionConfig::default(),
        },
        Backends::cpu(0),
        None,
    )
    .unwrap();
    let (addr, _db) = server_with(host, stations.path()).await;
    let learner = Client::login(addr, "learner@demo.invalid").await;
    let attempt = attempt_at(&learner, "demo-station").await;
    let start = Instant::now();
    let body = loop {
        let (status, _, body) = request_session(&learner, &attempt).await;
        assert_eq!(status, 503, "{body}");
        if body["error"]["code"] == "anatomy_failed" {
            break body;
        }
        assert_eq!(body["error"]["code"], "anatomy_preparing", "{body}");
        assert!(start.elapsed() < Duration::from_secs(30), "{body}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let message = body["error"]["message"].as_str().unwrap();
    assert!(message.contains("missing-region"), "{message}");
    let h = anatomy_health(addr).await;
    assert_eq!(h["ready"], false);
    assert_eq!(h["regions"]["missing-region"]["state"], "failed", "{h}");
    assert!(
        h["regions"]["missing-region"]["reason"]
            .as_str()
            .unwrap()
            .contains("missing-region"),
        "{h}"
    );
}
