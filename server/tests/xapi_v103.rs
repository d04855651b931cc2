//! xAPI 1.0.3 and 2.0.0 clients on one LRS endpoint: the version header each request is answered
//! with, the ETags each line sees for one stored document (SHA-1 for 1.0.x, SHA-256 for 2.0.x),
//! and the PUT preconditions of each line (1.0.3: profiles need a precondition header, State
//! does not; 2.0: only an existing document needs one).

use axum::http::{Method, StatusCode};
use serde_json::json;
use sha1::Sha1;
use sha2::{Digest, Sha256};

use crate::records_support::Response;
use crate::xapi_documents_support::{ACTIVITY, enc, mbox_agent, query, state_uri};
use crate::xapi_support::Lrs;

/// Sends an LRS request with the read-write credential, `version` as the version header (none
/// when `None`), the extra `headers` and a JSON or raw body.
pub(crate) async fn send_as(
    lrs: &Lrs,
    version: Option<&str>,
    method: Method,
    uri: &str,
    headers: &[(&str, &str)],
    body: Option<(&str, Vec<u8>)>,
) -> Response {
    let mut req = axum::http::Request::builder()
        .method(method)
        .uri(uri)
        .header("authorization", lrs.cred.basic());
    if let Some(v) = version {
        req = req.header("x-experience-api-version", v);
    }
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    let body = match body {
        Some((ct, bytes)) => {
            req = req.header("content-type", ct);
            axum::body::Body::from(bytes)
        }
        None => axum::body::Body::empty(),
    };
    lrs.app.request(req.body(body).unwrap()).await
}

fn answered_version(r: &Response) -> &str {
    r.headers["x-experience-api-version"].to_str().unwrap()
}

fn etag(r: &Response) -> String {
    r.headers["etag"].to_str().unwrap().to_owned()
}

fn agent_profile_uri(id: &str) -> String {
    format!(
        "/xapi/agents/profile?{}",
        query(&[("agent", &mbox_agent().to_string()), ("profileId", id)])
    )
}

fn activity_profile_uri(id: &str) -> String {
    format!(
        "/xapi/activities/profile?{}",
        query(&[("activityId", ACTIVITY), ("profileId", id)])
    )
}

#[tokio::test]
async fn xapi_v103_each_request_is_answered_in_its_own_version() {
    let lrs = Lrs::new().await;
    let uri = "/xapi/statements?limit=1";
    for (sent, answered) in [
        ("1.0.3", "1.0.3"),
        ("1.0.0", "1.0.3"),
        ("1.0", "1.0.3"),
        ("2.0.0", "2.0.0"),
    ] {
        let r = send_as(&lrs, Some(sent), Method::GET, uri, &[], None).await;
        assert_eq!(r.status, StatusCode::OK, "{sent}: {}", r.text);
        assert_eq!(answered_version(&r), answered, "{sent}");
    }
    // Without the header, or with one this LRS does not speak, the request is refused.
    for sent in [None, Some("0.95"), Some("2.1.0")] {
        let r = send_as(&lrs, sent, Method::GET, uri, &[], None).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{sent:?}");
        assert_eq!(answered_version(&r), "2.0.0", "{sent:?}");
    }
    // About lists both lines, whatever version the client names.
    for sent in [None, Some("1.0.3"), Some("2.0.0")] {
        let r = send_as(&lrs, sent, Method::GET, "/xapi/about", &[], None).await;
        assert_eq!(r.status, StatusCode::OK);
        assert_eq!(r.json["version"], json!(["2.0.0", "1.0.3"]));
    }
}

#[tokio::test]
async fn xapi_v103_etags_are_sha1_for_1_0_and_sha256_for_2_0_of_one_document() {
    let lrs = Lrs::new().await;
    let uri = agent_profile_uri("etags");
    let doc = json!({ "a": 1 }).to_string().into_bytes();
    let sha1 = format!("\"{}\"", hex::encode(Sha1::digest(&doc)));
    let sha256 = format!("\"{}\"", hex::encode(Sha256::digest(&doc)));
    let body = || Some(("application/json", doc.clone()));
    let r = send_as(
        &lrs,
        Some("1.0.3"),
        Method::PUT,
        &uri,
        &[("if-none-match", "*")],
        body(),
    )
    .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    assert_eq!(etag(&r), sha1);
    // The same stored bytes: each line sees its own hash, quoted.
    let r = send_as(&lrs, Some("1.0.3"), Method::GET, &uri, &[], None).await;
    assert_eq!(r.status, StatusCode::OK);
    assert_eq!(etag(&r), sha1);
    assert_eq!(r.text.as_bytes(), &doc[..]);
    let r = send_as(&lrs, Some("2.0.0"), Method::GET, &uri, &[], None).await;
    assert_eq!(etag(&r), sha256);
    assert_eq!(r.text.as_bytes(), &doc[..]);
    // A precondition holds only with the tag of the request's own line.
    for (version, wrong, right) in [("1.0.3", &sha256, &sha1), ("2.0.0", &sha1, &sha256)] {
        let r = send_as(
            &lrs,
            Some(version),
            Method::PUT,
            &uri,
            &[("if-match", wrong)],
            body(),
        )
        .await;
        assert_eq!(r.status, StatusCode::PRECONDITION_FAILED, "{version}");
        let r = send_as(
            &lrs,
            Some(version),
            Method::PUT,
            &uri,
            &[("if-match", right)],
            body(),
        )
        .await;
        assert_eq!(r.status, StatusCode::NO_CONTENT, "{version}: {}", r.text);
    }
    let r = send_as(
        &lrs,
        Some("1.0.3"),
        Method::DELETE,
        &uri,
        &[("if-match", &sha256)],
        None,
    )
    .await;
    assert_eq!(r.status, StatusCode::PRECONDITION_FAILED);
    let r = send_as(
        &lrs,
        Some("1.0.3"),
        Method::DELETE,
        &uri,
        &[("if-match", &sha1)],
        None,
    )
    .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT);
}

#[tokio::test]
async fn xapi_v103_profile_puts_need_a_precondition_in_1_0_and_state_puts_do_not() {
    let lrs = Lrs::new().await;
    let doc = || {
        Some((
            "application/json",
            json!({ "b": 2 }).to_string().into_bytes(),
        ))
    };
    for uri in [agent_profile_uri("pre"), activity_profile_uri("pre")] {
        // 1.0.3: no header on an absent profile is 400, on an existing one 409.
        let r = send_as(&lrs, Some("1.0.3"), Method::PUT, &uri, &[], doc()).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{uri}");
        assert_eq!(answered_version(&r), "1.0.3");
        let r = send_as(
            &lrs,
            Some("1.0.3"),
            Method::PUT,
            &uri,
            &[("if-none-match", "*")],
            doc(),
        )
        .await;
        assert_eq!(r.status, StatusCode::NO_CONTENT, "{uri}");
        let r = send_as(&lrs, Some("1.0.3"), Method::PUT, &uri, &[], doc()).await;
        assert_eq!(r.status, StatusCode::CONFLICT, "{uri}");
        // 2.0: no header on an absent profile creates it; on an existing one it is 409.
        let fresh = format!("{uri}-2");
        let r = send_as(&lrs, Some("2.0.0"), Method::PUT, &fresh, &[], doc()).await;
        assert_eq!(r.status, StatusCode::NO_CONTENT, "{fresh}");
        let r = send_as(&lrs, Some("2.0.0"), Method::PUT, &fresh, &[], doc()).await;
        assert_eq!(r.status, StatusCode::CONFLICT, "{fresh}");
    }
    // State: 1.0.3 overwrites without a header, 2.0 wants one for an existing document.
    let uri = state_uri(&mbox_agent(), "pre", None);
    for _ in 0..2 {
        let r = send_as(&lrs, Some("1.0.3"), Method::PUT, &uri, &[], doc()).await;
        assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    }
    let r = send_as(&lrs, Some("2.0.0"), Method::PUT, &uri, &[], doc()).await;
    assert_eq!(r.status, StatusCode::CONFLICT);
    // POST merges without a precondition in both lines.
    for v in ["1.0.3", "2.0.0"] {
        let r = send_as(
            &lrs,
            Some(v),
            Method::POST,
            &agent_profile_uri("pre"),
            &[],
            doc(),
        )
        .await;
        assert_eq!(r.status, StatusCode::NO_CONTENT, "{v}: {}", r.text);
    }
}

/// A form body of URL-encoded pairs.
pub(crate) fn form(pairs: &[(&str, &str)]) -> Option<(&'static str, Vec<u8>)> {
    let text = pairs
        .iter()
        .map(|(k, v)| format!("{}={}", enc(k), enc(v)))
        .collect::<Vec<_>>()
        .join("&");
    Some(("application/x-www-form-urlencoded", text.into_bytes()))
}

#[tokio::test]
async fn xapi_v103_alternate_request_syntax_for_1_0_only() {
    let lrs = Lrs::new().await;
    let id = uuid::Uuid::new_v4().to_string();
    let statement = json!({
        "actor": mbox_agent(),
        "verb": { "id": "http://adlnet.gov/expapi/verbs/experienced", "display": {"en-US": "experienced"} },
        "object": { "id": ACTIVITY },
    })
    .to_string();
    let uri = "/xapi/statements?method=PUT";
    // A PUT as a POST, with the version and the credential as form parameters.
    let basic = lrs.cred.basic();
    let pairs = [
        ("statementId", id.as_str()),
        ("content", statement.as_str()),
        ("X-Experience-API-Version", "1.0.3"),
        ("Authorization", basic.as_str()),
    ];
    let r = send_as(&lrs, None, Method::POST, uri, &[], form(&pairs)).await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    assert_eq!(answered_version(&r), "1.0.3");
    // The stored statement is the same through either line.
    for v in ["1.0.3", "2.0.0"] {
        let get = format!("/xapi/statements?statementId={id}");
        let r = send_as(&lrs, Some(v), Method::GET, &get, &[], None).await;
        assert_eq!(r.status, StatusCode::OK, "{v}: {}", r.text);
        assert_eq!(r.json["id"], id.as_str());
        assert_eq!(r.json["object"]["id"], ACTIVITY);
    }
    // A GET as a POST, the parameters in the form.
    let r = send_as(
        &lrs,
        Some("1.0.3"),
        Method::POST,
        "/xapi/statements?method=GET",
        &[],
        form(&[("statementId", &id)]),
    )
    .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(r.json["id"], id.as_str());
    // Document headers travel in the form too.
    let doc_params = [
        ("agent", &*mbox_agent().to_string()),
        ("profileId", "alt"),
        ("content", "{\"c\":3}"),
        ("Content-Type", "application/json"),
        ("If-None-Match", "*"),
    ]
    .map(|(k, v)| (k, v.to_owned()));
    let pairs: Vec<(&str, &str)> = doc_params.iter().map(|(k, v)| (*k, v.as_str())).collect();
    let r = send_as(
        &lrs,
        Some("1.0.3"),
        Method::POST,
        "/xapi/agents/profile?method=PUT",
        &[],
        form(&pairs),
    )
    .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    assert_eq!(
        etag(&r),
        format!("\"{}\"", hex::encode(Sha1::digest(b"{\"c\":3}")))
    );
    // Refused: another query parameter, a body that is not a form, an unknown method.
    let refused = [
        (
            "/xapi/statements?method=GET&limit=1",
            form(&[("limit", "1")]),
        ),
        (
            "/xapi/statements?method=GET",
            Some(("application/json", b"{}".to_vec())),
        ),
        ("/xapi/statements?method=PATCH", form(&[("limit", "1")])),
    ];
    for (uri, body) in refused {
        let r = send_as(&lrs, Some("1.0.3"), Method::POST, uri, &[], body).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{uri}: {}", r.text);
        assert_eq!(answered_version(&r), "1.0.3");
    }
    // 2.0 removed the syntax: the same request as 2.0 is refused.
    let r = send_as(
        &lrs,
        Some("2.0.0"),
        Method::POST,
        "/xapi/statements?method=GET",
        &[],
        form(&[("limit", "1")]),
    )
    .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST, "{}", r.text);
    assert_eq!(answered_version(&r), "2.0.0");
}

#[tokio::test]
async fn xapi_v103_statements_stored_once_read_in_each_line_s_format() {
    let lrs = Lrs::new().await;
    let id = uuid::Uuid::new_v4().to_string();
    let statement = json!({
        "id": id,
        "actor": mbox_agent(),
        "verb": { "id": "http://adlnet.gov/expapi/verbs/experienced" },
        "object": { "id": ACTIVITY },
        "context": { "contextAgents": [{ "objectType": "contextAgent", "agent": mbox_agent() }] },
    });
    let body = Some(("application/json", statement.to_string().into_bytes()));
    let r = send_as(
        &lrs,
        Some("2.0.0"),
        Method::POST,
        "/xapi/statements",
        &[],
        body,
    )
    .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let get = format!("/xapi/statements?statementId={id}");
    let r = send_as(&lrs, Some("2.0.0"), Method::GET, &get, &[], None).await;
    assert_eq!(r.json["version"], "2.0.0");
    assert!(r.json["context"]["contextAgents"].is_array());
    let r = send_as(&lrs, Some("1.0.3"), Method::GET, &get, &[], None).await;
    assert_eq!(r.status, StatusCode::OK);
    assert_eq!(r.json["version"], "1.0.0");
    assert!(
        r.json["context"].get("contextAgents").is_none(),
        "{}",
        r.text
    );
    assert_eq!(r.json["id"], id.as_str());
    // The same statement in a StatementResult.
    let r = send_as(
        &lrs,
        Some("1.0.3"),
        Method::GET,
        "/xapi/statements",
        &[],
        None,
    )
    .await;
    let listed = &r.json["statements"][0];
    assert_eq!(listed["id"], id.as_str());
    assert_eq!(listed["version"], "1.0.0");
}

/// A request that names no version (or one this LRS does not accept) is refused with 400 in every
/// version; the answer names the version its credential was registered as speaking, because 1.0.3
/// and 2.0.0 each require their own version there (Communication 3.3) and nothing else in such a
/// request tells them apart. The version a request names always wins.
#[tokio::test]
async fn xapi_v103_a_request_without_a_version_is_answered_in_its_credential_s_version() {
    let lrs = Lrs::new().await;
    let old = lrs
        .credential_from(json!({ "name": "SCORM Cloud 1.0.3", "xapi_version": "1.0.3" }))
        .await;
    // The default credential is a 2.0.0 one.
    let listed = lrs
        .as_admin(Method::GET, "/api/admin/lrs-credentials", None)
        .await;
    let versions: Vec<(String, String)> = listed
        .json
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            (
                c["key"].as_str().unwrap().to_owned(),
                c["xapi_version"].as_str().unwrap().to_owned(),
            )
        })
        .collect();
    assert!(
        versions.contains(&(lrs.cred.key.clone(), "2.0.0".into())),
        "{versions:?}"
    );
    assert!(
        versions.contains(&(old.key.clone(), "1.0.3".into())),
        "{versions:?}"
    );

    let statement = json!({"actor": mbox_agent(), "verb": {"id": "http://adlnet.gov/expapi/verbs/attempted"},
        "object": {"id": ACTIVITY}});
    let id = uuid::Uuid::new_v4();
    let requests = [
        (Method::GET, "/xapi/statements?limit=1".to_owned(), None),
        (
            Method::POST,
            "/xapi/statements".to_owned(),
            Some(("application/json", statement.to_string().into_bytes())),
        ),
        (
            Method::PUT,
            format!("/xapi/statements?statementId={id}"),
            Some(("application/json", statement.to_string().into_bytes())),
        ),
    ];
    for (method, uri, body) in &requests {
        for sent in [None, Some("0.95"), Some("3.0.0")] {
            for (cred, answered) in [(&old, "1.0.3"), (&lrs.cred, "2.0.0")] {
                let mut req = axum::http::Request::builder()
                    .method(method.clone())
                    .uri(uri.as_str())
                    .header("authorization", cred.basic());
                if let Some(v) = sent {
                    req = req.header("x-experience-api-version", v);
                }
                let body = match body {
                    Some((ct, bytes)) => {
                        req = req.header("content-type", *ct);
                        axum::body::Body::from(bytes.clone())
                    }
                    None => axum::body::Body::empty(),
                };
                let r = lrs.app.request(req.body(body).unwrap()).await;
                assert_eq!(r.status, StatusCode::BAD_REQUEST, "{method} {uri} {sent:?}");
                assert_eq!(
                    answered_version(&r),
                    answered,
                    "{method} {uri} {sent:?} {}",
                    cred.key
                );
            }
        }
    }
    // A wrong secret for the 1.0.3 key tells nothing about the credential: 2.0.0.
    let mut wrong = old.clone();
    wrong.secret = "0".repeat(64);
    let r = lrs
        .app
        .request(
            axum::http::Request::builder()
                .uri("/xapi/statements?limit=1")
                .header("authorization", wrong.basic())
                .body(axum::body::Body::empty())
                .unwrap(),
        )
        .await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST);
    assert_eq!(answered_version(&r), "2.0.0");
    // A 1.0.3 credential speaking 2.0 is answered in 2.0, and the reverse.
    let old_lrs = Lrs {
        app: lrs.app,
        admin: lrs.admin,
        cred: old,
    };
    let r = send_as(
        &old_lrs,
        Some("2.0.0"),
        Method::GET,
        "/xapi/statements?limit=1",
        &[],
        None,
    )
    .await;
    assert_eq!((r.status, answered_version(&r)), (StatusCode::OK, "2.0.0"));
    let r = send_as(
        &old_lrs,
        Some("1.0.3"),
        Method::GET,
        "/xapi/statements?limit=1",
        &[],
        None,
    )
    .await;
    assert_eq!((r.status, answered_version(&r)), (StatusCode::OK, "1.0.3"));
    // Nothing but the two versions is taken.
    for bad in [json!("1.0.2"), json!("2.0"), json!(2), json!(null)] {
        let body = json!({ "name": "x", "xapi_version": bad });
        let r = old_lrs
            .as_admin(Method::POST, "/api/admin/lrs-credentials", Some(body))
            .await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{bad}: {}", r.text);
        assert!(r.text.contains("xapi_version"), "{bad}: {}", r.text);
    }
}
