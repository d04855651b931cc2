//! A session's fixed settings: what stays the same for its whole life, also in snapshots.

use serde::{Deserialize, Serialize};

use super::modalities::fluoro::FluoroConfig;

/// Fixed settings of a session.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SessionConfig {
    /// C-arm detector and rendering.
    pub fluoro: FluoroConfig,
    /// Seed of everything random (quantum noise).
    pub seed: u64,
}

impl Default for SessionConfig {
    fn default() -> Self {
        SessionConfig {
            fluoro: FluoroConfig::default(),
            seed: 0x5e55_1011,
        }
    }
}
