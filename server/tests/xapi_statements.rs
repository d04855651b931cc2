//! The Statement resource, from the xAPI 2.0 specification (IEEE 9274.1.1; Communication 2.1,
//! Data 2.3-2.4): PUT/POST/GET, what the LRS fills, immutability, batch atomicity, voiding,
//! every query filter, `more` paging, the formats and the headers.

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};
use uuid::Uuid;

use crate::records_support::Response;
use crate::xapi_support::Lrs;

const VOIDED: &str = "http://adlnet.gov/expapi/verbs/voided";

/// A valid statement: `who` did `verb` to activity `activity` (all under example.org).
pub fn stmt(who: &str, verb: &str, activity: &str) -> Value {
    json!({
        "actor": { "objectType": "Agent", "name": who, "mbox": format!("mailto:{who}@example.org") },
        "verb": { "id": format!("http://example.org/verbs/{verb}"), "display": { "en-US": verb } },
        "object": { "objectType": "Activity", "id": format!("http://example.org/act/{activity}"),
            "definition": { "name": { "en-US": activity, "fr-FR": format!("le {activity}") } } }
    })
}

fn voiding(target: &str) -> Value {
    json!({
        "actor": { "mbox": "mailto:admin@example.org" },
        "verb": { "id": VOIDED, "display": { "en-US": "voided" } },
        "object": { "objectType": "StatementRef", "id": target }
    })
}

pub async fn post(lrs: &Lrs, body: Value) -> Response {
    lrs.send(Method::POST, "/xapi/statements", Some(body)).await
}

pub async fn get(lrs: &Lrs, query: &str) -> Response {
    lrs.send(Method::GET, &format!("/xapi/statements?{query}"), None)
        .await
}

/// The ids of a StatementResult, in order.
fn ids_of(r: &Response) -> Vec<String> {
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    r.json["statements"]
        .as_array()
        .expect("statements")
        .iter()
        .map(|s| s["id"].as_str().unwrap().to_owned())
        .collect()
}

fn enc(s: &str) -> String {
    s.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"-_.~".contains(&b) {
                char::from(b).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

async fn post_ids(lrs: &Lrs, body: Value) -> Vec<String> {
    let r = post(lrs, body).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    r.json
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_owned())
        .collect()
}

async fn count(lrs: &Lrs) -> i64 {
    sqlx::query_scalar("SELECT count(*) FROM xapi_statements")
        .fetch_one(lrs.app.pool())
        .await
        .unwrap()
}

#[tokio::test]
async fn put_stores_and_the_lrs_fills_id_stored_authority_version_timestamp() {
    let lrs = Lrs::new().await;
    let id = Uuid::new_v4().to_string();
    let mut s = stmt("ann", "attempted", "a1");
    // The client's own authority is replaced by the credential's (Data 2.4.9: SHOULD overwrite).
    s["authority"] = json!({ "mbox": "mailto:impostor@example.org" });
    let r = lrs
        .send(
            Method::PUT,
            &format!("/xapi/statements?statementId={id}"),
            Some(s.clone()),
        )
        .await;
    assert_eq!(r.status, StatusCode::NO_CONTENT, "{}", r.text);
    assert!(
        r.headers
            .contains_key("x-experience-api-consistent-through")
    );

    let g = get(&lrs, &format!("statementId={id}")).await;
    assert_eq!(g.status, StatusCode::OK, "{}", g.text);
    assert_eq!(g.headers["content-type"], "application/json");
    assert_eq!(g.json["id"], id.as_str());
    assert_eq!(g.json["authority"], lrs.cred.authority);
    assert_eq!(g.json["version"], "2.0.0");
    let stored = g.json["stored"].as_str().unwrap();
    assert_eq!(g.json["timestamp"], stored, "timestamp defaults to stored");
    assert!(stored.ends_with('Z') && stored.len() == 24, "{stored}");
    // Last-Modified names the same second as `stored` (an HTTP date has whole seconds).
    let lm = g.headers["last-modified"].to_str().unwrap();
    let t = time::OffsetDateTime::parse(stored, &time::format_description::well_known::Rfc3339)
        .unwrap();
    assert_eq!(lm, server::xapi::statements::timefmt::http_date(t));
    let ct = g.headers["x-experience-api-consistent-through"]
        .to_str()
        .unwrap();
    assert!(
        server::xapi::statements::timefmt::parse(ct).is_some(),
        "{ct}"
    );

    // Same id and content again (keys reordered, timestamp absent both times): a no-op.
    let again = lrs
        .send(
            Method::PUT,
            &format!("/xapi/statements?statementId={id}"),
            Some(s.clone()),
        )
        .await;
    assert_eq!(again.status, StatusCode::NO_CONTENT, "{}", again.text);
    let r = post(
        &lrs,
        json!([{ "id": id, "object": s["object"], "verb": s["verb"], "actor": s["actor"] }]),
    )
    .await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(r.json, json!([id]));
    // Other content under the same id: 409, and the stored statement is unchanged.
    let mut other = s.clone();
    other["verb"]["id"] = json!("http://example.com/different/verb/iri");
    let r = lrs
        .send(
            Method::PUT,
            &format!("/xapi/statements?statementId={id}"),
            Some(other),
        )
        .await;
    assert_eq!(r.status, StatusCode::CONFLICT, "{}", r.text);
    let g2 = get(&lrs, &format!("statementId={id}")).await;
    assert_eq!(g2.json, g.json);
    assert_eq!(count(&lrs).await, 1);
}

/// A request (method, URI, body with its content type) and the status it must get.
type Case<'a> = (Method, String, Option<(&'a str, Vec<u8>)>, u16);

#[tokio::test]
async fn put_and_post_refusals() {
    let lrs = Lrs::new().await;
    let id = Uuid::new_v4();
    let s = stmt("bob", "attempted", "a1");
    let mut mismatched = s.clone();
    mismatched["id"] = json!(Uuid::new_v4().to_string());
    let cases: Vec<Case<'_>> = vec![
        (Method::PUT, "/xapi/statements".into(), Some(("application/json", s.to_string().into_bytes())), 400),
        (Method::PUT, "/xapi/statements?statementId=nope".into(), Some(("application/json", s.to_string().into_bytes())), 400),
        (Method::PUT, format!("/xapi/statements?statementId={id}"), Some(("application/json", mismatched.to_string().into_bytes())), 400),
        (Method::PUT, format!("/xapi/statements?statementId={id}"), Some(("application/json", json!([s]).to_string().into_bytes())), 400),
        (Method::PUT, format!("/xapi/statements?statementId={id}&foo=1"), Some(("application/json", s.to_string().into_bytes())), 400),
        // The alternate request syntax is gone in 2.0.
        (Method::POST, "/xapi/statements?method=PUT".into(), Some(("application/x-www-form-urlencoded", b"statementId=x".to_vec())), 400),
        (Method::POST, "/xapi/statements?method=GET".into(), None, 400),
        (Method::POST, "/xapi/statements".into(), Some(("application/x-www-form-urlencoded", b"a=b".to_vec())), 400),
        (Method::POST, "/xapi/statements".into(), Some(("application/json", b"{not json".to_vec())), 400),
        (Method::POST, "/xapi/statements".into(), Some(("application/json", b"[]".to_vec())), 400),
        // U+0000 cannot be stored in jsonb: refused, never a 500.
        (Method::POST, "/xapi/statements".into(), Some(("application/json", s.to_string().replace("bob\"", "b\\u0000ob\"").into_bytes())), 400),
        // An unknown property (Data 2.2: the LRS rejects statements with properties not in the spec).
        (Method::POST, "/xapi/statements".into(), Some(("application/json", json!({ "actor": s["actor"], "verb": s["verb"], "object": s["object"], "dummy": 1 }).to_string().into_bytes())), 400),
        (Method::POST, "/xapi/statements".into(), Some(("application/json", json!({ "verb": s["verb"], "object": s["object"] }).to_string().into_bytes())), 400),
    ];
    for (m, uri, body, want) in cases {
        let r = lrs.raw(m.clone(), &uri, Some(&lrs.cred), &[], body).await;
        assert_eq!(r.status.as_u16(), want, "{m} {uri}: {}", r.text);
        assert_eq!(r.json["error"]["code"], "bad_request", "{uri}");
    }
    assert_eq!(count(&lrs).await, 0);
    // Over the body limit: 413 in the LRS's error shape.
    let big = vec![b' '; lrs.app.config.max_body_bytes + 1];
    let r = lrs
        .raw(
            Method::POST,
            "/xapi/statements",
            Some(&lrs.cred),
            &[],
            Some(("application/json", big)),
        )
        .await;
    assert_eq!(r.status, StatusCode::PAYLOAD_TOO_LARGE, "{}", r.text);
}

#[tokio::test]
async fn a_batch_is_stored_whole_or_not_at_all() {
    let lrs = Lrs::new().await;
    let ids = post_ids(
        &lrs,
        json!([
            stmt("a", "v1", "x"),
            stmt("b", "v2", "y"),
            stmt("c", "v3", "z")
        ]),
    )
    .await;
    assert_eq!(ids.len(), 3);
    // In order: the first id names the first statement.
    let g = get(&lrs, &format!("statementId={}", ids[0])).await;
    assert_eq!(g.json["actor"]["name"], "a");
    let g = get(&lrs, &format!("statementId={}", ids[2])).await;
    assert_eq!(g.json["actor"]["name"], "c");

    // One invalid statement: 400 and none of the valid ones stored.
    let fresh = Uuid::new_v4().to_string();
    let mut ok = stmt("d", "v", "x");
    ok["id"] = json!(fresh);
    let bad = json!({ "actor": ok["actor"], "object": ok["object"] });
    let r = post(&lrs, json!([ok.clone(), bad])).await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST, "{}", r.text);
    // The same id twice in one batch.
    let r = post(&lrs, json!([ok.clone(), ok.clone()])).await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST, "{}", r.text);
    // A conflict anywhere in the batch: 409 and nothing of it stored.
    let mut clash = stmt("other", "v", "x");
    clash["id"] = json!(ids[1]);
    let r = post(&lrs, json!([ok.clone(), clash])).await;
    assert_eq!(r.status, StatusCode::CONFLICT, "{}", r.text);
    assert_eq!(
        get(&lrs, &format!("statementId={fresh}")).await.status,
        StatusCode::NOT_FOUND
    );
    assert_eq!(count(&lrs).await, 3);
    // A retry of a stored batch is idempotent: same ids, nothing new.
    let mut again: Vec<Value> = Vec::new();
    for (i, who) in ["a", "b", "c"].iter().enumerate() {
        let mut s = stmt(who, &format!("v{}", i + 1), ["x", "y", "z"][i]);
        s["id"] = json!(ids[i]);
        again.push(s);
    }
    assert_eq!(post_ids(&lrs, Value::Array(again)).await, ids);
    assert_eq!(count(&lrs).await, 3);
}

#[tokio::test]
async fn voiding_hides_the_target_and_voiding_statements_cannot_be_voided() {
    let lrs = Lrs::new().await;
    let target = post_ids(&lrs, stmt("vic", "passed", "exam"))
        .await
        .remove(0);
    let void = post_ids(&lrs, voiding(&target)).await.remove(0);
    // Only voidedStatementId returns a voided statement.
    assert_eq!(
        get(&lrs, &format!("statementId={target}")).await.status,
        StatusCode::NOT_FOUND
    );
    let g = get(&lrs, &format!("voidedStatementId={target}")).await;
    assert_eq!(g.status, StatusCode::OK, "{}", g.text);
    assert_eq!(g.json["id"], target.as_str());
    assert_eq!(
        get(&lrs, &format!("voidedStatementId={void}")).await.status,
        StatusCode::NOT_FOUND
    );
    // Queries leave the voided statement out but return the voiding one.
    let all = ids_of(&get(&lrs, "").await);
    assert_eq!(all, vec![void.clone()]);
    // The voiding statement matches the target's filters (a StatementRef to a match).
    let by_agent = ids_of(
        &get(
            &lrs,
            &format!("agent={}", enc(r#"{"mbox":"mailto:vic@example.org"}"#)),
        )
        .await,
    );
    assert_eq!(by_agent, vec![void.clone()]);

    // Voiding a voiding statement: accepted and ignored (Data 2.3.2; XAPI-00016).
    let r = post(&lrs, voiding(&void)).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    assert_eq!(
        get(&lrs, &format!("statementId={void}")).await.status,
        StatusCode::OK
    );
    // A target the LRS does not have: not rejected; voided when it arrives.
    let later = Uuid::new_v4().to_string();
    post_ids(&lrs, voiding(&later)).await;
    let mut s = stmt("late", "passed", "exam");
    s["id"] = json!(later);
    post_ids(&lrs, s).await;
    assert_eq!(
        get(&lrs, &format!("statementId={later}")).await.status,
        StatusCode::NOT_FOUND
    );
    assert_eq!(
        get(&lrs, &format!("voidedStatementId={later}"))
            .await
            .status,
        StatusCode::OK
    );
    // A voiding statement's object must be a StatementRef.
    let mut bad = voiding(&target);
    bad["object"] = json!({ "id": "http://example.org/act/x" });
    assert_eq!(post(&lrs, bad).await.status, StatusCode::BAD_REQUEST);
}

#[tokio::test]
async fn single_statement_parameters_exclude_filters() {
    let lrs = Lrs::new().await;
    let id = post_ids(&lrs, stmt("p", "v", "x")).await.remove(0);
    for q in [
        format!("statementId={id}&voidedStatementId={id}"),
        format!("statementId={id}&limit=1"),
        format!("statementId={id}&verb=http%3A%2F%2Fexample.org%2Fverbs%2Fv"),
        format!("voidedStatementId={id}&since=2020-01-01T00:00:00Z"),
        "statementId=not-a-uuid".into(),
        "limit=-1".into(),
        "format=full".into(),
        "agent=%7B%22name%22%3A%22no%20ifi%22%7D".into(),
        "since=yesterday".into(),
        "unknown=1".into(),
        "verb=v&verb=w".into(),
    ] {
        assert_eq!(get(&lrs, &q).await.status, StatusCode::BAD_REQUEST, "{q}");
    }
    for q in [
        format!("statementId={id}&format=ids&attachments=false"),
        format!("statementId={}", id.to_uppercase()),
    ] {
        assert_eq!(get(&lrs, &q).await.status, StatusCode::OK, "{q}");
    }
    assert_eq!(
        get(&lrs, &format!("statementId={}", Uuid::new_v4()))
            .await
            .status,
        StatusCode::NOT_FOUND
    );
}

#[tokio::test]
async fn every_filter() {
    let lrs = Lrs::new().await;
    let reg = Uuid::new_v4().to_string();
    let mut a = stmt("amy", "attempted", "cap");
    a["context"] = json!({
        "registration": reg,
        "instructor": { "mbox": "mailto:teacher@example.org" },
        "contextActivities": { "parent": [{ "id": "http://example.org/act/course" }] }
    });
    let a = post_ids(&lrs, a).await.remove(0);
    let b = post_ids(&lrs, stmt("ben", "completed", "cap"))
        .await
        .remove(0);
    let mut c = stmt("cat", "attempted", "dog");
    c["object"] = json!({ "objectType": "Agent", "mbox": "mailto:amy@example.org" });
    let c = post_ids(&lrs, c).await.remove(0);
    // d targets b (StatementRef): it meets b's filter conditions.
    let d = post_ids(
        &lrs,
        json!({ "actor": { "mbox": "mailto:dan@example.org" },
                "verb": { "id": "http://example.org/verbs/confirmed" },
                "object": { "objectType": "StatementRef", "id": b } }),
    )
    .await
    .remove(0);

    let amy = enc(r#"{"mbox":"mailto:amy@example.org"}"#);
    let teacher = enc(r#"{"objectType":"Agent","mbox":"mailto:teacher@example.org"}"#);
    let cases: Vec<(String, Vec<&String>)> = vec![
        (String::new(), vec![&d, &c, &b, &a]),
        (format!("agent={amy}"), vec![&c, &a]),
        (format!("agent={teacher}"), vec![]),
        (format!("agent={teacher}&related_agents=true"), vec![&a]),
        // A Group with the same identifier is another identity (objectType differs).
        (
            format!(
                "agent={}",
                enc(r#"{"objectType":"Group","mbox":"mailto:amy@example.org"}"#)
            ),
            vec![],
        ),
        (
            format!("verb={}", enc("http://example.org/verbs/attempted")),
            vec![&c, &a],
        ),
        (
            format!("verb={}", enc("http://example.org/verbs/completed")),
            vec![&d, &b],
        ),
        (
            format!("activity={}", enc("http://example.org/act/cap")),
            vec![&d, &b, &a],
        ),
        (
            format!("activity={}", enc("http://example.org/act/course")),
            vec![],
        ),
        (
            format!(
                "activity={}&related_activities=true",
                enc("http://example.org/act/course")
            ),
            vec![&a],
        ),
        (format!("registration={reg}"), vec![&a]),
        (
            format!(
                "verb={}&activity={}",
                enc("http://example.org/verbs/attempted"),
                enc("http://example.org/act/cap")
            ),
            vec![&a],
        ),
        ("ascending=true".into(), vec![&a, &b, &c, &d]),
        ("limit=2&ascending=true".into(), vec![&a, &b]),
    ];
    for (q, want) in cases {
        let got = ids_of(&get(&lrs, &q).await);
        let want: Vec<String> = want.into_iter().cloned().collect();
        assert_eq!(got, want, "{q}");
    }
    // since (exclusive) and until (inclusive) on `stored`.
    let stored_b = get(&lrs, &format!("statementId={b}")).await.json["stored"]
        .as_str()
        .unwrap()
        .to_owned();
    let since = ids_of(&get(&lrs, &format!("since={}&ascending=true", enc(&stored_b))).await);
    assert!(!since.contains(&b) && !since.contains(&a), "{since:?}");
    let until = ids_of(&get(&lrs, &format!("until={}&ascending=true", enc(&stored_b))).await);
    assert_eq!(until, vec![a.clone(), b.clone()]);
    let r = get(&lrs, "since=2999-01-01T00:00:00Z").await;
    assert_eq!(r.json, json!({ "statements": [], "more": "" }));
}

#[tokio::test]
async fn more_pages_are_stable_under_concurrent_inserts() {
    let lrs = Lrs::new().await;
    let mut batch = Vec::new();
    for i in 0..7 {
        batch.push(stmt(&format!("u{i}"), "attempted", "paging"));
    }
    let ids = post_ids(&lrs, Value::Array(batch)).await;
    let verb = enc("http://example.org/verbs/attempted");
    let mut seen = Vec::new();
    let mut r = get(&lrs, &format!("verb={verb}&limit=3")).await;
    let mut pages = 0;
    loop {
        seen.extend(ids_of(&r));
        pages += 1;
        let more = r.json["more"].as_str().unwrap().to_owned();
        if more.is_empty() {
            break;
        }
        assert!(more.starts_with("/xapi/statements?"), "{more}");
        // A statement stored between pages is newer than every page of this query.
        post_ids(&lrs, stmt("late", "attempted", "paging")).await;
        r = lrs.send(Method::GET, &more, None).await;
    }
    assert_eq!(pages, 3);
    let mut want = ids.clone();
    want.reverse();
    assert_eq!(seen, want);
}

#[tokio::test]
async fn formats_ids_exact_canonical() {
    let lrs = Lrs::new().await;
    let id = post_ids(&lrs, stmt("fay", "attempted", "fmt"))
        .await
        .remove(0);
    // A later statement updates the activity's definition (a new name in German).
    let mut later = stmt("gus", "attempted", "fmt");
    later["object"]["definition"] = json!({ "name": { "de-DE": "das fmt" } });
    post_ids(&lrs, later).await;

    let exact = get(&lrs, &format!("statementId={id}&format=exact")).await;
    assert_eq!(exact.json["actor"]["name"], "fay");
    let ids = get(&lrs, &format!("statementId={id}&format=ids")).await;
    assert_eq!(
        ids.json["actor"],
        json!({ "objectType": "Agent", "mbox": "mailto:fay@example.org" })
    );
    assert_eq!(
        ids.json["verb"],
        json!({ "id": "http://example.org/verbs/attempted" })
    );
    // An Activity is its id alone ("Activity" is the default objectType; the ADL conformance
    // suite counts the keys).
    assert_eq!(
        ids.json["object"],
        json!({ "id": "http://example.org/act/fmt" })
    );

    let canon = lrs
        .raw(
            Method::GET,
            &format!("/xapi/statements?statementId={id}&format=canonical"),
            Some(&lrs.cred),
            &[("accept-language", "fr-FR, en;q=0.5")],
            None,
        )
        .await;
    assert_eq!(canon.status, StatusCode::OK, "{}", canon.text);
    assert_eq!(
        canon.json["object"]["definition"]["name"],
        json!({ "fr-FR": "le fmt" })
    );
    assert_eq!(
        canon.json["verb"]["display"],
        json!({ "en-US": "attempted" })
    );
    let de = lrs
        .raw(
            Method::GET,
            &format!("/xapi/statements?statementId={id}&format=canonical"),
            Some(&lrs.cred),
            &[("accept-language", "de")],
            None,
        )
        .await;
    assert_eq!(
        de.json["object"]["definition"]["name"],
        json!({ "de-DE": "das fmt" })
    );
    // Without format=canonical, Accept-Language changes nothing.
    let plain = lrs
        .raw(
            Method::GET,
            &format!("/xapi/statements?statementId={id}"),
            Some(&lrs.cred),
            &[("accept-language", "de")],
            None,
        )
        .await;
    assert_eq!(plain.json, exact.json);
}

#[tokio::test]
async fn head_answers_like_get_without_a_body() {
    let lrs = Lrs::new().await;
    post_ids(&lrs, stmt("h", "v", "x")).await;
    let r = lrs
        .raw(Method::HEAD, "/xapi/statements", Some(&lrs.cred), &[], None)
        .await;
    assert_eq!(r.status, StatusCode::OK);
    assert!(r.text.is_empty());
    assert!(
        r.headers
            .contains_key("x-experience-api-consistent-through")
    );
}

#[tokio::test]
async fn the_platform_stores_statements_in_its_own_transaction() {
    let lrs = Lrs::new().await;
    let authority = json!({ "objectType": "Agent", "account": { "homePage": "https://painsim.example", "name": "platform" } });
    let mut tx = lrs.app.pool().begin().await.unwrap();
    let ids = server::xapi::statements::store::insert_statements(
        &mut tx,
        vec![stmt("p1", "scored", "x"), stmt("p2", "scored", "x")],
        &authority,
    )
    .await
    .unwrap();
    tx.rollback().await.unwrap();
    assert_eq!(
        count(&lrs).await,
        0,
        "rolled back with the caller's transaction"
    );
    let mut conn = lrs.app.pool().acquire().await.unwrap();
    let mut s = stmt("p1", "scored", "x");
    s["id"] = json!(ids[0].to_string());
    let again =
        server::xapi::statements::store::insert_statements(&mut conn, vec![s.clone()], &authority)
            .await
            .unwrap();
    assert_eq!(again, vec![ids[0]]);
    // Same id and content: no-op; other content: conflict.
    server::xapi::statements::store::insert_statements(&mut conn, vec![s.clone()], &authority)
        .await
        .unwrap();
    s["verb"]["id"] = json!("http://example.org/verbs/other");
    let e = server::xapi::statements::store::insert_statements(&mut conn, vec![s], &authority)
        .await
        .unwrap_err();
    assert!(matches!(e, server::ApiError::Conflict(_)), "{e:?}");
    let g = get(&lrs, &format!("statementId={}", ids[0])).await;
    assert_eq!(g.json["authority"], authority);
}
