//! The real `server` binary with its embedded database: ready, SIGTERM, restart.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Minimal HTTP/1.1 GET returning (status, body); enough for health checks without a client crate.
pub fn http_get(addr: &str, path: &str) -> std::io::Result<(u16, String)> {
    let mut s = TcpStream::connect(addr)?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")?;
    let mut raw = String::new();
    s.read_to_string(&mut raw)?;
    let status = raw.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    let body = raw.split_once("\r\n\r\n").map(|(_, b)| b.to_owned()).unwrap_or_default();
    Ok((status, body))
}

struct Server {
    child: Child,
    addr: String,
}

fn spawn_server(data_dir: &std::path::Path) -> Server {
    let mut child = Command::new(env!("CARGO_BIN_EXE_server"))
        .env("PAINSIM_BIND", "127.0.0.1:0")
        .env("PAINSIM_DATA_DIR", data_dir)
        .env_remove("DATABASE_URL")
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn server");
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let line = lines.next().expect("server printed its URL").unwrap();
    let addr = line.split("http://").nth(1).and_then(|r| r.split('/').next()).expect("URL in the first line").to_owned();
    Server { child, addr }
}

fn wait_healthy(addr: &str, limit: Duration) -> (Duration, serde_json::Value) {
    let start = Instant::now();
    loop {
        if let Ok((code, body)) = http_get(addr, "/healthz") {
            let v: serde_json::Value = serde_json::from_str(&body).unwrap_or_default();
            let worker_settled = v["render_worker"]["state"] != "starting";
            if v["database"]["ready"] == true && worker_settled {
                if std::env::var_os("REQUIRE_GPU").is_some() {
                    assert_eq!(code, 200, "{v}");
                }
                return (start.elapsed(), v);
            }
        }
        assert!(start.elapsed() < limit, "server not healthy within {limit:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn postgres_pids_using(data_dir: &std::path::Path) -> Vec<u32> {
    let needle = data_dir.to_string_lossy().into_owned();
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|pid| {
            std::fs::read(format!("/proc/{pid}/cmdline"))
                .map(|c| String::from_utf8_lossy(&c).replace('\0', " "))
                .is_ok_and(|c| c.contains("postgres") && c.contains(&needle))
        })
        .filter(|pid| std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| !s.contains(") Z ")))
        .collect()
}

fn sigterm_and_wait(mut server: Server) {
    let status = Command::new("kill").args(["-TERM", &server.child.id().to_string()]).status().unwrap();
    assert!(status.success());
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        if let Some(st) = server.child.try_wait().unwrap() {
            assert!(st.success(), "server exit status after SIGTERM: {st}");
            return;
        }
        assert!(Instant::now() < deadline, "server did not exit after SIGTERM");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn embedded_default_serves_health_stops_cleanly_and_keeps_data() {
    let dir = tempfile::Builder::new().prefix("painsim-server").tempdir_in(std::env::temp_dir()).unwrap();
    // tempfile makes 0700 folders; the cluster's unprivileged account must be able to enter it.
    std::fs::set_permissions(dir.path(), std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let data = dir.path().join("data");

    let server = spawn_server(&data);
    let (first_ready, health) = wait_healthy(&server.addr, Duration::from_secs(60));
    eprintln!("first start (initdb included): healthy after {first_ready:?}; {health}");
    let id = health["database"]["installation_id"].as_str().expect("installation id").to_owned();
    assert_eq!(health["database"]["embedded"], true);
    assert!(!postgres_pids_using(&data).is_empty(), "the embedded cluster runs under the data folder");
    sigterm_and_wait(server);
    assert_eq!(postgres_pids_using(&data), Vec::<u32>::new(), "no PostgreSQL process after SIGTERM");

    let server = spawn_server(&data);
    let (second_ready, health) = wait_healthy(&server.addr, Duration::from_secs(60));
    eprintln!("restart: healthy after {second_ready:?}");
    assert_eq!(health["database"]["installation_id"], id.as_str(), "restart keeps the data");

    // A SIGKILLed server cannot stop its database itself; the parent-death signal does.
    let pid = server.child.id();
    let mut child = server.child;
    Command::new("kill").args(["-KILL", &pid.to_string()]).status().unwrap();
    child.wait().unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !postgres_pids_using(&data).is_empty() {
        assert!(Instant::now() < deadline, "postgres outlived a SIGKILLed server: {:?}", postgres_pids_using(&data));
        std::thread::sleep(Duration::from_millis(50));
    }
    let server = spawn_server(&data);
    let (_, health) = wait_healthy(&server.addr, Duration::from_secs(60));
    assert_eq!(health["database"]["installation_id"], id.as_str(), "data survives a SIGKILL too");
    sigterm_and_wait(server);
}
