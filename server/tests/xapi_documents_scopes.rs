//! Which documents a request reaches (xAPI 2.0, Communication "State Resource" and the profile
//! resources): the ids of a scope with `since` and Last-Modified, deleting all of a scope, the
//! registration as part of a state's key, and Agents keyed by their identity.

use std::time::Duration;

use axum::http::{Method, StatusCode};
use serde_json::json;
use time::OffsetDateTime;

use crate::xapi_documents_support::{
    ACTIVITY, enc, get_json, mbox_agent, post_json, put_json, query, resources, state_uri,
};
use crate::xapi_support::Lrs;

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
