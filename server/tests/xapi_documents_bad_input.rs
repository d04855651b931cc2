//! Refusals of the document, Agents and Activities resources (xAPI 2.0, Communication 3.2 "Error
//! Codes"): every missing, malformed, unknown, repeated or wrongly cased parameter is a 400 that
//! stores nothing, as is a request without the version header.

use axum::body::Body;
use axum::http::{Method, Request, StatusCode};
use serde_json::json;

use crate::xapi_documents_support::{ACTIVITY, mbox_agent, query};
use crate::xapi_support::Lrs;

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
