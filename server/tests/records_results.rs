//! The result path from a simulation session: the server's rubric evaluation
//! is the authority, a worker whose own evaluation differs stores nothing, impossible
//! measurements are refused, and no client of any role can post a result.

use axum::http::{Method, StatusCode};
use serde_json::json;
use server::records::RecordsState;
use server::records::auth::Role;
use server::records::results::{NewResult, store_session_result};
use sim_core::rubric::{Measurements, Outcome, Station};

use crate::records_support::{TestApp, World, facet_measurements_met, reproducibility};

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
    let e = store_session_result(&state, learner, attempt, req.clone(), &forged)
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
    let view = store_session_result(&state, learner, attempt, req, &honest)
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

/// A forged result posted by any identity (anonymous, both learners, both faculty, the admin)
/// to any attempt is refused, whatever the body claims, and nothing is stored: results come only
/// from the simulation.
#[tokio::test]
async fn no_client_of_any_role_can_post_a_result() {
    let app = TestApp::new(&[]).await;
    let w = World::build(&app, "forge").await;
    let before = app.counts().await;
    let perfect = json!({ "measurements": facet_measurements_met(), "reproducibility": reproducibility() });
    let absurd = json!({ "measurements": { "tip_to_target_mm": -1e308 }, "reproducibility": reproducibility() });
    for attempt in [w.attempt_open, w.attempt_submitted] {
        for (i, session) in w.sessions.iter().enumerate() {
            for body in [&perfect, &absurd] {
                for method in [Method::POST, Method::PUT, Method::PATCH] {
                    let path = format!("/api/attempts/{attempt}/results");
                    let r = app.send(method.clone(), &path, session.as_ref(), Some(body.clone())).await;
                    assert!(
                        [StatusCode::FORBIDDEN, StatusCode::NOT_FOUND, StatusCode::METHOD_NOT_ALLOWED]
                            .contains(&r.status),
                        "{method} {path} as {}: {} {}",
                        crate::records_support::ROLES[i],
                        r.status,
                        r.text
                    );
                }
            }
        }
    }
    assert_eq!(app.counts().await, before, "nothing stored changed");
    // The OpenAPI document offers no way to post a result either.
    let doc = app.send(Method::GET, "/api/openapi.json", None, None).await.json;
    for (path, item) in doc["paths"].as_object().unwrap() {
        if path.contains("result") {
            assert!(item.get("post").is_none() && item.get("put").is_none(), "{path}");
        }
    }
}

/// Measurements outside their physical range are refused by the rubric engine's check even when
/// the worker claims them (a bug or a forged worker), and nothing is stored.
#[tokio::test]
async fn impossible_session_measurements_are_refused_and_nothing_is_stored() {
    let app = TestApp::new(&[]).await;
    let w = World::build(&app, "range").await;
    let before = app.counts().await;
    for (key, value) in [("tip_to_target_mm", -1e308), ("tip_to_target_mm", -0.5), ("fluoro_acquisitions_count", -3.0)] {
        let mut m = facet_measurements_met();
        m[key] = json!(value);
        let r = app.submit(w.learner, w.attempt_open, m).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{key}={value}: {}", r.text);
        assert!(r.text.contains(key) && r.text.contains("physical range"), "{}", r.text);
    }
    assert_eq!(app.counts().await, before, "nothing stored changed");
}
