//! The state every LRS handler receives.

use std::sync::Arc;

use axum::extract::FromRef;
use sqlx::PgPool;

use crate::records::RecordsState;

/// State shared by the LRS handlers and the LMS-integration admin endpoints. Cheap to clone.
#[derive(Clone)]
pub struct XapiState {
    /// Database pool (the server's).
    pub pool: PgPool,
    /// The learning records' state: the admin endpoints authenticate sessions with it.
    pub records: RecordsState,
    /// The server's public origin (see [`crate::config::Config::public_url`]).
    pub public_url: Arc<str>,
    /// Largest accepted request body in bytes (the server's limit).
    pub max_body_bytes: usize,
}

impl FromRef<XapiState> for RecordsState {
    fn from_ref(state: &XapiState) -> RecordsState {
        state.records.clone()
    }
}
