//! The state every LTI handler receives, and the caches of platform keys and access tokens.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::extract::FromRef;
use rsa::RsaPublicKey;
use sqlx::PgPool;
use uuid::Uuid;

use crate::records::RecordsState;

/// How long an HTTP call to a platform may take (our choice: a platform answers in well under a
/// second; a hung one must not hold a launch or a delivery).
pub const PLATFORM_TIMEOUT: Duration = Duration::from_secs(10);

/// Access tokens by (platform, scopes): the token and when to renew it.
pub type TokenCache = Arc<Mutex<HashMap<(Uuid, String), (String, Instant)>>>;

/// State shared by the LTI handlers and the grade passback. Cheap to clone.
#[derive(Clone)]
pub struct LtiState {
    /// Database pool (the server's).
    pub pool: PgPool,
    /// The learning records' state: sessions, users, stations.
    pub records: RecordsState,
    /// The server's public origin (see [`crate::config::Config::public_url`]).
    pub public_url: Arc<str>,
    /// HTTP client for platform JWKS, tokens and services.
    pub http: reqwest::Client,
    /// Platform signing keys by (platform, kid).
    pub platform_keys: Arc<Mutex<HashMap<(Uuid, String), RsaPublicKey>>>,
    /// Access tokens by (platform, scopes), with their expiry.
    pub tokens: TokenCache,
}

impl LtiState {
    /// A state over `pool` with empty caches.
    pub fn new(pool: PgPool, records: RecordsState, public_url: &str) -> LtiState {
        let http = reqwest::Client::builder()
            .timeout(PLATFORM_TIMEOUT)
            .redirect(reqwest::redirect::Policy::none())
            .build()
            .expect("an HTTP client with rustls");
        LtiState {
            pool,
            records,
            public_url: public_url.trim_end_matches('/').into(),
            http,
            platform_keys: Arc::default(),
            tokens: Arc::default(),
        }
    }
}

impl FromRef<LtiState> for RecordsState {
    fn from_ref(state: &LtiState) -> RecordsState {
        state.records.clone()
    }
}
