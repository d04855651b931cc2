//! The state every learning-records handler receives. It imports no handler: handlers, the
//! extractors and the router all build on it.

use std::sync::Arc;

use sqlx::PgPool;
use uuid::Uuid;

use super::config::RecordsConfig;
use super::ratelimit;
use super::stations::StationCatalog;

/// State shared by the learning-records handlers. Cheap to clone.
#[derive(Clone)]
pub struct RecordsState {
    /// Database pool (the same one as the rest of the server).
    pub pool: PgPool,
    /// Settings.
    pub config: Arc<RecordsConfig>,
    /// Stations loaded from `assets/stations/` and registered in the database.
    pub stations: Arc<StationCatalog>,
    /// Per-client limiter of the authentication endpoints.
    pub auth_limiter: Arc<ratelimit::RateLimiter>,
    /// Per-account limiter of authenticated writes (checked by the `CurrentUser` extractor).
    pub write_limiter: Arc<ratelimit::RateLimiter>,
    /// Hash verified against when a login names an unknown e-mail (made once, on first need, so
    /// that unknown and known e-mails cost the same single verification).
    pub decoy_hash: Arc<std::sync::OnceLock<String>>,
    /// Accounts whose access was just revoked (disabled, or their password reset): whoever holds
    /// something open for a user (live simulation sessions) subscribes and closes it. The
    /// records never learn who listens.
    pub revocations: tokio::sync::broadcast::Sender<Uuid>,
}

impl RecordsState {
    /// Builds the state for the server's `app`: loads the stations synchronously. A station
    /// directory that fails to load is logged and leaves the catalog empty;
    /// [`super::startup::prepare`], which start-up runs first, turns the same failure into a
    /// start-up error.
    pub fn from_parts(pool: PgPool, config: RecordsConfig) -> RecordsState {
        let stations = StationCatalog::load(&config.stations_dir).unwrap_or_else(|e| {
            tracing::error!(error = %format!("{e:#}"), "no stations available");
            StationCatalog::default()
        });
        let auth_limiter =
            ratelimit::RateLimiter::new(config.auth_rate_per_minute, config.auth_burst);
        let write_limiter =
            ratelimit::RateLimiter::new(config.write_rate_per_minute, config.write_burst);
        RecordsState {
            pool,
            config: Arc::new(config),
            stations: Arc::new(stations),
            auth_limiter: Arc::new(auth_limiter),
            write_limiter: Arc::new(write_limiter),
            decoy_hash: Arc::default(),
            revocations: tokio::sync::broadcast::channel(64).0,
        }
    }
}
