//! NUL in client text or JSON: PostgreSQL stores no NUL in text or jsonb,
//! so every body holding one is refused with 400 naming the field, never a 500.

use axum::http::{Method, StatusCode};
use serde_json::json;
use server::records::auth::Role;

use crate::records_support::TestApp;

#[tokio::test]
async fn nul_in_a_json_body_is_a_400_naming_the_field() {
    let app = TestApp::new(&[]).await;
    let learner = app.user("nul-learner@example.org", Role::Learner).await;
    let course = app.course("NUL-1").await;
    app.member(course, learner, "learner").await;
    let s = app.login("nul-learner@example.org", None).await;
    let attempt = app.open_attempt(&s, course, "l4-l5-left-facet").await;
    // Each case names the table its request writes when it is accepted: a failed login is
    // recorded in `login_failures` (the password is wrong), an event in `activity_events`.
    let cases = [
        (
            None,
            "/api/auth/login".to_string(),
            json!({ "email": "nul-learner@example.org\u{0}", "password": "x" }),
            "email",
            "login_failures",
        ),
        (
            Some(&s),
            format!("/api/attempts/{attempt}/activity"),
            json!({ "kind": "injection", "detail": { "note": "a\u{0}b" } }),
            "detail.note",
            "activity_events",
        ),
        (
            Some(&s),
            format!("/api/attempts/{attempt}/activity"),
            json!({ "kind": "injection", "detail": { "k\u{0}": 1 } }),
            "detail.k\\u0000 (a key)",
            "activity_events",
        ),
    ];
    for (session, uri, body, field, table) in cases {
        let before = rows(&app, table).await;
        let r = app.send(Method::POST, &uri, session, Some(body)).await;
        assert_eq!(
            rows(&app, table).await,
            before,
            "{uri}: a refused body stored a row in {table} ({})",
            r.status
        );
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{uri}: {}", r.text);
        let message = r.json["error"]["message"].as_str().unwrap_or_default();
        assert!(
            message.starts_with(&format!("{field}: ")),
            "{uri}: {message}"
        );
        assert!(message.contains("NUL"), "{message}");
    }
    // The same requests without the NUL go through and are stored (so the counts above would
    // have seen a stored row).
    for (session, uri, body, status, table) in [
        (
            None,
            "/api/auth/login".to_string(),
            json!({ "email": "nul-learner@example.org", "password": "x" }),
            StatusCode::UNAUTHORIZED,
            "login_failures",
        ),
        (
            Some(&s),
            format!("/api/attempts/{attempt}/activity"),
            json!({ "kind": "injection", "detail": { "note": "ab" } }),
            StatusCode::CREATED,
            "activity_events",
        ),
    ] {
        let before = rows(&app, table).await;
        let r = app.send(Method::POST, &uri, session, Some(body)).await;
        assert_eq!(r.status, status, "{uri}: {}", r.text);
        assert_eq!(rows(&app, table).await, before + 1, "{uri}: {}", r.text);
    }
}

/// Counts the rows of one of the tables the requests above write.
async fn rows(app: &TestApp, table: &str) -> i64 {
    sqlx::query_scalar(&format!("SELECT count(*) FROM {table}"))
        .fetch_one(app.pool())
        .await
        .unwrap()
}

/// Found by the OpenAPI fuzz test: a NUL in a query filter reached the database (500).
#[tokio::test]
async fn nul_in_a_query_parameter_is_a_400_naming_it() {
    let app = TestApp::new(&[]).await;
    let admin = app.user("nul-admin@example.org", Role::Admin).await;
    let secret = app.enable_totp(admin).await;
    let code = server::records::totp::code_at(&secret, server::records::totp::unix_now());
    let s = app.login("nul-admin@example.org", Some(code)).await;
    for (uri, field) in [
        ("/api/reviews?station_id=a%00b", "station_id"),
        (
            "/api/reviews/export.csv?state=any&station_id=%00",
            "station_id",
        ),
        ("/api/audit?object_type=attempt&object_id=x%00", "object_id"),
        ("/api/audit?object_type=%00", "object_type"),
    ] {
        let r = app.send(Method::GET, uri, Some(&s), None).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{uri}: {}", r.text);
        let message = r.json["error"]["message"].as_str().unwrap_or_default();
        assert!(
            message.starts_with(&format!("{field}: ")),
            "{uri}: {message}"
        );
        assert!(message.contains("NUL"), "{message}");
    }
    let r = app
        .send(
            Method::GET,
            "/api/audit?object_type=attempt",
            Some(&s),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
}
