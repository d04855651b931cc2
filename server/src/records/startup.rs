//! Start-up work of the learning records, run before the server accepts requests.

use sqlx::PgPool;

use super::config::RecordsConfig;
use super::demo;
use super::stations::StationCatalog;

/// Start-up work of the learning records, run before serving: loads the stations and registers
/// their revisions (failing if a published revision was edited in place), and with the embedded
/// database creates the demo accounts and returns the notice to print.
pub async fn prepare(
    pool: &PgPool,
    config: &RecordsConfig,
    embedded_db: bool,
) -> anyhow::Result<Option<String>> {
    let stations = StationCatalog::load(&config.stations_dir)?;
    stations.register(pool).await?;
    tracing::info!(stations = stations.stations.len(), "stations registered");
    if !embedded_db {
        return Ok(None);
    }
    let accounts = demo::ensure_demo_accounts(pool, config.argon2).await?;
    Ok(Some(demo::startup_notice(&accounts)))
}
