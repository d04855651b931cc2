//! What a frame is rendered with (exposure, noise, supersampling, threads) and what comes out
//! (the transmission image and the 8-bit frame).

use serde::{Deserialize, Serialize};

use crate::fluoro::attenuation::EnergyModel;
use crate::fluoro::receptor::ReceptorSettings;
use crate::fluoro::scatter::superposition::ScatterSettings;

/// Automatic brightness: how transmission becomes grey.
///
/// Like a C-arm's automatic brightness control, the median log-transmission of a central region
/// of interest is mapped to `target_grey`, so the picture's brightness does not depend on patient
/// thickness or tube output. Grey is linear in `ln T` (a logarithmic tone curve), spanning
/// `log_range` natural-log units from black to white.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Exposure {
    /// Side of the central region of interest as a fraction of the image (0.5: the middle half).
    pub roi_fraction: f64,
    /// Grey level (0..1) of the region's median.
    pub target_grey: f64,
    /// `ln T` span from black to white (3.5: a factor of 33 in transmission; simulator choice
    /// giving bone, soft tissue and a needle distinct grey levels).
    pub log_range: f64,
}

impl Default for Exposure {
    fn default() -> Self {
        Exposure {
            roi_fraction: 0.5,
            target_grey: 0.5,
            log_range: 3.5,
        }
    }
}

/// Quantum (photon counting) noise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QuantumNoise {
    /// Mean detected quanta per pixel without attenuation (sets the noise level; a low-dose
    /// fluoroscopy pulse gives a few thousand per pixel, simulator choice).
    pub photons_per_pixel: f64,
    /// Seed; the same seed gives the same noise.
    pub seed: u64,
}

/// Everything that decides a frame besides the scene and the projection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RenderSettings {
    /// Single-energy or polychromatic transmission.
    pub energy: EnergyModel,
    /// `n` for `n x n` stratified samples in a supersampled pixel (1: pixel centre only).
    pub supersample: u32,
    /// Supersample only pixels at a silhouette (a neighbour's centre ray crosses other meshes) or
    /// within a pixel of a projected steel edge; `false` supersamples every pixel.
    pub adaptive: bool,
    /// Automatic brightness and tone mapping.
    pub exposure: Exposure,
    /// Quantum noise, or `None` for the noiseless expectation.
    pub noise: Option<QuantumNoise>,
    /// `false`: fluoroscopy polarity (more transmission is brighter: bone and steel dark);
    /// `true`: radiograph polarity.
    pub invert: bool,
    /// Worker threads (0: all available cores).
    pub threads: usize,
    /// Scattered radiation added to the primary before noise and display
    /// ([`crate::fluoro::scatter`]), or `None` for the primary image alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scatter: Option<ScatterSettings>,
    /// The image receptor's profile ([`crate::fluoro::receptor`]) applied to the signal, or
    /// `None` for an ideal detector.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub receptor: Option<ReceptorSettings>,
}

impl Default for RenderSettings {
    /// 80 kVp (the methods page's assumed starting beam), 4 x 4 adaptive supersampling (a 0.72 mm
    /// needle at 2x magnification is 2.5 pixels of 0.59 mm wide; 4 x 4 samples resolve its edges
    /// to 1/4 pixel), no noise.
    fn default() -> Self {
        RenderSettings {
            energy: EnergyModel::Spectral { kvp: 80 },
            supersample: 4,
            adaptive: true,
            exposure: Exposure::default(),
            noise: None,
            invert: false,
            threads: 0,
            scatter: None,
            receptor: None,
        }
    }
}

/// Per-pixel transmission before display.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransmissionImage {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Mean transmission over the pixel's samples (0 outside the collimator), row-major.
    pub transmission: Vec<f64>,
    /// Whether the pixel is inside the collimator opening.
    pub exposed: Vec<bool>,
    /// Number of supersampled pixels.
    pub supersampled_pixels: usize,
}

/// An 8-bit grey image, row-major, top row first.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Image {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Grey levels.
    pub pixels: Vec<u8>,
}

/// Grey level of pixels behind the collimator shutters.
pub const SHUTTER_GREY: u8 = 0;
