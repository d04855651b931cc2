//! The real `server` binary with its embedded database: ready, SIGTERM, restart.

use std::time::{Duration, Instant};

use crate::server_process::{ServerProcess, spawn_server};

fn spawn_embedded(data_dir: &std::path::Path) -> ServerProcess {
    // No session here: leave the anatomy (a phantom build) to the first session.
    // Info level: a shutdown that hangs in CI then shows which step it reached.
    let log = "info,sqlx=warn,wgpu_core=warn,wgpu_hal=error,naga=warn";
    spawn_server(data_dir, None, &[("PAINSIM_PREPARE_ANATOMY", "0".into()), ("RUST_LOG", log.into())])
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

#[test]
fn embedded_default_serves_health_stops_cleanly_and_keeps_data() {
    let dir = tempfile::Builder::new().prefix("painsim-server").tempdir_in(std::env::temp_dir()).unwrap();
    // tempfile makes 0700 folders; the cluster's unprivileged account must be able to enter it.
    std::fs::set_permissions(dir.path(), std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let data = dir.path().join("data");

    let server = spawn_embedded(&data);
    let (first_ready, health) = server.wait_healthy(Duration::from_secs(60));
    eprintln!("first start (initdb included): healthy after {first_ready:?}; {health}");
    let id = health["database"]["installation_id"].as_str().expect("installation id").to_owned();
    assert_eq!(health["database"]["embedded"], true);
    assert!(!postgres_pids_using(&data).is_empty(), "the embedded cluster runs under the data folder");
    server.sigterm_and_wait();
    assert_eq!(postgres_pids_using(&data), Vec::<u32>::new(), "no PostgreSQL process after SIGTERM");

    let server = spawn_embedded(&data);
    let (second_ready, health) = server.wait_healthy(Duration::from_secs(60));
    eprintln!("restart: healthy after {second_ready:?}");
    assert_eq!(health["database"]["installation_id"], id.as_str(), "restart keeps the data");

    // A SIGKILLed server cannot stop its database itself; the parent-death signal does.
    server.sigkill();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !postgres_pids_using(&data).is_empty() {
        assert!(Instant::now() < deadline, "postgres outlived a SIGKILLed server: {:?}", postgres_pids_using(&data));
        std::thread::sleep(Duration::from_millis(50));
    }
    let server = spawn_embedded(&data);
    let (_, health) = server.wait_healthy(Duration::from_secs(60));
    assert_eq!(health["database"]["installation_id"], id.as_str(), "data survives a SIGKILL too");
    server.sigterm_and_wait();
}
