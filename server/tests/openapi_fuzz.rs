//! The OpenAPI document against the real server: schemathesis (a pinned version, installed by
//! `.ci/install-deps test` into `target/schemathesis-venv`) fuzzes every documented operation as
//! four identities, one run each: anonymous, a learner (enrolled, with an open attempt), faculty
//! of the learner's course and an admin (both with TOTP enabled and logged in with a valid code).
//!
//! Each run uses every phase: examples (none yet: the document has no examples), coverage,
//! fuzzing, and the stateful phase over the links schemathesis infers from the document (utoipa
//! 5.5 writes explicit links with snake_case keys that schemathesis refuses, so the document
//! declares none). The checks are `not_a_server_error`, `status_code_conformance`,
//! `content_type_conformance`, `response_schema_conformance`, `positive_data_acceptance` (a
//! schema-valid request is not refused with 400 or 422: the document states every constraint the
//! server enforces) and `negative_data_rejection` (a request that breaks the document is
//! refused). Semantic refusals no schema can express (a wrong current password is 403, an attempt
//! in the wrong state 409, an unknown id 404) are documented responses and lie within
//! schemathesis's default expected statuses of `positive_data_acceptance`, so its defaults stay.
//! The one exception, configured for that operation alone in `tests/schemathesis.toml`: adding a
//! member whose account role does not fit the course role is a 400 (`records_bad_input.rs`).
//!
//! Bounded for CI: [`MAX_EXAMPLES`] cases per operation and phase, a fixed [`SEED`], one worker.
//! Each run's full output and JUnit report land in `target/openapi-fuzz/`, beside the document.
//! A run's exit status alone would also pass a run that tested nothing, so each run must also show
//! every operation the document lists, less the exclusions below, as tested: a JUnit test case per
//! operation, none skipped, the summary's selected and tested counts, every one of them run by the
//! coverage and the fuzzing phases, and at least two generated cases per operation.
//!
//! Exclusions, and why: only `POST /api/auth/logout` is left out of the three logged-in runs,
//! because it ends the very session the run authenticates with (everything after it would test
//! nothing but 401); the anonymous run covers it, and `records_auth.rs` tests logging out. The
//! other operations that could end a session cannot end the run's own: changing one's password
//! needs the current one (the fuzzer never has it, so it gets 403, and `records_accounts.rs`
//! tests the change), an admin cannot disable their own account (409), and disabling or
//! resetting other accounts only touches accounts created for this test, with the admin run last
//! so no other identity's run depends on them afterwards.
//!
//! The websocket handshake `GET /api/sessions/{session_id}/ws` is left out of every run: a
//! successful handshake answers 101 and switches protocols, which an HTTP schema fuzzer reads as
//! neither success nor refusal. Its handshake headers are documented, and the session protocol
//! behind it is fuzzed by `dispatch_ws_fuzz.rs` (malformed, oversized, out-of-range, bursts with
//! and without reading). Every other operation, the session, replay and worker routes included,
//! is fuzzed: nothing here lists operations. The server has the in-process dispatcher
//! over the render worker's demo region and station, as in `dispatch.rs`.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use render_worker::cluster::request_with_headers;
use render_worker::session::demo::demo_station_toml;
use serde_json::json;
use server::dispatch::Dispatcher;
use server::records::auth::Role;
use server::records::config::Argon2Cost;
use server::records::{totp, users};
use server::test_support::test_db;
use server::{AppState, app};
use uuid::Uuid;

use crate::dispatch::{base_workers, demo_host};
use crate::records_support::{PASSWORD, test_config};

/// Test cases per operation and phase, bounded for CI's time: on 2 cores in the dev profile the
/// four runs took 368 s at 40 (the fuzzing phase about 60 s of each run's 90) and about 225 s at
/// 20 (fuzzing 20 to 34 s of each run's 42 to 65).
const MAX_EXAMPLES: u32 = 20;

/// Fixed so that a failure reproduces.
const SEED: u64 = 20;

/// The checks every run applies.
const CHECKS: &str = "not_a_server_error,status_code_conformance,content_type_conformance,\
    response_schema_conformance,positive_data_acceptance,negative_data_rejection";

/// The schemathesis CLI in the virtualenv that `.ci/install-deps test` creates.
fn schemathesis() -> PathBuf {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../target/schemathesis-venv/bin/schemathesis");
    assert!(
        path.exists(),
        "{} is missing: run `.ci/install-deps test` to install schemathesis",
        path.display()
    );
    path
}

/// Logs in over HTTP; returns the cookie and the CSRF token.
async fn login(
    addr: std::net::SocketAddr,
    email: &str,
    totp_code: Option<String>,
) -> (String, String) {
    let r = request_with_headers(
        "POST",
        &format!("http://{addr}/api/auth/login"),
        Some(&json!({ "email": email, "password": PASSWORD, "totp_code": totp_code })),
        &[],
    )
    .await
    .expect("login request");
    assert_eq!(
        r.status,
        200,
        "login {email}: {}",
        String::from_utf8_lossy(&r.body)
    );
    let cookie = r
        .headers
        .iter()
        .filter(|(k, _)| k == "set-cookie")
        .filter_map(|(_, v)| v.split(';').next())
        .find(|c| c.starts_with("painsim_session="))
        .expect("session cookie")
        .to_string();
    let csrf = r.json().unwrap()["csrf_token"]
        .as_str()
        .unwrap()
        .to_string();
    (cookie, csrf)
}

/// What one schemathesis run reported, from its summary: operations tested, test cases (`N
/// generated, M passed` or how many found failures) and its closing line (`No issues found in
/// 5.1s`, or the failures and errors).
#[derive(Debug)]
struct RunCounts {
    operations: String,
    test_cases: String,
    outcome: String,
}

fn counts(output: &str) -> RunCounts {
    let lines: Vec<&str> = output.lines().map(str::trim).collect();
    let after = |heading: &str| {
        lines
            .iter()
            .rposition(|l| *l == heading)
            .and_then(|i| lines.get(i + 1))
            .map_or("(not reported)".to_string(), |l| l.to_string())
    };
    let operations = lines
        .iter()
        .rev()
        .find_map(|l| l.strip_prefix("Tested: "))
        .unwrap_or("(not reported)")
        .to_string();
    let outcome = lines
        .iter()
        .rev()
        .find(|l| l.starts_with("==="))
        .map_or("(not reported)", |l| {
            l.trim_matches(|c| c == '=' || c == ' ')
        })
        .to_string();
    RunCounts {
        operations,
        test_cases: after("Test cases:"),
        outcome,
    }
}

/// The operations a document lists, as schemathesis names them (`GET /api/auth/me`).
fn documented_operations(doc: &serde_json::Value) -> BTreeSet<String> {
    const METHODS: [&str; 8] = [
        "get", "put", "post", "delete", "patch", "head", "options", "trace",
    ];
    doc["paths"]
        .as_object()
        .expect("the document lists paths")
        .iter()
        .flat_map(|(path, item)| {
            METHODS
                .iter()
                .filter(|m| item.get(**m).is_some())
                .map(move |m| format!("{} {path}", m.to_uppercase()))
        })
        .collect()
}

/// The operations one JUnit report has a test case for (its stateful-phase case left out), and
/// how many cases it reports skipped.
fn junit_operations(xml: &str) -> (BTreeSet<String>, usize) {
    let names = xml
        .split("<testcase name=\"")
        .skip(1)
        .filter_map(|rest| rest.split('"').next())
        .map(|name| {
            name.replace("&quot;", "\"")
                .replace("&lt;", "<")
                .replace("&gt;", ">")
                .replace("&apos;", "'")
                .replace("&amp;", "&")
        })
        .filter(|name| name != "Stateful tests")
        .collect();
    (names, xml.matches("<skipped").count())
}

/// How many operations a phase of the run exercised (passed or failed) and how many it skipped
/// or could not run, from the line below its heading (`✅ 62 passed  ❌  1 failed`); `None`
/// when the output has no such phase.
fn phase_counts(lines: &[&str], phase: &str) -> Option<(u64, u64)> {
    let at = lines
        .iter()
        .position(|l| l.contains(&format!("{phase} (in ")))?;
    let line = lines[at + 1..].iter().find(|l| !l.is_empty())?;
    let words: Vec<&str> = line.split_whitespace().collect();
    let (mut exercised, mut not_run) = (0, 0);
    for pair in words.windows(2) {
        if let Ok(n) = pair[0].parse::<u64>() {
            if pair[1].starts_with("passed") || pair[1].starts_with("failed") {
                exercised += n;
            } else {
                not_run += n;
            }
        }
    }
    Some((exercised, not_run))
}

/// What shows that one run tested every operation it was meant to, each through the coverage
/// and fuzzing phases: its JUnit report (in `report`, which the run had to itself) and its
/// output. Returns each shortfall found.
fn coverage_problems(
    text: &str,
    report: &Path,
    expected: &BTreeSet<String>,
    documented: usize,
) -> Vec<String> {
    let mut problems = Vec::new();
    let reports: Vec<PathBuf> = std::fs::read_dir(report)
        .map(|d| d.filter_map(Result::ok).map(|e| e.path()).collect())
        .unwrap_or_default();
    match reports.as_slice() {
        [one] => {
            let xml = std::fs::read_to_string(one).expect("read the JUnit report");
            let (tested, skipped) = junit_operations(&xml);
            let missing: Vec<_> = expected.difference(&tested).collect();
            let unknown: Vec<_> = tested.difference(expected).collect();
            if !missing.is_empty() || !unknown.is_empty() {
                problems.push(format!(
                    "JUnit report: {} of {} operations tested; missing {missing:?}, \
                     not documented or excluded {unknown:?}",
                    tested.len(),
                    expected.len()
                ));
            }
            if skipped > 0 {
                problems.push(format!("JUnit report: {skipped} test cases skipped"));
            }
        }
        other => problems.push(format!("expected one JUnit report, found {other:?}")),
    }
    let lines: Vec<&str> = text.lines().map(str::trim).collect();
    let field = |name: &str| lines.iter().rev().find_map(|l| l.strip_prefix(name));
    let selected = format!("{}/{documented}", expected.len());
    if field("Selected: ") != Some(selected.as_str()) {
        problems.push(format!(
            "selected {:?}, expected {selected}",
            field("Selected: ")
        ));
    }
    let tested = expected.len().to_string();
    if field("Tested: ") != Some(tested.as_str()) {
        problems.push(format!(
            "tested {:?} operations, expected {tested}",
            field("Tested: ")
        ));
    }
    // Every operation runs in the coverage phase and in the fuzzing phase (the examples phase
    // skips those without examples, and the stateful phase follows links), so both report
    // every operation, none skipped.
    let operations = expected.len() as u64;
    for phase in ["Coverage", "Fuzzing"] {
        match phase_counts(&lines, phase) {
            Some((exercised, 0)) if exercised == operations => {}
            found => problems.push(format!(
                "{phase} phase: (exercised, skipped or not run) = {found:?}, \
                 expected {operations} exercised"
            )),
        }
    }
    // At least one generated case per operation in each of those two phases.
    let generated = lines
        .iter()
        .position(|l| *l == "Test cases:")
        .and_then(|i| lines.get(i + 1))
        .and_then(|l| l.split_whitespace().next())
        .and_then(|n| n.parse::<u64>().ok());
    if generated.is_none_or(|n| n < 2 * operations) {
        problems.push(format!(
            "{generated:?} test cases generated, fewer than two per operation ({})",
            2 * operations
        ));
    }
    problems
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_documented_operation_holds_under_schemathesis() {
    let cli = schemathesis();
    let stations = tempfile::tempdir().expect("temporary stations folder");
    std::fs::write(
        stations.path().join("demo-station.toml"),
        demo_station_toml(&[]),
    )
    .expect("write the demo station");
    let dir = stations.path().display().to_string();
    let config = test_config(&[("PAINSIM_STATIONS_DIR", &dir)]);
    let db = test_db().await;
    server::records::prepare(&db.pool, &config.records, false)
        .await
        .expect("stations register");
    let host = demo_host(8);
    let state = AppState {
        pool: db.pool.clone(),
        embedded_db: false,
        workers: base_workers(),
        dispatcher: Some(Dispatcher::new(Some(host.clone()), host, None)),
        config,
    };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind a loopback port");
    let addr = listener.local_addr().expect("local address");
    let router = app(state);
    tokio::spawn(async move { axum::serve(listener, router).await });

    // The identities' accounts (and a few bystanders for the admin's account operations).
    let pool = &db.pool;
    let account = |email: &'static str, role: Role| async move {
        users::create_user(
            pool,
            Argon2Cost::TEST_ONLY,
            email,
            email,
            role,
            PASSWORD,
            false,
        )
        .await
        .expect("create user")
        .id
    };
    let learner = account("fuzz-learner@example.org", Role::Learner).await;
    let faculty = account("fuzz-faculty@example.org", Role::Faculty).await;
    let admin = account("fuzz-admin@example.org", Role::Admin).await;
    account("fuzz-bystander@example.org", Role::Learner).await;
    let course = Uuid::new_v4();
    sqlx::query("INSERT INTO courses (id, code, title) VALUES ($1, 'FUZZ-1', 'Fuzzing')")
        .bind(course)
        .execute(pool)
        .await
        .unwrap();
    for (user, role) in [(learner, "learner"), (faculty, "faculty")] {
        sqlx::query("INSERT INTO course_members (course_id, user_id, role) VALUES ($1, $2, $3)")
            .bind(course)
            .bind(user)
            .bind(role)
            .execute(pool)
            .await
            .unwrap();
    }
    let with_totp = |user: Uuid| async move {
        let secret = totp::new_secret();
        sqlx::query("UPDATE users SET totp_secret = $2 WHERE id = $1")
            .bind(user)
            .bind(&secret)
            .execute(pool)
            .await
            .unwrap();
        Some(totp::code_at(&secret, totp::unix_now()))
    };
    let faculty_code = with_totp(faculty).await;
    let admin_code = with_totp(admin).await;
    let learner_login = login(addr, "fuzz-learner@example.org", None).await;
    let faculty_login = login(addr, "fuzz-faculty@example.org", faculty_code).await;
    let admin_login = login(addr, "fuzz-admin@example.org", admin_code).await;
    let r = request_with_headers(
        "POST",
        &format!("http://{addr}/api/attempts"),
        Some(&json!({ "course_id": course, "station_id": "demo-station" })),
        &[
            ("cookie", learner_login.0.as_str()),
            ("x-csrf-token", learner_login.1.as_str()),
        ],
    )
    .await
    .expect("open an attempt");
    assert_eq!(r.status, 201, "{}", String::from_utf8_lossy(&r.body));

    // The document under test, kept beside the reports for reading.
    let out_dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target/openapi-fuzz");
    std::fs::create_dir_all(&out_dir).expect("create target/openapi-fuzz");
    let doc = request_with_headers("GET", &format!("http://{addr}/api/openapi.json"), None, &[])
        .await
        .expect("fetch the document");
    assert_eq!(doc.status, 200);
    std::fs::write(out_dir.join("openapi.json"), &doc.body).expect("write openapi.json");
    let documented = documented_operations(&doc.json().expect("the document is JSON"));
    // The operations left out (see the module doc): each is documented, so leaving it out is
    // what keeps it from the run, and every other one must be tested.
    const WEBSOCKET: &str = "GET /api/sessions/{session_id}/ws";
    const LOGOUT: &str = "POST /api/auth/logout";
    for left_out in [WEBSOCKET, LOGOUT] {
        assert!(
            documented.contains(left_out),
            "{left_out} is not documented"
        );
    }

    let identities: [(&str, Option<&(String, String)>); 4] = [
        ("anonymous", None),
        ("learner", Some(&learner_login)),
        ("faculty", Some(&faculty_login)),
        ("admin", Some(&admin_login)),
    ];
    let started = Instant::now();
    let mut failed = Vec::new();
    let mut untested = Vec::new();
    for (who, auth) in identities {
        let mut cmd = Command::new(&cli);
        cmd.arg("--config-file")
            .arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/schemathesis.toml"))
            .arg("run")
            .arg(format!("http://{addr}/api/openapi.json"))
            .args(["--checks", CHECKS])
            .args(["--max-examples", &MAX_EXAMPLES.to_string()])
            .args(["--seed", &SEED.to_string()])
            .args([
                "--workers",
                "1",
                "--no-color",
                "--suppress-health-check",
                "all",
            ])
            .args(["--output-sanitize", "false"])
            // The websocket handshake is not an HTTP request/response pair: see the module doc.
            .args(["--exclude-path", "/api/sessions/{session_id}/ws"])
            .env("SCHEMATHESIS_HOOKS", "")
            .current_dir(std::env::temp_dir());
        if let Some((cookie, csrf)) = auth {
            cmd.args(["-H", &format!("Cookie: {cookie}")])
                .args(["-H", &format!("X-CSRF-Token: {csrf}")])
                .args(["--exclude-path", "/api/auth/logout"]);
        }
        let report = out_dir.join(who);
        // The run's report is the only one in its folder, so the check below reads this run's.
        match std::fs::remove_dir_all(&report) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                panic!("clear {}: {e}", report.display())
            }
            _ => {}
        }
        cmd.args(["--report", "junit", "--report-dir"]).arg(&report);
        let mut expected = documented.clone();
        expected.remove(WEBSOCKET);
        if auth.is_some() {
            expected.remove(LOGOUT);
        }
        let run_started = Instant::now();
        let out = tokio::task::spawn_blocking(move || cmd.output())
            .await
            .unwrap()
            .expect("run schemathesis");
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        std::fs::write(out_dir.join(format!("{who}.log")), &text).expect("write the run's output");
        let c = counts(&text);
        println!(
            "openapi fuzz as {who}: {} operations, test cases: {}; {} (exit {:?}, {:.0?})",
            c.operations,
            c.test_cases,
            c.outcome,
            out.status.code(),
            run_started.elapsed()
        );
        if !out.status.success() {
            println!("{text}");
            println!("(also in target/openapi-fuzz/{who}.log)");
            failed.push(who);
        }
        // A run that tested nothing also exits 0: it must have tested every operation.
        for problem in coverage_problems(&text, &report, &expected, documented.len()) {
            untested.push(format!("{who}: {problem}"));
        }
    }
    println!("openapi fuzz: four runs in {:.0?}", started.elapsed());
    assert!(
        untested.is_empty(),
        "schemathesis did not test every operation:\n{}",
        untested.join("\n")
    );
    assert!(
        failed.is_empty(),
        "schemathesis found failures as {failed:?} (output above)"
    );
}
