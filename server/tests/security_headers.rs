//! Security headers on every response and a JSON 404 for unknown API paths: one test per
//! header, over the web client's page, a public API route, an
//! authenticated API route and an error.

use axum::http::{Method, StatusCode};
use server::records::auth::Role;
use server::routes::headers::{
    CONTENT_SECURITY_POLICY_VALUE, HSTS_VALUE, PERMISSIONS_POLICY_VALUE,
};

use crate::records_support::{Response, TestApp};

/// The page, `/healthz`, an authenticated API answer and an API error.
async fn samples(app: &TestApp) -> Vec<(&'static str, Response)> {
    app.user("headers-learner@example.org", Role::Learner).await;
    let s = app.login("headers-learner@example.org", None).await;
    vec![
        ("page", app.send(Method::GET, "/", None, None).await),
        (
            "health",
            app.send(Method::GET, "/healthz", None, None).await,
        ),
        ("me", app.send(Method::GET, "/api/me", Some(&s), None).await),
        (
            "unauthenticated",
            app.send(Method::GET, "/api/attempts", None, None).await,
        ),
    ]
}

fn header<'a>(r: &'a Response, name: &str) -> Option<&'a str> {
    r.headers.get(name).and_then(|v| v.to_str().ok())
}

#[tokio::test]
async fn content_security_policy_allows_only_our_origin_and_no_framing() {
    let app = TestApp::new(&[]).await;
    for (what, r) in samples(&app).await {
        let csp = header(&r, "content-security-policy").unwrap_or_else(|| panic!("{what}"));
        assert_eq!(csp, CONTENT_SECURITY_POLICY_VALUE, "{what}");
        for directive in [
            "default-src 'self'",
            "script-src 'self'",
            "connect-src 'self'",
            "frame-ancestors 'none'",
            "object-src 'none'",
        ] {
            assert!(csp.contains(directive), "{what}: {directive}");
        }
        assert!(!csp.contains("unsafe-inline") && !csp.contains("unsafe-eval"));
    }
}

#[tokio::test]
async fn nosniff_referrer_and_permissions_policies_are_on_every_response() {
    let app = TestApp::new(&[]).await;
    for (what, r) in samples(&app).await {
        assert_eq!(
            header(&r, "x-content-type-options"),
            Some("nosniff"),
            "{what}"
        );
        assert_eq!(header(&r, "referrer-policy"), Some("no-referrer"), "{what}");
        assert_eq!(
            header(&r, "permissions-policy"),
            Some(PERMISSIONS_POLICY_VALUE),
            "{what}"
        );
    }
}

#[tokio::test]
async fn api_responses_are_not_stored_and_the_page_may_be() {
    let app = TestApp::new(&[]).await;
    for (what, r) in samples(&app).await {
        let cc = header(&r, "cache-control");
        match what {
            "me" | "unauthenticated" => assert_eq!(cc, Some("no-store"), "{what}"),
            _ => assert_ne!(cc, Some("no-store"), "{what}"),
        }
    }
}

#[tokio::test]
async fn hsts_only_where_the_deployment_serves_tls() {
    let plain = TestApp::new(&[]).await;
    for (what, r) in samples(&plain).await {
        assert_eq!(header(&r, "strict-transport-security"), None, "{what}");
    }
    let tls = TestApp::new(&[("PAINSIM_COOKIE_SECURE", "true")]).await;
    let r = tls.send(Method::GET, "/healthz", None, None).await;
    assert_eq!(header(&r, "strict-transport-security"), Some(HSTS_VALUE));
}

#[tokio::test]
async fn unknown_api_paths_get_a_json_404_not_the_page() {
    let app = TestApp::new(&[]).await;
    for path in ["/api/no-such-thing", "/api/attempts/x/y/z", "/api", "/api/"] {
        for method in [Method::GET, Method::POST, Method::DELETE] {
            let r = app.send(method.clone(), path, None, None).await;
            assert_eq!(
                r.status,
                StatusCode::NOT_FOUND,
                "{method} {path}: {}",
                r.text
            );
            assert_eq!(
                r.json["error"]["code"], "not_found",
                "{method} {path}: {}",
                r.text
            );
            assert!(
                header(&r, "content-type").is_some_and(|c| c.starts_with("application/json")),
                "{method} {path}"
            );
        }
    }
    // Known routes still answer; other paths still get the web client.
    let r = app.send(Method::GET, "/api/openapi.json", None, None).await;
    assert_eq!(r.status, StatusCode::OK);
    let r = app
        .send(Method::GET, "/some/client/route", None, None)
        .await;
    assert_eq!(r.status, StatusCode::OK);
    assert!(r.text.contains("<!doctype html>"));
}
