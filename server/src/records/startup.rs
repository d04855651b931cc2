//! Start-up work of the learning records, run before the server accepts requests.

use sqlx::PgPool;

use super::config::RecordsConfig;
use super::demo;
use super::stations::StationCatalog;

/// Start-up work of the learning records, run before serving: loads the stations and registers
/// their revisions (failing if a published revision was edited in place), and creates the demo
/// accounts when asked (`demo_accounts` set explicitly) or by default on a loopback bind with the
/// embedded database; returns the notice to print either way.
pub async fn prepare(
    pool: &PgPool,
    config: &RecordsConfig,
    embedded_db: bool,
) -> anyhow::Result<Option<String>> {
    let stations = StationCatalog::load(&config.stations_dir)?;
    stations.register(pool).await?;
    tracing::info!(stations = stations.stations.len(), "stations registered");
    match (config.demo_accounts, embedded_db, config.loopback_bind) {
        (Some(true), ..) | (None, true, true) => {}
        (None, true, false) => {
            tracing::warn!("demo accounts not created on a non-loopback bind");
            return Ok(Some(
                "Demo accounts are not created: the server binds a non-loopback address and \
                 their passwords are published (set PAINSIM_DEMO_ACCOUNTS=true to create them \
                 anyway). Create an administrator with `server create-admin --email ...`."
                    .into(),
            ));
        }
        (Some(false), ..) => {
            return Ok(Some(
                "Demo accounts are not created (PAINSIM_DEMO_ACCOUNTS=false).".into(),
            ));
        }
        (None, false, _) => return Ok(None),
    }
    let accounts = demo::ensure_demo_accounts(pool, config.argon2).await?;
    Ok(Some(demo::startup_notice(&accounts)))
}
