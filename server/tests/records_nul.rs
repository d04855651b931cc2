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
    let cases = [
        (
            None,
            "/api/auth/login".to_string(),
            json!({ "email": "nul-learner@example.org\u{0}", "password": "x" }),
            "email",
        ),
        (
            Some(&s),
            format!("/api/attempts/{attempt}/activity"),
            json!({ "kind": "injection", "detail": { "note": "a\u{0}b" } }),
            "detail.note",
        ),
        (
            Some(&s),
            format!("/api/attempts/{attempt}/activity"),
            json!({ "kind": "injection", "detail": { "k\u{0}": 1 } }),
            "detail.k\\u0000 (a key)",
        ),
    ];
    for (session, uri, body, field) in cases {
        let r = app.send(Method::POST, &uri, session, Some(body)).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{uri}: {}", r.text);
        let message = r.json["error"]["message"].as_str().unwrap_or_default();
        assert!(
            message.starts_with(&format!("{field}: ")),
            "{uri}: {message}"
        );
        assert!(message.contains("NUL"), "{message}");
    }
    // Nothing was stored, and the same requests without the NUL go through.
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{attempt}/activity"),
            Some(&s),
            Some(json!({ "kind": "injection", "detail": { "note": "ab" } })),
        )
        .await;
    assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
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
