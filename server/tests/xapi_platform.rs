//! The platform's own records as xAPI statements (`server::xapi::platform`): every record is
//! queued by a trigger in its own transaction, projected into statements once (deterministic ids),
//! and enqueued for forwarding.

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};
use server::xapi::platform::{Projector, statement_id, verbs};

use crate::records_support::{TestApp, World};

const PUBLIC: &str = "https://sim.example.org";

async fn forwarded(app: &TestApp) -> Vec<Value> {
    sqlx::query_scalar("SELECT payload FROM outbox WHERE kind = 'xapi-forward' ORDER BY id")
        .fetch_all(app.pool())
        .await
        .unwrap()
}

fn by_verb<'a>(statements: &'a [Value], verb: &str) -> Vec<&'a Value> {
    statements
        .iter()
        .filter(|s| s["verb"]["id"] == verb)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn records_become_statements_once_with_registration_and_results() {
    let app = TestApp::new(&[]).await;
    let w = World::build(&app, "xp").await;
    let learner = w.sessions[1].as_ref().unwrap();
    let faculty = w.sessions[3].as_ref().unwrap();
    for (kind, detail) in [
        ("page_viewed", json!({ "page": "briefing" })),
        ("image_acquired", json!({ "shot": 1 })),
        ("session_launched", json!({})),
    ] {
        let r = app
            .send(
                Method::POST,
                &format!("/api/attempts/{}/activity", w.attempt_open),
                Some(learner),
                Some(json!({ "kind": kind, "detail": detail })),
            )
            .await;
        assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
    }
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{}/review", w.attempt_submitted),
            Some(faculty),
            Some(json!({ "decision": "approve", "comment": "Clean approach." })),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let queued: i64 = sqlx::query_scalar("SELECT count(*) FROM xapi_projection_queue")
        .fetch_one(app.pool())
        .await
        .unwrap();
    let projector = Projector::new(app.pool().clone(), PUBLIC, None);
    let settled = projector.drain().await.unwrap();
    assert_eq!(settled, usize::try_from(queued).unwrap());
    assert_eq!(projector.drain().await.unwrap(), 0, "the queue is empty");
    let all = forwarded(&app).await;
    // Two attempts opened (2 x initialized), one submission (terminated), 3 posted events, one
    // scored result, one approval.
    assert_eq!(all.len(), 8, "{all:#?}");
    assert_eq!(by_verb(&all, verbs::INITIALIZED).len(), 2);
    assert_eq!(by_verb(&all, verbs::TERMINATED).len(), 1);
    assert_eq!(by_verb(&all, verbs::LAUNCHED).len(), 1);
    assert_eq!(by_verb(&all, verbs::INTERACTED).len(), 1);
    assert!(
        all.iter()
            .all(|s| s["verb"]["id"] != "http://adlnet.gov/expapi/verbs/completed")
    );

    let page = by_verb(&all, verbs::EXPERIENCED);
    assert_eq!(page.len(), 1, "reading is `experienced`");
    let page = page[0];
    assert_eq!(
        page["object"]["id"],
        format!("{PUBLIC}/xapi/activities/station/l4-l5-left-facet/page/briefing")
    );
    assert_eq!(
        page["context"]["contextActivities"]["parent"][0]["id"],
        format!("{PUBLIC}/xapi/activities/station/l4-l5-left-facet")
    );
    assert_eq!(page["context"]["registration"], w.attempt_open.to_string());
    assert_eq!(
        page["actor"],
        json!({ "objectType": "Agent", "account": { "homePage": PUBLIC, "name": w.learner.to_string() } })
    );

    let scored = by_verb(&all, verbs::SCORED);
    assert_eq!(scored.len(), 1);
    let scored = scored[0];
    let result_id: uuid::Uuid =
        sqlx::query_scalar("SELECT id FROM technical_results WHERE attempt_id = $1")
            .bind(w.attempt_submitted)
            .fetch_one(app.pool())
            .await
            .unwrap();
    assert_eq!(
        scored["id"],
        statement_id("technical_result", &result_id.to_string()).to_string()
    );
    assert_eq!(
        scored["context"]["registration"],
        w.attempt_submitted.to_string()
    );
    assert_eq!(scored["result"]["success"], true, "every criterion met");
    let score = &scored["result"]["score"];
    assert_eq!(
        (score["min"].as_f64(), score["max"].as_f64()),
        (Some(0.0), Some(1.0))
    );
    assert_eq!(score["scaled"], score["raw"]);
    let ext = |k: &str| format!("{PUBLIC}/xapi/extensions/{k}");
    assert_eq!(scored["result"]["extensions"][ext("incomplete")], false);
    assert!(
        scored["result"]["extensions"][ext("criteria")]
            .as_array()
            .unwrap()
            .len()
            >= 5
    );
    let repro = &scored["context"]["extensions"][ext("reproducibility")];
    for k in [
        "code_revision",
        "server_version",
        "asset_hashes",
        "device_profile",
        "imaging_settings",
        "station_sha256",
    ] {
        assert!(
            !repro[k].is_null(),
            "reproducibility record lacks {k}: {repro}"
        );
    }

    let approved = by_verb(&all, verbs::APPROVE);
    assert_eq!(approved.len(), 1);
    let approved = approved[0];
    assert_eq!(
        approved["actor"]["account"]["name"],
        w.faculty_a.to_string(),
        "by the faculty member"
    );
    assert_eq!(
        approved["object"],
        json!({ "objectType": "StatementRef", "id": scored["id"] })
    );
    assert_eq!(approved["result"]["response"], "Clean approach.");
    assert_eq!(
        approved["context"]["registration"],
        w.attempt_submitted.to_string()
    );

    // Re-projecting a record (e.g. after a crash between its statements and the queue delete, or
    // by hand) produces the same ids: nothing new is forwarded.
    sqlx::query("INSERT INTO xapi_projection_queue (source, record_id) SELECT 'technical_result', id::text FROM technical_results")
        .execute(app.pool())
        .await
        .unwrap();
    projector.drain().await.unwrap();
    assert_eq!(forwarded(&app).await.len(), 8);
    let ids: std::collections::HashSet<&str> =
        all.iter().map(|s| s["id"].as_str().unwrap()).collect();
    assert_eq!(ids.len(), 8, "distinct statement ids");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_result_that_does_not_replay_is_voided_and_incomplete_results_are_flagged() {
    let app = TestApp::new(&[]).await;
    let w = World::build(&app, "xv").await;
    // An incomplete result: only some measurements.
    let r = app
        .submit(
            w.learner,
            w.attempt_open,
            json!({ "tip_to_target_mm": 1.5 }),
        )
        .await;
    assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
    let incomplete_id = r.json["id"].as_str().unwrap().to_owned();
    let projector = Projector::new(app.pool().clone(), PUBLIC, None);
    projector.drain().await.unwrap();
    let ext = |k: &str| format!("{PUBLIC}/xapi/extensions/{k}");
    let all = forwarded(&app).await;
    let incomplete = all
        .iter()
        .find(|s| s["id"] == statement_id("technical_result", &incomplete_id).to_string())
        .expect("the incomplete result's statement");
    assert!(
        incomplete["result"].get("success").is_none(),
        "no success for an incomplete rubric"
    );
    assert_eq!(incomplete["result"]["extensions"][ext("incomplete")], true);
    assert!(
        !incomplete["result"]["extensions"][ext("incomplete-criteria")]
            .as_array()
            .unwrap()
            .is_empty()
    );

    let submitted: uuid::Uuid =
        sqlx::query_scalar("SELECT id FROM technical_results WHERE attempt_id = $1")
            .bind(w.attempt_submitted)
            .fetch_one(app.pool())
            .await
            .unwrap();
    sqlx::query("INSERT INTO result_replay_checks (result_id, verdict) VALUES ($1, 'identical'), ($1, 'differs')")
        .bind(submitted)
        .execute(app.pool())
        .await
        .unwrap();
    projector.drain().await.unwrap();
    let all = forwarded(&app).await;
    let voided = by_verb(&all, verbs::VOIDED);
    assert_eq!(
        voided.len(),
        1,
        "only the `differs` check corrects the record"
    );
    assert_eq!(
        voided[0]["object"],
        json!({ "objectType": "StatementRef", "id": statement_id("technical_result", &submitted.to_string()) })
    );
}

/// Counts every row of the projection queue.
async fn queue_len(app: &TestApp) -> i64 {
    sqlx::query_scalar("SELECT count(*) FROM xapi_projection_queue")
        .fetch_one(app.pool())
        .await
        .unwrap()
}

/// Counts the queue rows of one activity event, so a test can tell its own record's row apart
/// from those the world's fixtures queued.
async fn queued_rows(app: &TestApp, event: i64) -> i64 {
    sqlx::query_scalar(
        "SELECT count(*) FROM xapi_projection_queue \
         WHERE source = 'activity_event' AND record_id = $1",
    )
    .bind(event.to_string())
    .fetch_one(app.pool())
    .await
    .unwrap()
}

/// Inserts one `injection` event in its own transaction and commits or rolls it back.
async fn insert_event(app: &TestApp, w: &World, commit: bool) -> i64 {
    let mut tx = app.pool().begin().await.unwrap();
    let id: i64 = sqlx::query_scalar(
        "INSERT INTO activity_events (attempt_id, user_id, kind) \
         VALUES ($1, $2, 'injection') RETURNING id",
    )
    .bind(w.attempt_open)
    .bind(w.learner)
    .fetch_one(&mut *tx)
    .await
    .unwrap();
    if commit {
        tx.commit().await.unwrap();
    } else {
        tx.rollback().await.unwrap();
    }
    id
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rolled_back_record_is_never_projected() {
    let app = TestApp::new(&[]).await;
    let w = World::build(&app, "xr").await;

    // Positive control: the same insert, committed, is queued by its trigger. Without it the
    // rollback check below would pass even if nothing were ever queued.
    let before = queue_len(&app).await;
    let kept = insert_event(&app, &w, true).await;
    assert_eq!(
        queue_len(&app).await,
        before + 1,
        "a committed record is queued once"
    );
    assert_eq!(
        queued_rows(&app, kept).await,
        1,
        "the queued row is this record's"
    );

    let before = queue_len(&app).await;
    let dropped = insert_event(&app, &w, false).await;
    assert_eq!(
        queue_len(&app).await,
        before,
        "a rolled-back record leaves no queue row"
    );
    assert_eq!(queued_rows(&app, dropped).await, 0);

    // The projector turns the committed record into a statement and nothing into one for the
    // rolled-back record.
    Projector::new(app.pool().clone(), PUBLIC, None)
        .drain()
        .await
        .unwrap();
    let ids: Vec<Value> = forwarded(&app)
        .await
        .into_iter()
        .map(|s| s["id"].clone())
        .collect();
    let id_of = |event: i64| json!(statement_id("activity_event", &event.to_string()));
    assert!(
        ids.contains(&id_of(kept)),
        "the committed record is projected: {ids:?}"
    );
    assert!(
        !ids.contains(&id_of(dropped)),
        "the rolled-back record is not projected"
    );
}
