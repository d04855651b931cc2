//! Fixtures of the document-resource tests (State, Activity Profile, Agent Profile): the
//! Activity and Agent they use, query strings, the three resources' URIs, and raw exchanges with
//! the read-write credential.

use axum::body::Body;
use axum::http::{HeaderMap, Method, Request, StatusCode};
use serde_json::{Value, json};
use time::OffsetDateTime;
use tower::ServiceExt;

use crate::xapi_support::Lrs;

/// The Activity of the fixtures.
pub(crate) const ACTIVITY: &str = "http://example.org/xapi/activities/lumbar-epidural";

/// The Agent of the fixtures, identified by its mbox.
pub(crate) fn mbox_agent() -> Value {
    json!({ "objectType": "Agent", "mbox": "mailto:learner@example.org" })
}

/// Percent-encodes a query value (everything but RFC 3986 unreserved characters).
pub(crate) fn enc(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' => {
                (b as char).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// A query string from name-value pairs.
pub(crate) fn query(pairs: &[(&str, &str)]) -> String {
    pairs
        .iter()
        .map(|(k, v)| format!("{k}={}", enc(v)))
        .collect::<Vec<_>>()
        .join("&")
}

/// The three document resources: path and the parameters of one document named `id` (`agent`
/// given as JSON).
pub(crate) fn resources(agent: &Value, id: &str) -> Vec<(&'static str, String)> {
    let agent = agent.to_string();
    vec![
        (
            "/xapi/activities/state",
            query(&[("activityId", ACTIVITY), ("agent", &agent), ("stateId", id)]),
        ),
        (
            "/xapi/activities/profile",
            query(&[("activityId", ACTIVITY), ("profileId", id)]),
        ),
        (
            "/xapi/agents/profile",
            query(&[("agent", &agent), ("profileId", id)]),
        ),
    ]
}

/// The State URI of the document `id` of `agent` (and of `registration`, if given).
pub(crate) fn state_uri(agent: &Value, id: &str, registration: Option<&str>) -> String {
    let agent = agent.to_string();
    let mut pairs = vec![
        ("activityId", ACTIVITY),
        ("agent", agent.as_str()),
        ("stateId", id),
    ];
    if let Some(r) = registration {
        pairs.push(("registration", r));
    }
    format!("/xapi/activities/state?{}", query(&pairs))
}

/// A raw exchange with the read-write credential: status, headers and the body's bytes.
pub(crate) async fn exchange(
    lrs: &Lrs,
    method: Method,
    uri: &str,
    headers: &[(&str, &str)],
    body: Option<(&str, Vec<u8>)>,
) -> (StatusCode, HeaderMap, Vec<u8>) {
    let mut req = Request::builder()
        .method(method)
        .uri(uri)
        .header("x-experience-api-version", "2.0.0")
        .header("authorization", lrs.cred.basic());
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let body = match body {
        Some((ct, bytes)) => {
            req = req.header("content-type", ct);
            Body::from(bytes)
        }
        None => Body::empty(),
    };
    let resp = lrs
        .app
        .router
        .clone()
        .oneshot(req.body(body).unwrap())
        .await
        .unwrap();
    let status = resp.status();
    let headers = resp.headers().clone();
    let bytes = axum::body::to_bytes(resp.into_body(), 8 << 20)
        .await
        .unwrap()
        .to_vec();
    (status, headers, bytes)
}

/// PUT of a JSON document with the read-write credential: the status.
pub(crate) async fn put_json(
    lrs: &Lrs,
    uri: &str,
    headers: &[(&str, &str)],
    doc: &Value,
) -> StatusCode {
    let body = Some(("application/json", doc.to_string().into_bytes()));
    lrs.raw(Method::PUT, uri, Some(&lrs.cred), headers, body)
        .await
        .status
}

/// POST of a JSON document with the read-write credential: the status.
pub(crate) async fn post_json(
    lrs: &Lrs,
    uri: &str,
    headers: &[(&str, &str)],
    doc: &Value,
) -> StatusCode {
    let body = Some(("application/json", doc.to_string().into_bytes()));
    lrs.raw(Method::POST, uri, Some(&lrs.cred), headers, body)
        .await
        .status
}

/// GET with the read-write credential: the status and the JSON body.
pub(crate) async fn get_json(lrs: &Lrs, uri: &str) -> (StatusCode, Value) {
    let r = lrs.send(Method::GET, uri, None).await;
    (r.status, r.json)
}

/// The ETag of a stored document (its GET must answer 200).
pub(crate) async fn etag(lrs: &Lrs, uri: &str) -> String {
    let r = lrs.raw(Method::GET, uri, Some(&lrs.cred), &[], None).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    r.headers["etag"].to_str().unwrap().to_owned()
}

/// The `Last-Modified` of a response, as a time.
pub(crate) fn http_date(headers: &HeaderMap) -> OffsetDateTime {
    let text = headers["last-modified"].to_str().unwrap();
    let format = time::format_description::parse(
        "[weekday repr:short], [day] [month repr:short] [year] [hour]:[minute]:[second] GMT",
    )
    .unwrap();
    time::PrimitiveDateTime::parse(text, &format)
        .unwrap_or_else(|e| panic!("Last-Modified {text:?}: {e}"))
        .assume_utc()
}
