//! The query parameters of the LRS as its OpenAPI document shows them and as its handlers parse
//! them: the document's parameters of each route are those of the typed struct its handler
//! parses (names, order and which are required), and every documented parameter of every `/xapi`
//! route is accepted by the running server, while a missing required one, an unknown one and a
//! repeated one are refused with 400 (xAPI 2.0, Communication 3.2 "Error Codes").

use axum::http::Method;
use serde_json::{Value, json};
use server::xapi::activities::ActivitiesQuery;
use server::xapi::agents::AgentsQuery;
use server::xapi::documents::activity_profile::ActivityProfileResource;
use server::xapi::documents::agent_profile::AgentProfileResource;
use server::xapi::documents::params::QueryParams;
use server::xapi::documents::resource::DocumentResource;
use server::xapi::documents::state::StateResource;
use utoipa::openapi::Required;

use crate::xapi_documents_support::{ACTIVITY, mbox_agent, query};
use crate::xapi_support::Lrs;

/// A route's query parameters: (name, required), in the document's order.
type Documented = Vec<(String, bool)>;

/// The query parameters of a struct, as its `IntoParams` derive documents them.
fn struct_params<T: QueryParams>() -> Documented {
    let params: Documented = T::into_params(|| None)
        .into_iter()
        .map(|p| (p.name, p.required == Required::True))
        .collect();
    let names: Vec<&String> = params.iter().map(|(n, _)| n).collect();
    assert_eq!(
        names,
        T::names().iter().collect::<Vec<_>>(),
        "the parser takes the documented names"
    );
    params
}

/// The query parameters of every `/xapi` route in the served OpenAPI document, by
/// (method, path).
async fn documented(lrs: &Lrs) -> Vec<(Method, String, Documented)> {
    let doc = lrs
        .app
        .send(Method::GET, "/api/openapi.json", None, None)
        .await
        .json;
    let mut out = Vec::new();
    for (path, item) in doc["paths"].as_object().expect("paths") {
        if !path.starts_with("/xapi") {
            continue;
        }
        for (method, op) in item.as_object().expect("path item") {
            let Ok(method) = method.to_uppercase().parse::<Method>() else {
                continue;
            };
            let params = op["parameters"]
                .as_array()
                .into_iter()
                .flatten()
                .filter(|p| p["in"] == "query")
                .map(|p| {
                    let name = p["name"].as_str().expect("parameter name").to_owned();
                    (name, p["required"] == true)
                })
                .collect();
            out.push((method, path.clone(), params));
        }
    }
    out
}

/// A valid value of a documented parameter; `n` makes document and statement ids unique, so
/// that no request meets a document or statement an earlier one stored. A parameter without
/// one fails the test: a new parameter needs a value here, and so is exercised.
fn sample(name: &str, n: usize) -> String {
    match name {
        "activityId" => ACTIVITY.to_owned(),
        "agent" => mbox_agent().to_string(),
        "registration" => "6f1c0c5e-3b8a-4f0e-9d2c-1b0a99887766".to_owned(),
        "stateId" | "profileId" => format!("doc-{n}"),
        "since" | "until" => "2026-01-01T00:00:00Z".to_owned(),
        "statementId" | "voidedStatementId" => uuid::Uuid::new_v4().to_string(),
        "verb" => "http://adlnet.gov/expapi/verbs/experienced".to_owned(),
        "activity" => ACTIVITY.to_owned(),
        "related_activities" | "related_agents" | "attachments" | "ascending" => "false".into(),
        "limit" | "cursor" => "1".to_owned(),
        "format" => "exact".to_owned(),
        other => panic!("no sample value for the documented query parameter {other}"),
    }
}

/// A statement to store (under the id a PUT's query names).
fn statement() -> Vec<u8> {
    json!({
        "actor": mbox_agent(),
        "verb": { "id": "http://adlnet.gov/expapi/verbs/experienced" },
        "object": { "id": ACTIVITY },
    })
    .to_string()
    .into_bytes()
}

/// Sends `method path?pairs` with the read-write credential (a JSON body for writes).
async fn send(lrs: &Lrs, method: &Method, path: &str, pairs: &[(String, String)]) -> (u16, Value) {
    let pairs: Vec<(&str, &str)> = pairs
        .iter()
        .map(|(k, v)| (k.as_str(), v.as_str()))
        .collect();
    let uri = format!("{path}?{}", query(&pairs));
    let body = match *method {
        Method::PUT | Method::POST if path == "/xapi/statements" => {
            Some(("application/json", statement()))
        }
        Method::PUT | Method::POST => Some(("application/json", b"{\"v\":1}".to_vec())),
        _ => None,
    };
    let r = lrs
        .raw(method.clone(), &uri, Some(&lrs.cred), &[], body)
        .await;
    (r.status.as_u16(), r.json)
}

#[tokio::test]
async fn xapi_documented_query_parameters_are_the_parsed_structs() {
    let lrs = Lrs::new().await;
    let documented = documented(&lrs).await;
    let state = "/xapi/activities/state";
    let activity_profile = "/xapi/activities/profile";
    let agent_profile = "/xapi/agents/profile";
    // Each route and the struct its handler parses the query into.
    let parsed: Vec<(Method, &str, Documented)> = vec![
        (
            Method::GET,
            state,
            struct_params::<<StateResource as DocumentResource>::Get>(),
        ),
        (
            Method::PUT,
            state,
            struct_params::<<StateResource as DocumentResource>::Write>(),
        ),
        (
            Method::POST,
            state,
            struct_params::<<StateResource as DocumentResource>::Write>(),
        ),
        (
            Method::DELETE,
            state,
            struct_params::<<StateResource as DocumentResource>::Delete>(),
        ),
        (
            Method::GET,
            activity_profile,
            struct_params::<<ActivityProfileResource as DocumentResource>::Get>(),
        ),
        (
            Method::PUT,
            activity_profile,
            struct_params::<<ActivityProfileResource as DocumentResource>::Write>(),
        ),
        (
            Method::POST,
            activity_profile,
            struct_params::<<ActivityProfileResource as DocumentResource>::Write>(),
        ),
        (
            Method::DELETE,
            activity_profile,
            struct_params::<<ActivityProfileResource as DocumentResource>::Delete>(),
        ),
        (
            Method::GET,
            agent_profile,
            struct_params::<<AgentProfileResource as DocumentResource>::Get>(),
        ),
        (
            Method::PUT,
            agent_profile,
            struct_params::<<AgentProfileResource as DocumentResource>::Write>(),
        ),
        (
            Method::POST,
            agent_profile,
            struct_params::<<AgentProfileResource as DocumentResource>::Write>(),
        ),
        (
            Method::DELETE,
            agent_profile,
            struct_params::<<AgentProfileResource as DocumentResource>::Delete>(),
        ),
        (Method::GET, "/xapi/agents", struct_params::<AgentsQuery>()),
        (
            Method::GET,
            "/xapi/activities",
            struct_params::<ActivitiesQuery>(),
        ),
    ];
    for (method, path, params) in &parsed {
        let doc = documented
            .iter()
            .find(|(m, p, _)| m == method && p == path)
            .unwrap_or_else(|| panic!("{method} {path} is documented"));
        assert_eq!(
            &doc.2, params,
            "{method} {path}: the document shows the parsed struct"
        );
    }
    // Every route of these resources is one of them (the Statement and About resources document
    // their parameters inline and are exercised below like these).
    for (method, path, _) in &documented {
        let by_struct = parsed.iter().any(|(m, p, _)| m == method && p == path);
        let inline = matches!(path.as_str(), "/xapi/statements" | "/xapi/about");
        assert!(
            by_struct || inline,
            "{method} {path}: which struct parses its query?"
        );
    }
}

#[tokio::test]
async fn xapi_every_documented_query_parameter_is_accepted_and_bad_ones_refused() {
    let lrs = Lrs::new().await;
    let documented = documented(&lrs).await;
    assert!(
        documented.len() >= 17,
        "the walk reaches the LRS: {documented:?}"
    );
    let mut n = 0;
    let mut checked = 0;
    for (method, path, params) in &documented {
        let required = |n: &mut usize| -> Vec<(String, String)> {
            *n += 1;
            params
                .iter()
                .filter(|(_, r)| *r)
                .map(|(name, _)| (name.clone(), sample(name, *n)))
                .collect()
        };
        // The required ones alone, then with each optional one.
        let (status, body) = send(&lrs, method, path, &required(&mut n)).await;
        assert!(
            (200..300).contains(&status) || status == 404,
            "{method} {path} with its required parameters: {status} {body}"
        );
        for (name, _) in params.iter().filter(|(_, r)| !*r) {
            let mut pairs = required(&mut n);
            pairs.push((name.clone(), sample(name, n)));
            let (status, body) = send(&lrs, method, path, &pairs).await;
            assert!(
                (200..300).contains(&status) || status == 404,
                "{method} {path} with {name}: {status} {body}"
            );
            checked += 1;
        }
        // Without a required one: 400 naming it.
        for (name, _) in params.iter().filter(|(_, r)| *r) {
            let pairs: Vec<_> = required(&mut n)
                .into_iter()
                .filter(|(k, _)| k != name)
                .collect();
            let (status, body) = send(&lrs, method, path, &pairs).await;
            assert_eq!(status, 400, "{method} {path} without {name}: {body}");
            assert_eq!(
                body["error"]["message"],
                format!("{name}: required"),
                "{method} {path}"
            );
            checked += 1;
        }
        // The About resource takes no parameters and reads none; the others refuse what they do
        // not know.
        if path == "/xapi/about" {
            continue;
        }
        // An undocumented parameter: 400.
        let mut pairs = required(&mut n);
        pairs.push(("unknownParameter".into(), "1".into()));
        let (status, body) = send(&lrs, method, path, &pairs).await;
        let message = body["error"]["message"].as_str().unwrap_or_default();
        assert_eq!(
            status, 400,
            "{method} {path} with an unknown parameter: {body}"
        );
        assert!(
            message.contains("unknown parameter"),
            "{method} {path}: {message}"
        );
        // A documented one given twice: 400 (the Statement resource's PUT reads the first
        // `statementId` and is not held to this).
        let repeated = required(&mut n).into_iter().next().or_else(|| {
            params
                .first()
                .map(|(name, _)| (name.clone(), sample(name, n)))
        });
        if let Some((name, value)) = repeated
            && !(*method == Method::PUT && path == "/xapi/statements")
        {
            let mut pairs = required(&mut n);
            pairs.push((name.clone(), value.clone()));
            pairs.push((name.clone(), value));
            let (status, body) = send(&lrs, method, path, &pairs).await;
            assert_eq!(status, 400, "{method} {path} with {name} twice: {body}");
            let message = body["error"]["message"].as_str().unwrap_or_default();
            assert!(
                message.contains("more than once"),
                "{method} {path}: {message}"
            );
        }
    }
    assert!(
        checked >= 40,
        "every route's parameters were tried: {checked}"
    );
}
