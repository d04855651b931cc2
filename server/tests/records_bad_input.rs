//! Bad input: malformed JSON, wrong types, unknown fields, oversized bodies, unknown or malformed
//! ids, bad filters. Each gets a 4xx with a JSON error body whose message says what is wrong, no
//! request gets a 5xx, and no stored row changes.

use axum::http::{Method, StatusCode};
use serde_json::json;

use crate::records_support::{TestApp, World, reproducibility};

/// (who, method, uri, content type, body, expected status, fragment of the error message)
type Case<'a> = (
    &'a crate::records_support::Session,
    Method,
    String,
    &'a str,
    Vec<u8>,
    u16,
    &'a str,
);

#[tokio::test]
async fn bad_requests_get_clear_4xx_and_change_nothing() {
    let app = TestApp::new(&[("PAINSIM_MAX_BODY_BYTES", "65536")]).await;
    let w = World::build(&app, "bad").await;
    let learner = w.sessions[1].clone().unwrap();
    let faculty = w.sessions[3].clone().unwrap();
    let admin = w.sessions[5].clone().unwrap();
    let open = w.attempt_open;
    let unknown = uuid::Uuid::new_v4();
    let activity = format!("/api/attempts/{open}/activity");
    let results = format!("/api/attempts/{open}/results");
    let huge = format!(
        "{{\"kind\":\"injection\",\"detail\":{{\"x\":\"{}\"}}}}",
        "a".repeat(70_000)
    );
    let deep_detail = json!({ "kind": "injection", "detail": { "x": "b".repeat(5000) } });

    let table: Vec<Case<'_>> = vec![
        (&learner, Method::POST, activity.clone(), "application/json", b"{\"kind\": ".to_vec(), 400, "invalid JSON"),
        (&learner, Method::POST, activity.clone(), "application/json", b"[1, 2]".to_vec(), 400, "invalid JSON"),
        (&learner, Method::POST, activity.clone(), "application/json", br#"{"kind": 7}"#.to_vec(), 400, "kind"),
        (&learner, Method::POST, activity.clone(), "application/json", br#"{"kind": "teleport"}"#.to_vec(), 400, "unknown variant `teleport`"),
        (&learner, Method::POST, activity.clone(), "application/json", br#"{"kind": "injection", "extra": 1}"#.to_vec(), 400, "unknown field `extra`"),
        (&learner, Method::POST, activity.clone(), "application/json", br#"{"kind": "injection", "detail": [1]}"#.to_vec(), 400, "detail must be a JSON object"),
        (&learner, Method::POST, activity.clone(), "application/json", deep_detail.to_string().into_bytes(), 400, "at most 4096 bytes"),
        (&learner, Method::POST, activity.clone(), "application/json", br#"{"kind": "injection", "client_time": "yesterday"}"#.to_vec(), 400, "client_time"),
        (&learner, Method::POST, activity.clone(), "text/plain", br#"{"kind": "injection"}"#.to_vec(), 400, "Content-Type: application/json"),
        (&learner, Method::POST, activity.clone(), "application/json", huge.into_bytes(), 413, "65536 bytes"),
        (&learner, Method::POST, format!("/api/attempts/{unknown}/activity"), "application/json", br#"{"kind": "injection"}"#.to_vec(), 404, "attempt not found"),
        (&learner, Method::POST, "/api/attempts/not-a-uuid/activity".into(), "application/json", br#"{"kind": "injection"}"#.to_vec(), 400, "invalid path parameter"),
        // Results come only from the simulation: there is no route that takes them from a client.
        (&learner, Method::POST, results.clone(), "application/json", json!({ "measurements": { "tip_to_target_mm": 0.0 }, "reproducibility": reproducibility() }).to_string().into_bytes(), 404, "API endpoint not found"),
        (&admin, Method::POST, results.clone(), "application/json", br#"{"measurements": {}}"#.to_vec(), 404, "API endpoint not found"),
        (&learner, Method::POST, "/api/attempts".into(), "application/json", json!({ "course_id": w.course_a, "station_id": "no-such-station" }).to_string().into_bytes(), 404, "station \"no-such-station\" not found"),
        (&learner, Method::POST, "/api/attempts".into(), "application/json", json!({ "course_id": unknown, "station_id": "l4-l5-left-facet" }).to_string().into_bytes(), 404, "course not found"),
        (&learner, Method::POST, "/api/attempts".into(), "application/json", json!({ "course_id": "12", "station_id": "l4-l5-left-facet" }).to_string().into_bytes(), 400, "course_id"),
        (&faculty, Method::POST, format!("/api/attempts/{unknown}/review"), "application/json", br#"{"decision": "approve"}"#.to_vec(), 404, "not found"),
        (&faculty, Method::POST, format!("/api/attempts/{}/review", w.attempt_submitted), "application/json", br#"{"decision": "maybe"}"#.to_vec(), 400, "unknown variant `maybe`"),
        (&faculty, Method::POST, format!("/api/attempts/{}/review", w.attempt_submitted), "application/json", json!({ "decision": "approve", "comment": "c".repeat(4001) }).to_string().into_bytes(), 400, "at most 4000"),
        (&faculty, Method::POST, format!("/api/attempts/{open}/review"), "application/json", br#"{"decision": "approve"}"#.to_vec(), 409, "in_progress"),
        (&faculty, Method::POST, "/api/reviews/bulk-approve".into(), "application/json", br#"{"attempt_ids": []}"#.to_vec(), 400, "1 to 200"),
        (&faculty, Method::POST, "/api/reviews/bulk-approve".into(), "application/json", json!({ "attempt_ids": [w.attempt_submitted, w.attempt_submitted] }).to_string().into_bytes(), 400, "listed twice"),
        (&faculty, Method::POST, "/api/reviews/bulk-approve".into(), "application/json", json!({ "attempt_ids": [w.attempt_submitted, unknown] }).to_string().into_bytes(), 404, "not found"),
        (&faculty, Method::GET, "/api/reviews?state=lost".into(), "", vec![], 400, "not one of"),
        (&faculty, Method::GET, "/api/reviews?course_id=xyz".into(), "", vec![], 400, "invalid query parameter"),
        (&faculty, Method::GET, "/api/reviews?colour=red".into(), "", vec![], 400, "unknown field `colour`"),
        (&admin, Method::GET, "/api/audit?limit=0".into(), "", vec![], 400, "limit"),
        (&admin, Method::POST, "/api/users".into(), "application/json", br#"{"email": "not-an-address", "display_name": "x", "role": "learner", "password": "long-enough-password"}"#.to_vec(), 400, "not an e-mail address"),
        (&admin, Method::POST, "/api/users".into(), "application/json", br#"{"email": "a@b.org", "display_name": "x", "role": "learner", "password": "short"}"#.to_vec(), 400, "at least 12 characters"),
        (&admin, Method::POST, "/api/users".into(), "application/json", br#"{"email": "a@b.org", "display_name": "x", "role": "superuser", "password": "long-enough-password"}"#.to_vec(), 400, "unknown variant `superuser`"),
        (&admin, Method::POST, "/api/users".into(), "application/json", json!({ "email": w.learner_email, "display_name": "x", "role": "learner", "password": "long-enough-password" }).to_string().into_bytes(), 409, "already exists"),
        (&admin, Method::PUT, format!("/api/courses/{}/members/{unknown}", w.course_a), "application/json", br#"{"role": "learner"}"#.to_vec(), 404, "user not found"),
        (&admin, Method::PUT, format!("/api/courses/{unknown}/members/{}", w.outsider), "application/json", br#"{"role": "learner"}"#.to_vec(), 404, "course not found"),
        (&admin, Method::PUT, format!("/api/courses/{}/members/{}", w.course_a, w.outsider), "application/json", br#"{"role": "faculty"}"#.to_vec(), 400, "cannot be faculty"),
        (&admin, Method::GET, "/api/stations/nope".into(), "", vec![], 404, "not found"),
        (&admin, Method::POST, "/api/courses".into(), "application/json", br#"{"code": "", "title": "t"}"#.to_vec(), 400, "code needs"),
    ];
    let before = app.counts().await;
    let mut failures = Vec::new();
    for (i, (who, method, uri, ct, body, status, fragment)) in table.iter().enumerate() {
        let body = if ct.is_empty() {
            None
        } else {
            Some((*ct, body.clone()))
        };
        let r = app.send_raw(method.clone(), uri, Some(who), body).await;
        let message = r.json["error"]["message"].as_str().unwrap_or("");
        if r.status.as_u16() != *status
            || !message.contains(fragment)
            || r.json["error"]["code"].as_str().is_none()
        {
            failures.push(format!(
                "row {i}: {method} {uri}: {} {} (want {status} containing {fragment:?})",
                r.status,
                r.text.chars().take(300).collect::<String>()
            ));
        }
        assert!(
            r.status.as_u16() < 500,
            "row {i}: {method} {uri} answered {}",
            r.status
        );
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert_eq!(
        app.counts().await,
        before,
        "a rejected request changed stored data"
    );
    // Database details never reach the client.
    let r = app
        .send(Method::GET, "/api/reviews?state=lost", Some(&faculty), None)
        .await;
    assert!(!r.text.to_lowercase().contains("sql"), "{}", r.text);
    assert_eq!(r.status, StatusCode::BAD_REQUEST);
}
