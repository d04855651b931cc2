//! A session's fixed settings: what stays the same for its whole life, also in snapshots, with
//! each modality's part ([`FluoroConfig`] for the C-arm).

use serde::{Deserialize, Serialize};

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

/// Fixed settings of a session's C-arm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FluoroConfig {
    /// Square detector size, pixels.
    pub detector_pixels: u32,
    /// Detector side, mm (300: a 30 cm flat panel, as `Projection::default`).
    pub detector_mm: f64,
    /// Supersampling of silhouette pixels (`n x n`). Simulator choice for live use: 2.
    pub supersample: u32,
    /// Quantum noise on (seeded per image).
    pub noise: bool,
}

impl Default for FluoroConfig {
    fn default() -> Self {
        FluoroConfig {
            detector_pixels: 512,
            detector_mm: 300.0,
            supersample: 2,
            noise: true,
        }
    }
}
