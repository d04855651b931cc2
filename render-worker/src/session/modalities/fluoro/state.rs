//! The fluoroscopy modality's serializable state: the C-arm, technique and controls, and every
//! image it acquired with everything that decides its pixels.

use serde::{Deserialize, Serialize};
use sim_core::fluoro::Projection;

use super::dose::DoseTally;
use super::steel::NeedleShaft;
use super::{brightness, collimator, temporal};
use crate::session::config::FluoroConfig;

/// Everything that decides one image's pixels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AcquiredImage {
    /// Acquisition number in this session (0-based): shots and live frames together.
    pub index: u64,
    /// Simulation time, ms.
    pub t_ms: u64,
    /// C-arm projection.
    pub projection: Projection,
    /// Tube voltage.
    pub kvp: u32,
    /// Tube current.
    pub ma: f64,
    /// Live frame (true) or single shot.
    pub live: bool,
    /// The needle at that moment.
    pub needle: Option<NeedleShaft>,
    /// Quantum noise seed.
    pub noise_seed: u64,
    /// Version of the world's iodine field imaged (absent when there was none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iodine_version: Option<u64>,
    /// Tube charge of the frame, mAs: its quantum noise follows the detector kerma it gives
    /// (`sim_core::fluoro::detector`). Absent in images recorded before the detector model,
    /// which keep [`super::PHOTONS_PER_PIXEL_PER_MA`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mas: Option<f64>,
    /// Detector air kerma per pulse over the metering disc at this frame's technique, nGy (what
    /// the automatic brightness control measured; see [`brightness`]): the primary, and in
    /// sessions with scatter the total behind the grid (see [`super::scatter`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detector_kerma_ngy: Option<f64>,
    /// The live run this frame belongs to (1-based, as `live_runs` counts them), for the
    /// temporal chain ([`temporal`]); absent for shots and in sessions without the chain.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub run: Option<u32>,
    /// The recursive filter's level this live frame is displayed with (absent: no chain).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter: Option<sim_core::fluoro::temporal::FilterLevel>,
    /// The grid and air gap this frame was taken with ([`super::scatter`]); absent in
    /// sessions recorded before scatter, whose frames show the primary alone.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scatter: Option<super::scatter::ImageScatter>,
}

/// A mark on an image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Annotation {
    /// Continuous pixel coordinates.
    pub pixel: [f64; 2],
    /// What it names.
    pub label: String,
    /// The projection of the image it was placed on.
    pub projection: Projection,
    /// Simulation time, ms.
    pub t_ms: u64,
}

/// Serializable fluoroscopy state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FluoroState {
    /// Fixed configuration.
    pub config: FluoroConfig,
    /// Model point at the isocentre with the table at zero, mm.
    pub isocentre_mm: [f64; 3],
    /// Orbital rotation, degrees.
    pub orbital_deg: f64,
    /// Angular rotation, degrees.
    pub angular_deg: f64,
    /// Table translation, mm.
    pub table_mm: [f64; 3],
    /// Tube voltage.
    pub kvp: u32,
    /// Tube current.
    pub ma: f64,
    /// Live fluoroscopy running since this time (ms), or `None`.
    pub live_since_ms: Option<u64>,
    /// Fluoroscopy time booked so far (completed live runs and shots), ms.
    pub exposure_ms: u64,
    /// Single shots taken.
    pub shots: u32,
    /// Live runs started.
    pub live_runs: u32,
    /// Pulses per second of live fluoroscopy (see [`super::pulse`]); absent in sessions
    /// recorded before pulsing, which keep the continuous beam.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulse_rate_pps: Option<f64>,
    /// A change waits for the next pulse to be imaged (live runs, and the pulse it came in had
    /// already made an image; see [`super::pulse::pulse_due`]).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub pulse_pending: bool,
    /// Every image acquired (shots and live frames), oldest first; the last one is displayed.
    pub images: Vec<AcquiredImage>,
    /// Marks placed on images.
    pub annotations: Vec<Annotation>,
    /// Session seed for quantum noise.
    pub seed: u64,
    /// The radiation estimate booked so far.
    #[serde(default, skip_serializing_if = "DoseTally::is_empty")]
    pub dose: DoseTally,
    /// Automatic brightness control, or `None` for a technique set by hand (and in sessions
    /// recorded before the control existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub brightness: Option<brightness::BrightnessState>,
    /// Frames record their charge ([`AcquiredImage::mas`]) and their noise follows the
    /// detector kerma; `false` in sessions recorded before the detector model, whose frames keep
    /// [`super::PHOTONS_PER_PIXEL_PER_MA`] so that their replay gives what was recorded.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub detector_noise: bool,
    /// The learner's collimator, or `None` for the fully open field (and in sessions recorded
    /// before the collimator).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub collimator: Option<collimator::CollimatorSetting>,
    /// Side of the active detector field, mm ([`super::magnification`]), or `None` for the full
    /// detector (and in sessions recorded before the modes).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field_mm: Option<f64>,
    /// Detector lag and the recursive filter of live frames ([`temporal`]), or `None` in
    /// sessions recorded before the chain.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub temporal: Option<temporal::TemporalState>,
    /// The anti-scatter grid ([`super::scatter`]), or `None` in sessions recorded before
    /// scatter (no scatter is added to their images).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scatter: Option<super::scatter::ScatterState>,
    /// The image receptor (the station's, `sim_core::fluoro::receptor`), or `None` in sessions
    /// recorded before receptor profiles (an ideal detector).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub receptor: Option<sim_core::fluoro::receptor::ReceptorKind>,
}
