//! The authorization matrix: every learning-records endpoint x every role, from ONE table, with
//! a check that the table covers every route of the generated OpenAPI document (so a new
//! endpoint cannot be forgotten). Each write cell runs in a fresh fixture world, so a write in one
//! cell cannot change the outcome of another; read cells share one world.

use std::collections::BTreeSet;

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};

use crate::records_support::{PASSWORD, ROLES, TestApp, World};

/// What a cell's request needs from the world.
type Build = fn(&World) -> (String, Option<Value>);

struct Row {
    method: Method,
    /// The route as the OpenAPI document names it.
    route: &'static str,
    build: Build,
    /// Expected status per role, in [`ROLES`] order.
    expect: [u16; 6],
}

/// Settings of an LTI platform (unique per world and `tag`).
fn lti_platform_settings(w: &World, tag: &str) -> Value {
    json!({
        "name": format!("LMS {tag}"),
        "issuer": format!("https://lms.example.org/{}/{tag}", w.lti_platform),
        "client_id": "tool",
        "deployment_ids": ["1"],
        "auth_url": "https://lms.example.org/auth",
        "token_url": "https://lms.example.org/token",
        "jwks_url": "https://lms.example.org/jwks",
    })
}

fn rows() -> Vec<Row> {
    fn r(method: Method, route: &'static str, build: Build, expect: [u16; 6]) -> Row {
        Row {
            method,
            route,
            build,
            expect,
        }
    }
    use Method as M;
    vec![
        // Login is open to everyone; it answers for the credentials in the body (rotation for a
        // caller who already has a session).
        r(
            M::POST,
            "/api/auth/login",
            |w| {
                (
                    "/api/auth/login".into(),
                    Some(json!({ "email": w.learner_email, "password": PASSWORD })),
                )
            },
            [200, 200, 200, 200, 200, 200],
        ),
        r(
            M::POST,
            "/api/auth/logout",
            |_| ("/api/auth/logout".into(), None),
            [401, 204, 204, 204, 204, 204],
        ),
        r(
            M::GET,
            "/api/auth/me",
            |_| ("/api/auth/me".into(), None),
            [401, 200, 200, 200, 200, 200],
        ),
        // Everyone with a session may change their own password (with the current one).
        r(
            M::POST,
            "/api/auth/password",
            |_| {
                (
                    "/api/auth/password".into(),
                    Some(
                        json!({ "current_password": PASSWORD, "new_password": "another-password-456" }),
                    ),
                )
            },
            [401, 204, 204, 204, 204, 204],
        ),
        // Open to all; a token nobody issued is refused for everyone alike.
        r(
            M::POST,
            "/api/auth/password-reset",
            |_| {
                (
                    "/api/auth/password-reset".into(),
                    Some(
                        json!({ "reset_token": "ab".repeat(32), "new_password": "another-password-456" }),
                    ),
                )
            },
            [401, 401, 401, 401, 401, 401],
        ),
        r(
            M::POST,
            "/api/users/{user_id}/disable",
            |w| (format!("/api/users/{}/disable", w.other_learner), None),
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::POST,
            "/api/users/{user_id}/enable",
            |w| (format!("/api/users/{}/enable", w.other_learner), None),
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::POST,
            "/api/users/{user_id}/password-reset",
            |w| {
                (
                    format!("/api/users/{}/password-reset", w.other_learner),
                    None,
                )
            },
            [401, 403, 403, 403, 403, 201],
        ),
        // Faculty and admins of the fixture already have TOTP: 409 is "already enabled".
        r(
            M::POST,
            "/api/auth/totp/enroll",
            |_| ("/api/auth/totp/enroll".into(), None),
            [401, 403, 403, 409, 409, 409],
        ),
        r(
            M::POST,
            "/api/auth/totp/confirm",
            |_| {
                (
                    "/api/auth/totp/confirm".into(),
                    Some(json!({ "code": "123456" })),
                )
            },
            [401, 403, 403, 409, 409, 409],
        ),
        r(
            M::POST,
            "/api/users",
            |_| {
                (
                    "/api/users".into(),
                    Some(
                        json!({ "email": format!("new-{}@example.org", uuid::Uuid::new_v4()), "display_name": "New", "role": "learner", "password": PASSWORD }),
                    ),
                )
            },
            [401, 403, 403, 403, 403, 201],
        ),
        r(
            M::GET,
            "/api/users",
            |_| ("/api/users".into(), None),
            [401, 403, 403, 403, 403, 200],
        ),
        // LTI 1.3 platforms and the tool's keys are the admin's; filling a course from its LMS is
        // for the course's faculty and admins (the fixture courses came from no LMS: 404).
        r(
            M::POST,
            "/api/admin/lti/platforms",
            |w| {
                (
                    "/api/admin/lti/platforms".into(),
                    Some(lti_platform_settings(w, "new")),
                )
            },
            [401, 403, 403, 403, 403, 201],
        ),
        r(
            M::GET,
            "/api/admin/lti/platforms",
            |_| ("/api/admin/lti/platforms".into(), None),
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::PUT,
            "/api/admin/lti/platforms/{id}",
            |w| {
                (
                    format!("/api/admin/lti/platforms/{}", w.lti_platform),
                    Some(lti_platform_settings(w, "changed")),
                )
            },
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::DELETE,
            "/api/admin/lti/platforms/{id}",
            |w| (format!("/api/admin/lti/platforms/{}", w.lti_platform), None),
            [401, 403, 403, 403, 403, 204],
        ),
        r(
            M::POST,
            "/api/admin/lti/keys/rotate",
            |_| ("/api/admin/lti/keys/rotate".into(), None),
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::POST,
            "/api/lti/courses/{id}/memberships/sync",
            |w| {
                (
                    format!("/api/lti/courses/{}/memberships/sync", w.course_a),
                    None,
                )
            },
            [401, 403, 403, 404, 403, 404],
        ),
        // LMS integrations: LRS credentials are the admin's alone.
        r(
            M::POST,
            "/api/admin/lrs-credentials",
            |_| {
                (
                    "/api/admin/lrs-credentials".into(),
                    Some(json!({ "name": "Moodle, anaesthesia course" })),
                )
            },
            [401, 403, 403, 403, 403, 201],
        ),
        r(
            M::GET,
            "/api/admin/lrs-credentials",
            |_| ("/api/admin/lrs-credentials".into(), None),
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::POST,
            "/api/admin/lrs-credentials/{id}/revoke",
            |w| {
                (
                    format!("/api/admin/lrs-credentials/{}/revoke", w.lrs_credential),
                    None,
                )
            },
            [401, 403, 403, 403, 403, 200],
        ),
        // Forwarding to an external LRS: the admin's alone.
        r(
            M::GET,
            "/api/admin/lrs-forwarding",
            |_| ("/api/admin/lrs-forwarding".into(), None),
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::PUT,
            "/api/admin/lrs-forwarding",
            |_| {
                (
                    "/api/admin/lrs-forwarding".into(),
                    Some(
                        json!({ "endpoint": "https://lrs.example.org/xapi/", "key": "k", "secret": "s" }),
                    ),
                )
            },
            [401, 403, 403, 403, 403, 200],
        ),
        r(
            M::DELETE,
            "/api/admin/lrs-forwarding",
            |_| ("/api/admin/lrs-forwarding".into(), None),
            [401, 403, 403, 403, 403, 204],
        ),
        r(
            M::POST,
            "/api/courses",
            |_| {
                (
                    "/api/courses".into(),
                    Some(
                        json!({ "code": uuid::Uuid::new_v4().to_string(), "title": "New course" }),
                    ),
                )
            },
            [401, 403, 403, 403, 403, 201],
        ),
        r(
            M::GET,
            "/api/courses",
            |_| ("/api/courses".into(), None),
            [401, 200, 200, 200, 200, 200],
        ),
        r(
            M::GET,
            "/api/courses/{course_id}",
            |w| (format!("/api/courses/{}", w.course_a), None),
            [401, 200, 200, 200, 404, 200],
        ),
        r(
            M::PUT,
            "/api/courses/{course_id}/members/{user_id}",
            |w| {
                (
                    format!("/api/courses/{}/members/{}", w.course_a, w.outsider),
                    Some(json!({ "role": "learner" })),
                )
            },
            [401, 403, 403, 403, 403, 200],
        ),
        // Members see how the course's stations run; its faculty (and admins) set it.
        r(
            M::GET,
            "/api/courses/{course_id}/station-modes",
            |w| (format!("/api/courses/{}/station-modes", w.course_a), None),
            [401, 200, 200, 200, 404, 200],
        ),
        r(
            M::PUT,
            "/api/courses/{course_id}/station-modes/{station_id}",
            |w| {
                (
                    format!(
                        "/api/courses/{}/station-modes/l4-left-transforaminal",
                        w.course_a
                    ),
                    Some(json!({ "mode": "assessment" })),
                )
            },
            [401, 403, 403, 200, 404, 200],
        ),
        // The cohort dashboard is the course faculty's.
        r(
            M::GET,
            "/api/courses/{course_id}/cohort",
            |w| {
                (
                    format!(
                        "/api/courses/{}/cohort?station_id=l4-left-transforaminal",
                        w.course_a
                    ),
                    None,
                )
            },
            [401, 403, 403, 200, 404, 200],
        ),
        r(
            M::GET,
            "/api/courses/{course_id}/cohort.csv",
            |w| {
                (
                    format!(
                        "/api/courses/{}/cohort.csv?station_id=l4-left-transforaminal",
                        w.course_a
                    ),
                    None,
                )
            },
            [401, 403, 403, 200, 404, 200],
        ),
        r(
            M::GET,
            "/api/stations",
            |_| ("/api/stations".into(), None),
            [401, 200, 200, 200, 200, 200],
        ),
        r(
            M::GET,
            "/api/stations/{station_id}",
            |_| ("/api/stations/l4-left-transforaminal".into(), None),
            [401, 200, 200, 200, 200, 200],
        ),
        // Only learners of the course open attempts in it.
        r(
            M::POST,
            "/api/attempts",
            |w| {
                (
                    "/api/attempts".into(),
                    Some(
                        json!({ "course_id": w.course_a, "station_id": "l4-l5-interlaminar-epidural" }),
                    ),
                )
            },
            [401, 201, 201, 403, 403, 403],
        ),
        r(
            M::GET,
            "/api/attempts",
            |_| ("/api/attempts".into(), None),
            [401, 200, 200, 200, 200, 200],
        ),
        r(
            M::GET,
            "/api/attempts/{attempt_id}",
            |w| (format!("/api/attempts/{}", w.attempt_submitted), None),
            [401, 200, 404, 200, 404, 200],
        ),
        r(
            M::POST,
            "/api/attempts/{attempt_id}/activity",
            |w| {
                (
                    format!("/api/attempts/{}/activity", w.attempt_open),
                    Some(json!({ "kind": "image_acquired", "detail": { "view": "ap" } })),
                )
            },
            [401, 201, 404, 403, 404, 403],
        ),
        r(
            M::GET,
            "/api/attempts/{attempt_id}/activity",
            |w| {
                (
                    format!("/api/attempts/{}/activity", w.attempt_submitted),
                    None,
                )
            },
            [401, 200, 404, 200, 404, 200],
        ),
        r(
            M::POST,
            "/api/attempts/{attempt_id}/review",
            |w| {
                (
                    format!("/api/attempts/{}/review", w.attempt_submitted),
                    Some(json!({ "decision": "approve", "comment": "ok" })),
                )
            },
            [401, 403, 403, 200, 404, 200],
        ),
        r(
            M::GET,
            "/api/reviews",
            |_| ("/api/reviews".into(), None),
            [401, 403, 403, 200, 200, 200],
        ),
        r(
            M::GET,
            "/api/reviews/export.csv",
            |_| ("/api/reviews/export.csv?state=any".into(), None),
            [401, 403, 403, 200, 200, 200],
        ),
        r(
            M::POST,
            "/api/reviews/bulk-approve",
            |w| {
                (
                    "/api/reviews/bulk-approve".into(),
                    Some(json!({ "attempt_ids": [w.attempt_submitted], "comment": "" })),
                )
            },
            [401, 403, 403, 200, 404, 200],
        ),
        r(
            M::GET,
            "/api/audit",
            |_| ("/api/audit".into(), None),
            [401, 403, 403, 403, 403, 200],
        ),
        // Sessions (dispatch). The fixture's dispatcher has no render worker, so the cell asks
        // for a session of the submitted attempt: its learner passes authorization and gets 409
        // (submitted attempts take no session), everyone else is refused before. The submitted
        // attempt has no recorded session, so its replays are 404 even where they are allowed.
        // Opening sessions for real is `dispatch.rs`.
        r(
            M::POST,
            "/api/attempts/{attempt_id}/session",
            |w| {
                (
                    format!("/api/attempts/{}/session", w.attempt_submitted),
                    None,
                )
            },
            [401, 409, 404, 403, 404, 403],
        ),
        r(
            M::GET,
            "/api/sessions/{session_id}",
            |_| (format!("/api/sessions/{}", uuid::Uuid::nil()), None),
            [401, 404, 404, 404, 404, 404],
        ),
        r(
            M::GET,
            "/api/sessions/{session_id}/ws",
            |_| (format!("/api/sessions/{}/ws", uuid::Uuid::nil()), None),
            [401, 404, 404, 404, 404, 404],
        ),
        r(
            M::GET,
            "/api/attempts/{attempt_id}/replay",
            |w| {
                (
                    format!("/api/attempts/{}/replay", w.attempt_submitted),
                    None,
                )
            },
            [401, 404, 404, 404, 404, 404],
        ),
        r(
            M::GET,
            "/api/attempts/{attempt_id}/reveal",
            |w| {
                (
                    format!("/api/attempts/{}/reveal", w.attempt_submitted),
                    None,
                )
            },
            [401, 404, 404, 404, 404, 404],
        ),
        r(
            M::GET,
            "/api/attempts/{attempt_id}/debrief",
            |w| {
                (
                    format!("/api/attempts/{}/debrief", w.attempt_submitted),
                    None,
                )
            },
            [401, 404, 404, 404, 404, 404],
        ),
        r(
            M::GET,
            "/api/attempts/{attempt_id}/replay/frame",
            |w| {
                (
                    format!("/api/attempts/{}/replay/frame?step=0", w.attempt_submitted),
                    None,
                )
            },
            [401, 404, 404, 404, 404, 404],
        ),
        // Workers register with the cluster token, which this server has none of.
        r(
            M::POST,
            "/api/workers",
            |_| {
                (
                    "/api/workers".into(),
                    Some(
                        json!({ "url": "http://127.0.0.1:9", "capacity": 1, "renderer": {}, "adapter": null }),
                    ),
                )
            },
            [403, 403, 403, 403, 403, 403],
        ),
        r(
            M::GET,
            "/api/workers",
            |_| ("/api/workers".into(), None),
            [401, 403, 403, 403, 403, 200],
        ),
        // The API description is public.
        r(
            M::GET,
            "/api/openapi.json",
            |_| ("/api/openapi.json".into(), None),
            [200, 200, 200, 200, 200, 200],
        ),
    ]
}

/// Roles that must never see the learner's attempts.
const OUTSIDERS: [usize; 3] = [0, 2, 4];

#[tokio::test]
async fn every_endpoint_times_every_role_matches_the_table() {
    let app = TestApp::new(&[]).await;
    let table = rows();

    // Coverage: the table has exactly the routes of the OpenAPI document, plus the document itself.
    let doc = app
        .send(Method::GET, "/api/openapi.json", None, None)
        .await
        .json;
    let mut documented = BTreeSet::new();
    for (path, item) in doc["paths"].as_object().expect("paths") {
        // The LRS authenticates LMS integrations, not sessions: its own matrix is in `xapi_authz`.
        if path.starts_with("/xapi/") {
            continue;
        }
        for method in ["get", "post", "put", "patch", "delete"] {
            if item.get(method).is_some() {
                documented.insert((method.to_uppercase(), path.clone()));
            }
        }
    }
    documented.insert(("GET".into(), "/api/openapi.json".into()));
    let tabled: BTreeSet<_> = table
        .iter()
        .map(|r| (r.method.to_string(), r.route.to_string()))
        .collect();
    assert_eq!(tabled.len(), table.len(), "a route is listed twice");
    assert_eq!(
        tabled, documented,
        "the matrix table and the OpenAPI routes differ"
    );

    // Reads change nothing, so they share one world; every write cell gets a fresh one.
    let shared = World::build(&app, "shared").await;
    let mut mismatches = Vec::new();
    let (mut cells, mut worlds) = (0, 1);
    for (i, row) in table.iter().enumerate() {
        for (role, expected) in row.expect.iter().enumerate() {
            let own;
            let world = if row.method == Method::GET {
                &shared
            } else {
                worlds += 1;
                own = World::build(&app, &format!("{i}-{role}")).await;
                &own
            };
            let (uri, body) = (row.build)(world);
            let resp = app
                .send(
                    row.method.clone(),
                    &uri,
                    world.sessions[role].as_ref(),
                    body.clone(),
                )
                .await;
            cells += 1;
            assert!(
                resp.status.as_u16() < 500,
                "{} {uri} as {}: {} {}",
                row.method,
                ROLES[role],
                resp.status,
                resp.text
            );
            if resp.status.as_u16() != *expected {
                mismatches.push(format!(
                    "{} {} as {}: got {}, want {expected}: {}",
                    row.method, row.route, ROLES[role], resp.status, resp.text
                ));
            }
            if resp.status.is_client_error() {
                assert!(
                    resp.json["error"]["code"].is_string()
                        && resp.json["error"]["message"].is_string(),
                    "error body of {uri}: {}",
                    resp.text
                );
            }
            // Outsiders never learn anything about the learner's attempts (unless they named the
            // attempt themselves in the request).
            let named = uri.contains(&world.attempt_submitted.to_string())
                || body
                    .as_ref()
                    .is_some_and(|b| b.to_string().contains(&world.attempt_submitted.to_string()));
            if OUTSIDERS.contains(&role) && !named && row.route != "/api/auth/login" {
                for secret in [
                    world.attempt_submitted.to_string(),
                    world.attempt_open.to_string(),
                    world.learner_email.clone(),
                ] {
                    let excerpt: String = resp.text.chars().take(300).collect();
                    assert!(
                        !resp.text.contains(&secret),
                        "{} {uri} as {} leaks {secret}: {excerpt}",
                        row.method,
                        ROLES[role]
                    );
                }
            }
        }
    }
    eprintln!(
        "authorization matrix: {} endpoints x {} roles = {cells} cells ({worlds} fixture worlds), {} mismatches",
        table.len(),
        ROLES.len(),
        mismatches.len()
    );
    assert!(
        mismatches.is_empty(),
        "{} mismatches:\n{}",
        mismatches.len(),
        mismatches.join("\n")
    );
}

#[tokio::test]
async fn writes_need_the_csrf_token_and_lists_are_scoped() {
    let app = TestApp::new(&[]).await;
    let w = World::build(&app, "csrf").await;
    let learner = w.sessions[1].clone().unwrap();
    // A cookie without the CSRF header cannot write, even with a perfectly valid body.
    let forged = crate::records_support::Session {
        token: learner.token.clone(),
        csrf: "wrong".into(),
    };
    let before = app.counts().await;
    let r = app
        .send(
            Method::POST,
            &format!("/api/attempts/{}/activity", w.attempt_open),
            Some(&forged),
            Some(json!({ "kind": "injection" })),
        )
        .await;
    assert_eq!(r.status, StatusCode::FORBIDDEN, "{}", r.text);
    assert!(
        r.json["error"]["message"]
            .as_str()
            .unwrap()
            .contains("CSRF")
    );
    assert_eq!(app.counts().await, before);
    // Reads do not need it.
    assert_eq!(
        app.send(Method::GET, "/api/attempts", Some(&forged), None)
            .await
            .status,
        StatusCode::OK
    );

    // Each list holds exactly what the caller may see.
    let ids = |v: &Value| {
        v.as_array()
            .unwrap()
            .iter()
            .map(|a| a["id"].as_str().unwrap().to_owned())
            .collect::<BTreeSet<_>>()
    };
    let mine: BTreeSet<_> = [w.attempt_open.to_string(), w.attempt_submitted.to_string()].into();
    for (role, expected) in [
        (1, mine.clone()),
        (2, BTreeSet::new()),
        (3, mine.clone()),
        (4, BTreeSet::new()),
    ] {
        let r = app
            .send(
                Method::GET,
                "/api/attempts",
                w.sessions[role].as_ref(),
                None,
            )
            .await;
        assert_eq!(
            ids(&r.json),
            expected,
            "GET /api/attempts as {}",
            ROLES[role]
        );
    }
    // The queue of faculty A holds the submitted attempt; faculty B's is empty.
    let q = |role: usize| {
        let app = &app;
        let s = w.sessions[role].clone();
        async move {
            ids(&app
                .send(Method::GET, "/api/reviews", s.as_ref(), None)
                .await
                .json)
        }
    };
    assert_eq!(q(3).await, [w.attempt_submitted.to_string()].into());
    assert!(q(4).await.is_empty());
    let _ = (
        w.course_b,
        w.other_learner,
        w.faculty_a,
        w.faculty_b,
        w.admin,
        w.learner,
    );
}
