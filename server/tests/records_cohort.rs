//! The cohort dashboard's data (`records::cohort`): pass rates, learning curves against the
//! cohort's band, dose and fluoroscopy time, competency on the last three scored attempts with
//! safety criteria that no score offsets, filters, CSV, and who may read it.

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};
use server::records::RecordsState;
use server::records::auth::Role;
use server::records::results::{NewResult, store_session_result};
use sim_core::rubric::{Measurements, Station};
use uuid::Uuid;

use crate::records_support::{Session, TestApp, facet_measurements_met, reproducibility};

const STATION: &str = "l4-l5-left-facet";

fn station() -> Station {
    let text = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join(format!("../assets/stations/{STATION}.toml")),
    )
    .unwrap();
    Station::from_toml_str(&text).unwrap()
}

/// Opens an attempt as `session` and stores the result of `measurements` for it, as a
/// simulation session does at submit.
async fn scored(
    app: &TestApp,
    session: &Session,
    learner: Uuid,
    course: Uuid,
    measurements: Value,
) -> Uuid {
    let attempt = app.open_attempt(session, course, STATION).await;
    let state = RecordsState::from_parts(app.pool().clone(), app.config.clone());
    let req: NewResult = serde_json::from_value(json!({
        "measurements": measurements,
        "reproducibility": reproducibility(),
    }))
    .unwrap();
    let m: Measurements = req.measurements.clone();
    let rubric = station().evaluate(&m);
    store_session_result(&state, learner, attempt, req, &rubric)
        .await
        .unwrap();
    attempt
}

fn with(changes: Value) -> Value {
    let mut m = facet_measurements_met();
    for (k, v) in changes.as_object().unwrap() {
        m[k] = v.clone();
    }
    m
}

#[tokio::test]
async fn the_cohort_shows_rates_curves_dose_and_competency_to_its_faculty_only() {
    let app = TestApp::new(&[]).await;
    let course = app.course("COH-1").await;
    let other_course = app.course("COH-2").await;
    let faculty = app.user("coh-faculty@example.org", Role::Faculty).await;
    app.member(course, faculty, "faculty").await;
    let outsider = app.user("coh-outsider@example.org", Role::Faculty).await;
    app.member(other_course, outsider, "faculty").await;
    let mut learners = Vec::new();
    for name in ["ann", "bob", "cem"] {
        let email = format!("coh-{name}@example.org");
        let id = app.user(&email, Role::Learner).await;
        app.member(course, id, "learner").await;
        learners.push((id, app.login(&email, None).await));
    }
    let (ann, ann_s) = &learners[0];
    let (bob, bob_s) = &learners[1];
    let (_cem, cem_s) = &learners[2];
    // Ann: a miss, then three met in a row: competent.
    scored(
        &app,
        ann_s,
        *ann,
        course,
        with(json!({ "tip_to_target_mm": 9.0 })),
    )
    .await;
    for _ in 0..3 {
        scored(&app, ann_s, *ann, course, facet_measurements_met()).await;
    }
    // Bob: three high scores, the middle one with intravascular uptake (a safety criterion).
    scored(&app, bob_s, *bob, course, facet_measurements_met()).await;
    let unsafe_attempt = scored(
        &app,
        bob_s,
        *bob,
        course,
        with(json!({ "intravascular_uptake_bool": 1.0 })),
    )
    .await;
    scored(&app, bob_s, *bob, course, facet_measurements_met()).await;
    // Cem: one scored attempt and one still open.
    scored(
        &app,
        cem_s,
        learners[2].0,
        course,
        with(json!({ "air_kerma_mgy": 9.0 })),
    )
    .await;
    app.open_attempt(cem_s, course, STATION).await;

    let fs = app.login("coh-faculty@example.org", None).await;
    let path = format!("/api/courses/{course}/cohort?station_id={STATION}");
    let r = app.send(Method::GET, &path, Some(&fs), None).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let c = &r.json;
    assert_eq!(c["attempts"], 9);
    assert_eq!(c["scored_attempts"], 8);
    let crit = |id: &str| {
        c["criteria"]
            .as_array()
            .unwrap()
            .iter()
            .find(|k| k["id"] == id)
            .unwrap()
            .clone()
    };
    assert_eq!(crit("tip_at_target")["met"], 7);
    assert_eq!(crit("tip_at_target")["not_met"], 1);
    assert_eq!(crit("tip_at_target")["pass_rate"], 7.0 / 8.0);
    assert_eq!(crit("no_intravascular_injection")["critical"], true);
    assert_eq!(crit("no_intravascular_injection")["not_met"], 1);

    let learner = |email: &str| {
        c["learners"]
            .as_array()
            .unwrap()
            .iter()
            .find(|l| l["email"] == email)
            .unwrap()
            .clone()
    };
    let a = learner("coh-ann@example.org");
    assert_eq!(a["competency"]["status"], "competent", "{a:#}");
    assert_eq!(a["attempts"].as_array().unwrap().len(), 4);
    assert_eq!(a["attempts"][0]["criteria"]["tip_at_target"], "not_met");
    assert_eq!(a["attempts"][3]["air_kerma_mgy"], 3.5);
    assert_eq!(a["attempts"][3]["fluoro_time_s"], 12.0);
    let b = learner("coh-bob@example.org");
    assert_eq!(b["competency"]["status"], "not_yet", "{b:#}");
    assert!(
        b["competency"]["reason"]
            .as_str()
            .unwrap()
            .contains("no_intravascular_injection"),
        "{b:#}"
    );
    assert_eq!(b["attempts"][1]["attempt_id"], unsafe_attempt.to_string());
    assert_eq!(
        b["attempts"][1]["critical_failures"],
        json!(["no_intravascular_injection"])
    );
    let cem = learner("coh-cem@example.org");
    assert_eq!(cem["competency"]["status"], "too_few_attempts");
    assert_eq!(
        cem["attempts"][1]["score"],
        Value::Null,
        "the open attempt is on the curve unscored"
    );
    // The band: three learners' first scored attempts; Ann alone has a fourth.
    assert_eq!(c["band"][0]["n"], 1);
    assert_eq!(c["band"][0]["learners"], 3);
    assert_eq!(c["band"][3]["learners"], 1);
    let b0 = &c["band"][0];
    assert!(
        b0["p25"].as_f64() <= b0["median"].as_f64() && b0["median"].as_f64() <= b0["p75"].as_f64()
    );

    // Filters: one learner.
    let r = app
        .send(
            Method::GET,
            &format!("{path}&learner_id={bob}"),
            Some(&fs),
            None,
        )
        .await;
    assert_eq!(r.json["learners"].as_array().unwrap().len(), 1);
    assert_eq!(r.json["attempts"], 3);
    assert_eq!(
        r.json["band"], c["band"],
        "the band stays the whole cohort's"
    );
    let r = app
        .send(
            Method::GET,
            &format!("{path}&mode=assessment"),
            Some(&fs),
            None,
        )
        .await;
    assert_eq!(r.json["attempts"], 0, "every attempt ran in practice");

    // CSV: a header and one row per attempt, criteria as columns.
    let r = app
        .send(
            Method::GET,
            &format!("/api/courses/{course}/cohort.csv?station_id={STATION}"),
            Some(&fs),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::OK);
    let lines: Vec<&str> = r.text.split("\r\n").filter(|l| !l.is_empty()).collect();
    assert_eq!(lines.len(), 10, "{}", r.text);
    assert!(lines[0].contains("\"criterion:no_intravascular_injection\""));
    assert!(
        lines
            .iter()
            .any(|l| l.contains("\"no_intravascular_injection\"") && l.contains("\"not_met\"")),
        "{}",
        r.text
    );

    // Who may read it: not learners, not another course's faculty; bad requests are 400/404.
    let r = app.send(Method::GET, &path, Some(ann_s), None).await;
    assert_eq!(r.status, StatusCode::FORBIDDEN);
    let os = app.login("coh-outsider@example.org", None).await;
    let r = app.send(Method::GET, &path, Some(&os), None).await;
    assert_eq!(r.status, StatusCode::NOT_FOUND);
    for (q, status) in [
        ("", StatusCode::BAD_REQUEST),
        ("?station_id=nope", StatusCode::NOT_FOUND),
        (
            &format!("?station_id={STATION}&mode=exam") as &str,
            StatusCode::BAD_REQUEST,
        ),
        (
            &format!("?station_id={STATION}&learner_id=x") as &str,
            StatusCode::BAD_REQUEST,
        ),
        (
            &format!("?station_id={STATION}&extra=1") as &str,
            StatusCode::BAD_REQUEST,
        ),
    ] {
        let r = app
            .send(
                Method::GET,
                &format!("/api/courses/{course}/cohort{q}"),
                Some(&fs),
                None,
            )
            .await;
        assert_eq!(r.status, status, "{q}: {}", r.text);
    }
}
