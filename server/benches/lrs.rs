//! Benchmark of the learning record store (`/xapi/statements`) over loopback HTTP against a real
//! PostgreSQL (the private test cluster), with realistic statements: the platform's own `scored`
//! statements (result with per-criterion extensions, registration, context activities and the
//! reproducibility record in context extensions; about 1.6 kB of JSON each) and engagement
//! statements, from 1,000 learners over 9 stations.
//!
//! Reported, with the design targets in brackets. Simulator choice: latencies well inside the
//! 0.1 s that users perceive as instantaneous (Nielsen, *Usability Engineering*, 1993), and a
//! throughput that takes every learner of the bench's population posting three statements in
//! the same second:
//! 1. statements/s of batched POSTs (100 per request, 4 concurrent clients) [>= 3,000/s on 2 cores];
//! 2. p50/p99 of a single-statement POST, one client [p99 < 20 ms];
//! 3. p50/p99 of filtered GETs (agent; agent + verb; activity; registration; verb + since) over a
//!    store of 10^6 statements [p99 < 50 ms].
//!
//! `BENCH_QUICK=1` (CI): 2,000 statements for throughput, 200 single POSTs, a store of 2 * 10^4
//! statements and 100 GETs per filter; the full run fills 10^6 (several minutes).

use std::sync::Arc;
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{Value, json};
use server::records::config::Argon2Cost;
use server::records::{auth::Role, users};
use server::{AppState, Config, app, workers::Workers};
use sha2::{Digest, Sha256};
use sim_core::stats::{percentile_of_sorted, sorted};

/// Makes one filtered GET's query string.
type QueryFn = dyn Fn(&mut Gen) -> String;

/// Learners in the generated population. Our choice: a large residency programme's cohort
/// over several years.
const LEARNERS: u64 = 1000;
/// Stations (the platform's nine).
const STATIONS: u64 = 9;
/// Statements per batched POST. Our choice: what the platform's forwarder sends.
const BATCH: usize = 100;
/// Concurrent clients of the batched phase (the forwarders of two or more platforms, and LMSs).
const CLIENTS: usize = 4;

const VERBS: [&str; 6] = [
    "http://adlnet.gov/expapi/verbs/launched",
    "http://adlnet.gov/expapi/verbs/initialized",
    "http://adlnet.gov/expapi/verbs/interacted",
    "http://adlnet.gov/expapi/verbs/experienced",
    "http://adlnet.gov/expapi/verbs/scored",
    "http://adlnet.gov/expapi/verbs/terminated",
];

/// A seeded generator, so runs are comparable.
struct Gen(rand::rngs::StdRng);

impl Gen {
    fn seeded(seed: u64) -> Gen {
        Gen(<rand::rngs::StdRng as rand::SeedableRng>::seed_from_u64(
            seed,
        ))
    }

    fn next(&mut self) -> u64 {
        rand::RngCore::next_u64(&mut self.0)
    }
}

fn learner(i: u64) -> Value {
    json!({"objectType": "Agent", "name": format!("Learner {i}"),
        "account": {"homePage": "https://sim.example.org", "name": format!("learner-{i}")}})
}

fn station(i: u64) -> String {
    format!("https://sim.example.org/xapi/activities/station/station-{i}")
}

fn registration(learner: u64, attempt: u64) -> String {
    format!("{:08x}-0000-4000-8000-{:012x}", learner, attempt)
}

/// One realistic statement.
fn statement(g: &mut Gen) -> Value {
    let (l, s, a) = (g.next() % LEARNERS, g.next() % STATIONS, g.next() % 20);
    let verb = VERBS[(g.next() % VERBS.len() as u64) as usize];
    let mut st = json!({
        "actor": learner(l),
        "verb": {"id": verb, "display": {"en-US": verb.rsplit('/').next().unwrap()}},
        "object": {"objectType": "Activity", "id": station(s), "definition": {
            "name": {"en-US": format!("Station {s}")},
            "type": "http://adlnet.gov/expapi/activities/simulation"}},
        "context": {
            "registration": registration(l, a),
            "platform": "pain-sim",
            "contextActivities": {"grouping": [{"id": "https://sim.example.org/xapi/activities/course/DEMO-101"}]},
            "extensions": {"https://sim.example.org/xapi/extensions/reproducibility": {
                "code_revision": "8fe8948", "server_version": "0.1.0",
                "station_sha256": "4f0c1b9e0d3c2a5b6e7f8091a2b3c4d5e6f708192a3b4c5d6e7f8091a2b3c4d5",
                "asset_hashes": {"region": "9b1c", "meshes": "77aa"},
                "device_profile": {"fluoro": "default", "kvp": 80},
                "imaging_settings": {"magnification": 1.0, "collimation_mm": 200}}}},
        "timestamp": "2026-11-27T05:00:00.000Z",
    });
    if verb.ends_with("scored") {
        let raw = (g.next() % 101) as f64;
        st["result"] = json!({"score": {"scaled": raw / 100.0, "raw": raw, "min": 0.0, "max": 100.0},
            "success": raw >= 70.0, "completion": true, "duration": "PT7M12S",
            "extensions": {"https://sim.example.org/xapi/extensions/criteria": [
                {"id": "needle-tip-in-target", "met": true, "measured_mm": 1.8, "limit_mm": 3.0},
                {"id": "contrast-spread", "met": raw >= 70.0, "measured": "epidural"},
                {"id": "fluoro-time", "met": true, "measured_s": 21.5, "limit_s": 60.0}]}});
    }
    st
}

/// The median, 99th percentile and largest of `ms` (NaN for none).
fn stats(ms: Vec<f64>) -> (f64, f64, f64) {
    let ms = sorted(ms);
    (
        percentile_of_sorted(&ms, 50.0),
        percentile_of_sorted(&ms, 99.0),
        percentile_of_sorted(&ms, 100.0),
    )
}

struct Client {
    http: reqwest::Client,
    base: String,
    auth: String,
}

impl Client {
    async fn post(&self, body: &Value) {
        let r = self
            .http
            .post(format!("{}/xapi/statements", self.base))
            .header("X-Experience-API-Version", "2.0.0")
            .header("Authorization", &self.auth)
            .json(body)
            .send()
            .await
            .expect("POST");
        let status = r.status();
        let text = r.text().await.unwrap_or_default();
        assert!(status.is_success(), "POST: {status} {text}");
    }

    async fn get(&self, query: &str) -> usize {
        let r = self
            .http
            .get(format!("{}/xapi/statements?{query}", self.base))
            .header("X-Experience-API-Version", "2.0.0")
            .header("Authorization", &self.auth)
            .send()
            .await
            .expect("GET");
        let status = r.status();
        let body: Value = r.json().await.unwrap_or(Value::Null);
        assert!(status.is_success(), "GET {query}: {status} {body}");
        body["statements"].as_array().map_or(0, Vec::len)
    }
}

/// Posts `total` statements in batches from [`CLIENTS`] concurrent clients; returns statements/s.
async fn fill(client: &Arc<Client>, total: usize, seed: u64) -> f64 {
    let start = Instant::now();
    let per_client = total.div_ceil(CLIENTS);
    let mut tasks = Vec::new();
    for c in 0..CLIENTS {
        let client = client.clone();
        tasks.push(tokio::spawn(async move {
            let mut g = Gen::seeded(seed * 1000 + c as u64);
            let mut left = per_client;
            while left > 0 {
                let n = left.min(BATCH);
                let batch: Vec<Value> = (0..n).map(|_| statement(&mut g)).collect();
                client.post(&Value::Array(batch)).await;
                left -= n;
            }
        }));
    }
    for t in tasks {
        t.await.expect("client task");
    }
    (per_client * CLIENTS) as f64 / start.elapsed().as_secs_f64()
}

fn urlencode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                (b as char).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let (throughput_n, singles, store, gets) = if quick {
        (2_000, 200, 20_000, 100)
    } else {
        (50_000, 2_000, 1_000_000, 500)
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async move {
        let mut config = Config::from_lookup(|_| None).expect("configuration");
        config.records.argon2 = Argon2Cost::TEST_ONLY;
        config.max_body_bytes = 8 << 20;
        let db = server::test_support::test_db().await;
        server::records::prepare(&db.pool, &config.records, false).await.expect("records");
        let admin = users::create_user(&db.pool, Argon2Cost::TEST_ONLY, "admin@bench.invalid", "Admin", Role::Admin, "bench-password-123", false)
            .await
            .expect("admin")
            .id;
        let (key, secret) = ("benchmark-lms", "benchmark-secret");
        sqlx::query(
            "INSERT INTO lrs_credentials (id, name, key, secret_sha256, can_read, can_write, authority, created_by)
             VALUES ($1, 'bench', $2, $3, TRUE, TRUE, $4, $5)",
        )
        .bind(uuid::Uuid::new_v4())
        .bind(key)
        .bind(Sha256::digest(secret.as_bytes()).to_vec())
        .bind(json!({"objectType": "Agent", "name": "bench", "account": {"homePage": "https://sim.example.org/xapi/", "name": key}}))
        .bind(admin)
        .execute(&db.pool)
        .await
        .expect("credential");
        let state = AppState {
            pool: db.pool.clone(),
            embedded_db: true,
            workers: Workers::start_in_process(),
            dispatcher: None,
            config,
        };
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        tokio::spawn(async move { axum::serve(listener, app(state)).await });
        let client = Arc::new(Client {
            http: reqwest::Client::builder().pool_max_idle_per_host(16).build().unwrap(),
            base: format!("http://{addr}"),
            auth: format!("Basic {}", base64::engine::general_purpose::STANDARD.encode(format!("{key}:{secret}"))),
        });
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        println!("## Learning record store (loopback HTTP, PostgreSQL, {cores} cores)\n");

        // Warm-up (connections, plans), not counted.
        fill(&client, 400, 0).await;
        let rate = fill(&client, throughput_n, 1).await;
        println!("| measurement | value | goal |");
        println!("|---|---:|---|");
        println!("| batched POST ({BATCH}/request, {CLIENTS} clients, {throughput_n} statements) | {rate:.0} statements/s | >= 3000 |");

        let mut g = Gen::seeded(7);
        let mut ms = Vec::with_capacity(singles);
        for _ in 0..singles {
            let s = statement(&mut g);
            let t = Instant::now();
            client.post(&s).await;
            ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let (p50, p99, max) = stats(ms);
        println!("| single POST, {singles} requests | p50 {p50:.2} ms, p99 {p99:.2} ms, max {max:.1} ms | p99 < 20 ms |");

        let stored: i64 = sqlx::query_scalar("SELECT count(*) FROM xapi_statements")
            .fetch_one(&db.pool)
            .await
            .unwrap_or(0);
        let missing = (store as i64 - stored).max(0) as usize;
        let t = Instant::now();
        if missing > 0 {
            fill(&client, missing, 2).await;
        }
        let fill_s = t.elapsed().as_secs_f64();
        sqlx::query("ANALYZE").execute(&db.pool).await.expect("analyze");
        let stored: i64 = sqlx::query_scalar("SELECT count(*) FROM xapi_statements")
            .fetch_one(&db.pool)
            .await
            .unwrap_or(0);
        println!("| store filled to {stored} statements | {fill_s:.0} s ({:.0} statements/s) | |", missing as f64 / fill_s.max(1e-9));

        let mut g = Gen::seeded(99);
        let filters: [(&str, Box<QueryFn>); 5] = [
            ("agent", Box::new(|g: &mut Gen| format!("agent={}", urlencode(&learner(g.next() % LEARNERS).to_string())))),
            ("agent + verb", Box::new(|g: &mut Gen| format!("agent={}&verb={}", urlencode(&learner(g.next() % LEARNERS).to_string()), urlencode(VERBS[4])))),
            ("activity", Box::new(|g: &mut Gen| format!("activity={}", urlencode(&station(g.next() % STATIONS))))),
            ("registration", Box::new(|g: &mut Gen| format!("registration={}", registration(g.next() % LEARNERS, g.next() % 20)))),
            ("verb + since", Box::new(|_: &mut Gen| format!("verb={}&since={}", urlencode(VERBS[4]), urlencode("2026-01-01T00:00:00Z")))),
        ];
        let mut all = Vec::new();
        for (name, q) in &filters {
            let mut ms = Vec::with_capacity(gets);
            let mut returned = 0;
            for _ in 0..gets {
                let query = format!("{}&limit=25", q(&mut g));
                let t = Instant::now();
                returned += client.get(&query).await;
                ms.push(t.elapsed().as_secs_f64() * 1e3);
            }
            all.extend(ms.iter().copied());
            let (p50, p99, max) = stats(ms);
            println!("| GET ?{name}, limit 25, {gets} requests ({:.1} statements each) | p50 {p50:.2} ms, p99 {p99:.2} ms, max {max:.1} ms | p99 < 50 ms |", returned as f64 / gets as f64);
        }
        let (p50, p99, _) = stats(all);
        println!("| all filtered GETs | p50 {p50:.2} ms, p99 {p99:.2} ms | p99 < 50 ms |");
        tokio::time::sleep(Duration::from_millis(10)).await;
    });
}
