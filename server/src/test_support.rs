//! Test databases: one private cluster per test process, one fresh database per test.
//!
//! Every integration test calls [`test_db`], which starts (once per process) a private cluster
//! from [`crate::embedded_pg`] in a temporary folder, creates a new database with a unique name,
//! and runs the migrations in it. The test command therefore needs no database set up by hand,
//! and tests never see each other's rows.

use std::path::PathBuf;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};

use sqlx::postgres::PgPoolOptions;
use sqlx::{Connection, PgConnection, PgPool};

use crate::embedded_pg::PrivateCluster;

static CLUSTER: OnceLock<PrivateCluster> = OnceLock::new();
static NEXT_DB: AtomicU32 = AtomicU32::new(0);

/// The process-wide test cluster (started on first use).
pub fn test_cluster() -> &'static PrivateCluster {
    CLUSTER.get_or_init(|| {
        let base = std::env::temp_dir();
        remove_stale_clusters(&base);
        let root = base.join(format!("painsim-test-pg-{}", std::process::id()));
        PrivateCluster::start(&root).unwrap_or_else(|e| panic!("cannot start the test PostgreSQL cluster: {e}"))
    })
}

/// Folders of test clusters whose process has ended (their postmaster went with it).
fn remove_stale_clusters(base: &std::path::Path) {
    let Ok(entries) = std::fs::read_dir(base) else { return };
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(pid) = name.strip_prefix("painsim-test-pg-").and_then(|p| p.parse::<u32>().ok())
            && !PathBuf::from(format!("/proc/{pid}")).exists()
        {
            let _ = std::fs::remove_dir_all(e.path());
        }
    }
}

/// A fresh, migrated database for one test.
pub struct TestDb {
    /// A pool connected to it.
    pub pool: PgPool,
    /// Its name.
    pub name: String,
    /// A URL other processes (a spawned server binary) can use to reach it.
    pub url: String,
}

/// Creates a new database with every migration applied.
pub async fn test_db() -> TestDb {
    let cluster = test_cluster();
    let name = format!("test_{}_{}", std::process::id(), NEXT_DB.fetch_add(1, Ordering::Relaxed));
    let mut admin = PgConnection::connect_with(&cluster.connect_options("postgres")).await.expect("connect to the test cluster");
    sqlx::query(&format!("CREATE DATABASE \"{name}\"")).execute(&mut admin).await.expect("create test database");
    admin.close().await.ok();
    let pool = PgPoolOptions::new().max_connections(5).connect_with(cluster.connect_options(&name)).await.expect("connect to test database");
    crate::db::migrate(&pool).await.expect("migrations apply to a fresh database");
    TestDb { url: cluster.url(&name), pool, name }
}
