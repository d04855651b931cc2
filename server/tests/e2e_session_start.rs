//! Session start in headless Chromium (`web-client/tests/e2e_start.mjs`): a learner who opens a
//! station while its anatomy is still being prepared reads the preparation's stage and progress
//! in the page, then gets the live session and a first image without doing anything else; a
//! learner who opens one while every session slot is taken reads the server's capacity message,
//! then gets the session once a slot frees.

use std::path::Path;
use std::time::{Duration, Instant};

use render_worker::session::sha256_hex;
use serde_json::{Value, json};
use sim_core::anatomy::phantom;

use crate::anatomy_readiness::{phantom_building_host, server_with};
use crate::dispatch::{Client, Received, acked};
use crate::dispatch_support::demo_server_sized;
use crate::e2e_browser::{BROWSER_TURN, can_run, run_script};

fn messages(report: &Value) -> Vec<String> {
    report["messages"]
        .as_array()
        .map(|m| {
            m.iter()
                .filter_map(|s| s.as_str().map(str::to_owned))
                .collect()
        })
        .unwrap_or_default()
}

/// The learner opens the facet station while its region, the real lumbar phantom at 4 mm voxels,
/// is built from nothing by the real pipeline: the page shows the stages with a growing
/// percentage, then the session and a first image.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_the_preparation_then_the_first_image() {
    if !can_run("the_page_shows_the_preparation_then_the_first_image") {
        return;
    }
    let _turn = BROWSER_TURN.lock().await;
    let stations = tempfile::tempdir().unwrap();
    let name = "l4-l5-left-facet.toml";
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../assets/stations")
            .join(name),
    )
    .unwrap();
    std::fs::write(stations.path().join(name), &text).unwrap();
    let station = sim_core::rubric::Station::from_toml_str(&text).unwrap();
    assert_eq!(station.region, phantom::REGION_NAME);
    let assets = tempfile::tempdir().unwrap();
    let host = phantom_building_host(
        vec![(station, sha256_hex(text.as_bytes()))],
        assets.path(),
        Duration::from_millis(400),
    );
    let (addr, _db) = server_with(host, stations.path()).await;
    let report = run_script("e2e_start.mjs", addr, "start-prepare", &[]).await;
    let seen = messages(&report);
    println!("page messages while waiting: {seen:#?}\nreport: {report:#}");
    let percents: Vec<u32> = seen
        .iter()
        .filter(|m| m.starts_with("Preparing the anatomy (lumbar-phantom)"))
        .filter_map(|m| {
            let (head, _) = m.split_once(" % done")?;
            head.rsplit(' ').next()?.parse().ok()
        })
        .collect();
    assert!(
        percents.len() >= 3 && percents.last() > percents.first(),
        "the page did not show the preparation moving on: {seen:?}"
    );
    // The pipeline's stages in words: the phantom is voxelised, labelled and meshed.
    assert!(
        seen.iter()
            .any(|m| m.contains(", meshing the structures: ")),
        "the page never named the stage: {seen:?}"
    );
    assert!(
        percents.windows(2).all(|w| w[0] <= w[1]) && percents.iter().all(|p| *p <= 100),
        "progress went backwards or past 100 %: {percents:?}"
    );
    assert!(
        report["first_image_mean"].as_f64().unwrap_or(0.0) > 5.0,
        "the first image is black: {report:#}"
    );
    assert!(
        report["console_errors"]
            .as_array()
            .is_some_and(Vec::is_empty),
        "{report:#}"
    );
}

/// Every slot of a one-session worker is taken: the page says so in the server's words and waits;
/// once the running session is submitted, the learner's session opens and shows an image.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_shows_the_capacity_message_then_the_session() {
    if !can_run("the_page_shows_the_capacity_message_then_the_session") {
        return;
    }
    let _turn = BROWSER_TURN.lock().await;
    let toml = render_worker::session::demo::demo_station_toml(&[]);
    let srv = demo_server_sized(true, None, &toml, 1).await;
    let holder = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_, first) = holder.start_demo_attempt().await;
    let ws_path = first["ws"].as_str().unwrap().to_owned();
    // The holder submits a few seconds after the browser began to wait.
    let release = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_secs(6)).await;
        let mut ws = holder.websocket(&ws_path).await;
        let mut got = Received::default();
        ws.send(1, json!({ "type": "submit" })).await;
        ws.until(&mut got, |r| acked(r) == [1]).await;
        Instant::now()
    });
    let report = run_script("e2e_start.mjs", srv.addr, "start-capacity", &[]).await;
    release.await.unwrap();
    let seen = messages(&report);
    println!("page messages while waiting: {seen:#?}\nreport: {report:#}");
    assert!(
        seen.iter().any(
            |m| m.contains("all 1 live-session slots") && m.contains("Waiting for a free slot")
        ),
        "the page never showed the capacity message: {seen:?}"
    );
    assert!(
        report["waited_ms"].as_f64().unwrap_or(0.0) >= 5000.0,
        "the session opened before a slot was free: {report:#}"
    );
    assert!(
        report["first_image_mean"].as_f64().unwrap_or(0.0) > 5.0,
        "the first image is black: {report:#}"
    );
}
