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
