//! The result path from a simulation session (issue 14): the server's rubric evaluation is the
//! authority, and a worker whose own evaluation differs stores nothing.

use axum::http::{Method, StatusCode};
use serde_json::json;
use server::records::RecordsState;
use server::records::auth::Role;
use server::records::results::{NewResult, ResultSource, submit_result_for};
use sim_core::rubric::{Measurements, Outcome, Station};

use crate::records_support::{TestApp, facet_measurements_met, reproducibility};

#[tokio::test]
async fn a_session_result_is_stored_only_when_the_workers_rubric_equals_the_servers() {
    let app = TestApp::new(&[]).await;
    let learner = app.user("results-learner@example.org", Role::Learner).await;
    let course = app.course("RES-1").await;
    app.member(course, learner, "learner").await;
    let ls = app.login("results-learner@example.org", None).await;
    let attempt = app.open_attempt(&ls, course, "l4-l5-left-facet").await;
    let state = RecordsState::from_parts(app.pool().clone(), app.config.clone());
    let req: NewResult = serde_json::from_value(json!({
        "measurements": facet_measurements_met(),
        "reproducibility": reproducibility(),
    }))
    .unwrap();
    // What the worker would have computed: the same station's rubric on the same measurements.
    let station_file = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../assets/stations/l4-l5-left-facet.toml"),
    )
    .unwrap();
    let station = Station::from_toml_str(&station_file).unwrap();
    let measurements: Measurements = req.measurements.clone();
    let honest = station.evaluate(&measurements);
    assert_eq!(honest.outcome, Outcome::Met);

    // A worker that claims another outcome: refused, nothing stored, the attempt stays open.
    let mut forged = honest.clone();
    forged.score = forged.score.map(|s| s - 0.25);
    forged.outcome = Outcome::NotMet;
    let e = submit_result_for(
        &state,
        learner,
        attempt,
        req.clone(),
        ResultSource::Session {
            worker_rubric: &forged,
        },
    )
    .await
    .unwrap_err();
    // Internal: logged with both results, never shown to the client in detail.
    assert!(
        matches!(&e, server::ApiError::Internal(m) if m.contains("differs")),
        "{e:?}"
    );
    let stored: i64 =
        sqlx::query_scalar("SELECT count(*) FROM technical_results WHERE attempt_id = $1")
            .bind(attempt)
            .fetch_one(app.pool())
            .await
            .unwrap();
    assert_eq!(stored, 0);
    let r = app
        .send(
            Method::GET,
            &format!("/api/attempts/{attempt}"),
            Some(&ls),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(r.json["attempt"]["state"], "in_progress", "{}", r.text);

    // The honest worker's result is stored, with the server's evaluation, as a server result.
    let view = submit_result_for(
        &state,
        learner,
        attempt,
        req,
        ResultSource::Session {
            worker_rubric: &honest,
        },
    )
    .await
    .unwrap();
    assert_eq!(view.outcome, "met");
    let source: String =
        sqlx::query_scalar("SELECT source FROM technical_results WHERE attempt_id = $1")
            .bind(attempt)
            .fetch_one(app.pool())
            .await
            .unwrap();
    assert_eq!(source, "server");
}
