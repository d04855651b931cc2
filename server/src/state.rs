//! The application state every handler may reach.

use sqlx::PgPool;

use crate::config::Config;
use crate::dispatch::Dispatcher;
use crate::workers::Workers;

/// Everything a request handler may need. Cheap to clone.
#[derive(Clone)]
pub struct AppState {
    /// Database pool.
    pub pool: PgPool,
    /// True when the database is the embedded private cluster.
    pub embedded_db: bool,
    /// Render workers.
    pub workers: Workers,
    /// Session dispatch chosen at start-up (or by a test); `None`: [`crate::app`] builds the default
    /// from the configuration (see [`crate::dispatch::Dispatcher::for_app`]).
    pub dispatcher: Option<Dispatcher>,
    /// Configuration in force.
    pub config: Config,
}
