//! Station scorers: rubric measurements from live session state, and the result of a submit.
//!
//! # Measurements and how each is derived
//! Needle (session level):
//! - `tip_to_target_mm`: straight distance from the needle tip to the target named by the
//!   `tip_to_target_mm` criterion (else the station's first target), model frame.
//! - `needle_depth_mm`: buried shaft length, skin to tip, along the tract.
//! - `tip_medial_to_pedicle_mm`: in the AP view (patient x), how far the tip lies medial of the
//!   named pedicle point (positive = medial, towards the midline).
//! - `dural_puncture_bool`: 1 when the tip has been inside the `dural_sac` structure after any
//!   needle command (the tip and the buried channel sampled every millimetre are checked).
//!
//! Needle handling (see [`super::hands`]), present from the start of every attempt:
//! - `skin_punctures_count`: `needle_puncture` and `needle_place` commands accepted.
//! - `redirections_count`: advances into new tissue on a branch that left at least 2 mm of
//!   channel behind (withdraw, re-aim by hub tilt or bevel, advance), summed over every needle
//!   (`sim_core::needle::hub`).
//! - `bone_contacts_count`: episodes of bone contact (a feed stopped or deflected by bone after
//!   one that was not).
//! - `lor_confirmed_bool`: 1 once the loss-of-resistance plunger gave way with the outlet in the
//!   epidural space before any injection through the contrast syringe.
//! - `false_loss_count`: losses felt with the outlet outside the epidural space.
//! - `aspiration_done_bool`: 1 once the learner aspirated with the needle in the body.
//!
//! Fluoroscopy (see `modalities/fluoro/`):
//! - `fluoro_acquisitions_count` (shots plus live runs) and `fluoro_exposure_s`, also reported
//!   as `fluoro_time_s`.
//! - `air_kerma_mgy` and `kerma_area_product_gycm2`: the radiation estimate (incident air kerma
//!   at the skin entrance of the central ray, and kerma-area product; see
//!   `modalities/fluoro/dose.rs`). An estimate, not a dose record.
//! - `ap_endplate_tilt_deg`: the smallest angle between the central ray and the L4 inferior
//!   endplate plane over the AP-like acquisitions (|orbital| <= 10 degrees). The endplate normal
//!   is read from the `L4_cortical` mesh where rays from the L4 body centre towards the L5 body
//!   centre leave the bone.
//! - `ipsilateral_oblique_deg` / `clo_angle_deg`: the obliquity of the last acquisition that was
//!   oblique (>= 10 degrees) towards the target's side / away from it. With this C-arm's
//!   convention (the central ray is `(-sin o, cos o, 0)` for orbital `o` and no angulation), an
//!   ipsilateral oblique view of a left-sided target, whose beam line runs from
//!   posterior-left to anterior-right, has a negative orbital angle: ipsilateral obliquity is
//!   `side * orbital` with side -1 left, +1 right of the L4 body centre.
//! - `beam_to_joint_plane_deg`: the smallest angle between the central ray and the facet joint
//!   plane nearest the target over all acquisitions; the joint plane is estimated from the bone
//!   meshes around the facet joint landmark (the thinnest gap direction).
//! - `annotation_error_mm`: for the last annotation whose label names a target or landmark, the
//!   distance from that point to the ray through the marked pixel.
//!
//! Contrast (see `modalities/contrast/scorers.rs`): the pattern measurements from the transport
//! model's field and ledger (`epidural_spread_bool`, `perineural_spread_bool`,
//! `intravascular_uptake_bool`, `intrathecal_contrast_bool`, `epidural_levels_count`, ...),
//! present once iodine was injected.
//!
//! Measurements that need what this worker does not have yet (ultrasound visibility, the
//! facet stations' `intra_articular_spread_bool`: the transport model has no joint space) are
//! simply absent, so the rubric engine reports the result as incomplete rather than scoring a
//! zero.

use std::collections::BTreeMap;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use sim_core::rubric::{Measurements, RubricResult};

use super::anatomy::{primary_target, target_side};
use super::modalities::fluoro::BackendProfile;
use super::world::World;

/// Revision of the code that produced a result: the crate version and, when the build saw a git
/// checkout, the commit (with `-dirty` for uncommitted changes).
pub fn code_revision() -> String {
    format!(
        "render-worker {} ({})",
        env!("CARGO_PKG_VERSION"),
        option_env!("RENDER_WORKER_GIT_REVISION").unwrap_or("git revision unknown")
    )
}

/// Needle measurements from the shared world.
pub fn measure_needle(world: &World, out: &mut Measurements) {
    let h = &world.hands;
    let flag = |b: bool| if b { 1.0 } else { 0.0 };
    out.insert("skin_punctures_count".into(), f64::from(h.skin_punctures));
    let current = world.needle.as_ref().map_or(0, |n| n.state.redirections);
    out.insert(
        "redirections_count".into(),
        f64::from(h.redirections_before + current),
    );
    out.insert("bone_contacts_count".into(), f64::from(h.bone_contacts));
    out.insert("lor_confirmed_bool".into(), flag(h.lor_confirmed));
    out.insert("false_loss_count".into(), f64::from(h.false_losses));
    out.insert("aspiration_done_bool".into(), flag(h.aspirations > 0));
    let Some(n) = &world.needle else {
        return;
    };
    let tip = n.state.tip_mm();
    out.insert("needle_depth_mm".into(), n.state.buried_mm());
    if let Some(t) = primary_target(&world.station) {
        out.insert(
            "tip_to_target_mm".into(),
            tip.distance(DVec3::from_array(t)),
        );
    }
    if let Some(ped) = world
        .station
        .station
        .rubric
        .criteria
        .iter()
        .find(|c| c.measurement == "tip_medial_to_pedicle_mm")
        .and_then(|c| c.target.as_ref())
        .and_then(|t| world.station.targets.get(t))
    {
        let side = target_side(&world.region, *ped);
        // Medial is towards the midline: -x for a right-sided point, +x for a left-sided one.
        out.insert("tip_medial_to_pedicle_mm".into(), -side * (tip.x - ped[0]));
    }
    if world.region.entry("dural_sac").is_some() {
        let v = if n.entered.contains("dural_sac") {
            1.0
        } else {
            0.0
        };
        out.insert("dural_puncture_bool".into(), v);
    }
    // Regions with vertebral arteries (the cervical phantom): whether the needle entered either.
    if world.region.entry("vertebral_artery_left").is_some() {
        let hit = ["vertebral_artery_left", "vertebral_artery_right"]
            .iter()
            .any(|a| n.entered.contains(*a));
        out.insert("vertebral_artery_puncture_bool".into(), flag(hit));
    }
}

/// What goes with a technical result so it can be reproduced and audited.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReproducibilityRecord {
    /// See [`code_revision`].
    pub code_revision: String,
    /// Station id.
    pub station_id: String,
    /// Station revision.
    pub station_revision: u32,
    /// Rubric revision.
    pub rubric_revision: u32,
    /// SHA-256 of the station file.
    pub station_sha256: String,
    /// Region name.
    pub region: String,
    /// Where the region came from.
    pub region_source: String,
    /// SHA-256 of every region file (from its provenance).
    pub asset_sha256: BTreeMap<String, String>,
    /// The renderer that made the frames.
    pub renderer: BackendProfile,
    /// Per-modality settings at submit (C-arm pose, technique, detector...).
    pub modalities: BTreeMap<String, serde_json::Value>,
    /// Station modalities this worker could not provide.
    pub unavailable_modalities: Vec<String>,
    /// Accepted commands.
    pub log_len: usize,
    /// SHA-256 of the JSON log.
    pub log_sha256: String,
    /// SHA-256 of the initial state (JSON snapshot).
    pub initial_state_sha256: String,
    /// SHA-256 of the final state.
    pub final_state_sha256: String,
}

/// The result of a submit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SubmitResult {
    /// Every measurement the session could make (also ones this rubric does not read).
    pub measurements: Measurements,
    /// The rubric engine's result, from the measurements the rubric reads.
    pub rubric: RubricResult,
    /// How to reproduce it.
    pub record: ReproducibilityRecord,
}
