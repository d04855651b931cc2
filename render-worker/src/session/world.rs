//! What every part of a session shares: the anatomy, the station, the simulation clock, the
//! needle (an instrument seen by every modality) and the ledger of injected fluid; and the
//! changes of it that modalities react to ([`WorldChange`]).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use sim_core::fluoro::IodineField;
use sim_core::needle::{ForceState, InitialResponse, InstrumentProfile, LorSyringe, NeedleState};
use sim_core::rubric::Station;

use super::command::Agent;
use super::region::Region;

/// Largest feed substep of session needles, mm. Simulator choice: half a millimetre resolves
/// contact with the thinnest bone features of the phantom (1.8 mm cortex) and keeps a 50 mm
/// feed at 100 substeps.
pub const NEEDLE_SUBSTEP_MM: f64 = 0.5;

/// Structures whose entry by the needle tip is recorded (for critical rubric items such as a
/// dural puncture). Names of the lumbar and cervical phantoms' structures.
pub const WATCHED_STRUCTURES: [&str; 5] = [
    "dural_sac",
    "aorta",
    "inferior_vena_cava",
    "vertebral_artery_left",
    "vertebral_artery_right",
];

/// A station with its targets resolved into the region's model frame.
#[derive(Debug, Clone)]
pub struct StationContext {
    /// The validated station.
    pub station: Station,
    /// SHA-256 of the station file text (empty when built in code).
    pub station_sha256: String,
    /// Station targets in the model frame, mm.
    pub targets: BTreeMap<String, [f64; 3]>,
}

/// Frame note of the stations authored before the phantom published landmarks (see
/// `assets/stations/README.md`): their targets are relative to the L4 vertebral body centre.
pub const L4_ORIGIN_NOTE: &str = "origin at the L4 vertebral body centre";

impl StationContext {
    /// Resolves the targets: a target naming a landmark the region publishes is that landmark;
    /// otherwise stations whose `frame_note` says their origin is the L4 vertebral body centre
    /// are shifted by the region's `L4_body_centre` landmark (when it has one), and all others
    /// are taken to be in the model frame already.
    pub fn new(station: Station, station_sha256: String, region: &Region) -> StationContext {
        let offset = if station.frame_note.contains(L4_ORIGIN_NOTE) {
            region
                .landmarks
                .get("L4_body_centre")
                .copied()
                .unwrap_or([0.0; 3])
        } else {
            [0.0; 3]
        };
        let targets = station
            .targets
            .iter()
            .map(|t| {
                let at = t
                    .landmark
                    .as_ref()
                    .and_then(|l| region.landmarks.get(l))
                    .copied()
                    .unwrap_or_else(|| std::array::from_fn(|a| t.position_mm[a] + offset[a]));
                (t.name.clone(), at)
            })
            .collect();
        StationContext {
            station,
            station_sha256,
            targets,
        }
    }

    /// A named point: a station target first, else a region landmark.
    pub fn point(&self, region: &Region, name: &str) -> Option<[f64; 3]> {
        self.targets
            .get(name)
            .or_else(|| region.landmarks.get(name))
            .copied()
    }
}

/// The needle in the session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NeedleInstrument {
    /// Instrument id from the station's tray.
    pub instrument: String,
    /// Kinematic state.
    pub state: NeedleState,
    /// Watched structures the tip has been inside (see [`WATCHED_STRUCTURES`]).
    pub entered: BTreeSet<String>,
}

/// The needle profile for a tray instrument kind, or `None` for a non-needle.
pub fn profile_for_kind(kind: &str) -> Option<InstrumentProfile> {
    match kind {
        "spinal-needle" => Some(InstrumentProfile::spinal_22g_quincke()),
        "tuohy-needle" => Some(InstrumentProfile::tuohy_18g()),
        "steerable-needle" => Some(InstrumentProfile::flexible_prebent()),
        _ => None,
    }
}

/// A fresh needle state at a skin entry.
pub fn new_needle(
    profile: InstrumentProfile,
    entry_mm: [f64; 3],
    direction: [f64; 3],
    bevel_reference: [f64; 3],
) -> Result<NeedleState, sim_core::needle::NeedleError> {
    NeedleState::new(
        profile,
        DVec3::from_array(entry_mm),
        DVec3::from_array(direction),
        DVec3::from_array(bevel_reference),
        NEEDLE_SUBSTEP_MM,
        InitialResponse::Relaxed,
    )
}

/// What the hands hold and have done (part of the session snapshot; see
/// `super::hands`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Hands {
    /// The skin marker, model frame, mm (taken away at the puncture).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_mm: Option<[f64; 3]>,
    /// Skin punctures (each `needle_puncture` and `needle_place`).
    #[serde(default)]
    pub skin_punctures: u32,
    /// Redirections of needles that are out of the body again.
    #[serde(default)]
    pub redirections_before: u32,
    /// Episodes of bone contact (a feed stopped or deflected by bone after one that was not).
    #[serde(default)]
    pub bone_contacts: u32,
    /// The last feed ended on bone.
    #[serde(default)]
    pub on_bone: bool,
    /// Insertion force model state of the needle in the body.
    #[serde(default)]
    pub force: ForceState,
    /// Largest total force during the current needle's insertion, N.
    #[serde(default)]
    pub peak_force_n: f64,
    /// The loss-of-resistance syringe on the hub.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub syringe: Option<LorSyringe>,
    /// Constant pressure held on the plunger.
    #[serde(default)]
    pub hold: bool,
    /// The plunger was giving way at the last check.
    #[serde(default)]
    pub giving_way: bool,
    /// A loss was felt with the outlet in the epidural space before any injection.
    #[serde(default)]
    pub lor_confirmed: bool,
    /// Losses felt with the outlet outside the epidural space.
    #[serde(default)]
    pub false_losses: u32,
    /// Volume that left the loss-of-resistance syringe, ml.
    #[serde(default)]
    pub lor_injected_ml: f64,
    /// Entries of the world's injection ledger that came from the loss-of-resistance syringe.
    #[serde(default)]
    pub lor_ledger_entries: usize,
    /// Aspirations done.
    #[serde(default)]
    pub aspirations: u32,
}

/// One injection through the needle, as the session recorded it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Injection {
    /// Simulation time the injection started, ms.
    pub t_ms: u64,
    /// What was injected.
    pub agent: Agent,
    /// Volume, ml.
    pub volume_ml: f64,
    /// Rate, ml/s.
    pub rate_ml_per_s: f64,
    /// The needle tip (the outlet) at that moment, model frame, mm.
    pub tip_mm: [f64; 3],
}

/// What changed in the shared world after a command, so every modality can react (a live
/// fluoroscopy view re-renders when the needle moves; a still image does not).
#[derive(Debug, Clone, PartialEq)]
pub enum WorldChange {
    /// The needle moved or was placed.
    Needle,
    /// Fluid left the needle (the entry just added to [`World::injections`]).
    FluidInjected(Injection),
    /// The contrast modality's iodine field changed (now in [`World::iodine`]): what the
    /// fluoroscopy renderers ray-march.
    Iodine,
    /// The C-arm moved (now in [`World::carm`]).
    CArm,
    /// The skin marker was put down or taken away (now in [`Hands::marker_mm`]).
    Marker,
}

/// Where the C-arm's central beam runs, for views that show it (the ultrasound placement view).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CArmAxis {
    /// The isocentre with the table translation applied, model frame, mm.
    pub isocentre_mm: [f64; 3],
    /// Unit direction of the central ray, from the source to the detector.
    pub beam_dir: [f64; 3],
}

/// Shared session state.
#[derive(Debug, Clone)]
pub struct World {
    /// Anatomy (shared by all sessions in the same region).
    pub region: Arc<Region>,
    /// Station and resolved targets.
    pub station: Arc<StationContext>,
    /// Simulation time of the latest accepted command, ms since the session started.
    pub clock_ms: u64,
    /// The needle, once placed.
    pub needle: Option<NeedleInstrument>,
    /// Bumped whenever the needle geometry changes.
    pub needle_version: u64,
    /// Every injection so far, oldest first.
    pub injections: Vec<Injection>,
    /// The iodine in the body as whole-voxel stock-equivalent density, published by the contrast
    /// modality (`None` at stations without one and before the first injection). Derived from
    /// the contrast modality's state, so not part of snapshots.
    pub iodine: Option<Arc<IodineField>>,
    /// Bumped whenever [`World::iodine`] changes.
    pub iodine_version: u64,
    /// The C-arm's central beam at stations with fluoroscopy (published by that modality,
    /// derived from its state, so not part of snapshots).
    pub carm: Option<CArmAxis>,
    /// What the hands hold and have done: skin marker, syringe, force state, tallies.
    pub hands: Hands,
}

/// Records the watched structures the tip or the buried channel (sampled every millimetre) is
/// inside after a needle move.
pub fn mark_entered(n: &mut NeedleInstrument, region: &Region) {
    let mut points = n.state.tract.polyline(n.state.buried_mm(), 1.0);
    points.push(n.state.tip_mm());
    for name in WATCHED_STRUCTURES {
        if n.entered.contains(name) {
            continue;
        }
        if points
            .iter()
            .any(|p| region.contains(name, p.to_array()) == Some(true))
        {
            n.entered.insert(name.to_string());
        }
    }
}

/// Why a modality has no ray through a pixel of the image it displays.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImageRayError {
    /// No image has been taken yet.
    #[error("no {modality} image yet: take a shot first")]
    NoImage {
        /// Modality name.
        modality: &'static str,
    },
    /// The pixel lies outside the image.
    #[error("{pixel:?} is outside the {width} x {height} image")]
    OutsideImage {
        /// The continuous pixel asked for.
        pixel: [f64; 2],
        /// Image width, pixels.
        width: u32,
        /// Image height, pixels.
        height: u32,
    },
}
