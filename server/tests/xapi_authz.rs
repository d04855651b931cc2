//! The LRS authorization matrix: every `/xapi/` route of the OpenAPI document x every kind of
//! caller, from ONE table, with a check that the table covers every `/xapi/` route of the
//! document (the learning-records matrix, `records_authz.rs`, covers the rest).
//!
//! Callers, in [`CALLERS`] order: no credentials, a wrong secret, a revoked credential, a
//! read-only, a write-only and a read-write credential, and an admin's cookie session without
//! Basic (the LRS authenticates LMS integrations only).

use std::collections::BTreeSet;

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};

use crate::xapi_support::{Cred, Lrs};

/// The callers of each row's cells.
pub const CALLERS: [&str; 7] = [
    "none",
    "wrong secret",
    "revoked",
    "read-only",
    "write-only",
    "read-write",
    "admin session",
];

/// What a cell sends: URI and JSON body.
type Build = fn() -> (String, Option<Value>);

struct Row {
    method: Method,
    /// The route as the OpenAPI document names it.
    route: &'static str,
    build: Build,
    /// Expected status per caller, in [`CALLERS`] order.
    expect: [u16; 7],
}

fn statement() -> Value {
    json!({
        "actor": { "mbox": "mailto:authz@example.org" },
        "verb": { "id": "http://example.org/verbs/checked" },
        "object": { "id": "http://example.org/act/authz" }
    })
}

fn rows() -> Vec<Row> {
    fn r(method: Method, route: &'static str, build: Build, expect: [u16; 7]) -> Row {
        Row {
            method,
            route,
            build,
            expect,
        }
    }
    use Method as M;
    vec![
        // About is open to everyone.
        r(
            M::GET,
            "/xapi/about",
            || ("/xapi/about".into(), None),
            [200; 7],
        ),
        r(
            M::PUT,
            "/xapi/statements",
            || {
                (
                    format!("/xapi/statements?statementId={}", uuid::Uuid::new_v4()),
                    Some(statement()),
                )
            },
            [401, 401, 401, 403, 204, 204, 401],
        ),
        r(
            M::POST,
            "/xapi/statements",
            || ("/xapi/statements".into(), Some(statement())),
            [401, 401, 401, 403, 200, 200, 401],
        ),
        r(
            M::GET,
            "/xapi/statements",
            || ("/xapi/statements?limit=1".into(), None),
            [401, 401, 401, 200, 403, 200, 401],
        ),
        // Documents: each cell names a document of its own, so a GET finds nothing (404 once
        // the caller may read) and a write needs no precondition (a new document).
        r(
            M::GET,
            "/xapi/activities/state",
            || (state_uri(), None),
            [401, 401, 401, 404, 403, 404, 401],
        ),
        r(
            M::PUT,
            "/xapi/activities/state",
            || (state_uri(), Some(json!({"v": 1}))),
            WRITE,
        ),
        r(
            M::POST,
            "/xapi/activities/state",
            || (state_uri(), Some(json!({"v": 1}))),
            WRITE,
        ),
        r(
            M::DELETE,
            "/xapi/activities/state",
            || (state_uri(), None),
            WRITE,
        ),
        r(
            M::GET,
            "/xapi/activities/profile",
            || (activity_profile_uri(), None),
            [401, 401, 401, 404, 403, 404, 401],
        ),
        r(
            M::PUT,
            "/xapi/activities/profile",
            || (activity_profile_uri(), Some(json!({"v": 1}))),
            WRITE,
        ),
        r(
            M::POST,
            "/xapi/activities/profile",
            || (activity_profile_uri(), Some(json!({"v": 1}))),
            WRITE,
        ),
        r(
            M::DELETE,
            "/xapi/activities/profile",
            || (activity_profile_uri(), None),
            WRITE,
        ),
        r(
            M::GET,
            "/xapi/agents/profile",
            || (agent_profile_uri(), None),
            [401, 401, 401, 404, 403, 404, 401],
        ),
        r(
            M::PUT,
            "/xapi/agents/profile",
            || (agent_profile_uri(), Some(json!({"v": 1}))),
            WRITE,
        ),
        r(
            M::POST,
            "/xapi/agents/profile",
            || (agent_profile_uri(), Some(json!({"v": 1}))),
            WRITE,
        ),
        r(
            M::DELETE,
            "/xapi/agents/profile",
            || (agent_profile_uri(), None),
            WRITE,
        ),
        r(
            M::GET,
            "/xapi/agents",
            || (format!("/xapi/agents?agent={}", enc(&agent())), None),
            READ,
        ),
        r(
            M::GET,
            "/xapi/activities",
            || {
                (
                    format!("/xapi/activities?activityId={}", enc(ACTIVITY)),
                    None,
                )
            },
            READ,
        ),
    ]
}

/// Expected statuses of a document write and of a read that finds something.
const WRITE: [u16; 7] = [401, 401, 401, 403, 204, 204, 401];
const READ: [u16; 7] = [401, 401, 401, 200, 403, 200, 401];
const ACTIVITY: &str = "http://example.org/act/authz";

fn agent() -> String {
    json!({ "mbox": "mailto:authz@example.org" }).to_string()
}

fn enc(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                (b as char).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

fn state_uri() -> String {
    format!(
        "/xapi/activities/state?activityId={}&agent={}&stateId={}",
        enc(ACTIVITY),
        enc(&agent()),
        uuid::Uuid::new_v4()
    )
}

fn activity_profile_uri() -> String {
    format!(
        "/xapi/activities/profile?activityId={}&profileId={}",
        enc(ACTIVITY),
        uuid::Uuid::new_v4()
    )
}

fn agent_profile_uri() -> String {
    format!(
        "/xapi/agents/profile?agent={}&profileId={}",
        enc(&agent()),
        uuid::Uuid::new_v4()
    )
}

#[tokio::test]
async fn every_lrs_route_times_every_caller_matches_the_table() {
    let lrs = Lrs::new().await;
    let table = rows();

    let doc = lrs
        .app
        .send(Method::GET, "/api/openapi.json", None, None)
        .await
        .json;
    let mut documented = BTreeSet::new();
    for (path, item) in doc["paths"].as_object().expect("paths") {
        if !path.starts_with("/xapi/") {
            continue;
        }
        for method in ["get", "post", "put", "patch", "delete"] {
            if item.get(method).is_some() {
                documented.insert((method.to_uppercase(), path.clone()));
            }
        }
    }
    let tabled: BTreeSet<_> = table
        .iter()
        .map(|r| (r.method.to_string(), r.route.to_string()))
        .collect();
    assert_eq!(tabled.len(), table.len(), "a route is listed twice");
    assert_eq!(
        tabled, documented,
        "the LRS matrix and the OpenAPI /xapi/ routes differ"
    );

    let read = lrs.credential("read-only", true, false).await;
    let write = lrs.credential("write-only", false, true).await;
    let revoked = lrs.credential("revoked", true, true).await;
    let r = lrs
        .app
        .send(
            Method::POST,
            &format!("/api/admin/lrs-credentials/{}/revoke", revoked.id),
            Some(&lrs.admin),
            None,
        )
        .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let wrong = Cred {
        secret: "0".repeat(64),
        ..lrs.cred.clone()
    };
    let creds: [Option<&Cred>; 7] = [
        None,
        Some(&wrong),
        Some(&revoked),
        Some(&read),
        Some(&write),
        Some(&lrs.cred),
        None,
    ];
    let mut mismatches = Vec::new();
    let mut cells = 0;
    for row in &table {
        for (caller, expected) in row.expect.iter().enumerate() {
            let (uri, body) = (row.build)();
            let body = body.map(|b| ("application/json", b.to_string().into_bytes()));
            let resp = if CALLERS[caller] == "admin session" {
                let mut req = axum::http::Request::builder()
                    .method(row.method.clone())
                    .uri(&uri)
                    .header("x-experience-api-version", "2.0.0")
                    .header("cookie", format!("painsim_session={}", lrs.admin.token))
                    .header("x-csrf-token", &lrs.admin.csrf);
                let b = match body {
                    Some((ct, bytes)) => {
                        req = req.header("content-type", ct);
                        axum::body::Body::from(bytes)
                    }
                    None => axum::body::Body::empty(),
                };
                lrs.app.request(req.body(b).unwrap()).await
            } else {
                lrs.raw(row.method.clone(), &uri, creds[caller], &[], body)
                    .await
            };
            cells += 1;
            if resp.status.as_u16() != *expected {
                mismatches.push(format!(
                    "{} {} as {}: expected {expected}, got {} ({})",
                    row.method, row.route, CALLERS[caller], resp.status, resp.text
                ));
            }
            if resp.status == StatusCode::UNAUTHORIZED {
                assert!(resp.headers.contains_key("www-authenticate"), "{uri}");
            }
        }
    }
    assert!(
        mismatches.is_empty(),
        "{} of {cells} cells differ:\n{}",
        mismatches.len(),
        mismatches.join("\n")
    );
}
