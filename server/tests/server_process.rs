//! The real `server` binary as a child process, shared by the whole-process tests
//! (`process`, `records_sigkill`, `session_sigkill`, `cluster_failover`): spawn it on a data folder (embedded
//! database) or a test database, read its address, wait for health, SIGTERM or SIGKILL it.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use server::records::config::Argon2Cost;
use server::test_support::{TestDb, test_db};

/// One HTTP/1.1 request over a fresh connection; returns (status, head, body). Small enough for
/// health checks and JSON calls without a client crate; status 0 never comes back (an error does).
pub fn http(
    addr: &str,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> std::io::Result<(u16, String, String)> {
    let mut s = TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut req = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Type: application/json\r\nContent-Length: {}\r\n",
        body.len()
    );
    for (k, v) in headers {
        req.push_str(&format!("{k}: {v}\r\n"));
    }
    req.push_str("\r\n");
    req.push_str(body);
    s.write_all(req.as_bytes())?;
    let mut raw = String::new();
    s.read_to_string(&mut raw)?;
    let status = raw
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let (head, body) = raw.split_once("\r\n\r\n").unwrap_or((&raw, ""));
    Ok((status, head.to_owned(), body.to_owned()))
}

/// `GET path`: (status, body).
pub fn http_get(addr: &str, path: &str) -> std::io::Result<(u16, String)> {
    http(addr, "GET", path, &[], "").map(|(s, _, b)| (s, b))
}

/// `/healthz` of the server at `addr` as JSON, whatever its status; `Null` when it cannot be
/// read (not listening yet, or not JSON).
pub fn health(addr: &str) -> serde_json::Value {
    http_get(addr, "/healthz")
        .ok()
        .and_then(|(_, b)| serde_json::from_str(&b).ok())
        .unwrap_or(serde_json::Value::Null)
}

/// A fresh database with the demo accounts and the demo station, and what a spawned `server`
/// needs to serve them: the station folder, an empty assets folder (the demo region is built in
/// memory, `render_worker::session::loader::load_region`) and the environment naming both, with
/// [`fast_auth_env`].
pub struct DemoDeployment {
    /// The database.
    pub db: TestDb,
    /// The environment of a `server` process over it.
    pub env: Vec<(&'static str, String)>,
    _stations: tempfile::TempDir,
    _assets: tempfile::TempDir,
}

/// Prepares a [`DemoDeployment`].
pub async fn demo_deployment() -> DemoDeployment {
    let db = test_db().await;
    let stations = tempfile::tempdir().unwrap();
    std::fs::write(
        stations.path().join("demo-station.toml"),
        render_worker::session::demo::demo_station_toml(&[]),
    )
    .unwrap();
    let assets = tempfile::tempdir().unwrap();
    let stations_dir = stations.path().display().to_string();
    let mut config = server::Config::from_lookup(|k| {
        (k == "PAINSIM_STATIONS_DIR").then(|| stations_dir.clone())
    })
    .expect("test configuration");
    config.records.argon2 = Argon2Cost::TEST_ONLY;
    server::records::prepare(&db.pool, &config.records, true)
        .await
        .expect("stations and demo accounts");
    let mut env = fast_auth_env();
    env.push(("PAINSIM_STATIONS_DIR", stations_dir));
    env.push(("PAINSIM_ASSETS_DIR", assets.path().display().to_string()));
    DemoDeployment {
        db,
        env,
        _stations: stations,
        _assets: assets,
    }
}

/// [`spawn_server`] against the database at `url`, from async code.
pub async fn spawn_on(
    data: &std::path::Path,
    url: &str,
    env: &[(&'static str, String)],
) -> ServerProcess {
    let (data, url, env) = (data.to_owned(), url.to_owned(), env.to_vec());
    tokio::task::spawn_blocking(move || spawn_server(&data, Some(&url), &env))
        .await
        .expect("spawn task")
}

/// The settings that make logins cheap and unthrottled in tests (argon2 at its test cost, rate
/// limits out of the way).
pub fn fast_auth_env() -> Vec<(&'static str, String)> {
    vec![
        (
            "PAINSIM_ARGON2_MEMORY_KIB",
            Argon2Cost::TEST_ONLY.memory_kib.to_string(),
        ),
        ("PAINSIM_ARGON2_ITERATIONS", "1".into()),
        ("PAINSIM_AUTH_RATE_PER_MINUTE", "100000".into()),
        ("PAINSIM_AUTH_BURST", "100000".into()),
        ("PAINSIM_WRITE_RATE_PER_MINUTE", "1000000".into()),
        ("PAINSIM_WRITE_BURST", "1000000".into()),
    ]
}

/// A running `server` process.
pub struct ServerProcess {
    /// The child.
    pub child: Child,
    /// `127.0.0.1:port` it serves on.
    pub addr: String,
}

/// Starts the `server` binary on a loopback port with `data_dir`, against `database_url` (or the
/// embedded cluster under `data_dir` when `None`), with `env` added. Returns once it printed its
/// URL; its stdout keeps being drained so it never blocks on a full pipe.
pub fn spawn_server(
    data_dir: &std::path::Path,
    database_url: Option<&str>,
    env: &[(&str, String)],
) -> ServerProcess {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_server"));
    cmd.env("PAINSIM_BIND", "127.0.0.1:0")
        .env("PAINSIM_DATA_DIR", data_dir)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    match database_url {
        Some(url) => cmd.env("DATABASE_URL", url),
        None => cmd.env_remove("DATABASE_URL"),
    };
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("spawn server");
    let mut lines = BufReader::new(child.stdout.take().expect("piped stdout")).lines();
    let line = lines
        .next()
        .expect("server printed its URL")
        .expect("readable stdout");
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|r| r.split('/').next())
        .expect("URL in the first line")
        .to_owned();
    std::thread::spawn(move || for _ in lines {});
    ServerProcess { child, addr }
}

impl ServerProcess {
    /// Polls `/healthz` until the database is ready and the render worker settled (no longer
    /// `starting`); returns how long it took and the last report. Panics after `limit`.
    pub fn wait_healthy(&self, limit: Duration) -> (Duration, serde_json::Value) {
        let start = Instant::now();
        loop {
            if let Ok((code, body)) = http_get(&self.addr, "/healthz") {
                let v: serde_json::Value = serde_json::from_str(&body).unwrap_or_default();
                let worker_settled = v["render_worker"]["state"] != "starting";
                if v["database"]["ready"] == true && worker_settled {
                    if std::env::var_os("REQUIRE_GPU").is_some() {
                        assert_eq!(code, 200, "{v}");
                    }
                    return (start.elapsed(), v);
                }
            }
            assert!(
                start.elapsed() < limit,
                "server not healthy within {limit:?}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// SIGKILL, and reap it.
    pub fn sigkill(mut self) {
        let status = Command::new("kill")
            .args(["-KILL", &self.child.id().to_string()])
            .status()
            .expect("run kill");
        assert!(status.success());
        self.child.wait().expect("reap the server");
    }

    /// SIGTERM, then waits (60 s at most) for a successful exit.
    pub fn sigterm_and_wait(mut self) {
        let status = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .expect("run kill");
        assert!(status.success());
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Some(st) = self.child.try_wait().expect("wait for the server") {
                assert!(st.success(), "server exit status after SIGTERM: {st}");
                return;
            }
            assert!(
                Instant::now() < deadline,
                "server did not exit within 60 s after SIGTERM; its threads:\n{}",
                thread_report(self.child.id())
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// Each thread of process `pid`: name, state and the kernel function it waits in, so a hang
/// says where it hangs.
pub fn thread_report(pid: u32) -> String {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return format!("(process {pid} has no /proc entry)");
    };
    let mut lines: Vec<String> = tasks
        .flatten()
        .map(|t| {
            let dir = t.path();
            let read = |f: &str| {
                std::fs::read_to_string(dir.join(f))
                    .unwrap_or_default()
                    .trim()
                    .to_owned()
            };
            let stat = read("stat");
            let state = stat
                .rsplit(") ")
                .next()
                .and_then(|r| r.split(' ').next())
                .unwrap_or("?")
                .to_owned();
            format!(
                "{:>8} {:<20} {} {}",
                t.file_name().to_string_lossy(),
                read("comm"),
                state,
                read("wchan")
            )
        })
        .collect();
    lines.sort();
    lines.join("\n")
}

impl Drop for ServerProcess {
    /// A test that fails half-way leaves no server behind.
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
