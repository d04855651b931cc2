//! Helpers of the learning-records tests: an app over a fresh database, an HTTP-ish client over
//! `oneshot`, and a fixture world of users, courses and attempts.

use std::collections::HashMap;
use std::sync::OnceLock;

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderMap, Method, Request, StatusCode};
use serde_json::{Value, json};
use server::records::auth::Role;
use server::records::config::Argon2Cost;
use server::records::{RecordsConfig, totp, users};
use server::test_support::{TestDb, test_db};
use server::{AppState, Config, app, workers::Workers};
use sqlx::PgPool;
use tower::ServiceExt;
use uuid::Uuid;

/// Password of every fixture account.
pub const PASSWORD: &str = "fixture-password-123";

/// One render worker for the whole test binary (its GPU self-test is slow and irrelevant here),
/// settled before first use so the process never exits mid-initialisation.
fn workers() -> Workers {
    static W: OnceLock<Workers> = OnceLock::new();
    W.get_or_init(|| {
        let w = Workers::start_in_process();
        w.wait_until_settled(std::time::Duration::from_secs(120));
        w
    })
    .clone()
}

/// A dispatcher with no render worker at all (an empty replay host, no in-process host): the
/// records tests exercise the dispatch routes' authorization without building any anatomy, so an
/// authorized request to open a session gets 503 (no worker), deterministically.
fn no_worker_dispatcher() -> server::dispatch::Dispatcher {
    let host = render_worker::session::SessionHost::with_regions(
        Vec::new(),
        Vec::new(),
        render_worker::session::Backends::cpu(0),
        1,
        render_worker::session::SessionConfig::default(),
    );
    server::dispatch::Dispatcher::new(None, host, None)
}

/// Configuration for tests: cheap argon2, generous auth limits unless a test sets its own.
pub fn test_config(overrides: &[(&str, &str)]) -> Config {
    let mut map: HashMap<String, String> = [
        ("PAINSIM_AUTH_RATE_PER_MINUTE", "100000"),
        ("PAINSIM_AUTH_BURST", "100000"),
        ("PAINSIM_LOGIN_MAX_FAILURES", "1000"),
        ("PAINSIM_WRITE_RATE_PER_MINUTE", "1000000"),
        ("PAINSIM_WRITE_BURST", "1000000"),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    for (k, v) in overrides {
        map.insert(k.to_string(), v.to_string());
    }
    let mut c = Config::from_lookup(|k| map.get(k).cloned()).expect("test configuration");
    c.records.argon2 = Argon2Cost::TEST_ONLY;
    c
}

/// The production router over a fresh database.
pub struct TestApp {
    /// Router (clones share the rate limiter and station catalog).
    pub router: Router,
    /// The database.
    pub db: TestDb,
    /// Settings in force.
    pub config: RecordsConfig,
}

impl TestApp {
    /// A fresh database and the app over it.
    pub async fn new(overrides: &[(&str, &str)]) -> TestApp {
        let db = test_db().await;
        let config = test_config(overrides);
        let records = config.records.clone();
        server::records::prepare(&db.pool, &records, false)
            .await
            .expect("stations register");
        let state = AppState {
            pool: db.pool.clone(),
            embedded_db: false,
            workers: workers(),
            dispatcher: Some(no_worker_dispatcher()),
            config,
        };
        TestApp {
            router: app(state),
            db,
            config: records,
        }
    }

    /// The pool.
    pub fn pool(&self) -> &PgPool {
        &self.db.pool
    }

    /// Sends a request; returns status, headers and the body (JSON when it parses, else a string).
    pub async fn send(
        &self,
        method: Method,
        uri: &str,
        session: Option<&Session>,
        body: Option<Value>,
    ) -> Response {
        let bytes = body.map(|b| b.to_string().into_bytes());
        self.send_raw(method, uri, session, bytes.map(|b| ("application/json", b)))
            .await
    }

    /// Sends raw bytes with a content type.
    pub async fn send_raw(
        &self,
        method: Method,
        uri: &str,
        session: Option<&Session>,
        body: Option<(&str, Vec<u8>)>,
    ) -> Response {
        let mut req = Request::builder().method(method).uri(uri);
        if let Some(s) = session {
            req = req
                .header("cookie", format!("painsim_session={}", s.token))
                .header("x-csrf-token", &s.csrf);
        }
        let body = match body {
            Some((ct, bytes)) => {
                req = req.header("content-type", ct);
                Body::from(bytes)
            }
            None => Body::empty(),
        };
        self.request(req.body(body).unwrap()).await
    }

    /// Sends a built request through the router and reads the whole response.
    pub async fn request(&self, req: Request<Body>) -> Response {
        let resp = self.router.clone().oneshot(req).await.unwrap();
        let status = resp.status();
        let headers = resp.headers().clone();
        let bytes = axum::body::to_bytes(resp.into_body(), 256 << 20)
            .await
            .unwrap();
        let text = String::from_utf8_lossy(&bytes).into_owned();
        let json = serde_json::from_str(&text).unwrap_or(Value::String(text.clone()));
        Response {
            status,
            headers,
            json,
            text,
        }
    }

    /// Logs in; panics unless it succeeds.
    pub async fn login(&self, email: &str, totp_code: Option<String>) -> Session {
        let r = self
            .send(
                Method::POST,
                "/api/auth/login",
                None,
                Some(json!({ "email": email, "password": PASSWORD, "totp_code": totp_code })),
            )
            .await;
        assert_eq!(r.status, StatusCode::OK, "login {email}: {}", r.text);
        Session::from_login(&r)
    }

    /// Creates an account directly.
    pub async fn user(&self, email: &str, role: Role) -> Uuid {
        users::create_user(
            self.pool(),
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
    }

    /// Enables TOTP for a user directly (as if enrolled) and returns the secret.
    pub async fn enable_totp(&self, user: Uuid) -> Vec<u8> {
        let secret = totp::new_secret();
        sqlx::query("UPDATE users SET totp_secret = $2 WHERE id = $1")
            .bind(user)
            .bind(&secret)
            .execute(self.pool())
            .await
            .unwrap();
        secret
    }

    /// Creates a course directly.
    pub async fn course(&self, code: &str) -> Uuid {
        let id = Uuid::new_v4();
        sqlx::query("INSERT INTO courses (id, code, title) VALUES ($1, $2, $2)")
            .bind(id)
            .bind(code)
            .execute(self.pool())
            .await
            .unwrap();
        id
    }

    /// Adds a member directly.
    pub async fn member(&self, course: Uuid, user: Uuid, role: &str) {
        sqlx::query("INSERT INTO course_members (course_id, user_id, role) VALUES ($1, $2, $3)")
            .bind(course)
            .bind(user)
            .bind(role)
            .execute(self.pool())
            .await
            .unwrap();
    }

    /// Opens an attempt through the API; panics unless it succeeds.
    pub async fn open_attempt(&self, session: &Session, course: Uuid, station: &str) -> Uuid {
        let r = self
            .send(
                Method::POST,
                "/api/attempts",
                Some(session),
                Some(json!({ "course_id": course, "station_id": station })),
            )
            .await;
        assert_eq!(r.status, StatusCode::CREATED, "{}", r.text);
        r.json["id"].as_str().unwrap().parse().unwrap()
    }

    /// Stores a technical result for `learner`'s `attempt` the way a simulation session does
    /// (`store_session_result` with the worker's evaluation of the same station's rubric): the
    /// records tests exercise review and approval, not the session that made the measurements
    /// (that is `dispatch.rs`). Clients cannot post results at all.
    pub async fn store_result(
        &self,
        learner: Uuid,
        attempt: Uuid,
        measurements: Value,
    ) -> Result<server::records::results::TechnicalResultView, server::ApiError> {
        let station_id: String = sqlx::query_scalar("SELECT station_id FROM attempts WHERE id = $1")
            .bind(attempt)
            .fetch_one(self.pool())
            .await
            .unwrap();
        let text = std::fs::read_to_string(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join(format!("../assets/stations/{station_id}.toml")),
        )
        .unwrap();
        let station = sim_core::rubric::Station::from_toml_str(&text).unwrap();
        let req: server::records::results::NewResult = serde_json::from_value(
            json!({ "measurements": measurements, "reproducibility": reproducibility() }),
        )
        .unwrap();
        let mut read = req.measurements.clone();
        read.retain(|k, _| station.rubric.criteria.iter().any(|c| &c.measurement == k));
        let worker_rubric = station.evaluate(&read);
        let state = server::records::RecordsState::from_parts(self.pool().clone(), self.config.clone());
        server::records::results::store_session_result(&state, learner, attempt, req, &worker_rubric).await
    }

    /// [`TestApp::store_result`] as a response: 201 with the stored result, or the error the
    /// session relay would have got.
    pub async fn submit(&self, learner: Uuid, attempt: impl std::fmt::Display, measurements: Value) -> Response {
        use axum::response::IntoResponse;
        let attempt: Uuid = attempt.to_string().parse().expect("an attempt id");
        let (status, headers, text) = match self.store_result(learner, attempt, measurements).await {
            Ok(view) => (StatusCode::CREATED, HeaderMap::new(), serde_json::to_string(&view).unwrap()),
            Err(e) => {
                let r = e.into_response();
                let (parts, body) = r.into_parts();
                let bytes = axum::body::to_bytes(body, usize::MAX).await.unwrap();
                (parts.status, parts.headers, String::from_utf8_lossy(&bytes).into_owned())
            }
        };
        Response { status, headers, json: serde_json::from_str(&text).unwrap_or(Value::String(text.clone())), text }
    }

    /// Row counts of every learning-records table, and every attempt's state (to show that
    /// nothing stored changed).
    pub async fn counts(&self) -> Vec<(String, String)> {
        let mut out = Vec::new();
        for t in [
            "users",
            "auth_sessions",
            "courses",
            "course_members",
            "station_revisions",
            "attempts",
            "activity_events",
            "technical_results",
            "result_replay_checks",
            "reviews",
            "audit_events",
        ] {
            let n: i64 = sqlx::query_scalar(&format!("SELECT count(*) FROM {t}"))
                .fetch_one(self.pool())
                .await
                .unwrap();
            out.push((t.to_string(), n.to_string()));
        }
        let states: Option<String> = sqlx::query_scalar(
            "SELECT string_agg(id::text || '=' || state, ',' ORDER BY id) FROM attempts",
        )
        .fetch_one(self.pool())
        .await
        .unwrap();
        out.push(("attempt states".into(), states.unwrap_or_default()));
        out
    }
}

/// A response.
#[derive(Debug)]
pub struct Response {
    /// Status.
    pub status: StatusCode,
    /// Headers.
    pub headers: HeaderMap,
    /// Body as JSON (a JSON string when it was not JSON).
    pub json: Value,
    /// Body as text.
    pub text: String,
}

/// A logged-in session: cookie token and CSRF token.
#[derive(Debug, Clone)]
pub struct Session {
    /// Session cookie value.
    pub token: String,
    /// CSRF token.
    pub csrf: String,
}

impl Session {
    /// From a successful login response.
    pub fn from_login(r: &Response) -> Session {
        let token = r
            .headers
            .get_all("set-cookie")
            .iter()
            .filter_map(|v| v.to_str().ok())
            .find_map(|c| {
                c.strip_prefix("painsim_session=")
                    .map(|v| v.split(';').next().unwrap().to_owned())
            })
            .expect("session cookie");
        Session {
            token,
            csrf: r.json["csrf_token"]
                .as_str()
                .expect("csrf token")
                .to_owned(),
        }
    }
}

/// A valid reproducibility record.
pub fn reproducibility() -> Value {
    json!({
        "code_revision": "0123abc",
        "asset_hashes": { "lumbar-phantom/meshes.glb": "a".repeat(64) },
        "device_profile": { "detector": "flat-panel-30cm" },
        "imaging_settings": { "kvp": 80, "ma": 2.0, "lao_deg": 0, "cranial_deg": 0 },
        "interaction_log_ref": "session-log-1"
    })
}

/// Measurements for `l4-l5-left-facet` that meet every criterion.
pub fn facet_measurements_met() -> Value {
    json!({
        "ap_endplate_tilt_deg": 1.0,
        "beam_to_joint_plane_deg": 3.0,
        "tip_to_target_mm": 1.5,
        "intra_articular_spread_bool": 1.0,
        "intravascular_uptake_bool": 0.0,
        "fluoro_acquisitions_count": 8.0,
        "skin_punctures_count": 1.0,
        "redirections_count": 1.0,
        "bone_contacts_count": 1.0,
        "air_kerma_mgy": 3.5,
        "fluoro_time_s": 12.0
    })
}

/// The fixture world of the authorization matrix.
pub struct World {
    /// Course A (the attempt's course).
    pub course_a: Uuid,
    /// Course B.
    pub course_b: Uuid,
    /// The owner learner (of A).
    pub learner: Uuid,
    /// Another learner (also of A).
    pub other_learner: Uuid,
    /// Faculty of A.
    pub faculty_a: Uuid,
    /// Faculty of B.
    pub faculty_b: Uuid,
    /// Admin.
    pub admin: Uuid,
    /// A user not in any course (target of membership changes).
    pub outsider: Uuid,
    /// The learner's attempt in progress.
    pub attempt_open: Uuid,
    /// The learner's submitted attempt.
    pub attempt_submitted: Uuid,
    /// Sessions: None for anonymous, then learner, other learner, faculty A, faculty B, admin.
    pub sessions: Vec<Option<Session>>,
    /// E-mail of the learner.
    pub learner_email: String,
    /// An LRS credential of an LMS integration (created by the admin).
    pub lrs_credential: Uuid,
    /// A registered LTI platform.
    pub lti_platform: Uuid,
}

/// Names of the matrix roles, in the order of [`World::sessions`].
pub const ROLES: [&str; 6] = [
    "anonymous",
    "learner",
    "other learner",
    "faculty of the course",
    "faculty of another course",
    "admin",
];

impl World {
    /// Builds a world with unique e-mails and course codes (`tag` makes them unique).
    pub async fn build(app: &TestApp, tag: &str) -> World {
        let e = |who: &str| format!("{who}-{tag}@example.org");
        let learner = app.user(&e("learner"), Role::Learner).await;
        let other_learner = app.user(&e("other"), Role::Learner).await;
        let faculty_a = app.user(&e("fa"), Role::Faculty).await;
        let faculty_b = app.user(&e("fb"), Role::Faculty).await;
        let admin = app.user(&e("admin"), Role::Admin).await;
        let outsider = app.user(&e("outsider"), Role::Learner).await;
        let course_a = app.course(&format!("A-{tag}")).await;
        let course_b = app.course(&format!("B-{tag}")).await;
        app.member(course_a, learner, "learner").await;
        app.member(course_a, other_learner, "learner").await;
        app.member(course_a, faculty_a, "faculty").await;
        app.member(course_b, faculty_b, "faculty").await;
        let now = totp::unix_now();
        let mut sessions = vec![None];
        for (who, id) in [
            ("learner", learner),
            ("other", other_learner),
            ("fa", faculty_a),
            ("fb", faculty_b),
            ("admin", admin),
        ] {
            let code = if matches!(who, "fa" | "fb" | "admin") {
                let secret = app.enable_totp(id).await;
                Some(totp::code_at(&secret, now))
            } else {
                None
            };
            sessions.push(Some(app.login(&e(who), code).await));
        }
        let ls = sessions[1].as_ref().unwrap();
        let attempt_open = app.open_attempt(ls, course_a, "l4-l5-left-facet").await;
        let attempt_submitted = app.open_attempt(ls, course_a, "l4-l5-left-facet").await;
        app.store_result(learner, attempt_submitted, facet_measurements_met())
            .await
            .expect("a session result is stored");
        let lrs_credential = Uuid::new_v4();
        sqlx::query(
            "INSERT INTO lrs_credentials (id, name, key, secret_sha256, can_read, can_write, authority, created_by)
             VALUES ($1, $2, $3, sha256($2::bytea), TRUE, TRUE, '{}'::jsonb, $4)",
        )
        .bind(lrs_credential)
        .bind(format!("LMS {tag}"))
        .bind(lrs_credential.simple().to_string())
        .bind(admin)
        .execute(&app.db.pool)
        .await
        .expect("a fixture LRS credential");
        let lti_platform = Uuid::new_v4();
        sqlx::query(
            "INSERT INTO lti_platforms (id, name, issuer, client_id, deployment_ids, auth_url, token_url, jwks_url)
             VALUES ($1, $2, $3, 'tool', ARRAY['1'], 'https://lms.example.org/auth',
                     'https://lms.example.org/token', 'https://lms.example.org/jwks')",
        )
        .bind(lti_platform)
        .bind(format!("LMS {tag}"))
        .bind(format!("https://lms.example.org/{tag}"))
        .execute(&app.db.pool)
        .await
        .expect("a fixture LTI platform");
        World {
            course_a,
            course_b,
            learner,
            other_learner,
            faculty_a,
            faculty_b,
            admin,
            outsider,
            attempt_open,
            attempt_submitted,
            sessions,
            learner_email: e("learner"),
            lrs_credential,
            lti_platform,
        }
    }
}
