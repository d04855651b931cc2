//! The debrief page (`web-client/debrief.html`) in headless Chromium: the demo learner's
//! submitted attempt (the scripted session of `disclosure::run_session`: shots, two punctures,
//! a bone contact, injections and a submit) is debriefed by the learner and by faculty of the
//! course; a second one, straight down the midline into the dural sac, has its reveal outlined
//! and its failed safety criterion shown; an attempt still in progress says it is not
//! submitted yet. The script
//! (`web-client/tests/e2e_debrief.mjs`) reports what the page shows; this test checks it
//! against the server's own debrief and reveal.

use serde_json::{Value, json};

use crate::disclosure::{run_session, station_toml};
use crate::dispatch_support::{Client, Received, acked, demo_server_for};
use crate::e2e_browser::{BROWSER_TURN, can_run, run_script, strings};

/// The array at `key` of `v`.
fn array<'a>(v: &'a Value, key: &str) -> &'a Vec<Value> {
    v[key]
        .as_array()
        .unwrap_or_else(|| panic!("{key} is not an array: {v:#}"))
}

/// A submitted attempt of `learner`: a shot, the needle placed in AP down the midline through
/// the demo dural sac (y -35 to -20 mm, |x| < 8 mm under the posterior skin at y = -120 mm, as
/// in `debrief::the_reveal_outlines_the_structures_the_needle_passed_through`), a second shot
/// that shows it, and the submit.
async fn attempt_through_the_sac(learner: &Client) -> String {
    let (attempt, session) = learner.start_demo_attempt().await;
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.send(2, json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [0, -120, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] })).await;
    ws.send(3, json!({ "type": "needle_feed", "mm": 45 })).await;
    ws.send(4, json!({ "type": "needle_feed", "mm": 45 })).await;
    ws.send(5, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r).len() == 5).await;
    ws.send(6, json!({ "type": "submit" })).await;
    ws.until(&mut got, |r| {
        r.texts.iter().any(|t| t["type"] == "technical_result")
    })
    .await;
    attempt
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn debrief_page_for_learner_and_faculty_in_headless_chromium() {
    if !can_run("debrief_page_for_learner_and_faculty_in_headless_chromium") {
        return;
    }
    let _turn = BROWSER_TURN.lock().await;
    let srv = demo_server_for(true, None, &station_toml()).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, _) = run_session(&learner).await;
    let sac_attempt = attempt_through_the_sac(&learner).await;
    // A second attempt, its session open and nothing submitted.
    let (open_attempt, _) = learner.start_demo_attempt().await;
    // What the server says, to hold the page to.
    let (s, debrief) = learner
        .call("GET", &format!("/api/attempts/{attempt}/debrief"), None)
        .await;
    assert_eq!(s, 200, "{debrief}");
    let (s, reveal) = learner
        .call("GET", &format!("/api/attempts/{attempt}/reveal"), None)
        .await;
    assert_eq!(s, 200, "{reveal}");
    let (s, sac_reveal) = learner
        .call("GET", &format!("/api/attempts/{sac_attempt}/reveal"), None)
        .await;
    assert_eq!(s, 200, "{sac_reveal}");
    let (s, sac_debrief) = learner
        .call("GET", &format!("/api/attempts/{sac_attempt}/debrief"), None)
        .await;
    assert_eq!(s, 200, "{sac_debrief}");

    let report = run_script(
        "e2e_debrief.mjs",
        srv.addr,
        "debrief",
        &[
            ("E2E_ATTEMPT", attempt.as_str()),
            ("E2E_OPEN_ATTEMPT", open_attempt.as_str()),
            ("E2E_REVEAL_ATTEMPT", sac_attempt.as_str()),
        ],
    )
    .await;
    // The whole report, for the figures (one line).
    eprintln!("debrief in the browser: {report}");
    assert_eq!(
        strings(&report["steps"]),
        [
            "debrief",
            "reveal",
            "stepped",
            "played",
            "accessible",
            "sac",
            "in progress",
            "faculty",
            "logged out"
        ]
    );

    // The criteria table: one row per criterion of the debrief, in its order, with the
    // server's explanation and the safety criteria marked.
    let page = &report["learner"];
    let criteria = array(&debrief, "criteria");
    let rows = array(page, "rows");
    assert_eq!(rows.len(), criteria.len(), "{page:#}");
    assert!(!rows.is_empty());
    for (row, c) in rows.iter().zip(criteria) {
        assert_eq!(row["id"], c["id"], "{row:#}");
        assert_eq!(row["status"], c["status"], "{row:#}");
        assert_eq!(row["critical"], c["critical"], "{row:#}");
        let cells = strings(&row["cells"]);
        assert_eq!(cells.len(), 5, "{row:#}");
        assert!(cells[0].contains(c["description"].as_str().unwrap()));
        assert_eq!(cells[4], c["explanation"].as_str().unwrap());
        if c["critical"] == true {
            assert!(cells[0].contains("Safety"), "{row:#}");
        }
        if c["value"].is_number() {
            assert_ne!(cells[1], "not measured", "{row:#}");
        }
    }
    assert_eq!(
        strings(&page["header_rows"]),
        [
            "Criterion",
            "Measured",
            "Tolerance",
            "Status",
            "Explanation"
        ]
    );
    // The outcome in neutral words, worded as a technical statement.
    let outcome = page["outcome"].as_str().unwrap();
    assert!(
        outcome.contains("not a certification") && !outcome.to_lowercase().contains("competent"),
        "{outcome}"
    );
    assert!(
        page["score"].as_str().unwrap().contains("threshold"),
        "{page:#}"
    );

    // The reveal of the scripted session: its legend lists the structures the needle passed
    // through, in the server's order (the scripted needle ends on bone through the skin only,
    // an envelope that is listed but not outlined).
    let legend_names = |page: &Value| -> Vec<String> {
        array(page, "legend")
            .iter()
            .map(|l| l["structure"].as_str().unwrap().to_owned())
            .collect()
    };
    assert_eq!(legend_names(page), strings(&reveal["touched"]), "{page:#}");
    assert_eq!(report["reveal"]["width"], reveal["width"]);

    // The reveal through the sac: the legend lists the touched structures in the server's
    // order, and each outlined one has pixels of its colour on the canvas (the API's outline
    // runs drawn 3 px wide: at least as many pixels as the outline has runs).
    let sac_page = &report["sac"];
    let touched = strings(&sac_reveal["touched"]);
    assert!(touched.contains(&"dural_sac"), "{sac_reveal}");
    assert_eq!(legend_names(sac_page), touched, "{sac_page:#}");
    let counts = &report["sac_reveal"]["counts"];
    let outlines = array(&sac_reveal, "outlines");
    assert!(!outlines.is_empty(), "{sac_reveal}");
    for o in outlines {
        let name = o["structure"].as_str().unwrap();
        let runs = o["runs"].as_array().unwrap().len() as u64;
        let drawn = counts[name].as_u64().unwrap_or(0);
        assert!(
            drawn >= runs,
            "{name}: {drawn} pixels for {runs} runs: {report:#}"
        );
    }
    assert!(counts["dural_sac"].as_u64().unwrap() > 0, "{report:#}");
    // The image itself is under the outlines (grey pixels, most of the canvas).
    let area = sac_reveal["width"].as_u64().unwrap() * sac_reveal["height"].as_u64().unwrap();
    assert!(
        report["sac_reveal"]["grey"].as_u64().unwrap() > area / 2,
        "{report:#}"
    );
    assert!(
        sac_page["reveal_label"]
            .as_str()
            .unwrap()
            .contains("dural sac"),
        "{sac_page:#}"
    );
    // Its failed safety criterion: a banner and a marked row; a violation tick on the bar.
    let safety = &report["sac_safety"];
    assert_eq!(safety["banner_shown"], true, "{safety:#}");
    assert!(
        safety["banner"]
            .as_str()
            .unwrap()
            .contains("The tip never entered the dural sac."),
        "{safety:#}"
    );
    assert_eq!(array(safety, "failed_rows").len(), 1, "{safety:#}");
    let sac_kinds: Vec<&str> = array(sac_page, "ticks")
        .iter()
        .map(|t| t["kind"].as_str().unwrap())
        .collect();
    let api_kinds: Vec<&str> = array(&sac_debrief, "events")
        .iter()
        .map(|e| e["kind"].as_str().unwrap())
        .collect();
    assert_eq!(sac_kinds, api_kinds);
    assert!(sac_kinds.contains(&"violation"), "{sac_kinds:?}");
    assert!(array(&report, "axe_sac").is_empty(), "{report:#}");

    // The replay bar: one tick per event at its step, the same events as buttons.
    let events = array(&debrief, "events");
    let ticks = array(page, "ticks");
    assert_eq!(ticks.len(), events.len(), "{page:#}");
    for (t, e) in ticks.iter().zip(events) {
        assert_eq!(t["step"], e["step"], "{t:#}");
        assert_eq!(t["kind"], e["kind"], "{t:#}");
        assert!(
            t["title"]
                .as_str()
                .unwrap()
                .contains(e["label"].as_str().unwrap())
        );
    }
    assert_eq!(array(page, "events").len(), events.len());
    assert_eq!(page["range_max"], debrief["steps"]);

    // Stepping forward onto a shot changes the frame (a new image: far above JPEG noise, which
    // is 0 between two decodes of one JPEG) and announces the event.
    let st = &report["stepping"];
    assert_eq!(st["after_step"], st["target_step"], "{st:#}");
    assert_eq!(
        st["before_step"].as_u64().unwrap() + 1,
        st["target_step"].as_u64().unwrap()
    );
    assert_eq!(st["after_frame"], "image", "{st:#}");
    assert!(st["mean_diff"].as_f64().unwrap() > 0.5, "{st:#}");
    let live = st["live_forward"].as_str().unwrap();
    assert!(
        live.starts_with(&format!("Step {} of", st["target_step"])) && live.contains("Shot"),
        "{st:#}"
    );
    assert_eq!(array(st, "current_event").len(), 1, "{st:#}");
    assert_eq!(
        report["keyboard"]["step"].as_u64().unwrap(),
        st["target_step"].as_u64().unwrap() + 1
    );
    assert_eq!(report["keyboard"]["prev_event_step"], st["target_step"]);
    assert_eq!(
        report["keyboard"]["focus_outline"]["style"], "solid",
        "{report:#}"
    );

    // Play advances the step; pause holds it; one frame request at a time throughout.
    let play = &report["play"];
    assert_eq!(play["playing"]["pressed"], "true", "{play:#}");
    assert!(
        play["paused_at"].as_u64().unwrap() >= play["start"].as_u64().unwrap() + 3,
        "{play:#}"
    );
    assert_eq!(play["after_pause"], play["paused_at"], "{play:#}");
    assert_eq!(play["state_after"], "Paused", "{play:#}");
    assert_eq!(play["frame_stats"]["maxInFlight"], 1, "{play:#}");

    // Accessible: every control named, every image labelled, a live region; axe-core's WCAG 2
    // A/AA rules pass in both themes, which differ.
    let a = &report["accessible"];
    assert_eq!(a["unlabeled_buttons"], 0, "{a:#}");
    assert_eq!(a["unlabeled_inputs"], 0, "{a:#}");
    assert_eq!(a["unlabeled_images"], 0, "{a:#}");
    assert!(a["live_regions"].as_u64().unwrap() >= 1, "{a:#}");
    assert!(array(&report, "axe_light").is_empty(), "{report:#}");
    assert!(array(&report, "axe_dark").is_empty(), "{report:#}");
    assert_ne!(
        report["theme"]["dark_bg"], report["theme"]["light_bg"],
        "{report:#}"
    );

    // The attempt in progress: a clear message, nothing else.
    let open = &report["in_progress"];
    assert_eq!(open["state"], "not-submitted", "{open:#}");
    assert!(
        open["status"]
            .as_str()
            .unwrap()
            .contains("not submitted yet"),
        "{open:#}"
    );
    assert_eq!(open["rows"], 0);
    assert_eq!(open["summary_hidden"], true);

    // Faculty see the same page for the same attempt.
    assert_eq!(report["faculty_open"]["state"], "ready", "{report:#}");
    let f = &report["faculty"];
    for key in ["rows", "legend", "events", "outcome", "score"] {
        assert_eq!(f[key], page[key], "{key}");
    }
    assert_eq!(array(f, "ticks").len(), events.len());
    assert_eq!(
        report["faculty_reveal"]["counts"],
        report["reveal"]["counts"]
    );
    assert_eq!(
        report["faculty_sac_reveal"]["counts"], report["sac_reveal"]["counts"],
        "{report:#}"
    );

    // Logged out: a link to log in.
    assert_eq!(report["logged_out"]["state"], "login", "{report:#}");
    assert_eq!(report["logged_out"]["link_shown"], true, "{report:#}");
    assert!(
        report["console_errors"].as_array().unwrap().is_empty(),
        "{report:#}"
    );
}
