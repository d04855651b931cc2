//! The LRS's document resources (State, Activity Profile, Agent Profile), tested from the xAPI 2.0
//! specification (IEEE 9274.1.1, Communication "Document Resources"): storage of any content
//! byte-exact with its ETag and Last-Modified, HEAD, deletes, and the JSON merge of POST. The
//! other concerns are in the `xapi_documents_*` files beside this one, their fixtures in
//! `xapi_documents_support`.

use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use serde_json::json;
use sha2::{Digest, Sha256};
use time::OffsetDateTime;

use crate::xapi_documents_support::{
    etag, exchange, get_json, http_date, mbox_agent, post_json, resources, state_uri,
};
use crate::xapi_support::Lrs;

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
    assert_eq!(r.json["error"]["code"], "not_found", "the API's error body");
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
