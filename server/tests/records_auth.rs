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
        ("PAINSIM_LOGIN_IDLE_SECS", "600"),
        ("PAINSIM_LOGIN_ABSOLUTE_SECS", "3600"),
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

#[tokio::test]
async fn create_admin_command_of_the_real_binary() {
    let app = TestApp::new(&[]).await;
    let run = |email: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_server"))
            .args(["create-admin", "--email", email])
            .env("DATABASE_URL", &app.db.url)
            .env("PAINSIM_ADMIN_PASSWORD", PASSWORD)
            .env("PAINSIM_ARGON2_MEMORY_KIB", "64")
            .env("PAINSIM_ARGON2_ITERATIONS", "1")
            .env("RUST_LOG", "warn")
            .output()
            .expect("run server create-admin")
    };
    let out = run("first-admin@example.org");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("created admin first-admin@example.org"));
    let role: String =
        sqlx::query_scalar("SELECT role FROM users WHERE email = 'first-admin@example.org'")
            .fetch_one(app.pool())
            .await
            .unwrap();
    assert_eq!(role, "admin");
    // The password was taken from the environment, not the command line, and works.
    let s = app.login("first-admin@example.org", None).await;
    assert_eq!(
        app.send(Method::GET, "/api/audit", Some(&s), None)
            .await
            .status,
        StatusCode::OK
    );
    // A second run for the same address fails with a clear message and exit status 2.
    let out = run("first-admin@example.org");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("already exists"));
}

#[tokio::test]
async fn an_edited_published_station_revision_is_refused() {
    let app = TestApp::new(&[]).await;
    // `TestApp::new` registered the repository's stations. A copy whose rubric changed but whose
    // revisions did not must be refused, naming the station and the fix.
    let dir = tempfile::tempdir().unwrap();
    let original =
        std::fs::read_to_string(app.config.stations_dir.join("l4-l5-left-facet.toml")).unwrap();
    let edited = original.replace("pass_threshold = 0.75", "pass_threshold = 0.5");
    assert_ne!(original, edited);
    std::fs::write(dir.path().join("l4-l5-left-facet.toml"), &edited).unwrap();
    let mut cfg = app.config.clone();
    cfg.stations_dir = dir.path().to_owned();
    let err = server::records::prepare(app.pool(), &cfg, false)
        .await
        .unwrap_err();
    let msg = format!("{err:#}");
    assert!(
        msg.contains("l4-l5-left-facet") && msg.contains("bump"),
        "{msg}"
    );
    // Bumping the rubric revision makes it a new, accepted revision.
    std::fs::write(
        dir.path().join("l4-l5-left-facet.toml"),
        edited.replacen("[rubric]\nrevision = 2", "[rubric]\nrevision = 3", 1),
    )
    .unwrap();
    server::records::prepare(app.pool(), &cfg, false)
        .await
        .unwrap();
    let revisions: i64 = sqlx::query_scalar(
        "SELECT count(*) FROM station_revisions WHERE station_id = 'l4-l5-left-facet'",
    )
    .fetch_one(app.pool())
    .await
    .unwrap();
    assert_eq!(revisions, 2);
}

/// Failures are throttled per client and account together: a client that
/// guesses wrong is throttled for that account, but the real user on another client still logs
/// in, and the attacker is not throttled on other accounts either.
#[tokio::test]
async fn one_client_guessing_cannot_lock_a_user_out() {
    use axum::extract::ConnectInfo;
    use tower::ServiceExt;
    let app = TestApp::new(&[("PAINSIM_LOGIN_MAX_FAILURES", "3")]).await;
    app.user("victim@example.org", Role::Learner).await;
    let login = |peer: &'static str, pw: &'static str| {
        let router = app.router.clone();
        async move {
            let mut req = axum::http::Request::builder()
                .method(Method::POST)
                .uri("/api/auth/login")
                .header("content-type", "application/json")
                .body(axum::body::Body::from(
                    json!({ "email": "victim@example.org", "password": pw }).to_string(),
                ))
                .unwrap();
            let addr: std::net::SocketAddr = peer.parse().unwrap();
            req.extensions_mut().insert(ConnectInfo(addr));
            router.oneshot(req).await.unwrap().status()
        }
    };
    for _ in 0..3 {
        assert_eq!(
            login("203.0.113.7:40000", "wrong-password-000").await,
            StatusCode::UNAUTHORIZED
        );
    }
    // The guessing client is throttled, even with the right password...
    assert_eq!(
        login("203.0.113.7:40001", PASSWORD).await,
        StatusCode::TOO_MANY_REQUESTS
    );
    // ...the real user elsewhere is not.
    assert_eq!(login("198.51.100.20:50000", PASSWORD).await, StatusCode::OK);
    // A distributed attack (many clients, many failures) throttles the account everywhere.
    let max_all = 3 * server::records::login::ACCOUNT_WIDE_FACTOR;
    sqlx::query(
        "INSERT INTO login_failures (email, client) SELECT 'victim@example.org', 'bot-' || g FROM generate_series(1, $1::int) g",
    )
    .bind(max_all as i32)
    .execute(app.pool())
    .await
    .unwrap();
    assert_eq!(
        login("198.51.100.20:50000", PASSWORD).await,
        StatusCode::TOO_MANY_REQUESTS
    );
}
