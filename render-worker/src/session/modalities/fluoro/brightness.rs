//! Automatic brightness control in a session: after every frame (a shot or a live pulse) the
//! detector's primary air kerma over the central metering disc is measured at the frame's
//! technique and [`sim_core::fluoro::brightness::next_technique`] sets the technique of the
//! next frame, so that a lateral view is driven hotter than an AP one, as on a real C-arm.
//!
//! - New sessions start on the standard curve; `{"type": "brightness", "curve": "low_dose"}`
//!   chooses another (`standard`, `low_dose`, `high_contrast`), and a `technique` command sets
//!   the voltage and current by hand, which turns the control off until a `brightness` command.
//! - Each frame's technique, charge and measured detector kerma are part of its
//!   [`super::AcquiredImage`], and the step runs while the command that acquired it is applied,
//!   from the scene alone (never from a rendered frame), so a replay chooses the same techniques
//!   on any renderer and every frame replays bit for bit.
//! - The loop regulates the current of live fluoroscopy: each pulse carries a video frame's
//!   charge (`mA / 30` mAs, see [`super::pulse`]); a shot exposes the same current for
//!   [`super::SHOT_EXPOSURE_MS`] and so reaches the detector with three pulses' kerma.
//! - Sessions recorded before the control existed have no `brightness` in their state: they
//!   keep their manual technique.

use serde::{Deserialize, Serialize};
use sim_core::fluoro::Projection;
use sim_core::fluoro::brightness::{
    BrightnessCurve, FrameExposure, Limit, METERING_RAYS_ACROSS, Metering, Technique, TubeLimits,
    meter, next_technique_to,
};

use super::pulse::CONTINUOUS_FRAMES_PER_S;
use crate::session::command::{CommandError, ModalityCommand};
use crate::session::region::Region;

/// The command kind that chooses the curve.
pub const BRIGHTNESS_KIND: &str = "brightness";

/// The curve a new session starts with.
pub const DEFAULT_CURVE: BrightnessCurve = BrightnessCurve::Standard;

/// The control's state (part of the fluoroscopy state while the control is on).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BrightnessState {
    /// The curve followed.
    pub curve: BrightnessCurve,
    /// The limit that held the last step below its target, if one did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limited_by: Option<Limit>,
}

impl BrightnessState {
    /// The control on `curve`, nothing measured yet.
    pub fn on(curve: BrightnessCurve) -> BrightnessState {
        BrightnessState {
            curve,
            limited_by: None,
        }
    }
}

/// The fields of a `brightness` command.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BrightnessCommand {
    /// `standard`, `low_dose` or `high_contrast`.
    curve: String,
}

/// The curve a `brightness` command asks for, or its field-named error.
pub fn parse(command: &ModalityCommand) -> Result<BrightnessCurve, CommandError> {
    let BrightnessCommand { curve } = command.parse()?;
    crate::session::command::named_choice(
        "curve",
        &curve,
        BrightnessCurve::parse,
        "standard, low_dose or high_contrast (a technique command sets kVp and mA by hand)",
    )
}

/// Seconds of tube current per live pulse (a video frame's charge).
pub const PULSE_S: f64 = 1.0 / CONTINUOUS_FRAMES_PER_S;

/// The metering of the last view, kept while the C-arm stays (not part of the state: it is a
/// pure function of the scene and the view).
#[derive(Debug, Default)]
pub struct MeteringCache {
    view: Option<(Projection, Metering)>,
}

impl MeteringCache {
    /// The metering of `projection` on `region`, metered on a change of view only.
    pub fn get(&mut self, region: &Region, projection: &Projection) -> &Metering {
        let fresh = !matches!(&self.view, Some((p, _)) if p == projection);
        if fresh {
            let m = meter(&region.scene, projection, METERING_RAYS_ACROSS);
            self.view = Some((*projection, m));
        }
        &self.view.as_ref().expect("set above").1
    }
}

/// The measured detector air kerma per pulse of a frame at `technique` (nGy: the metered
/// primary times `signal_factor`, 1 for the primary alone or the scatter model's total behind
/// the grid), and the control's next technique (`None`: the control is off, or the step keeps
/// the technique), towards the curve's target times `target_factor` (a magnification mode's).
pub fn step(
    state: &mut Option<BrightnessState>,
    metering: &Metering,
    technique: Technique,
    exposure: &FrameExposure,
    target_factor: f64,
    signal_factor: f64,
) -> (f64, Option<Technique>) {
    let measured = metering.detector_kerma_ngy(technique, exposure) * signal_factor;
    let Some(s) = state.as_mut() else {
        return (measured, None);
    };
    let next = next_technique_to(
        s.curve,
        s.curve.target_ngy_per_frame() * target_factor,
        &TubeLimits::default(),
        exposure,
        technique,
        measured,
    );
    s.limited_by = next.limited_by;
    (
        measured,
        (next.technique != technique).then_some(next.technique),
    )
}

/// The technique of the image on display (`shown`: its kVp, mA and metered kerma), the
/// technique of the next frame and the control's state, for acks.
pub fn technique_json(
    shown: Option<(u32, f64, Option<f64>)>,
    next: Technique,
    pulse_rate_pps: Option<f64>,
    state: Option<BrightnessState>,
) -> serde_json::Value {
    serde_json::json!({
        "kvp": shown.map_or(next.kvp, |s| s.0),
        "ma": shown.map_or(next.ma, |s| s.1),
        "pulse_rate_pps": pulse_rate_pps,
        "brightness": state.map_or("manual", |b| b.curve.name()),
        "limited_by": state.and_then(|b| b.limited_by),
        "detector_kerma_ngy": shown.and_then(|s| s.2),
        "next_kvp": next.kvp,
        "next_ma": next.ma,
    })
}
