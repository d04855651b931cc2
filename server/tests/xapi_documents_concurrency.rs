//! Concurrency of the document resources (xAPI 2.0, Communication "Concurrency"): ETags,
//! `If-Match` and `If-None-Match` (412 when one fails, nothing changed), 409 for a PUT without
//! either to an existing document, and concurrent POSTs that all merge.

use axum::http::{Method, StatusCode};
use serde_json::json;

use crate::xapi_documents_support::{
    etag, get_json, mbox_agent, post_json, put_json, resources, state_uri,
};
use crate::xapi_support::Lrs;

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
