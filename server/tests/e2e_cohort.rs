//! The faculty cohort dashboard (`web-client/cohort.html`) end to end in headless Chromium:
//! `web-client/tests/e2e_cohort.mjs` against the real server with the demo accounts. Two demo
//! learners have scored attempts at the demo station (stored as a simulation session stores
//! them at submit): the first misses the target once and then meets every criterion three
//! times (competent); the second scores well three times but punctures the dura in the middle
//! attempt (not yet: a safety criterion no score offsets). The faculty account opens the
//! dashboard: charts drawn, data tables, competency words, the CSV export, the learner filter,
//! the dark theme, axe-core's WCAG 2 A/AA rules, a station set to assessment kept over a
//! reload; a learner account is told the page is for faculty.

use render_worker::session::demo::{demo_station, demo_station_toml};
use serde_json::{Value, json};
use server::records::RecordsState;
use server::records::results::{NewResult, store_session_result};

use crate::dispatch_support::{Client, demo_server};
use crate::e2e_browser::{BROWSER_TURN, can_run, run_script, strings};

/// The demo station's id (`render_worker::session::demo::demo_station_toml`).
const STATION: &str = "demo-station";

/// Measurements that meet every criterion of the demo station (its rubric's tolerances:
/// endplate tilt within 2 degrees, beam within 5 degrees of the joint plane, tip within 2 mm,
/// no dural puncture, at most 10 acquisitions), with a dose that grows with `k` and a
/// fluoroscopy time that shrinks (so the dose chart's lines do not lie on one another).
fn met(k: f64) -> Value {
    json!({
        "ap_endplate_tilt_deg": 1.0,
        "beam_to_joint_plane_deg": 3.0,
        "tip_to_target_mm": 1.5,
        "dural_puncture_bool": 0.0,
        "fluoro_acquisitions_count": 8.0,
        "air_kerma_mgy": 2.0 + k,
        "kerma_area_product_gycm2": 0.2 + 0.1 * k,
        "fluoro_time_s": 30.0 - 4.0 * k
    })
}

/// [`met`] with some measurements changed.
fn with(k: f64, changes: Value) -> Value {
    let mut m = met(k);
    for (key, v) in changes.as_object().unwrap() {
        m[key] = v.clone();
    }
    m
}

/// Opens an attempt as `client` in `course` and stores the result of `measurements` for it,
/// as a simulation session does at submit.
async fn scored(state: &RecordsState, client: &Client, course: &Value, measurements: Value) {
    let learner: uuid::Uuid = {
        let (s, me) = client.call("GET", "/api/auth/me", None).await;
        assert_eq!(s, 200, "{me}");
        me["user"]["id"].as_str().unwrap().parse().unwrap()
    };
    let attempt: uuid::Uuid = client.new_attempt_in(course).await.parse().unwrap();
    let req: NewResult = serde_json::from_value(json!({
        "measurements": measurements,
        "reproducibility": crate::records_support::reproducibility(),
    }))
    .unwrap();
    // The worker evaluates the measurements its rubric reads (as `TestApp::store_result`).
    let station = demo_station(&[]).0;
    let mut read = req.measurements.clone();
    read.retain(|k, _| station.rubric.criteria.iter().any(|c| &c.measurement == k));
    let rubric = station.evaluate(&read);
    store_session_result(state, learner, attempt, req, &rubric)
        .await
        .unwrap();
}

/// Rows of a table in the report (each a list of cell texts).
fn rows(v: &Value) -> Vec<Vec<&str>> {
    v.as_array()
        .unwrap_or_else(|| panic!("not a table: {v}"))
        .iter()
        .map(strings)
        .collect()
}

/// A drawn chart: a canvas with a size, many painted pixels and more than the background's
/// colours. 2,000 pixels is far below what axes and gridlines alone paint on a 300 px tall chart
/// (measured: tens of thousands) and far above a blank canvas (0); 3 colours are the least a
/// chart with a text colour, a grid colour and one series has.
fn assert_drawn(charts: &Value, context: &str) {
    for name in ["criteria", "curves", "dose"] {
        let c = &charts[name];
        assert!(
            c["width"].as_u64().unwrap_or(0) > 0 && c["height"].as_u64().unwrap_or(0) > 0,
            "{context} {name}: {c}"
        );
        assert!(
            c["painted"].as_u64().unwrap() > 2_000,
            "{context} {name}: {c}"
        );
        assert!(c["colours"].as_u64().unwrap() >= 3, "{context} {name}: {c}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn faculty_read_the_cohort_dashboard_and_set_a_station_mode_in_headless_chromium() {
    if !can_run("faculty_read_the_cohort_dashboard_and_set_a_station_mode_in_headless_chromium") {
        return;
    }
    let _turn = BROWSER_TURN.lock().await;
    let srv = demo_server(false, None).await;
    // The records' state over the same database and the same station file (the result store
    // checks the station's hash against the attempt's revision).
    let stations = tempfile::tempdir().unwrap();
    std::fs::write(
        stations.path().join("demo-station.toml"),
        demo_station_toml(&[]),
    )
    .unwrap();
    let dir = stations.path().display().to_string();
    let config =
        server::Config::from_lookup(|k| (k == "PAINSIM_STATIONS_DIR").then(|| dir.clone()))
            .expect("test configuration");
    let state = RecordsState::from_parts(srv.db.pool.clone(), config.records);

    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    let course = faculty.demo_course().await;
    let ann = Client::login(srv.addr, "learner@demo.invalid").await;
    let bob = Client::login(srv.addr, "learner2@demo.invalid").await;
    // The first learner: a miss (tip 9 mm from the target), then three attempts that meet
    // every criterion.
    scored(
        &state,
        &ann,
        &course,
        with(0.0, json!({ "tip_to_target_mm": 9.0 })),
    )
    .await;
    for k in 1..4 {
        scored(&state, &ann, &course, met(f64::from(k))).await;
    }
    // The second: three high scores, the middle one with a dural puncture.
    scored(&state, &bob, &course, met(1.0)).await;
    scored(
        &state,
        &bob,
        &course,
        with(2.0, json!({ "dural_puncture_bool": 1.0 })),
    )
    .await;
    scored(&state, &bob, &course, met(3.0)).await;

    let course_id = course.as_str().unwrap();
    let report = run_script(
        "e2e_cohort.mjs",
        srv.addr,
        "cohort",
        &[
            ("E2E_COURSE", course_id),
            ("E2E_STATION", STATION),
            ("E2E_LEARNER2", "learner2@demo.invalid"),
        ],
    )
    .await;
    eprintln!("cohort dashboard in the browser: {report}");
    assert_eq!(
        strings(&report["steps"]),
        [
            "dashboard",
            "csv",
            "filtered",
            "mode filter",
            "dark",
            "axe",
            "mode",
            "learner"
        ]
    );
    assert_eq!(report["console_errors"], json!([]), "{report:#}");

    // The whole cohort: 5 criteria of the demo station, one of them a safety criterion; 7
    // attempts, all scored; the band over the first learner's 4 scored attempts.
    let all = &report["all"];
    assert_drawn(&all["charts"], "all");
    for f in ["criteria", "curves", "dose"] {
        let fig = &all["figures"][f];
        assert_eq!(fig["role"], "img", "{f}: {fig}");
        assert!(fig["label"].as_str().unwrap().len() > 20, "{f}: {fig}");
        assert!(!fig["caption"].as_str().unwrap().is_empty(), "{f}: {fig}");
        assert_eq!(fig["followed_by_table"], true, "{f}: {fig}");
    }
    assert_eq!(all["unnamed_controls"], json!([]), "{all:#}");
    let criteria = rows(&all["criteria"]);
    assert_eq!(criteria.len(), 5, "{criteria:?}");
    let safety: Vec<_> = criteria.iter().filter(|r| r[2] == "safety").collect();
    assert_eq!(safety.len(), 1, "{criteria:?}");
    // no_dural_puncture: met in 6 of 7 scored attempts; so is tip_at_target.
    assert_eq!(safety[0][0], "no_dural_puncture");
    assert_eq!(safety[0][6], "86 %");
    let tip = criteria.iter().find(|r| r[0] == "tip_at_target").unwrap();
    assert_eq!((tip[3], tip[4], tip[6]), ("6", "1", "86 %"), "{tip:?}");
    assert_eq!(rows(&all["curves"]).len(), 7);
    let band = rows(&all["band"]);
    assert_eq!(band.len(), 4, "{band:?}");
    assert_eq!((band[0][1], band[3][1]), ("2", "1"), "{band:?}");
    let dose = rows(&all["dose"]);
    assert_eq!(dose.len(), 7, "{dose:?}");
    // The first learner's first attempt: air kerma 2 mGy, KAP 0.2 Gy cm^2, 30 s.
    assert!(
        dose.iter()
            .any(|r| r[0] == "Demo Learner" && r[1] == "1" && r[6..9] == ["2.00", "0.200", "30.0"]),
        "{dose:?}"
    );
    let competency = rows(&all["competency"]);
    assert_eq!(competency.len(), 2, "{competency:?}");
    let of = |name: &str| competency.iter().find(|r| r[0] == name).unwrap().clone();
    let ann_row = of("Demo Learner");
    assert!(
        ann_row[1].ends_with("Competent (technical criteria)"),
        "{ann_row:?}"
    );
    assert_eq!(ann_row[3], "attempts 2, 3, 4");
    let bob_row = of("Demo Learner Two");
    assert!(
        bob_row[1].ends_with("Not yet: safety criterion failed (no_dural_puncture)"),
        "{bob_row:?}"
    );
    assert!(
        bob_row[2].contains("no score elsewhere offsets it"),
        "{bob_row:?}"
    );
    assert_eq!(all["safety_rows"], 1);
    assert!(
        all["notice"]
            .as_str()
            .unwrap()
            .contains("faculty judgement"),
        "{all:#}"
    );

    // The CSV: a header with each criterion, and one row per attempt.
    let csv = &report["csv"];
    assert_eq!(csv["file"], "cohort.csv");
    assert_eq!(csv["rows"], 7, "{csv}");
    assert!(
        strings(&csv["header"]).contains(&"criterion:no_dural_puncture"),
        "{csv}"
    );

    // Filtered to the second learner: their rows only, the cohort's band kept, the CSV link
    // and the page's address carrying the filter.
    let f = &report["filtered"];
    let learner_id = f["learner_id"].as_str().unwrap();
    assert_drawn(&f["charts"], "filtered");
    assert_eq!(rows(&f["competency"]).len(), 1);
    assert_eq!(rows(&f["competency"])[0][0], "Demo Learner Two");
    assert_eq!(rows(&f["dose"]).len(), 3);
    assert_eq!(rows(&f["curves"]).len(), 3);
    assert_eq!(
        rows(&f["band"]),
        band,
        "the reference band stays the cohort's"
    );
    assert!(
        f["csv_href"]
            .as_str()
            .unwrap()
            .contains(&format!("learner_id={learner_id}")),
        "{f:#}"
    );
    assert_eq!(f["csv_rows"], 3, "{f:#}");
    assert!(
        f["address"]
            .as_str()
            .unwrap()
            .contains(&format!("learner={learner_id}")),
        "{f:#}"
    );
    // Assessment only: no attempt ran in assessment mode, so none, and the filter in the link.
    let a = &report["assessment_only"];
    assert_eq!(a["dose_rows"], 0, "{a}");
    assert!(
        a["csv_href"]
            .as_str()
            .unwrap()
            .ends_with("&mode=assessment"),
        "{a}"
    );
    assert_eq!(a["canvases"], 3, "{a}");
    assert_eq!(report["dark"]["theme"], "dark");
    assert_drawn(&report["dark"]["charts"], "dark");

    // axe-core: no WCAG 2 A/AA violation.
    assert_eq!(report["axe"], json!([]), "{:#}", report["axe"]);

    // The station mode: practice until set, assessment after the save and a reload, and so
    // in the API.
    assert_eq!(report["mode_before"], "practice");
    assert!(
        report["mode_saved_text"]
            .as_str()
            .unwrap()
            .starts_with("Saved:"),
        "{report:#}"
    );
    assert_eq!(report["mode_after_reload"], "assessment");
    let (s, modes) = faculty
        .call(
            "GET",
            &format!("/api/courses/{course_id}/station-modes"),
            None,
        )
        .await;
    assert_eq!(s, 200);
    let demo = modes
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["station_id"] == STATION)
        .unwrap();
    assert_eq!(demo["mode"], "assessment", "{modes}");

    // A learner is told the page is for faculty and sees no cohort.
    assert!(
        report["learner_message"]
            .as_str()
            .unwrap()
            .contains("for faculty"),
        "{report:#}"
    );
    assert_eq!(report["learner_sees_cohort"], false);
}
