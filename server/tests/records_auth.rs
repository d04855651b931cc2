//! Sessions and login: cookie attributes, idle and absolute expiry, rotation, logout, per-account
//! throttling, per-client rate limiting, demo accounts.

use axum::http::{Method, StatusCode};
use serde_json::json;
use server::records::auth::Role;

use crate::records_support::{PASSWORD, TestApp};

fn cookies(r: &crate::records_support::Response) -> Vec<String> {
    r.headers
        .get_all("set-cookie")
        .iter()
        .map(|v| v.to_str().unwrap().to_owned())
        .collect()
}

#[tokio::test]
async fn cookies_expiry_rotation_and_logout() {
    let app = TestApp::new(&[
        ("PAINSIM_COOKIE_SECURE", "true"),
        ("PAINSIM_SESSION_IDLE_SECS", "600"),
        ("PAINSIM_SESSION_ABSOLUTE_SECS", "3600"),
    ])
    .await;
    app.user("u@example.org", Role::Learner).await;
    let r = app
        .send(
            Method::POST,
            "/api/auth/login",
            None,
            Some(json!({ "email": " U@Example.org ", "password": PASSWORD })),
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let set = cookies(&r);
    let session = set
        .iter()
        .find(|c| c.starts_with("painsim_session="))
        .unwrap();
    for attr in [
        "HttpOnly",
        "SameSite=Strict",
        "Secure",
        "Path=/",
        "Max-Age=3600",
    ] {
        assert!(session.contains(attr), "{session} lacks {attr}");
    }
    let csrf = set.iter().find(|c| c.starts_with("painsim_csrf=")).unwrap();
    assert!(
        !csrf.contains("HttpOnly") && csrf.contains("SameSite=Strict"),
        "{csrf}"
    );
    let s1 = crate::records_support::Session::from_login(&r);
    // Only the hash of the token is stored.
    let stored: Vec<u8> = sqlx::query_scalar("SELECT token_sha256 FROM auth_sessions")
        .fetch_one(app.pool())
        .await
        .unwrap();
    assert_eq!(stored.len(), 32);
    assert!(!hex::encode(&stored).contains(&s1.token));
    assert_eq!(
        app.send(Method::GET, "/api/auth/me", Some(&s1), None)
            .await
            .status,
        StatusCode::OK
    );

    // Rotation: logging in again with the old cookie replaces it.
    let r = app
        .send(
            Method::POST,
            "/api/auth/login",
            Some(&s1),
            Some(json!({ "email": "u@example.org", "password": PASSWORD })),
        )
        .await;
    let s2 = crate::records_support::Session::from_login(&r);
    assert_ne!(s1.token, s2.token);
    assert_ne!(s1.csrf, s2.csrf);
    assert_eq!(
        app.send(Method::GET, "/api/auth/me", Some(&s1), None)
            .await
            .status,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        app.send(Method::GET, "/api/auth/me", Some(&s2), None)
            .await
            .status,
        StatusCode::OK
    );

    // Idle expiry: a session unused for longer than the idle limit is refused (and not revived).
    sqlx::query("UPDATE auth_sessions SET last_seen_at = now() - interval '601 seconds'")
        .execute(app.pool())
        .await
        .unwrap();
    assert_eq!(
        app.send(Method::GET, "/api/auth/me", Some(&s2), None)
            .await
            .status,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        app.send(Method::GET, "/api/auth/me", Some(&s2), None)
            .await
            .status,
        StatusCode::UNAUTHORIZED
    );

    // Absolute expiry: even a session in constant use ends.
    let s3 = app.login("u@example.org", None).await;
    sqlx::query("UPDATE auth_sessions SET expires_at = now() - interval '1 second'")
        .execute(app.pool())
        .await
        .unwrap();
    assert_eq!(
        app.send(Method::GET, "/api/auth/me", Some(&s3), None)
            .await
            .status,
        StatusCode::UNAUTHORIZED
    );

    // Logout deletes the session and clears the cookies.
    let s4 = app.login("u@example.org", None).await;
    let r = app
        .send(Method::POST, "/api/auth/logout", Some(&s4), None)
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT);
    assert!(cookies(&r).iter().all(|c| c.contains("Max-Age=0")));
    assert_eq!(
        app.send(Method::GET, "/api/auth/me", Some(&s4), None)
            .await
            .status,
        StatusCode::UNAUTHORIZED
    );
}

#[tokio::test]
async fn failed_logins_are_throttled_per_account() {
    let app = TestApp::new(&[("PAINSIM_LOGIN_MAX_FAILURES", "3")]).await;
    app.user("t@example.org", Role::Learner).await;
    app.user("other@example.org", Role::Learner).await;
    let attempt = |email: &'static str, pw: &'static str| {
        let app = &app;
        async move {
            app.send(
                Method::POST,
                "/api/auth/login",
                None,
                Some(json!({ "email": email, "password": pw })),
            )
            .await
        }
    };
    for _ in 0..3 {
        let r = attempt("t@example.org", "wrong-password-000").await;
        assert_eq!(
            (r.status, r.json["error"]["code"].as_str()),
            (StatusCode::UNAUTHORIZED, Some("invalid_credentials"))
        );
    }
    // Now even the right password is refused, with Retry-After; other accounts are unaffected.
    let r = attempt("t@example.org", PASSWORD).await;
    assert_eq!(r.status, StatusCode::TOO_MANY_REQUESTS, "{}", r.text);
    assert!(r.headers.get("retry-after").is_some());
    assert_eq!(
        attempt("other@example.org", PASSWORD).await.status,
        StatusCode::OK
    );
    // Unknown accounts answer exactly like wrong passwords.
    let r = attempt("nobody@example.org", "whatever-password").await;
    assert_eq!(
        (r.status, r.json["error"]["message"].as_str()),
        (StatusCode::UNAUTHORIZED, Some("wrong e-mail or password"))
    );
    // After the window the account can log in again.
    sqlx::query("UPDATE login_failures SET at = at - interval '1 hour'")
        .execute(app.pool())
        .await
        .unwrap();
    assert_eq!(
        attempt("t@example.org", PASSWORD).await.status,
        StatusCode::OK
    );
}

#[tokio::test]
async fn auth_endpoints_are_rate_limited_per_client() {
    // Burst 4, then 1 per minute: the fifth request in a row is refused.
    let app = TestApp::new(&[
        ("PAINSIM_AUTH_RATE_PER_MINUTE", "1"),
        ("PAINSIM_AUTH_BURST", "4"),
    ])
    .await;
    app.user("r@example.org", Role::Learner).await;
    for i in 0..4 {
        let r = app
            .send(
                Method::POST,
                "/api/auth/login",
                None,
                Some(json!({ "email": "r@example.org", "password": PASSWORD })),
            )
            .await;
        assert_eq!(r.status, StatusCode::OK, "request {i}: {}", r.text);
    }
    let r = app
        .send(
            Method::POST,
            "/api/auth/login",
            None,
            Some(json!({ "email": "r@example.org", "password": PASSWORD })),
        )
        .await;
    assert_eq!(r.status, StatusCode::TOO_MANY_REQUESTS);
    assert_eq!(r.json["error"]["code"], "too_many_requests");
}

#[tokio::test]
async fn demo_accounts_are_marked_and_idempotent() {
    let app = TestApp::new(&[]).await;
    let cfg = app.config.clone();
    let notice = server::records::prepare(app.pool(), &cfg, true)
        .await
        .unwrap()
        .expect("embedded run has demo accounts");
    assert!(
        notice.contains("DEMO ACCOUNTS") && notice.contains("learner@demo.invalid"),
        "{notice}"
    );
    server::records::prepare(app.pool(), &cfg, true)
        .await
        .unwrap();
    let demo: i64 = sqlx::query_scalar(
        "SELECT count(*) FROM users WHERE is_demo AND email LIKE '%@demo.invalid'",
    )
    .fetch_one(app.pool())
    .await
    .unwrap();
    assert_eq!(demo, 4);
    let r = app.send(Method::POST, "/api/auth/login", None, Some(json!({ "email": "learner@demo.invalid", "password": server::records::demo::DEMO_PASSWORD }))).await;
    assert_eq!(r.status, StatusCode::OK);
    assert_eq!(r.json["user"]["is_demo"], true);
    // An external database gets no demo accounts.
    assert!(
        server::records::prepare(app.pool(), &cfg, false)
            .await
            .unwrap()
            .is_none()
    );
}

#[tokio::test]
async fn create_admin_makes_a_working_admin() {
    let app = TestApp::new(&[]).await;
    let u = server::records::users::create_admin(
        app.pool(),
        app.config.argon2,
        "Root@Example.org",
        PASSWORD,
    )
    .await
    .unwrap();
    assert_eq!(u.email, "root@example.org");
    let s = app.login("root@example.org", None).await;
    assert_eq!(
        app.send(Method::GET, "/api/users", Some(&s), None)
            .await
            .status,
        StatusCode::OK
    );
    assert!(
        server::records::users::create_admin(
            app.pool(),
            app.config.argon2,
            "root@example.org",
            PASSWORD
        )
        .await
        .is_err()
    );
    assert!(
        server::records::users::create_admin(
            app.pool(),
            app.config.argon2,
            "x@example.org",
            "short"
        )
        .await
        .is_err()
    );
}
