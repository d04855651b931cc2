//! The private cluster: created once, reused with its data, and gone after stop.

use server::embedded_pg::PrivateCluster;
use sqlx::Connection;

fn process_alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| !s.contains(") Z "))
}

#[test]
fn restart_keeps_data_and_stop_leaves_no_process() {
    let dir = tempfile::Builder::new().prefix("painsim-embedded").tempdir_in(std::env::temp_dir()).unwrap();
    // tempfile makes 0700 folders; the cluster's unprivileged account must be able to enter it.
    std::fs::set_permissions(dir.path(), std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let root = dir.path().join("pg");
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();

    let first = PrivateCluster::start(&root).expect("first start creates the cluster");
    let pid1 = first.pid();
    rt.block_on(async {
        let mut c = sqlx::PgConnection::connect_with(&first.connect_options("postgres")).await.unwrap();
        sqlx::query("CREATE TABLE kept (v TEXT)").execute(&mut c).await.unwrap();
        sqlx::query("INSERT INTO kept VALUES ('survives a restart')").execute(&mut c).await.unwrap();
        c.close().await.unwrap();
    });
    first.stop().unwrap();
    assert!(!process_alive(pid1), "postmaster {pid1} still running after stop");

    let second = PrivateCluster::start(&root).expect("second start reuses the cluster");
    let v: String = rt.block_on(async {
        let mut c = sqlx::PgConnection::connect_with(&second.connect_options("postgres")).await.unwrap();
        sqlx::query_scalar("SELECT v FROM kept").fetch_one(&mut c).await.unwrap()
    });
    assert_eq!(v, "survives a restart");
    // Only the private socket: no TCP listener, trust limited to `local`.
    let hba = std::fs::read_to_string(second.data_dir().join("pg_hba.conf")).unwrap();
    assert!(hba.lines().filter(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty()).all(|l| l.starts_with("local")));
    let pid2 = second.pid();
    second.stop().unwrap();
    assert!(!process_alive(pid2));
}

#[test]
fn missing_binaries_give_a_clear_error() {
    let empty = tempfile::tempdir().unwrap();
    let e = server::embedded_pg::PgBinaries::locate_in(&[empty.path().to_owned()]).unwrap_err().to_string();
    assert!(e.contains("`initdb`") && e.contains("apt-get install postgresql"), "{e}");
    // And the real machine has them (CI installs postgresql).
    let found = server::embedded_pg::PgBinaries::locate().expect("initdb and postgres are installed");
    assert!(found.initdb.ends_with("initdb") && found.postgres.ends_with("postgres"));
}

#[expect(unsafe_code, reason = "kill(2) has no safe wrapper in std")]
fn signal(pid: u32, sig: i32) {
    // SAFETY: kill(2) on processes of this test's own private cluster.
    unsafe {
        libc::kill(pid as libc::pid_t, sig);
    }
}

/// After the postmaster is killed with a backend left behind (stopped, so it cannot exit on its
/// own and keeps the shared memory attached), and with a lock file naming a live process that is
/// not postgres, the next start recovers by itself and keeps the data.
#[test]
fn a_killed_cluster_restarts_despite_orphans_and_a_stale_lock_file() {
    let dir = tempfile::Builder::new().prefix("painsim-embedded").tempdir_in(std::env::temp_dir()).unwrap();
    std::fs::set_permissions(dir.path(), std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    let root = dir.path().join("pg");
    let rt = tokio::runtime::Builder::new_current_thread().enable_all().build().unwrap();

    let first = PrivateCluster::start(&root).expect("first start");
    let postmaster = first.pid();
    let (_conn, backend) = rt.block_on(async {
        let mut c = sqlx::PgConnection::connect_with(&first.connect_options("postgres")).await.unwrap();
        sqlx::query("CREATE TABLE kept (v TEXT)").execute(&mut c).await.unwrap();
        sqlx::query("INSERT INTO kept VALUES ('survives a kill')").execute(&mut c).await.unwrap();
        let pid: i32 = sqlx::query_scalar("SELECT pg_backend_pid()").fetch_one(&mut c).await.unwrap();
        (c, pid as u32)
    });
    signal(backend, libc::SIGSTOP);
    signal(postmaster, libc::SIGKILL);
    for _ in 0..100 {
        if !process_alive(postmaster) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert!(!process_alive(postmaster));
    assert!(process_alive(backend), "the orphaned backend is still there");
    let data = first.data_dir().to_owned();
    drop(first);

    let second = PrivateCluster::start(&root).expect("restart after a SIGKILL with an orphan left behind");
    assert!(!process_alive(backend), "the orphan was cleaned up");
    let v: String = rt.block_on(async {
        let mut c = sqlx::PgConnection::connect_with(&second.connect_options("postgres")).await.unwrap();
        sqlx::query_scalar("SELECT v FROM kept").fetch_one(&mut c).await.unwrap()
    });
    assert_eq!(v, "survives a kill");
    signal(second.pid(), libc::SIGKILL);
    std::thread::sleep(std::time::Duration::from_millis(500));
    drop(second);

    // A lock file whose pid now belongs to another live process (pid 1 here): postgres alone
    // refuses to start on it.
    let lock = data.join("postmaster.pid");
    let text = std::fs::read_to_string(&lock).unwrap_or_default();
    let rest: Vec<&str> = text.lines().skip(1).collect();
    std::fs::write(&lock, format!("1\n{}\n", rest.join("\n"))).unwrap();
    let third = PrivateCluster::start(&root).expect("restart over a stale lock file");
    third.stop().unwrap();
}
