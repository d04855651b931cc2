//! The LRS's document resources (State, Activity Profile, Agent Profile) and its Agents and
//! Activities resources, tested from the xAPI 2.0 specification (IEEE 9274.1.1, Communication
//! "Document Resources", "State Resource", "Agents Resource", "Activities Resource", "Agent
//! Profile Resource", "Activity Profile Resource", "Concurrency", "Error Codes"): storage of any
//! content byte-exact, the JSON merge of POST, ETags and the 409/412 concurrency rules,
//! Last-Modified and `since`, deletes, agent equivalence, registration scoping, refusals of bad
//! parameters, HEAD, the body limit, and the authorization of every route.

use std::time::Duration;

use axum::body::Body;
use axum::http::{HeaderMap, Method, Request, StatusCode};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use time::OffsetDateTime;
use tower::ServiceExt;

use crate::xapi_support::Lrs;

pub(crate) const ACTIVITY: &str = "http://example.org/xapi/activities/lumbar-epidural";

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

pub(crate) async fn get_json(lrs: &Lrs, uri: &str) -> (StatusCode, Value) {
    let r = lrs.send(Method::GET, uri, None).await;
    (r.status, r.json)
}

pub(crate) async fn etag(lrs: &Lrs, uri: &str) -> String {
    let r = lrs.raw(Method::GET, uri, Some(&lrs.cred), &[], None).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    r.headers["etag"].to_str().unwrap().to_owned()
}

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

#[tokio::test]
async fn xapi_documents_store_any_content_byte_exact_with_etag_and_last_modified() {
    let lrs = Lrs::new().await;
    let uri = state_uri(&mbox_agent(), "bookmark", None);
    // Every byte value, NUL included, under a non-JSON content type.
    let binary: Vec<u8> = (0..=255u8).cycle().take(4096).collect();
    let before = OffsetDateTime::now_utc();
    let (status, headers, _) = exchange(
        &lrs,
        Method::PUT,
        &uri,
        &[],
        Some(("image/png", binary.clone())),
    )
    .await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let expected_etag = format!("\"{}\"", hex::encode(Sha256::digest(&binary)));
    assert_eq!(
        headers["etag"],
        expected_etag.as_str(),
        "the PUT names its ETag"
    );
    let after = OffsetDateTime::now_utc();
    let (status, headers, bytes) = exchange(&lrs, Method::GET, &uri, &[], None).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(bytes, binary, "stored byte-exact");
    assert_eq!(headers["content-type"], "image/png");
    assert_eq!(headers["etag"], expected_etag.as_str());
    // Last-Modified has a resolution of one second (RFC 9110 5.6.7): within the PUT's second.
    let modified = http_date(&headers);
    assert!(
        modified >= before.replace_nanosecond(0).unwrap() && modified <= after,
        "{modified} not within [{before}, {after}]"
    );

    // JSON is stored as sent too (spacing, key order), with its parameters.
    let text = "{ \"z\": 1,\n  \"a\": \"\\u0000 nul\" }";
    let (status, _, _) = exchange(
        &lrs,
        Method::PUT,
        &uri,
        &[("if-match", &expected_etag)],
        Some(("application/json; charset=utf-8", text.as_bytes().to_vec())),
    )
    .await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let (_, headers, bytes) = exchange(&lrs, Method::GET, &uri, &[], None).await;
    assert_eq!(bytes, text.as_bytes());
    assert_eq!(headers["content-type"], "application/json; charset=utf-8");

    // No Content-Type at all: application/octet-stream (RFC 9110 8.3).
    let uri2 = state_uri(&mbox_agent(), "untyped", None);
    let mut req = Request::builder()
        .method(Method::PUT)
        .uri(&uri2)
        .header("x-experience-api-version", "2.0.0")
        .header("authorization", lrs.cred.basic());
    req = req.header("if-none-match", "*");
    let r = lrs
        .app
        .request(req.body(Body::from("plain bytes")).unwrap())
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    let (_, headers, bytes) = exchange(&lrs, Method::GET, &uri2, &[], None).await;
    assert_eq!(bytes, b"plain bytes");
    assert_eq!(headers["content-type"], "application/octet-stream");

    // HEAD: the GET's status and headers, no body.
    let (status, headers, bytes) = exchange(&lrs, Method::HEAD, &uri, &[], None).await;
    assert_eq!(status, StatusCode::OK);
    assert!(headers.contains_key("etag"));
    assert!(bytes.is_empty());

    // DELETE, then the document is gone; deleting again is still 204.
    for _ in 0..2 {
        let (status, _, _) = exchange(&lrs, Method::DELETE, &uri, &[], None).await;
        assert_eq!(status, StatusCode::NO_CONTENT);
    }
    let (status, _, _) = exchange(&lrs, Method::GET, &uri, &[], None).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let r = lrs.raw(Method::GET, &uri, Some(&lrs.cred), &[], None).await;
    assert_eq!(r.json["error"]["code"], "not_found", "an XapiError body");
}

#[tokio::test]
async fn xapi_documents_post_merges_json_objects_and_refuses_other_merges() {
    let lrs = Lrs::new().await;
    for (path, params) in resources(&mbox_agent(), "merge") {
        let uri = format!("{path}?{params}");
        // POST to a missing document stores it as PUT would.
        let first = json!({ "x": "foo", "y": "bar", "car": { "make": "Ford", "model": "Escape" } });
        assert_eq!(
            post_json(&lrs, &uri, &[], &first).await,
            StatusCode::NO_CONTENT
        );
        // Top-level properties are replaced whole (Communication 2.2 "JSON Procedure").
        let second = json!({ "x": "bash", "z": "faz", "car": { "make": "Dodge" } });
        assert_eq!(
            post_json(&lrs, &uri, &[], &second).await,
            StatusCode::NO_CONTENT
        );
        let merged = json!({ "x": "bash", "y": "bar", "z": "faz", "car": { "make": "Dodge" } });
        assert_eq!(
            get_json(&lrs, &uri).await,
            (StatusCode::OK, merged.clone()),
            "{path}"
        );

        // A non-JSON document posted onto a JSON one: 400, nothing changes.
        let r = lrs
            .raw(
                Method::POST,
                &uri,
                Some(&lrs.cred),
                &[],
                Some(("text/plain", b"abcdefg".to_vec())),
            )
            .await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{path}: {}", r.text);
        // JSON that is not an object, or not JSON at all: 400, nothing changes.
        for bad in ["[1, 2]", "\"text\"", "{\"unclosed\": ", "{}["] {
            let body = Some(("application/json", bad.as_bytes().to_vec()));
            let r = lrs
                .raw(Method::POST, &uri, Some(&lrs.cred), &[], body)
                .await;
            assert_eq!(
                r.status,
                StatusCode::BAD_REQUEST,
                "{path} {bad}: {}",
                r.text
            );
        }
        assert_eq!(
            get_json(&lrs, &uri).await,
            (StatusCode::OK, merged),
            "{path} unchanged"
        );

        // A stored non-JSON document cannot take a JSON merge: 400, nothing changes.
        let etag_now = etag(&lrs, &uri).await;
        let body = Some(("application/octet-stream", b"/ asdf / undefined".to_vec()));
        let r = lrs
            .raw(
                Method::PUT,
                &uri,
                Some(&lrs.cred),
                &[("if-match", &etag_now)],
                body,
            )
            .await;
        assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
        assert_eq!(
            post_json(&lrs, &uri, &[], &json!({ "a": 1 })).await,
            StatusCode::BAD_REQUEST
        );
        let (_, headers, bytes) = exchange(&lrs, Method::GET, &uri, &[], None).await;
        assert_eq!(bytes, b"/ asdf / undefined");
        assert_eq!(headers["content-type"], "application/octet-stream");
    }
    // A POSTed JSON value that is not an object never creates a document.
    let uri = state_uri(&mbox_agent(), "array", None);
    let r = lrs
        .raw(
            Method::POST,
            &uri,
            Some(&lrs.cred),
            &[],
            Some(("application/json", b"[1]".to_vec())),
        )
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST);
    assert_eq!(get_json(&lrs, &uri).await.0, StatusCode::NOT_FOUND);
    // NUL in JSON strings is data like any other (the document is stored as bytes).
    let nul = json!({ "k\u{0}": "v\u{0}" });
    assert_eq!(
        post_json(&lrs, &uri, &[], &nul).await,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        post_json(&lrs, &uri, &[], &json!({ "more": "\u{0}" })).await,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        get_json(&lrs, &uri).await,
        (
            StatusCode::OK,
            json!({ "k\u{0}": "v\u{0}", "more": "\u{0}" })
        )
    );
}

#[tokio::test]
async fn xapi_documents_concurrency_etags_409_and_412() {
    let lrs = Lrs::new().await;
    for (path, params) in resources(&mbox_agent(), "concurrency") {
        let uri = format!("{path}?{params}");
        let v1 = json!({ "name": "one" });
        let v2 = json!({ "name": "two" });
        // If-Match on a missing document fails; If-None-Match: * creates it.
        assert_eq!(
            put_json(&lrs, &uri, &[("if-match", "*")], &v1).await,
            StatusCode::PRECONDITION_FAILED
        );
        assert_eq!(get_json(&lrs, &uri).await.0, StatusCode::NOT_FOUND);
        assert_eq!(
            put_json(&lrs, &uri, &[("if-none-match", "*")], &v1).await,
            StatusCode::NO_CONTENT
        );
        let tag = etag(&lrs, &uri).await;
        assert!(
            tag.starts_with('"') && tag.ends_with('"') && tag.len() == 66,
            "{tag}"
        );
        // A PUT with neither header to an existing document: 409 with an explanation, unchanged.
        let r = lrs
            .raw(
                Method::PUT,
                &uri,
                Some(&lrs.cred),
                &[],
                Some(("application/json", v2.to_string().into_bytes())),
            )
            .await;
        assert_eq!(r.status, StatusCode::CONFLICT, "{path}");
        assert!(
            r.json["error"]["message"]
                .as_str()
                .unwrap()
                .contains("If-Match")
        );
        // Wrong tags fail with 412 on PUT, POST and DELETE, and change nothing.
        for wrong in [
            ("if-match", "\"1234\""),
            ("if-none-match", "*"),
            ("if-none-match", tag.as_str()),
        ] {
            assert_eq!(
                put_json(&lrs, &uri, &[wrong], &v2).await,
                StatusCode::PRECONDITION_FAILED,
                "{path} {wrong:?}"
            );
            assert_eq!(
                post_json(&lrs, &uri, &[wrong], &v2).await,
                StatusCode::PRECONDITION_FAILED,
                "{path} {wrong:?}"
            );
            let r = lrs
                .raw(Method::DELETE, &uri, Some(&lrs.cred), &[wrong], None)
                .await;
            assert_eq!(
                r.status,
                StatusCode::PRECONDITION_FAILED,
                "{path} {wrong:?}"
            );
        }
        // A weak tag never matches If-Match (strong comparison, RFC 9110 13.1.1).
        let weak = format!("W/{tag}");
        assert_eq!(
            put_json(&lrs, &uri, &[("if-match", &weak)], &v2).await,
            StatusCode::PRECONDITION_FAILED
        );
        assert_eq!(
            get_json(&lrs, &uri).await,
            (StatusCode::OK, v1.clone()),
            "{path} unchanged"
        );
        // The right tag (in a list, too) passes; the ETag then changes.
        let list = format!("\"nope\", {tag}");
        assert_eq!(
            put_json(&lrs, &uri, &[("if-match", &list)], &v2).await,
            StatusCode::NO_CONTENT
        );
        assert_eq!(get_json(&lrs, &uri).await, (StatusCode::OK, v2.clone()));
        let tag2 = etag(&lrs, &uri).await;
        assert_ne!(tag, tag2);
        // The old tag is stale now.
        assert_eq!(
            post_json(&lrs, &uri, &[("if-match", &tag)], &v1).await,
            StatusCode::PRECONDITION_FAILED
        );
        assert_eq!(
            post_json(&lrs, &uri, &[("if-match", &tag2)], &json!({ "more": 1 })).await,
            StatusCode::NO_CONTENT
        );
        let tag3 = etag(&lrs, &uri).await;
        // If-Match: * passes on an existing document; DELETE with the right tag deletes.
        assert_eq!(
            post_json(&lrs, &uri, &[("if-match", "*")], &json!({})).await,
            StatusCode::NO_CONTENT
        );
        assert_eq!(etag(&lrs, &uri).await, tag3, "merging {{}} changes nothing");
        let r = lrs
            .raw(
                Method::DELETE,
                &uri,
                Some(&lrs.cred),
                &[("if-match", &tag3)],
                None,
            )
            .await;
        assert_eq!(r.status, StatusCode::NO_CONTENT);
        assert_eq!(get_json(&lrs, &uri).await.0, StatusCode::NOT_FOUND);
        // POST and DELETE without headers are not refused (2.0 asks the headers of PUT only).
        assert_eq!(
            post_json(&lrs, &uri, &[], &v1).await,
            StatusCode::NO_CONTENT
        );
        assert_eq!(
            post_json(&lrs, &uri, &[], &v2).await,
            StatusCode::NO_CONTENT
        );
        let r = lrs
            .raw(Method::DELETE, &uri, Some(&lrs.cred), &[], None)
            .await;
        assert_eq!(r.status, StatusCode::NO_CONTENT);
    }
}

#[tokio::test]
async fn xapi_documents_concurrent_posts_all_merge() {
    // Sixteen concurrent POSTs of different properties to one new document: the row lock and
    // the insert race retry serialise them, so the document ends with all sixteen.
    let lrs = Lrs::new().await;
    let uri = state_uri(&mbox_agent(), "race", None);
    let posts = (0..16).map(|i| {
        let lrs = &lrs;
        let uri = uri.clone();
        async move { post_json(lrs, &uri, &[], &json!({ format!("k{i}"): i })).await }
    });
    for status in futures::future::join_all(posts).await {
        assert_eq!(status, StatusCode::NO_CONTENT);
    }
    let (status, doc) = get_json(&lrs, &uri).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(doc.as_object().unwrap().len(), 16, "{doc}");
}

#[tokio::test]
async fn xapi_documents_ids_since_and_delete_all() {
    let lrs = Lrs::new().await;
    let agent = mbox_agent().to_string();
    let ids_uri = |extra: &[(&str, &str)]| {
        let mut pairs = vec![("activityId", ACTIVITY), ("agent", agent.as_str())];
        pairs.extend_from_slice(extra);
        format!("/xapi/activities/state?{}", query(&pairs))
    };
    let (status, ids) = get_json(&lrs, &ids_uri(&[])).await;
    assert_eq!(
        (status, ids),
        (StatusCode::OK, json!([])),
        "no documents: an empty array"
    );

    assert_eq!(
        post_json(&lrs, &state_uri(&mbox_agent(), "s1", None), &[], &json!({})).await,
        StatusCode::NO_CONTENT
    );
    // `since` compares the database's clock with ours (one machine): 50 ms apart is our margin.
    tokio::time::sleep(Duration::from_millis(50)).await;
    let between = OffsetDateTime::now_utc();
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(
        post_json(&lrs, &state_uri(&mbox_agent(), "s2", None), &[], &json!({})).await,
        StatusCode::NO_CONTENT
    );
    let r = lrs
        .raw(Method::GET, &ids_uri(&[]), Some(&lrs.cred), &[], None)
        .await;
    assert_eq!(r.json, json!(["s1", "s2"]));
    assert!(r.headers.contains_key("last-modified"), "of the newest");
    let fmt = |t: OffsetDateTime| {
        t.format(&time::format_description::well_known::Rfc3339)
            .unwrap()
    };
    let (_, ids) = get_json(&lrs, &ids_uri(&[("since", &fmt(between))])).await;
    assert_eq!(ids, json!(["s2"]), "since is exclusive of older documents");
    let later = OffsetDateTime::now_utc() + Duration::from_secs(3600);
    let (_, ids) = get_json(&lrs, &ids_uri(&[("since", &fmt(later))])).await;
    assert_eq!(ids, json!([]));
    // An offset other than Z is the same instant.
    let offset = between.to_offset(time::UtcOffset::from_hms(5, 30, 0).unwrap());
    let (_, ids) = get_json(&lrs, &ids_uri(&[("since", &fmt(offset))])).await;
    assert_eq!(ids, json!(["s2"]));
    // Updating s1 makes it newer than `between`.
    assert_eq!(
        post_json(
            &lrs,
            &state_uri(&mbox_agent(), "s1", None),
            &[],
            &json!({ "a": 1 })
        )
        .await,
        StatusCode::NO_CONTENT
    );
    let (_, ids) = get_json(&lrs, &ids_uri(&[("since", &fmt(between))])).await;
    assert_eq!(ids, json!(["s2", "s1"]));

    // Another activity's states are not listed, nor deleted with these.
    let other = format!(
        "/xapi/activities/state?{}",
        query(&[
            ("activityId", "http://example.org/other"),
            ("agent", &agent),
            ("stateId", "s1")
        ])
    );
    assert_eq!(
        post_json(&lrs, &other, &[], &json!({})).await,
        StatusCode::NO_CONTENT
    );
    let r = lrs
        .raw(Method::DELETE, &ids_uri(&[]), Some(&lrs.cred), &[], None)
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT);
    assert_eq!(get_json(&lrs, &ids_uri(&[])).await.1, json!([]));
    assert_eq!(get_json(&lrs, &other).await.0, StatusCode::OK);

    // The profile resources list their ids the same way.
    let profiles = format!(
        "/xapi/activities/profile?{}",
        query(&[("activityId", ACTIVITY)])
    );
    let agent_profiles = format!("/xapi/agents/profile?{}", query(&[("agent", &agent)]));
    for (path, params) in resources(&mbox_agent(), "p1") {
        if path != "/xapi/activities/state" {
            assert_eq!(
                post_json(&lrs, &format!("{path}?{params}"), &[], &json!({})).await,
                StatusCode::NO_CONTENT
            );
        }
    }
    for list in [&profiles, &agent_profiles] {
        assert_eq!(
            get_json(&lrs, list).await,
            (StatusCode::OK, json!(["p1"])),
            "{list}"
        );
        let (_, ids) = get_json(&lrs, &format!("{list}&since={}", enc(&fmt(later)))).await;
        assert_eq!(ids, json!([]));
    }
}

#[tokio::test]
async fn xapi_documents_registration_scopes_states() {
    let lrs = Lrs::new().await;
    let r1 = "6f1c0c5e-3b8a-4f0e-9d2c-1b0a99887766";
    let r2 = "0b7a9d3e-1111-4222-8333-944455556666";
    let a = mbox_agent();
    assert_eq!(
        post_json(
            &lrs,
            &state_uri(&a, "s", None),
            &[],
            &json!({ "reg": "none" })
        )
        .await,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        post_json(
            &lrs,
            &state_uri(&a, "s", Some(r1)),
            &[],
            &json!({ "reg": 1 })
        )
        .await,
        StatusCode::NO_CONTENT
    );
    assert_eq!(
        post_json(
            &lrs,
            &state_uri(&a, "t", Some(r2)),
            &[],
            &json!({ "reg": 2 })
        )
        .await,
        StatusCode::NO_CONTENT
    );
    // The registration is part of a document's key.
    assert_eq!(
        get_json(&lrs, &state_uri(&a, "s", None)).await.1,
        json!({ "reg": "none" })
    );
    assert_eq!(
        get_json(&lrs, &state_uri(&a, "s", Some(r1))).await.1,
        json!({ "reg": 1 })
    );
    assert_eq!(
        get_json(&lrs, &state_uri(&a, "s", Some(r2))).await.0,
        StatusCode::NOT_FOUND
    );
    // Upper-case hex is the same UUID.
    assert_eq!(
        get_json(&lrs, &state_uri(&a, "s", Some(&r1.to_uppercase())))
            .await
            .1,
        json!({ "reg": 1 })
    );
    // Ids: of one registration when given, of all without (Activity + Agent [+ registration]).
    let agent = a.to_string();
    let ids = |reg: Option<&str>| {
        let mut pairs = vec![("activityId", ACTIVITY), ("agent", agent.as_str())];
        if let Some(r) = reg {
            pairs.push(("registration", r));
        }
        format!("/xapi/activities/state?{}", query(&pairs))
    };
    let mut all = get_json(&lrs, &ids(None))
        .await
        .1
        .as_array()
        .unwrap()
        .clone();
    all.sort_by_key(|v| v.as_str().unwrap().to_owned());
    assert_eq!(all, vec![json!("s"), json!("s"), json!("t")]);
    assert_eq!(get_json(&lrs, &ids(Some(r1))).await.1, json!(["s"]));
    assert_eq!(get_json(&lrs, &ids(Some(r2))).await.1, json!(["t"]));
    // DELETE all of one registration leaves the others.
    let r = lrs
        .raw(Method::DELETE, &ids(Some(r1)), Some(&lrs.cred), &[], None)
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT);
    assert_eq!(
        get_json(&lrs, &state_uri(&a, "s", Some(r1))).await.0,
        StatusCode::NOT_FOUND
    );
    assert_eq!(
        get_json(&lrs, &state_uri(&a, "s", None)).await.0,
        StatusCode::OK
    );
    assert_eq!(
        get_json(&lrs, &state_uri(&a, "t", Some(r2))).await.0,
        StatusCode::OK
    );
    // Without a registration, DELETE takes every registration's states.
    let r = lrs
        .raw(Method::DELETE, &ids(None), Some(&lrs.cred), &[], None)
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT);
    assert_eq!(get_json(&lrs, &ids(None)).await.1, json!([]));
}

#[tokio::test]
async fn xapi_documents_agents_are_keyed_by_identity() {
    let lrs = Lrs::new().await;
    let bare = json!({ "mbox": "mailto:learner@example.org" });
    let named =
        json!({ "objectType": "Agent", "name": "A Learner", "mbox": "mailto:learner@example.org" });
    let other = json!({ "objectType": "Agent", "mbox": "mailto:someone-else@example.org" });
    let account = json!({ "account": { "homePage": "https://lms.example.org", "name": "u-17" } });
    let account_named = json!({ "name": "U", "account": { "name": "u-17", "homePage": "https://lms.example.org" } });
    for ((path, stored), (_, same)) in resources(&bare, "who")
        .into_iter()
        .zip(resources(&named, "who"))
    {
        if path == "/xapi/activities/profile" {
            continue;
        }
        assert_eq!(
            put_json(&lrs, &format!("{path}?{stored}"), &[], &json!({ "n": 1 })).await,
            StatusCode::NO_CONTENT
        );
        assert_eq!(
            get_json(&lrs, &format!("{path}?{same}")).await,
            (StatusCode::OK, json!({ "n": 1 })),
            "{path}"
        );
    }
    for (path, params) in resources(&other, "who") {
        if path != "/xapi/activities/profile" {
            assert_eq!(
                get_json(&lrs, &format!("{path}?{params}")).await.0,
                StatusCode::NOT_FOUND,
                "{path}"
            );
        }
    }
    for ((path, stored), (_, same)) in resources(&account, "acct")
        .into_iter()
        .zip(resources(&account_named, "acct"))
    {
        if path == "/xapi/activities/profile" {
            continue;
        }
        assert_eq!(
            put_json(&lrs, &format!("{path}?{stored}"), &[], &json!({ "n": 2 })).await,
            StatusCode::NO_CONTENT
        );
        assert_eq!(
            get_json(&lrs, &format!("{path}?{same}")).await.1,
            json!({ "n": 2 }),
            "{path}"
        );
    }
    // An identified Group's profile is the Agent's with the same identifier (Agent Profile note).
    let group = json!({ "objectType": "Group", "mbox": "mailto:learner@example.org" });
    let (path, params) = resources(&group, "who").remove(2);
    assert_eq!(
        get_json(&lrs, &format!("{path}?{params}")).await,
        (StatusCode::OK, json!({ "n": 1 }))
    );
}

#[tokio::test]
async fn xapi_documents_refuse_bad_parameters_with_400() {
    let lrs = Lrs::new().await;
    let agent = mbox_agent().to_string();
    let doc = json!({ "a": 1 });
    let state = |pairs: &[(&str, &str)]| format!("/xapi/activities/state?{}", query(pairs));
    let base = [
        ("activityId", ACTIVITY),
        ("agent", agent.as_str()),
        ("stateId", "s"),
    ];
    let without = |name: &str| -> Vec<(&str, &str)> {
        base.iter().copied().filter(|(k, _)| *k != name).collect()
    };
    let with = |name: &'static str, value: &'static str| -> Vec<(&str, &str)> {
        let mut v: Vec<(&str, &str)> = base.iter().copied().filter(|(k, _)| *k != name).collect();
        v.push((name, value));
        v
    };
    let mut bad: Vec<(Method, String)> = Vec::new();
    for m in [Method::PUT, Method::POST, Method::GET, Method::DELETE] {
        bad.push((m.clone(), state(&without("activityId"))));
        bad.push((m.clone(), state(&without("agent"))));
        for (name, value) in [
            ("agent", "not JSON"),
            ("agent", "true"),
            (
                "agent",
                "{\"objectType\":\"Agent\",\"name\":\"no identifier\"}",
            ),
            ("agent", "{\"mbox\":\"learner@example.org\"}"),
            (
                "agent",
                "{\"mbox\":\"mailto:a@example.org\",\"openid\":\"http://id.example.org/a\"}",
            ),
            ("agent", "{\"account\":{\"name\":\"no home page\"}}"),
            ("agent", "{\"mbox\":\"mailto:a\\u0000@example.org\"}"),
            ("activityId", "true"),
            ("activityId", "undefined"),
            ("activityId", "{\"key\":\"value\"}"),
            ("activityId", "http://example.org/has space"),
            ("registration", "true"),
            ("registration", "6f1c0c5e3b8a4f0e9d2c1b0a99887766"),
            ("stateId", ""),
            ("stateId", "nul\u{0}"),
        ] {
            bad.push((m.clone(), state(&with(name, value))));
        }
        // Unknown, repeated and wrongly cased parameters (Communication 3.2).
        bad.push((m.clone(), format!("{}&foo=bar", state(&base))));
        bad.push((m.clone(), format!("{}&stateId=again", state(&base))));
        bad.push((
            m.clone(),
            state(&[
                ("activityId", ACTIVITY),
                ("agent", &agent),
                ("StateId", "s"),
            ]),
        ));
    }
    for m in [Method::PUT, Method::POST] {
        bad.push((m, state(&without("stateId"))));
    }
    bad.push((
        Method::DELETE,
        format!("{}&since=2026-01-01T00:00:00Z", state(&base)),
    ));
    bad.push((
        Method::GET,
        state(&[
            ("activityId", ACTIVITY),
            ("agent", &agent),
            ("since", "not a timestamp"),
        ]),
    ));
    bad.push((
        Method::GET,
        state(&[
            ("activityId", ACTIVITY),
            ("agent", &agent),
            ("since", "true"),
        ]),
    ));
    bad.push((
        Method::GET,
        state(&[
            ("activityId", ACTIVITY),
            ("agent", &agent),
            ("since", "2026-01-01T00:00:00"),
        ]),
    ));
    // The profile resources.
    let ap = |pairs: &[(&str, &str)]| format!("/xapi/activities/profile?{}", query(pairs));
    let gp = |pairs: &[(&str, &str)]| format!("/xapi/agents/profile?{}", query(pairs));
    for m in [Method::PUT, Method::POST, Method::GET, Method::DELETE] {
        bad.push((m.clone(), ap(&[("profileId", "p")])));
        bad.push((m.clone(), ap(&[("activityId", "true"), ("profileId", "p")])));
        bad.push((
            m.clone(),
            ap(&[
                ("activityId", ACTIVITY),
                ("profileId", "p"),
                ("agent", &agent),
            ]),
        ));
        bad.push((m.clone(), gp(&[("profileId", "p")])));
        bad.push((m.clone(), gp(&[("agent", "true"), ("profileId", "p")])));
        bad.push((
            m.clone(),
            gp(&[
                ("agent", &agent),
                ("profileId", "p"),
                ("activityId", ACTIVITY),
            ]),
        ));
    }
    for m in [Method::PUT, Method::POST, Method::DELETE] {
        bad.push((m.clone(), ap(&[("activityId", ACTIVITY)])));
        bad.push((m.clone(), gp(&[("agent", &agent)])));
    }
    bad.push((
        Method::GET,
        ap(&[("activityId", ACTIVITY), ("since", "yesterday")]),
    ));
    bad.push((
        Method::GET,
        gp(&[("agent", &agent), ("since", "yesterday")]),
    ));
    // Agents and Activities.
    bad.push((Method::GET, "/xapi/agents".into()));
    bad.push((
        Method::GET,
        format!(
            "/xapi/agents?{}",
            query(&[(
                "agent",
                "{\"name\":\"Rick James\",\"objectType\":\"Agent\"}"
            )])
        ),
    ));
    bad.push((
        Method::GET,
        format!(
            "/xapi/agents?{}",
            query(&[(
                "agent",
                "{\"objectType\":\"Group\",\"mbox\":\"mailto:g@example.org\"}"
            )])
        ),
    ));
    bad.push((
        Method::GET,
        format!("/xapi/agents?{}&x=1", query(&[("agent", &agent)])),
    ));
    bad.push((Method::GET, "/xapi/activities".into()));
    bad.push((Method::GET, "/xapi/activities?activityId=true".into()));
    bad.push((
        Method::GET,
        format!(
            "/xapi/activities?{}&ActivityId=x",
            query(&[("activityId", ACTIVITY)])
        ),
    ));

    for (method, uri) in &bad {
        let body = matches!(*method, Method::PUT | Method::POST)
            .then(|| ("application/json", doc.to_string().into_bytes()));
        let r = lrs
            .raw(method.clone(), uri, Some(&lrs.cred), &[], body)
            .await;
        assert_eq!(
            r.status,
            StatusCode::BAD_REQUEST,
            "{method} {uri}: {}",
            r.text
        );
        assert_eq!(r.json["error"]["code"], "bad_request", "{method} {uri}");
    }
    // Nothing was stored by any of them.
    let n: i64 = sqlx::query_scalar("SELECT count(*) FROM xapi_documents")
        .fetch_one(lrs.app.pool())
        .await
        .unwrap();
    assert_eq!(n, 0);
    // A PUT of application/json that is not JSON is refused as well.
    let r = lrs
        .raw(
            Method::PUT,
            &state(&base),
            Some(&lrs.cred),
            &[],
            Some(("application/json", b"{".to_vec())),
        )
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST);

    // Without the version header: 400 from the version middleware, before anything else.
    let req = Request::builder()
        .method(Method::GET)
        .uri(state(&base))
        .header("authorization", lrs.cred.basic())
        .body(Body::empty())
        .unwrap();
    let r = lrs.app.request(req).await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST);
    assert_eq!(r.headers["x-experience-api-version"], "2.0.0");
}
