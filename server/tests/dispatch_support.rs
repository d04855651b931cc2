//! Fixtures of the dispatch tests, shared by every module that drives live sessions through the
//! server (`dispatch`, `dispatch_hardening`, `dispatch_ws_fuzz`, `modality_extension`,
//! `e2e_browser`, ...): the in-process demo host, a server on a loopback port over a fresh
//! database, a logged-in HTTP client and a session websocket with helpers.
//!
//! Sessions run on the render worker's analytic demo region (boxes of known geometry) and its
//! demo station, so frames render in milliseconds; the station file is written to a temporary
//! stations folder that the learning records load too, so both sides agree on its hash.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use futures::{SinkExt, StreamExt};
use render_worker::cluster::request_with_headers;
use render_worker::session::demo::{demo_region, demo_station, demo_station_toml};
use render_worker::session::{Backends, SessionConfig, SessionHost};
use serde_json::{Value, json};
use server::dispatch::Dispatcher;
use server::records::config::Argon2Cost;
use server::test_support::{TestDb, test_db};
use server::{AppState, Config, app, workers::Workers};
use sim_core::rubric::Station;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

/// Password of the demo accounts.
pub const DEMO_PASSWORD: &str = server::records::demo::DEMO_PASSWORD;

/// One render worker status tracker for the whole test binary (see `records_support`).
pub fn base_workers() -> Workers {
    static W: OnceLock<Workers> = OnceLock::new();
    W.get_or_init(|| {
        let w = Workers::start_in_process();
        w.wait_until_settled(Duration::from_secs(120));
        w
    })
    .clone()
}

/// An in-process session host over the demo station and region.
pub fn demo_host(capacity: usize) -> SessionHost {
    demo_host_with(capacity, &[])
}

/// [`demo_host`] whose demo station also lists `extra_modalities` (`"contrast"`).
pub fn demo_host_with(capacity: usize, extra_modalities: &[&str]) -> SessionHost {
    demo_host_for(capacity, demo_station(extra_modalities))
}

/// An in-process session host over one station (parsed, with the SHA-256 of its text) on the
/// demo region.
pub fn demo_host_for(capacity: usize, station: (Station, String)) -> SessionHost {
    SessionHost::with_regions(
        vec![station],
        vec![Arc::new(demo_region())],
        Backends::cpu(0),
        capacity,
        SessionConfig::default(),
    )
}

/// A server on a loopback port over a fresh database with the demo accounts and station.
pub struct DemoServer {
    /// Its address.
    pub addr: SocketAddr,
    /// The database.
    pub db: TestDb,
    /// The dispatcher it uses.
    pub dispatcher: Dispatcher,
    /// The demo station and the SHA-256 of its text.
    pub station: (Station, String),
    /// The cluster token, if workers are accepted.
    pub token: Option<String>,
    stations: tempfile::TempDir,
}

/// Starts a [`DemoServer`]: sessions in-process when `in_process`, and remote workers accepted
/// with `worker_token`.
pub async fn demo_server(in_process: bool, worker_token: Option<&str>) -> DemoServer {
    demo_server_with(in_process, worker_token, &[]).await
}

/// [`demo_server`] whose demo station also lists `extra_modalities` (`"contrast"`).
pub async fn demo_server_with(
    in_process: bool,
    worker_token: Option<&str>,
    extra_modalities: &[&str],
) -> DemoServer {
    demo_server_for(
        in_process,
        worker_token,
        &demo_station_toml(extra_modalities),
    )
    .await
}

/// [`demo_server_with`] over the station `station_toml` (on the demo region), written to the
/// stations folder the learning records load and served by an in-process host.
pub async fn demo_server_for(
    in_process: bool,
    worker_token: Option<&str>,
    station_toml: &str,
) -> DemoServer {
    demo_server_sized(in_process, worker_token, station_toml, 8).await
}

/// [`demo_server_for`] whose in-process host holds at most `capacity` sessions.
pub async fn demo_server_sized(
    in_process: bool,
    worker_token: Option<&str>,
    station_toml: &str,
    capacity: usize,
) -> DemoServer {
    let station = Station::from_toml_str(station_toml)
        .unwrap_or_else(|e| panic!("test station: {e}\n{station_toml}"));
    let hash = render_worker::session::sha256_hex(station_toml.as_bytes());
    let stations = tempfile::tempdir().expect("temporary stations folder");
    std::fs::write(stations.path().join("demo-station.toml"), station_toml)
        .expect("write the demo station");
    let config = test_config(stations.path());
    let db = test_db().await;
    server::records::prepare(&db.pool, &config.records, true)
        .await
        .expect("stations and demo accounts");
    let host = demo_host_for(capacity, (station.clone(), hash.clone()));
    let (addr, dispatcher) = serve_replica(
        db.pool.clone(),
        config,
        host,
        in_process,
        worker_token,
        "replica-a",
    )
    .await;
    DemoServer {
        addr,
        db,
        dispatcher,
        station: (station, hash),
        token: worker_token.map(str::to_owned),
        stations,
    }
}

/// The configuration of a test server over the stations of `stations` (fast password hashing,
/// no login rate limits).
fn test_config(stations: &std::path::Path) -> Config {
    let map: HashMap<&str, String> = [
        ("PAINSIM_STATIONS_DIR", stations.display().to_string()),
        ("PAINSIM_AUTH_RATE_PER_MINUTE", "100000".into()),
        ("PAINSIM_AUTH_BURST", "100000".into()),
    ]
    .into_iter()
    .collect();
    let mut config = Config::from_lookup(|k| map.get(k).cloned()).expect("test configuration");
    config.records.argon2 = Argon2Cost::TEST_ONLY;
    config
}

/// One server replica over `pool`: its own in-process demo host (when `in_process`) and
/// dispatcher named `replica`, served on a loopback port with the peers' addresses (as the
/// server binary does).
async fn serve_replica(
    pool: sqlx::PgPool,
    config: Config,
    host: SessionHost,
    in_process: bool,
    worker_token: Option<&str>,
    replica: &str,
) -> (SocketAddr, Dispatcher) {
    let dispatcher = Dispatcher::new(
        in_process.then(|| host.clone()),
        host,
        worker_token.map(str::to_owned),
    );
    dispatcher.set_replica(replica);
    let state = AppState {
        pool,
        embedded_db: true,
        workers: base_workers(),
        dispatcher: Some(dispatcher.clone()),
        config,
    };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind a loopback port");
    let addr = listener.local_addr().expect("local address");
    let router = app(state).into_make_service_with_connect_info::<SocketAddr>();
    tokio::spawn(async move { axum::serve(listener, router).await });
    (addr, dispatcher)
}

/// A second server replica beside `srv`: the same database (through a pool of its own), its own
/// in-process demo host and dispatcher, named `replica`. PostgreSQL is all they share.
pub async fn second_replica(srv: &DemoServer, replica: &str) -> (SocketAddr, Dispatcher) {
    let config = test_config(srv.stations.path());
    let pool = sqlx::PgPool::connect(&srv.db.url)
        .await
        .expect("a second pool to the test database");
    let host = demo_host_for(8, srv.station.clone());
    serve_replica(pool, config, host, true, srv.token.as_deref(), replica).await
}

/// A logged-in HTTP client (cookie and CSRF token).
#[derive(Clone)]
pub struct Client {
    /// Server address.
    pub addr: SocketAddr,
    /// `painsim_session=...`.
    pub cookie: String,
    /// CSRF token.
    pub csrf: String,
}

impl Client {
    /// Logs in a demo account.
    pub async fn login(addr: SocketAddr, email: &str) -> Client {
        let r = request_with_headers(
            "POST",
            &format!("http://{addr}/api/auth/login"),
            Some(&json!({ "email": email, "password": DEMO_PASSWORD })),
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
        Client { addr, cookie, csrf }
    }

    /// A request; returns status and JSON (or Null).
    pub async fn call(&self, method: &str, path: &str, body: Option<Value>) -> (u16, Value) {
        let headers = [
            ("Cookie", self.cookie.as_str()),
            ("X-CSRF-Token", self.csrf.as_str()),
        ];
        let r = request_with_headers(
            method,
            &format!("http://{}{path}", self.addr),
            body.as_ref(),
            &headers,
        )
        .await
        .expect("request");
        (r.status, r.json().unwrap_or(Value::Null))
    }

    /// Opens an attempt at the demo station in the demo course and its session.
    pub async fn start_demo_attempt(&self) -> (String, Value) {
        let (id, (s, session)) = self.try_demo_attempt().await;
        assert_eq!(s, 201, "{session}");
        (id, session)
    }

    /// The id of the demo course (`DEMO-101`) as the caller's course list gives it.
    pub async fn demo_course(&self) -> Value {
        let (s, courses) = self.call("GET", "/api/courses", None).await;
        assert_eq!(s, 200);
        courses
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["code"] == "DEMO-101")
            .expect("demo course")["id"]
            .clone()
    }

    /// Opens a demo attempt and asks for its session: the attempt id, the status and the body.
    pub async fn try_demo_attempt(&self) -> (String, (u16, Value)) {
        let course = self.demo_course().await;
        let id = self.new_attempt_in(&course).await;
        let answer = self.session_of(&id).await;
        (id, answer)
    }

    /// Asks for the session of an existing attempt (the running one, or resumed): status, body.
    pub async fn session_of(&self, attempt: &str) -> (u16, Value) {
        self.call("POST", &format!("/api/attempts/{attempt}/session"), None)
            .await
    }

    /// Opens an attempt at the demo station in `course`; its id.
    pub async fn new_attempt_in(&self, course: &Value) -> String {
        let (s, attempt) = self
            .call(
                "POST",
                "/api/attempts",
                Some(json!({ "course_id": course, "station_id": "demo-station" })),
            )
            .await;
        assert_eq!(s, 201, "{attempt}");
        attempt["id"].as_str().unwrap().to_string()
    }

    /// Opens the session's websocket through the server.
    pub async fn websocket(&self, ws_path: &str) -> Ws {
        let mut req = format!("ws://{}{ws_path}", self.addr)
            .into_client_request()
            .unwrap();
        req.headers_mut()
            .insert("Cookie", self.cookie.parse().unwrap());
        let (ws, _) = tokio_tungstenite::connect_async(req)
            .await
            .expect("websocket through the server");
        Ws { ws }
    }
}

/// A session websocket with helpers.
pub struct Ws {
    /// The socket itself.
    pub ws: tokio_tungstenite::WebSocketStream<
        tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>,
    >,
}

/// What arrived: text messages as JSON, and frames as (input_seq, jpeg length).
#[derive(Debug, Default)]
pub struct Received {
    /// Text messages.
    pub texts: Vec<Value>,
    /// Frames: the input sequence they reflect.
    pub frames: Vec<u64>,
}

impl Ws {
    /// Sends a command.
    pub async fn send(&mut self, seq: u64, command: Value) {
        let m = json!({ "type": "command", "seq": seq, "command": command }).to_string();
        self.ws.send(Message::Text(m.into())).await.expect("send");
    }

    /// The next message (at most 60 s: a hang fails the test).
    pub async fn next_message(&mut self) -> Message {
        tokio::time::timeout(Duration::from_secs(60), self.ws.next())
            .await
            .expect("a message within 60 s")
            .expect("open")
            .expect("ok")
    }

    /// Reads until the server closes the socket (within `within`: a hang fails the test),
    /// keeping the text messages that arrive; the close code and reason, `None` when the socket
    /// ended without a close frame.
    pub async fn until_closed(
        &mut self,
        got: &mut Received,
        within: Duration,
    ) -> Option<(u16, String)> {
        let deadline = tokio::time::Instant::now() + within;
        loop {
            let m = tokio::time::timeout_at(deadline, self.ws.next())
                .await
                .expect("the socket closes in time");
            match m {
                Some(Ok(Message::Text(t))) => got.texts.push(serde_json::from_str(&t).unwrap()),
                Some(Ok(Message::Close(f))) => {
                    return f.map(|f| (u16::from(f.code), f.reason.to_string()));
                }
                Some(Ok(_)) => {}
                Some(Err(_)) | None => return None,
            }
        }
    }

    /// Reads until `done` holds for what arrived (at most 60 s: a hang fails the test).
    pub async fn until(&mut self, got: &mut Received, done: impl Fn(&Received) -> bool) {
        while !done(got) {
            match self.next_message().await {
                Message::Text(t) => got.texts.push(serde_json::from_str(&t).unwrap()),
                Message::Binary(b) => {
                    let f =
                        render_worker::session::frame::EncodedFrame::parse(&b).expect("a frame");
                    got.frames.push(f.input_seq);
                }
                _ => {}
            }
        }
    }
}

/// Disables the account `email` as the demo admin (through the server at `addr`): its login
/// sessions are revoked, and with them its live sessions.
pub async fn disable_account(addr: SocketAddr, pool: &sqlx::PgPool, email: &str) {
    let user: uuid::Uuid = sqlx::query_scalar("SELECT id FROM users WHERE email = $1")
        .bind(email)
        .fetch_one(pool)
        .await
        .unwrap();
    let admin = Client::login(addr, "admin@demo.invalid").await;
    let (s, body) = admin
        .call("POST", &format!("/api/users/{user}/disable"), None)
        .await;
    assert_eq!(s, 200, "{body}");
}

/// Acknowledged sequence numbers (not duplicates).
pub fn acked(r: &Received) -> Vec<u64> {
    r.texts
        .iter()
        .filter(|t| t["type"] == "ack" && t["duplicate"] != true)
        .map(|t| t["seq"].as_u64().unwrap())
        .collect()
}
