//! Throughput and latency of the Statement resource (issue 17's benchmark, in process through
//! the production router over the test PostgreSQL): batched POSTs of realistic statements, then
//! single POSTs and filtered GETs over the store. Ignored by default (it measures, it does not
//! check); run with `cargo test -p server --test tests -- --ignored xapi_statements_bench
//! --nocapture`, `XAPI_BENCH_N` statements in the store (default 20000).

use std::time::Instant;

use axum::http::{Method, StatusCode};
use serde_json::{Value, json};

use crate::xapi_support::Lrs;

/// A statement shaped like the platform's: actor account, verb, activity with a definition,
/// result with score and extensions, context with registration, parent and extensions.
fn realistic(i: usize) -> Value {
    json!({
        "actor": { "objectType": "Agent", "name": format!("Learner {}", i % 500),
            "account": { "homePage": "https://painsim.example.org", "name": format!("learner-{}", i % 500) } },
        "verb": { "id": "http://adlnet.gov/expapi/verbs/scored", "display": { "en-US": "scored" } },
        "object": { "objectType": "Activity", "id": format!("https://painsim.example.org/stations/{}", i % 40),
            "definition": { "name": { "en-US": format!("Station {}", i % 40) },
                "type": "http://adlnet.gov/expapi/activities/simulation" } },
        "result": { "score": { "scaled": 0.75, "raw": 75, "min": 0, "max": 100 }, "success": true,
            "completion": true, "duration": "PT12M30S",
            "extensions": { "https://painsim.example.org/xapi/criteria": { "needle_tip_mm": 2.5, "contrast": true } } },
        "context": { "registration": uuid::Uuid::new_v4().to_string(),
            "contextActivities": { "parent": [{ "id": "https://painsim.example.org/courses/anaesthesia" }] },
            "extensions": { "https://painsim.example.org/xapi/reproducibility": { "seed": i, "build": "abc123" } } },
        "timestamp": "2026-11-27T04:00:00.000Z"
    })
}

fn pct(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() as f64 - 1.0) * p).round() as usize]
}

#[tokio::test]
#[ignore = "benchmark: run by hand"]
async fn xapi_statements_bench() {
    let n: usize = std::env::var("XAPI_BENCH_N")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000);
    let lrs = Lrs::new().await;
    let batch = 200;
    let t = Instant::now();
    for b in 0..n.div_ceil(batch) {
        let body: Vec<Value> = (0..batch).map(|i| realistic(b * batch + i)).collect();
        let r = lrs
            .send(Method::POST, "/xapi/statements", Some(Value::Array(body)))
            .await;
        assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    }
    let secs = t.elapsed().as_secs_f64();
    println!(
        "batched POST: {n} statements in {secs:.1} s = {:.0} statements/s",
        n as f64 / secs
    );
    let mut single = Vec::new();
    for i in 0..300 {
        let t = Instant::now();
        let r = lrs
            .send(Method::POST, "/xapi/statements", Some(realistic(n + i)))
            .await;
        single.push(t.elapsed().as_secs_f64() * 1e3);
        assert_eq!(r.status, StatusCode::OK);
    }
    println!(
        "single POST: p50 {:.1} ms, p99 {:.1} ms",
        pct(&mut single, 0.5),
        pct(&mut single, 0.99)
    );
    let mut gets = Vec::new();
    for i in 0..300 {
        let agent = format!(
            "%7B%22account%22%3A%7B%22homePage%22%3A%22https%3A%2F%2Fpainsim.example.org%22%2C%22name%22%3A%22learner-{}%22%7D%7D",
            i % 500
        );
        let uri = format!(
            "/xapi/statements?agent={agent}&verb=http%3A%2F%2Fadlnet.gov%2Fexpapi%2Fverbs%2Fscored&limit=25"
        );
        let t = Instant::now();
        let r = lrs.send(Method::GET, &uri, None).await;
        gets.push(t.elapsed().as_secs_f64() * 1e3);
        assert_eq!(r.status, StatusCode::OK);
    }
    println!(
        "filtered GET: p50 {:.1} ms, p99 {:.1} ms",
        pct(&mut gets, 0.5),
        pct(&mut gets, 0.99)
    );
}
