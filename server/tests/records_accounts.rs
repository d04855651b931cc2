//! Account management: changing one's password, an admin disabling an
//! account (its sessions revoked at once) and enabling it again, and an admin-started password
//! reset completed with a one-time token.

use axum::http::{Method, StatusCode};
use serde_json::json;
use server::records::auth::Role;

use crate::records_support::{PASSWORD, TestApp};

const NEW_PASSWORD: &str = "a-brand-new-password-789";

async fn login_status(app: &TestApp, email: &str, password: &str) -> (StatusCode, String) {
    let r = app
        .send(
            Method::POST,
            "/api/auth/login",
            None,
            Some(json!({ "email": email, "password": password })),
        )
        .await;
    (r.status, r.text)
}

/// The status of `GET /api/auth/me` for a session (200 alive, 401 revoked).
async fn me_status(app: &TestApp, s: &crate::records_support::Session) -> StatusCode {
    app.send(Method::GET, "/api/auth/me", Some(s), None)
        .await
        .status
}

async fn audit_actions(app: &TestApp, user: uuid::Uuid) -> Vec<String> {
    sqlx::query_scalar(
        "SELECT action FROM audit_events WHERE object_type = 'user' AND object_id = $1 ORDER BY id",
    )
    .bind(user.to_string())
    .fetch_all(app.pool())
    .await
    .unwrap()
}

#[tokio::test]
async fn changing_ones_password_needs_the_current_one_and_revokes_other_sessions() {
    let app = TestApp::new(&[("PAINSIM_LOGIN_MAX_FAILURES", "3")]).await;
    let me = app.user("pw@example.org", Role::Learner).await;
    let here = app.login("pw@example.org", None).await;
    let elsewhere = app.login("pw@example.org", None).await;
    let change =
        |current: &str, new: &str| json!({ "current_password": current, "new_password": new });

    // Wrong current password: refused, and counted as a failed login of this client.
    let r = app
        .send(
            Method::POST,
            "/api/auth/password",
            Some(&here),
            Some(change("not-it-at-all", NEW_PASSWORD)),
        )
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.text);
    assert!(r.text.contains("current_password"), "{}", r.text);
    // A weak new password: 400 naming the field; nothing changed.
    let r = app
        .send(
            Method::POST,
            "/api/auth/password",
            Some(&here),
            Some(change(PASSWORD, "short")),
        )
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST, "{}", r.text);
    assert!(r.text.contains("new_password"), "{}", r.text);
    // No CSRF token: refused.
    let mut no_csrf = here.clone();
    no_csrf.csrf = String::new();
    let r = app
        .send(
            Method::POST,
            "/api/auth/password",
            Some(&no_csrf),
            Some(change(PASSWORD, NEW_PASSWORD)),
        )
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.text);
    assert_eq!(
        login_status(&app, "pw@example.org", PASSWORD).await.0,
        StatusCode::OK
    );

    let r = app
        .send(
            Method::POST,
            "/api/auth/password",
            Some(&here),
            Some(change(PASSWORD, NEW_PASSWORD)),
        )
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    // This session goes on; every other one is revoked.
    assert_eq!(me_status(&app, &here).await, StatusCode::OK);
    assert_eq!(me_status(&app, &elsewhere).await, StatusCode::UNAUTHORIZED);
    assert_eq!(
        login_status(&app, "pw@example.org", PASSWORD).await.0,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        login_status(&app, "pw@example.org", NEW_PASSWORD).await.0,
        StatusCode::OK
    );
    assert!(
        audit_actions(&app, me)
            .await
            .contains(&"password_changed".to_string())
    );

    // Guessing the current password through a stolen session is throttled like logins are.
    let mut last = StatusCode::OK;
    for _ in 0..5 {
        last = app
            .send(
                Method::POST,
                "/api/auth/password",
                Some(&here),
                Some(change("guess-guess-guess", "whatever-password-1")),
            )
            .await
            .status;
    }
    assert_eq!(last, StatusCode::TOO_MANY_REQUESTS);
}

#[tokio::test]
async fn an_admin_disables_an_account_revoking_its_sessions_and_enables_it_again() {
    let app = TestApp::new(&[]).await;
    let admin = app.user("boss@example.org", Role::Admin).await;
    let learner = app.user("dis@example.org", Role::Learner).await;
    let faculty = app.user("fac@example.org", Role::Faculty).await;
    let as_admin = app.login("boss@example.org", None).await;
    let as_learner = app.login("dis@example.org", None).await;
    let as_faculty = app.login("fac@example.org", None).await;
    let disable = format!("/api/users/{learner}/disable");

    // Only admins; not one's own account; unknown ids are 404.
    let r = app
        .send(Method::POST, &disable, Some(&as_faculty), None)
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.text);
    let r = app
        .send(
            Method::POST,
            &format!("/api/users/{admin}/disable"),
            Some(&as_admin),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::CONFLICT, "{}", r.text);
    let r = app
        .send(
            Method::POST,
            &format!("/api/users/{}/disable", uuid::Uuid::new_v4()),
            Some(&as_admin),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::NOT_FOUND, "{}", r.text);
    let r = app
        .send(
            Method::POST,
            "/api/users/not-a-uuid/disable",
            Some(&as_admin),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST, "{}", r.text);

    let r = app
        .send(Method::POST, &disable, Some(&as_admin), None)
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(
        (
            r.json["disabled"].as_bool(),
            r.json["sessions_revoked"].as_u64()
        ),
        (Some(true), Some(1))
    );
    // Revoked at once; the right password is refused (and says why), a wrong one says nothing more.
    assert_eq!(me_status(&app, &as_learner).await, StatusCode::UNAUTHORIZED);
    let (status, text) = login_status(&app, "dis@example.org", PASSWORD).await;
    assert_eq!(status, StatusCode::FORBIDDEN, "{text}");
    assert!(text.contains("disabled"), "{text}");
    let (status, text) = login_status(&app, "dis@example.org", "wrong-password-000").await;
    assert_eq!(status, StatusCode::UNAUTHORIZED, "{text}");
    assert!(!text.contains("disabled"), "{text}");
    // The listing shows it; other accounts are untouched.
    let users = app
        .send(Method::GET, "/api/users", Some(&as_admin), None)
        .await
        .json;
    let row = users
        .as_array()
        .unwrap()
        .iter()
        .find(|u| u["id"] == learner.to_string().as_str())
        .unwrap()
        .clone();
    assert_eq!(row["disabled"], true);
    assert_eq!(me_status(&app, &as_faculty).await, StatusCode::OK);
    let _ = faculty;

    let r = app
        .send(
            Method::POST,
            &format!("/api/users/{learner}/enable"),
            Some(&as_admin),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(
        login_status(&app, "dis@example.org", PASSWORD).await.0,
        StatusCode::OK
    );
    let actions = audit_actions(&app, learner).await;
    assert!(
        actions.contains(&"user_disabled".into()) && actions.contains(&"user_enabled".into()),
        "{actions:?}"
    );
}

#[tokio::test]
async fn an_admin_started_reset_sets_a_new_password_once_with_its_token() {
    let app = TestApp::new(&[]).await;
    app.user("root@example.org", Role::Admin).await;
    let learner = app.user("forgot@example.org", Role::Learner).await;
    let as_admin = app.login("root@example.org", None).await;
    let as_learner = app.login("forgot@example.org", None).await;
    let start = format!("/api/users/{learner}/password-reset");
    let complete = |token: &str, pw: &str| json!({ "reset_token": token, "new_password": pw });

    // Learners cannot start resets (not even their own).
    let r = app
        .send(Method::POST, &start, Some(&as_learner), None)
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.text);
    let first = app.send(Method::POST, &start, Some(&as_admin), None).await;
    assert_eq!(first.status, StatusCode::CREATED, "{}", first.text);
    let first_token = first.json["reset_token"].as_str().unwrap().to_owned();
    // A second reset voids the first token.
    let second = app.send(Method::POST, &start, Some(&as_admin), None).await;
    let token = second.json["reset_token"].as_str().unwrap().to_owned();
    assert_ne!(first_token, token);
    // The token is stored only hashed.
    let stored: i64 = sqlx::query_scalar(
        "SELECT count(*) FROM password_resets WHERE encode(token_sha256, 'hex') = $1",
    )
    .bind(&token)
    .fetch_one(app.pool())
    .await
    .unwrap();
    assert_eq!(stored, 0);

    for (body, status, words) in [
        (
            complete(&first_token, NEW_PASSWORD),
            StatusCode::UNAUTHORIZED,
            "unknown, used or expired",
        ),
        (
            complete("XYZ", NEW_PASSWORD),
            StatusCode::BAD_REQUEST,
            "reset_token",
        ),
        (
            complete(&token, "short"),
            StatusCode::BAD_REQUEST,
            "new_password",
        ),
        (
            json!({ "reset_token": token }),
            StatusCode::BAD_REQUEST,
            "new_password",
        ),
    ] {
        let r = app
            .send(Method::POST, "/api/auth/password-reset", None, Some(body))
            .await;
        assert_eq!(r.status, status, "{}", r.text);
        assert!(r.text.contains(words), "{}", r.text);
    }
    assert_eq!(
        login_status(&app, "forgot@example.org", PASSWORD).await.0,
        StatusCode::OK
    );

    let r = app
        .send(
            Method::POST,
            "/api/auth/password-reset",
            None,
            Some(complete(&token, NEW_PASSWORD)),
        )
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    assert_eq!(me_status(&app, &as_learner).await, StatusCode::UNAUTHORIZED);
    assert_eq!(
        login_status(&app, "forgot@example.org", PASSWORD).await.0,
        StatusCode::UNAUTHORIZED
    );
    assert_eq!(
        login_status(&app, "forgot@example.org", NEW_PASSWORD)
            .await
            .0,
        StatusCode::OK
    );
    // Used once only.
    let r = app
        .send(
            Method::POST,
            "/api/auth/password-reset",
            None,
            Some(complete(&token, "yet-another-password-1")),
        )
        .await;
    assert_eq!(r.status, StatusCode::UNAUTHORIZED, "{}", r.text);

    // An expired token is refused.
    let r = app.send(Method::POST, &start, Some(&as_admin), None).await;
    let stale = r.json["reset_token"].as_str().unwrap().to_owned();
    sqlx::query(
        "UPDATE password_resets SET expires_at = now() - interval '1 second' WHERE used_at IS NULL",
    )
    .execute(app.pool())
    .await
    .unwrap();
    let r = app
        .send(
            Method::POST,
            "/api/auth/password-reset",
            None,
            Some(complete(&stale, "expired-password-123")),
        )
        .await;
    assert_eq!(r.status, StatusCode::UNAUTHORIZED, "{}", r.text);
    let actions = audit_actions(&app, learner).await;
    assert!(
        actions.contains(&"password_reset_started".into())
            && actions.contains(&"password_reset_completed".into()),
        "{actions:?}"
    );
}

/// Authenticated writes are limited per account: a script posting activity as fast as it can
/// gets 429 with Retry-After after the burst, while reads and other accounts go on.
#[tokio::test]
async fn authenticated_writes_are_rate_limited_per_account() {
    let app = TestApp::new(&[
        ("PAINSIM_WRITE_RATE_PER_MINUTE", "60"),
        ("PAINSIM_WRITE_BURST", "20"),
    ])
    .await;
    let w = crate::records_support::World::build(&app, "rate").await;
    let learner = w.sessions[1].clone().unwrap();
    let other = w.sessions[2].clone().unwrap();
    let path = format!("/api/attempts/{}/activity", w.attempt_open);
    let mut statuses = Vec::new();
    for _ in 0..250 {
        let r = app
            .send(
                Method::POST,
                &path,
                Some(&learner),
                Some(json!({ "kind": "view_changed" })),
            )
            .await;
        if r.status == StatusCode::TOO_MANY_REQUESTS {
            assert!(r.headers.contains_key("retry-after"), "{:?}", r.headers);
        }
        statuses.push(r.status);
    }
    let created = statuses
        .iter()
        .filter(|s| **s == StatusCode::CREATED)
        .count();
    let limited = statuses
        .iter()
        .filter(|s| **s == StatusCode::TOO_MANY_REQUESTS)
        .count();
    // The burst of 20 less the fixture's own writes as this learner (opening two attempts), plus
    // at most a few tokens refilled (1/s) while the loop ran.
    assert!((15..=30).contains(&created), "{created} writes accepted");
    assert_eq!(created + limited, 250, "{statuses:?}");
    // Reads are not writes; another account has its own bucket.
    assert_eq!(me_status(&app, &learner).await, StatusCode::OK);
    let r = app
        .send(Method::POST, "/api/auth/logout", Some(&other), None)
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
}
