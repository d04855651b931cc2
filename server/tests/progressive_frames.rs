//! Progressive frames through the server: a C-arm move and a shot on a GPU worker that drafts
//! (forced on the small demo region) reach the browser as a draft, marked in the frame header,
//! and then the full frame of the same input. The recorded session replays both bit for bit
//! (`replay/frame?quality=draft` and the plain `replay/frame`), and the replay check of the
//! submitted result finds the final image identical: the relay never takes a draft as the image
//! of record. In the browser, the page marks a draft as a preview until the full frame comes.
//! The same holds for the B-mode view of a probe move on the CPU reference.

use std::sync::Arc;

use render_worker::cluster::request_with_headers;
use render_worker::session::demo::{demo_region, demo_station_toml};
use render_worker::session::frame::EncodedFrame;
use render_worker::session::modalities::fluoro::GpuFluoroBackend;
use render_worker::session::{Backends, SessionConfig, SessionHost, sha256_hex};
use serde_json::json;
use sim_core::rubric::Station;
use tokio_tungstenite::tungstenite::Message;

use crate::anatomy_readiness::server_with;
use crate::dispatch::{Client, acked};
use crate::dispatch_support::Received;

/// The frames that arrive until the full frame of input `seq`: (draft, input_seq, JPEG).
async fn frames_until_full(
    ws: &mut crate::dispatch_support::Ws,
    got: &mut Received,
    seq: u64,
) -> Vec<(bool, u64, Vec<u8>)> {
    view_frames_until_full(ws, got, None, seq).await
}

/// A frame shown: (step, JPEG).
type Step = (u64, Vec<u8>);
/// Frames shown.
type Shown = Vec<Step>;

/// `frames` (after input `seq`) into the drafts and the full frames of `seq`, by step: every
/// draft is of the newest input.
fn sort_frames(frames: Vec<(bool, u64, Vec<u8>)>, seq: u64, drafts: &mut Shown, fulls: &mut Shown) {
    for (draft, input_seq, jpeg) in frames {
        if draft {
            assert_eq!(input_seq, seq, "a draft of the newest input");
            drafts.push((seq, jpeg));
        } else if input_seq == seq {
            fulls.push((seq, jpeg));
        }
    }
}

/// Submits the attempt (input `seq`), then checks that its recorded session replays every draft
/// and full frame shown (`shown`, of the view `view_query` names: `""` or `"&view=..."`) byte for
/// byte, and that the stored result's replay check finds the final images identical (the relay
/// never takes a draft as the image of record).
#[allow(clippy::too_many_arguments)]
async fn submit_and_check_replays(
    ws: &mut crate::dispatch_support::Ws,
    got: &mut Received,
    seq: u64,
    learner: &Client,
    addr: std::net::SocketAddr,
    attempt: &str,
    view_query: &str,
    (drafts, fulls): (&[Step], &[Step]),
) {
    ws.send(seq, json!({ "type": "submit" })).await;
    ws.until(got, |r| acked(r).contains(&seq)).await;
    for (quality, shown) in [("draft", drafts), ("full", fulls)] {
        for (step, jpeg) in shown {
            let query = format!("step={step}{view_query}&quality={quality}");
            let r = replay_frame(addr, attempt, &learner.cookie, &query).await;
            assert_eq!(r.status, 200, "{query}");
            assert!(r.body == *jpeg, "{query}: the replayed frame differs");
        }
    }
    let (_, replay) = learner
        .call("GET", &format!("/api/attempts/{attempt}/replay"), None)
        .await;
    assert_eq!(replay["identical"], true, "{replay:#}");
}

/// A recorded attempt's `replay/frame` with `query`, as `cookie`'s user asks for it.
async fn replay_frame(
    addr: std::net::SocketAddr,
    attempt: &str,
    cookie: &str,
    query: &str,
) -> render_worker::cluster::HttpResponse {
    let url = format!("http://{addr}/api/attempts/{attempt}/replay/frame?{query}");
    request_with_headers("GET", &url, None, &[("Cookie", cookie)])
        .await
        .unwrap()
}

/// A server whose in-process worker renders on the GPU and drafts the demo region (forced: it
/// is far below the triangle count that gets drafts by default), or `None` without a GPU
/// (fails instead under `REQUIRE_GPU=1`).
async fn drafting_server() -> Option<(
    std::net::SocketAddr,
    server::test_support::TestDb,
    tempfile::TempDir,
)> {
    let ctx = match render_worker::gpu::GpuContext::new_headless() {
        Ok(ctx) => ctx,
        Err(e) if std::env::var("REQUIRE_GPU").is_ok_and(|v| v == "1") => {
            panic!("REQUIRE_GPU=1 but no GPU context: {e}")
        }
        Err(e) => {
            eprintln!("progressive frames test skipped: no GPU context ({e})");
            return None;
        }
    };
    let region = Arc::new(demo_region());
    let fluoro = GpuFluoroBackend::new(ctx).drafting_from(Some(0));
    fluoro
        .wait_for_draft_scene(&region)
        .expect("the demo region gets a draft scene");
    let toml = demo_station_toml(&[]);
    let stations = tempfile::tempdir().unwrap();
    std::fs::write(stations.path().join("demo-station.toml"), &toml).unwrap();
    let station = Station::from_toml_str(&toml).unwrap();
    let host = SessionHost::with_regions(
        vec![(station, sha256_hex(toml.as_bytes()))],
        vec![region],
        Backends::new(Arc::new(fluoro), Backends::cpu(1).ultrasound),
        2,
        SessionConfig::default(),
    );
    let (addr, db) = server_with(host, stations.path()).await;
    Some((addr, db, stations))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_carm_move_shows_a_draft_then_the_full_frame_and_both_replay() {
    let Some((addr, _db, _stations)) = drafting_server().await else {
        return;
    };
    let learner = Client::login(addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let mut ws = learner
        .websocket(session["ws"].as_str().expect("ws path"))
        .await;
    let mut got = Received::default();
    // Each shot after a C-arm move: a draft first, then the full frame of the same input. A
    // draft the relay did not pass on in time would be replaced by the full frame (newest
    // wins), so a few moves are tried; the first one is always drafted (nothing is kept yet).
    let mut drafts = Vec::new();
    let mut fulls = Vec::new();
    let mut seq = 0;
    for k in 0..3 {
        seq += 1;
        ws.send(
            seq,
            json!({ "type": "carm_pose", "orbital_deg": 10 + 10 * k, "angular_deg": -5 }),
        )
        .await;
        seq += 1;
        ws.send(seq, json!({ "type": "shot" })).await;
        let frames = frames_until_full(&mut ws, &mut got, seq).await;
        sort_frames(frames, seq, &mut drafts, &mut fulls);
    }
    assert!(!drafts.is_empty(), "no draft arrived");
    assert_eq!(fulls.len(), 3, "one full frame per shot");
    // A needle-free shot with nothing moved: the full frame only.
    seq += 1;
    ws.send(seq, json!({ "type": "shot" })).await;
    let frames = frames_until_full(&mut ws, &mut got, seq).await;
    assert!(
        frames.iter().all(|(draft, ..)| !draft),
        "a shot without a C-arm move is not drafted"
    );
    let last_full = frames.last().unwrap().2.clone();
    seq += 1;
    let shown = (&drafts[..], &fulls[..]);
    submit_and_check_replays(&mut ws, &mut got, seq, &learner, addr, &attempt, "", shown).await;
    let frame_at = |step: u64, quality: &str| {
        let query = format!("step={step}&quality={quality}");
        let (attempt, cookie) = (attempt.clone(), learner.cookie.clone());
        async move { replay_frame(addr, &attempt, &cookie, &query).await }
    };
    for (step, jpeg) in &drafts {
        let r = frame_at(*step, "full").await;
        assert!(r.body != *jpeg, "step {step}: the full replay is the draft");
    }
    let r = frame_at(seq, "full").await;
    assert!(r.body == last_full);
    let r = frame_at(0, "draft").await;
    assert_eq!(r.status, 204, "no image before the first shot");
    let r = frame_at(2, "sharp").await;
    assert_eq!(r.status, 400, "an unknown quality is refused");
}

/// The browser (`web-client/tests/e2e_preview.mjs`): each C-arm turn and shot draws a draft with
/// the "Preview" badge shown, then the full frame with it hidden again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_marks_the_draft_as_a_preview_until_the_full_frame() {
    if !crate::e2e_browser::can_run("the_page_marks_the_draft_as_a_preview_until_the_full_frame") {
        return;
    }
    let _turn = crate::e2e_browser::BROWSER_TURN.lock().await;
    let Some((addr, _db, _stations)) = drafting_server().await else {
        return;
    };
    let report = crate::e2e_browser::run_script("e2e_preview.mjs", addr, "preview", &[]).await;
    eprintln!("preview in the browser: {report}");
    assert_eq!(
        report["steps"],
        json!(["session open", "shots"]),
        "{report:#}"
    );
    let drafts = report["drafts"].as_u64().unwrap();
    assert!(drafts >= 1, "no draft reached the page: {report:#}");
    // Three full frames at least (one per shot) besides the drafts.
    assert!(
        report["frames"].as_u64().unwrap() >= drafts + 3,
        "{report:#}"
    );
    // The badge went up with a draft and down with the full frame that followed, and is down.
    let badge: Vec<&str> = report["badge"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    assert!(
        badge.windows(2).any(|w| w == ["shown", "hidden"]),
        "{report:#}"
    );
    assert_eq!(
        report["final"],
        json!({ "draft": false, "badge_hidden": true })
    );
}

/// The frames of `view` (of every view: `None`) that arrive until its full frame of input `seq`
/// or newer: (draft, input_seq, JPEG).
async fn view_frames_until_full(
    ws: &mut crate::dispatch_support::Ws,
    got: &mut Received,
    view: Option<render_worker::session::ViewId>,
    seq: u64,
) -> Vec<(bool, u64, Vec<u8>)> {
    let mut frames = Vec::new();
    loop {
        match ws.next_message().await {
            Message::Text(t) => got.texts.push(serde_json::from_str(&t).unwrap()),
            Message::Binary(b) => {
                let f = EncodedFrame::parse(&b).expect("a frame");
                if view.is_some_and(|v| v != f.view) {
                    continue;
                }
                frames.push((f.draft, f.input_seq, f.jpeg));
                if !f.draft && f.input_seq >= seq {
                    return frames;
                }
            }
            _ => {}
        }
    }
}

/// Probe moves through the server on the CPU reference (the demo server's in-process worker):
/// the B-mode view gets a draft, marked in the frame header, then the full frame of the same
/// input; the recorded session replays both byte for byte
/// (`replay/frame?view=ultrasound&quality=draft`, and `quality=full`), and the replay check of
/// the submitted result finds the final images identical.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_probe_move_shows_a_b_mode_draft_then_the_full_frame_and_both_replay() {
    use render_worker::session::ViewId;
    let srv = crate::dispatch_support::demo_server_for(
        true,
        None,
        &crate::e2e_browser::ultrasound_demo_station_toml(),
    )
    .await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let mut ws = learner
        .websocket(session["ws"].as_str().expect("ws path"))
        .await;
    let mut got = Received::default();
    let mut seq = 1;
    ws.send(
        seq,
        json!({ "type": "probe_select", "instrument": "curvilinear-probe" }),
    )
    .await;
    view_frames_until_full(&mut ws, &mut got, Some(ViewId::ULTRASOUND), seq).await;
    // Rocked and turned, as a learner holds the probe. A draft the relay did not pass on in time
    // would be replaced by the full frame (newest wins), so a few moves are tried.
    let (mut drafts, mut fulls) = (Vec::new(), Vec::new());
    for k in 0..3 {
        seq += 1;
        let slide = if k % 2 == 0 { 2.0 } else { -1.0 };
        ws.send(
            seq,
            json!({ "type": "probe_move", "slide_mm": [slide, 0.0], "tilt_deg": [3.0, -2.0], "rotate_deg": 5.0 }),
        )
        .await;
        let frames = view_frames_until_full(&mut ws, &mut got, Some(ViewId::ULTRASOUND), seq).await;
        sort_frames(frames, seq, &mut drafts, &mut fulls);
    }
    assert!(!drafts.is_empty(), "no B-mode draft arrived");
    assert_eq!(fulls.len(), 3, "one full frame per move");
    seq += 1;
    let shown = (&drafts[..], &fulls[..]);
    let (addr, view) = (srv.addr, "&view=ultrasound");
    submit_and_check_replays(
        &mut ws, &mut got, seq, &learner, addr, &attempt, view, shown,
    )
    .await;
    for (step, jpeg) in &fulls {
        assert!(
            drafts.iter().all(|(s, d)| s != step || d != jpeg),
            "step {step}: the full frame is the draft"
        );
    }
}
