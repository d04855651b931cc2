//! The Agents and Activities resources of the LRS, the authorization matrix of every route of
//! these and the document resources, and the body limit of document writes.

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};

use crate::xapi_documents_support::{ACTIVITY, exchange, get_json, mbox_agent, query, state_uri};
use crate::xapi_support::{Cred, Lrs};

#[tokio::test]
async fn xapi_documents_agents_resource_returns_the_person() {
    let lrs = Lrs::new().await;
    let person = |agent: Value| {
        let lrs = &lrs;
        async move {
            let uri = format!("/xapi/agents?{}", query(&[("agent", &agent.to_string())]));
            let (status, body) = get_json(lrs, &uri).await;
            assert_eq!(status, StatusCode::OK, "{body}");
            body
        }
    };
    // An Agent the LRS has never seen still gets its Person object.
    assert_eq!(
        person(
            json!({ "objectType": "Agent", "name": "xAPI mbox", "mbox": "mailto:xapi@adlnet.gov" })
        )
        .await,
        json!({ "objectType": "Person", "name": ["xAPI mbox"], "mbox": ["mailto:xapi@adlnet.gov"] })
    );
    let sha = "cd9b00a5611f94eaa7b1661edab976068e364975";
    assert_eq!(
        person(json!({ "mbox_sha1sum": sha })).await,
        json!({ "objectType": "Person", "mbox_sha1sum": [sha] })
    );
    assert_eq!(
        person(json!({ "openid": "http://openid.example.org/12345" })).await,
        json!({ "objectType": "Person", "openid": ["http://openid.example.org/12345"] })
    );
    let account = json!({ "homePage": "http://www.example.com/agentId/1", "name": "Rick James" });
    assert_eq!(
        person(json!({ "objectType": "Agent", "account": account })).await,
        json!({ "objectType": "Person", "account": [account] })
    );
    // HEAD works like GET.
    let uri = format!(
        "/xapi/agents?{}",
        query(&[("agent", &mbox_agent().to_string())])
    );
    let (status, _, body) = exchange(&lrs, Method::HEAD, &uri, &[], None).await;
    assert_eq!((status, body.len()), (StatusCode::OK, 0));
}

#[tokio::test]
async fn xapi_documents_activities_resource_returns_the_activity() {
    let lrs = Lrs::new().await;
    let uri = |id: &str| format!("/xapi/activities?{}", query(&[("activityId", id)]));
    // Unknown: still an Activity object.
    let unknown = "http://www.example.com/never-before-seen-activityId/1";
    assert_eq!(
        get_json(&lrs, &uri(unknown)).await,
        (
            StatusCode::OK,
            json!({ "objectType": "Activity", "id": unknown })
        )
    );
    // Known: with the canonical definition the Statement resource keeps in xapi_activities.
    let definition = json!({
        "type": "http://adlnet.gov/expapi/activities/meeting",
        "name": { "en-US": "example meeting", "fr-FR": "réunion" },
    });
    sqlx::query(
        "INSERT INTO xapi_activities (activity_id, definition) VALUES ($1, $2), ($3, '{}')",
    )
    .bind(ACTIVITY)
    .bind(&definition)
    .bind("http://example.org/no-definition")
    .execute(lrs.app.pool())
    .await
    .unwrap();
    assert_eq!(
        get_json(&lrs, &uri(ACTIVITY)).await,
        (
            StatusCode::OK,
            json!({ "objectType": "Activity", "id": ACTIVITY, "definition": definition })
        )
    );
    assert_eq!(
        get_json(&lrs, &uri("http://example.org/no-definition"))
            .await
            .1,
        json!({ "objectType": "Activity", "id": "http://example.org/no-definition" })
    );
    let (status, _, body) = exchange(&lrs, Method::HEAD, &uri(ACTIVITY), &[], None).await;
    assert_eq!((status, body.len()), (StatusCode::OK, 0));
}

/// One route of the authorization matrix: method, path and a query that names a document.
fn routes() -> Vec<(Method, String)> {
    let agent = mbox_agent().to_string();
    let state = format!(
        "/xapi/activities/state?{}",
        query(&[
            ("activityId", ACTIVITY),
            ("agent", &agent),
            ("stateId", "m")
        ])
    );
    let ap = format!(
        "/xapi/activities/profile?{}",
        query(&[("activityId", ACTIVITY), ("profileId", "m")])
    );
    let gp = format!(
        "/xapi/agents/profile?{}",
        query(&[("agent", &agent), ("profileId", "m")])
    );
    let mut out = Vec::new();
    for uri in [&state, &ap, &gp] {
        for m in [Method::GET, Method::PUT, Method::POST, Method::DELETE] {
            out.push((m, uri.clone()));
        }
    }
    out.push((
        Method::GET,
        format!("/xapi/agents?{}", query(&[("agent", &agent)])),
    ));
    out.push((
        Method::GET,
        format!("/xapi/activities?{}", query(&[("activityId", ACTIVITY)])),
    ));
    out
}

#[tokio::test]
async fn xapi_documents_authorization_matrix() {
    // Every route of these resources x no credential / revoked / read-only / write-only /
    // read-write. GETs find the document a read-write PUT stored first (200); a write stores
    // with If-Match: * against that document (204).
    let lrs = Lrs::new().await;
    let read_only = lrs.credential("LMS read-only", true, false).await;
    let write_only = lrs.credential("LMS write-only", false, true).await;
    let revoked = lrs.credential("LMS revoked", true, true).await;
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

    let routes = routes();
    // The matrix covers every documented route of these resources.
    let doc = lrs
        .app
        .send(Method::GET, "/api/openapi.json", None, None)
        .await
        .json;
    let mut documented = Vec::new();
    for (path, item) in doc["paths"].as_object().unwrap() {
        let ours = [
            "/xapi/activities/state",
            "/xapi/activities/profile",
            "/xapi/agents/profile",
            "/xapi/agents",
            "/xapi/activities",
        ];
        if ours.contains(&path.as_str()) {
            for m in ["get", "put", "post", "delete"] {
                if item.get(m).is_some() {
                    documented.push(format!("{} {path}", m.to_uppercase()));
                }
            }
        }
    }
    let mut covered: Vec<String> = routes
        .iter()
        .map(|(m, uri)| format!("{m} {}", uri.split('?').next().unwrap()))
        .collect();
    documented.sort();
    covered.sort();
    assert_eq!(documented, covered, "every documented route has a row");

    let who: [(&str, Option<&Cred>); 5] = [
        ("none", None),
        ("revoked", Some(&revoked)),
        ("read-only", Some(&read_only)),
        ("write-only", Some(&write_only)),
        ("read-write", Some(&lrs.cred)),
    ];
    for (method, uri) in &routes {
        for (name, cred) in &who {
            // Each cell starts from the stored document.
            if uri.contains("?")
                && !uri.starts_with("/xapi/agents?")
                && !uri.starts_with("/xapi/activities?")
            {
                let r = lrs
                    .raw(
                        Method::PUT,
                        uri,
                        Some(&lrs.cred),
                        &[("if-match", "*")],
                        Some(("application/json", b"{}".to_vec())),
                    )
                    .await;
                if r.status == StatusCode::PRECONDITION_FAILED {
                    let r = lrs
                        .raw(
                            Method::PUT,
                            uri,
                            Some(&lrs.cred),
                            &[],
                            Some(("application/json", b"{}".to_vec())),
                        )
                        .await;
                    assert_eq!(r.status, StatusCode::NO_CONTENT);
                }
            }
            let write = *method != Method::GET;
            let expected = match (*name, write) {
                ("none" | "revoked", _) => 401,
                ("read-only", true) | ("write-only", false) => 403,
                (_, true) => 204,
                (_, false) => 200,
            };
            let body = matches!(*method, Method::PUT | Method::POST)
                .then(|| ("application/json", b"{\"v\":1}".to_vec()));
            let r = lrs
                .raw(method.clone(), uri, *cred, &[("if-match", "*")], body)
                .await;
            assert_eq!(
                r.status.as_u16(),
                expected,
                "{name} {method} {uri}: {}",
                r.text
            );
            if expected == 401 {
                assert!(r.headers.contains_key("www-authenticate"));
            }
        }
    }
}

#[tokio::test]
async fn xapi_documents_body_limit_is_413() {
    let lrs = Lrs::new().await;
    let uri = state_uri(&mbox_agent(), "big", None);
    // The server-wide limit (PAINSIM_MAX_BODY_BYTES, 1 MiB by default): at the limit is stored...
    let limit = 1 << 20;
    let exact: Vec<u8> = (0..limit).map(|i| (i % 251) as u8).collect();
    let (status, _, _) = exchange(
        &lrs,
        Method::PUT,
        &uri,
        &[],
        Some(("application/octet-stream", exact.clone())),
    )
    .await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    assert_eq!(exchange(&lrs, Method::GET, &uri, &[], None).await.2, exact);
    // ... one byte more is 413, and nothing changes.
    let over = vec![7u8; limit + 1];
    let r = lrs
        .raw(
            Method::POST,
            &state_uri(&mbox_agent(), "bigger", None),
            Some(&lrs.cred),
            &[],
            Some(("application/octet-stream", over)),
        )
        .await;
    assert_eq!(r.status, StatusCode::PAYLOAD_TOO_LARGE);
    assert_eq!(r.json["error"]["code"], "payload_too_large");
    assert_eq!(
        get_json(&lrs, &state_uri(&mbox_agent(), "bigger", None))
            .await
            .0,
        StatusCode::NOT_FOUND
    );
}
