//! Automatic brightness control (ABC): the C-arm's feedback loop that holds the air kerma the
//! detector receives per frame at a target by stepping the tube voltage and current along a
//! curve, within the tube's limits and the regulatory limit on the skin entrance rate.
//!
//! # The loop
//! Each frame is exposed with the technique the loop chose after the previous frame. The
//! detector signal of that frame is metered over a central disc ([`meter`]; the air kerma per
//! frame averaged over the disc, [`Metering::detector_kerma_ngy`]); from it [`next_technique`]
//! chooses the technique of the next frame. Like the water-equivalent lookup of real
//! controllers it reads the frame as a water-equivalent thickness (the soft-tissue thickness
//! with the same kerma transmission at the frame's kVp), finds the point of the curve whose
//! predicted output through that thickness is the target, and rounds the voltage down to the
//! committed spectra's 5 kVp steps with the current making up the difference; within
//! [`DEADBAND`] of the target it keeps the technique. Bone makes the
//! patient harder or softer than water, so the first step after a view change lands within a
//! few percent and the next ones close the gap: the test below asks for 5 % in at most 5 frames.
//!
//! # Curves
//! AAPM Report 125 (P. Rauch et al., "Functionality and operation of fluoroscopic automatic
//! brightness control/automatic dose rate control logic in modern cardiovascular and
//! interventional angiography systems", Med. Phys. 39 (2012) 2826-2828) describes the kinds of
//! curve a controller follows through kVp-mA space; ours are three of them (knots are simulator
//! choices in that shape):
//! - [`BrightnessCurve::Standard`]: voltage and current rise together;
//! - [`BrightnessCurve::LowDose`]: the voltage rises first (a harder beam reaches the detector
//!   with less skin dose), at a lower target;
//! - [`BrightnessCurve::HighContrast`]: the voltage is held low (iodine and bone contrast fall
//!   with kVp) while the current rises to its maximum, then the voltage follows.
//!
//! # Limits
//! [`TubeLimits`]: the fluoroscopy current and the tube power (simulator choices for a mobile
//! C-arm), and 88 mGy/min of air kerma at the skin entrance (US 21 CFR 1020.32(d)(2), equipment
//! made on or after 19 May 1995, normal mode; taken at the skin along the central ray, which is
//! stricter than the regulation's measurement point for a C-arm, 30 cm from the image
//! receptor, whenever the skin lies farther than that from the detector, as in the spine views
//! here). A kept technique is checked against the limits too. When a limit holds the output below
//! the target the frame is darker at the detector and noisier, and the step says which limit.

use serde::{Deserialize, Serialize};

use super::attenuation::{BasisDepths, basis_depths};
use super::detector::{kerma_model, open_field_kerma_ngy};
use super::dose::{REFERENCE_DISTANCE_MM, air_kerma_ugy_per_mas_at_1m_interpolated};
use super::geometry::Projection;
use super::rows::thread_count;
use super::scene::{ChordScratch, SceneRef};
use super::spectrum::{Basis, Spectrum};
use crate::par::par_map_on;

/// Diameter of the metering disc as a fraction of the detector side. Simulator choice: the
/// central third, the usual sensing field of an image-intensifier or flat-panel C-arm.
pub const METERING_FRACTION: f64 = 1.0 / 3.0;

/// Rays across the metering disc's diameter (about `0.785 n^2` rays inside the disc).
/// Simulator choice: 10 (about 80 rays, 4.6 mm apart at the isocentre) resolves a vertebral
/// body within the disc; the metering of a new view then costs about 1.4 ms on the default
/// phantom (12 across: 2.1 ms, which with the temporal chain went over the 3 ms a 512^2 live
/// frame may spend on the imaging chain; the `brightness` bench).
pub const METERING_RAYS_ACROSS: usize = 10;

/// Fewest metering rays per thread. Simulator choice: a ray through the default phantom's
/// meshes costs about 50 us, a thread's start tens.
const METERING_RAYS_PER_THREAD: usize = 16;

/// Smallest tube current the controller sets, mA (simulator choice: the low end of a mobile
/// C-arm's fluoroscopy range).
pub const MIN_MA: f64 = 0.2;

/// Relative deviation from the target within which the loop keeps its technique. Simulator
/// choice: 3 %, so that the technique does not hunt between neighbouring steps from frame to
/// frame (the 5 kVp steps and the water-equivalent reading differ by a few percent).
pub const DEADBAND: f64 = 0.03;

/// Lowest and highest voltage the controller uses, kVp (the committed spectra's range).
pub const KVP_RANGE: (u32, u32) = (40, 120);

/// A controller curve through kVp-mA space (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BrightnessCurve {
    /// Voltage and current rise together.
    Standard,
    /// The voltage first, at a lower target.
    LowDose,
    /// The current first, the voltage held low.
    HighContrast,
}

impl BrightnessCurve {
    /// Every curve.
    pub const ALL: [BrightnessCurve; 3] = [
        BrightnessCurve::Standard,
        BrightnessCurve::LowDose,
        BrightnessCurve::HighContrast,
    ];

    /// The JSON name (`standard`, `low_dose`, `high_contrast`).
    pub fn name(self) -> &'static str {
        match self {
            BrightnessCurve::Standard => "standard",
            BrightnessCurve::LowDose => "low_dose",
            BrightnessCurve::HighContrast => "high_contrast",
        }
    }

    /// The curve called `name`.
    pub fn parse(name: &str) -> Option<BrightnessCurve> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }

    /// The curve's knots `(kVp, mA)`, both nondecreasing (simulator choices, module docs).
    pub fn knots(self) -> &'static [(f64, f64)] {
        match self {
            BrightnessCurve::Standard => &[
                (60.0, MIN_MA),
                (70.0, 1.0),
                (80.0, 2.0),
                (90.0, 3.0),
                (100.0, 4.0),
                (110.0, 5.0),
                (120.0, 6.0),
            ],
            BrightnessCurve::LowDose => &[
                (70.0, MIN_MA),
                (90.0, 0.6),
                (110.0, 1.2),
                (120.0, 2.5),
                (120.0, 6.0),
            ],
            BrightnessCurve::HighContrast => {
                &[(60.0, MIN_MA), (65.0, 2.0), (70.0, 6.0), (120.0, 6.0)]
            }
        }
    }

    /// Target detector air kerma per frame, nGy: of the metered signal, which is the primary
    /// alone in sessions recorded before the scatter model and otherwise the total behind the
    /// anti-scatter grid (primary through the grid plus scatter, see
    /// [`Metering::scatter_factor`]). Standard: 3 nGy, simulator choice that drives an adult AP
    /// lumbar view to about 80 kVp and 3-4 mA at 7.5 pulses per second with the grid in (bench
    /// `brightness`), at the low end of the 10-40 nGy per frame of flat-panel fluoroscopy (A. R.
    /// Cowen, A. G. Davies and M. U. Sivananthan, "The design and imaging characteristics of
    /// dynamic, solid-state, flat-panel x-ray image detectors for digital fluoroscopy and
    /// fluorography", Clin. Radiol. 63 (2008) 1073-1085). Low dose: 60 % of it; high contrast:
    /// the standard target.
    pub fn target_ngy_per_frame(self) -> f64 {
        match self {
            BrightnessCurve::Standard | BrightnessCurve::HighContrast => 3.0,
            BrightnessCurve::LowDose => 1.8,
        }
    }

    /// The point of the curve at position `s` (0 to `knots - 1`, clamped): `(kVp, mA)`.
    pub fn at(self, s: f64) -> (f64, f64) {
        let k = self.knots();
        let s = s.clamp(0.0, (k.len() - 1) as f64);
        let i = (s.floor() as usize).min(k.len() - 2);
        let f = s - i as f64;
        (
            k[i].0 + f * (k[i + 1].0 - k[i].0),
            k[i].1 + f * (k[i + 1].1 - k[i].1),
        )
    }
}

/// What the tube and the regulations allow in fluoroscopy.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TubeLimits {
    /// Highest fluoroscopy current, mA. Simulator choice: 6 mA, the top of the curves.
    pub max_ma: f64,
    /// Highest continuous electrical power `kVp x mA` at full beam duty, W. Simulator choice:
    /// 600 W (120 kVp at 5 mA), a mobile C-arm's fluoroscopy rating; pulsed beams may draw
    /// more current in proportion to their lower duty.
    pub max_power_w: f64,
    /// Highest air kerma rate at the skin entrance, mGy/min (21 CFR 1020.32(d)(2): 88 mGy/min
    /// in normal mode).
    pub max_skin_kerma_rate_mgy_per_min: f64,
}

impl Default for TubeLimits {
    fn default() -> Self {
        TubeLimits {
            max_ma: 6.0,
            max_power_w: 600.0,
            max_skin_kerma_rate_mgy_per_min: 88.0,
        }
    }
}

/// How much a magnification mode raises the target detector kerma: `full / field` (a field of
/// half the side gets twice the kerma per frame). Simulator choice: the quanta per pixel then
/// fall as `field / full` instead of as the area ratio `(field / full)^2` a constant target would
/// give, so a magnified image is somewhat noisier but not four times (NCRP Report 168, 2010,
/// describes the dose increase of magnification modes, by about the area ratio for image
/// intensifiers and by less for flat panels). 1 for a non-positive or non-finite field.
pub fn magnification_target_factor(full_field_mm: f64, field_mm: f64) -> f64 {
    let f = full_field_mm / field_mm;
    if f.is_finite() && f > 0.0 { f } else { 1.0 }
}

/// How a frame is exposed, besides its technique.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FrameExposure {
    /// Seconds of tube current per frame (charge per frame = mA x this, mAs).
    pub frame_s: f64,
    /// Fraction of the continuous beam delivered over time (pulsed fluoroscopy: below 1).
    pub duty: f64,
    /// Focal spot to detector, mm.
    pub source_to_detector_mm: f64,
    /// Focal spot to skin entrance along the central ray, mm.
    pub source_to_skin_mm: f64,
}

/// A tube voltage (a committed spectrum) and current.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Technique {
    /// kVp.
    pub kvp: u32,
    /// mA.
    pub ma: f64,
}

/// The limit that held a step's output below its target.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Limit {
    /// The end of the curve.
    Curve,
    /// The tube's current.
    Current,
    /// The tube's power.
    Power,
    /// The skin entrance kerma rate.
    SkinRate,
}

/// One step of the loop.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Step {
    /// The technique of the next frame.
    pub technique: Technique,
    /// The detector air kerma per frame the controller expects of it, nGy.
    pub predicted_ngy: f64,
    /// The water-equivalent thickness the frame was read as, mm.
    pub water_equivalent_mm: f64,
    /// The limit that held the output below the target, if one did.
    pub limited_by: Option<Limit>,
}

/// The metering disc's rays of one view: their basis depths (independent of the technique, so
/// one metering gives the signal at any technique).
#[derive(Debug, Clone, PartialEq)]
pub struct Metering {
    /// 60 keV basis depths per ray inside the disc and the collimation.
    pub depths: Vec<BasisDepths>,
    /// Distance from the last surface the central ray leaves (the patient's exit skin) to the
    /// detector, mm: the air gap of the scatter model; the whole source-to-detector distance
    /// when the ray meets nothing.
    pub air_gap_mm: f64,
}

/// Meters the view `projection` of `scene`: `rays_across^2` rays on a square grid over the
/// central disc of diameter [`METERING_FRACTION`] of the detector side, those inside the disc
/// and the collimator opening kept. The anatomy only (an instrument's steel or injected iodine
/// covers a small part of the disc; simulator choice).
pub fn meter<'a>(
    scene: impl Into<SceneRef<'a>>,
    projection: &Projection,
    rays_across: usize,
) -> Metering {
    meter_on(scene, projection, rays_across, 0)
}

/// [`meter`] on up to `threads` threads (0: one per core); the same result on any number.
pub fn meter_on<'a>(
    scene: impl Into<SceneRef<'a>>,
    projection: &Projection,
    rays_across: usize,
    threads: usize,
) -> Metering {
    let scene = scene.into();
    let n = rays_across.max(1);
    let [w, h] = projection.detector_pixels;
    let (cx, cy) = (0.5 * f64::from(w), 0.5 * f64::from(h));
    let side_px = f64::from(w.min(h));
    let radius_px = 0.5 * METERING_FRACTION * side_px;
    let mut pixels = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            // Cell centres of an n x n grid over the disc's bounding square.
            let ox = ((i as f64 + 0.5) / n as f64 * 2.0 - 1.0) * radius_px;
            let oy = ((j as f64 + 0.5) / n as f64 * 2.0 - 1.0) * radius_px;
            if ox * ox + oy * oy > radius_px * radius_px {
                continue;
            }
            let px = [cx + ox, cy + oy];
            if projection.is_exposed(px) {
                pixels.push(px);
            }
        }
    }
    // Each ray on its own, in order: the same depths on any number of threads. The rays are the
    // command's work before its frame (after a C-arm move: about 80 rays through every mesh of
    // the scene, 3.4-4.9 ms of the default phantom on one core).
    let workers = thread_count(threads).min(pixels.len().div_ceil(METERING_RAYS_PER_THREAD));
    let depths: Vec<BasisDepths> = par_map_on(
        workers,
        pixels.len(),
        &|k| {
            let ray = projection.pixel_ray(pixels[k]);
            let chords = scene
                .ray_chords(
                    ray.origin_mm,
                    ray.dir,
                    ray.detector_t_mm,
                    &mut ChordScratch::default(),
                )
                .chords_mm;
            basis_depths(&chords, 0.0)
        },
        &mut |_| {},
    );
    let centre = projection.pixel_ray([cx, cy]);
    let mut hits = Vec::new();
    let mut last_exit: Option<f64> = None;
    for entry in scene.entries() {
        entry.bvh.all_hits(
            centre.origin_mm,
            centre.dir,
            0.0,
            centre.detector_t_mm,
            &mut hits,
        );
        if let Some(h) = hits.iter().rev().find(|h| !h.entering) {
            last_exit = Some(last_exit.map_or(h.t_mm, |t: f64| t.max(h.t_mm)));
        }
    }
    let air_gap_mm = centre.detector_t_mm - last_exit.unwrap_or(0.0);
    Metering { depths, air_gap_mm }
}

impl Metering {
    /// The detector's total signal over its primary at the disc's centre, by the scatter model:
    /// `T_p (1 + SPR)` with the grid (`T_p` its primary transmission), `1 + SPR` without, for
    /// the disc's water-equivalent thickness at `kvp`, a field of half-sides `half_x_mm` and
    /// `half_y_mm` at the detector and this view's air gap
    /// ([`crate::fluoro::scatter::superposition::centre_spr`]); NaN where the disc's
    /// transmission is.
    pub fn scatter_factor(&self, kvp: u32, half_x_mm: f64, half_y_mm: f64, grid: bool) -> f64 {
        let t = self.kerma_transmission(kvp);
        if !t.is_finite() {
            return f64::NAN;
        }
        let water_mm = water_equivalent_mm(kvp, t);
        let spr = crate::fluoro::scatter::superposition::centre_spr(
            kvp,
            water_mm,
            half_x_mm,
            half_y_mm,
            self.air_gap_mm,
            grid,
        )
        .unwrap_or(f64::NAN);
        let primary = if grid {
            crate::fluoro::scatter::AntiScatterGrid::FLUOROSCOPY.primary_transmission()
        } else {
            1.0
        };
        primary * (1.0 + spr)
    }

    /// The disc's mean kerma transmission at `kvp`; NaN with no ray (shutters closed over
    /// the disc: nothing to meter, and the loop holds its technique) or a voltage without a
    /// spectrum.
    pub fn kerma_transmission(&self, kvp: u32) -> f64 {
        let Ok(model) = kerma_model(kvp) else {
            return f64::NAN;
        };
        if self.depths.is_empty() {
            return f64::NAN;
        }
        self.depths
            .iter()
            .map(|a| model.transmission(a))
            .sum::<f64>()
            / self.depths.len() as f64
    }

    /// The disc's mean detector air kerma per frame, nGy, at `technique` (NaN for a voltage
    /// without a spectrum).
    pub fn detector_kerma_ngy(&self, technique: Technique, exposure: &FrameExposure) -> f64 {
        open_field_kerma_ngy(
            f64::from(technique.kvp),
            technique.ma * exposure.frame_s,
            exposure.source_to_detector_mm,
        ) * self.kerma_transmission(technique.kvp)
    }
}

/// Kerma transmission of `mm` of soft tissue at `kvp`.
fn water_transmission(kvp: u32, mm: f64) -> f64 {
    let mut a = [0.0; Basis::COUNT];
    a[Basis::Water.index()] = super::attenuation::SOFT_TISSUE_MU_60KEV_PER_CM * mm * 0.1;
    kerma_model(kvp).map_or(f64::NAN, |m| m.transmission(&a))
}

/// [`water_transmission`] at a voltage between the committed ones (linear in `ln T`).
fn water_transmission_between(kvp: f64, mm: f64) -> f64 {
    let lo = ((kvp / 5.0).floor() * 5.0).clamp(40.0, 115.0);
    let f = ((kvp - lo) / 5.0).clamp(0.0, 1.0);
    let (t0, t1) = (
        water_transmission(lo as u32, mm),
        water_transmission(lo as u32 + 5, mm),
    );
    (t0.ln() * (1.0 - f) + t1.ln() * f).exp()
}

/// The soft-tissue thickness (mm, 0 to 2,000) whose kerma transmission at `kvp` is `t` (NaN
/// for a voltage without a spectrum).
pub fn water_equivalent_mm(kvp: u32, t: f64) -> f64 {
    if kerma_model(kvp).is_err() {
        return f64::NAN;
    }
    if t.is_nan() || t >= 1.0 {
        return 0.0;
    }
    let (mut lo, mut hi) = (0.0, 2000.0);
    if t <= water_transmission(kvp, hi) {
        return hi;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if water_transmission(kvp, mid) > t {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Skin entrance air kerma rate of `technique`, mGy/min.
pub fn skin_kerma_rate_mgy_per_min(technique: Technique, exposure: &FrameExposure) -> f64 {
    let ugy_per_s = air_kerma_ugy_per_mas_at_1m_interpolated(f64::from(technique.kvp))
        * technique.ma
        * exposure.duty
        * (REFERENCE_DISTANCE_MM / exposure.source_to_skin_mm).powi(2);
    ugy_per_s * 60.0 / 1000.0
}

/// The highest current the limits allow at `kvp`, and the limit that sets it.
fn max_current(kvp: u32, limits: &TubeLimits, exposure: &FrameExposure) -> (f64, Limit) {
    let mut best = (limits.max_ma, Limit::Current);
    let duty = exposure.duty.clamp(1e-6, 1.0);
    let power = limits.max_power_w / (f64::from(kvp) * duty);
    if power < best.0 {
        best = (power, Limit::Power);
    }
    let per_ma = skin_kerma_rate_mgy_per_min(Technique { kvp, ma: 1.0 }, exposure);
    if per_ma > 0.0 {
        let skin = limits.max_skin_kerma_rate_mgy_per_min / per_ma;
        if skin < best.0 {
            best = (skin, Limit::SkinRate);
        }
    }
    best
}

/// The technique of the next frame, after a frame exposed at `current` whose metered detector
/// air kerma was `measured_ngy` per frame (module docs). A measurement that is not a positive
/// finite number (no ray metered, a broken frame) keeps the technique.
pub fn next_technique(
    curve: BrightnessCurve,
    limits: &TubeLimits,
    exposure: &FrameExposure,
    current: Technique,
    measured_ngy: f64,
) -> Step {
    next_technique_to(
        curve,
        curve.target_ngy_per_frame(),
        limits,
        exposure,
        current,
        measured_ngy,
    )
}

/// [`next_technique`] towards `target_ngy` per frame instead of the curve's own target (a
/// magnification mode raises it; see [`magnification_target_factor`]). A target that is not a
/// positive finite number keeps the technique.
pub fn next_technique_to(
    curve: BrightnessCurve,
    target_ngy: f64,
    limits: &TubeLimits,
    exposure: &FrameExposure,
    current: Technique,
    measured_ngy: f64,
) -> Step {
    let target = target_ngy;
    let sid = exposure.source_to_detector_mm;
    let open = |kvp: f64, ma: f64| open_field_kerma_ngy(kvp, ma * exposure.frame_s, sid);
    let open_now = open(f64::from(current.kvp), current.ma);
    let usable = measured_ngy.is_finite()
        && measured_ngy > 0.0
        && open_now > 0.0
        && target.is_finite()
        && target > 0.0;
    if !usable || Spectrum::tungsten(current.kvp).is_err() {
        return Step {
            technique: current,
            predicted_ngy: measured_ngy,
            water_equivalent_mm: f64::NAN,
            limited_by: None,
        };
    }
    let t_w = water_equivalent_mm(current.kvp, measured_ngy / open_now);
    // Within the deadband the technique is kept, as long as it is still within the limits (a
    // faster pulse rate or a nearer skin can put a kept technique over them).
    let within_limits = current.ma <= max_current(current.kvp, limits, exposure).0 + 1e-9;
    if (measured_ngy / target - 1.0).abs() <= DEADBAND && within_limits {
        return Step {
            technique: current,
            predicted_ngy: measured_ngy,
            water_equivalent_mm: t_w,
            limited_by: None,
        };
    }
    // Predicted output along the (continuous) curve, nondecreasing in `s`.
    let predicted = |s: f64| {
        let (kv, ma) = curve.at(s);
        open(kv, ma) * water_transmission_between(kv, t_w)
    };
    let top = (curve.knots().len() - 1) as f64;
    let (s, mut limited_by) = if predicted(top) < target {
        (top, Some(Limit::Curve))
    } else {
        let (mut lo, mut hi) = (0.0, top);
        for _ in 0..50 {
            let mid = 0.5 * (lo + hi);
            if predicted(mid) < target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (hi, None)
    };
    // Down to the committed 5 kVp steps (the current makes up the difference, keeping the
    // curve's character: a low-voltage curve stays low).
    let floor5 = |kv: f64| ((kv / 5.0 + 1e-9).floor() * 5.0).clamp(40.0, 120.0) as u32;
    let kv_c = curve.at(s).0;
    // Hysteresis: a curve point within half a step of the current voltage's span keeps the
    // voltage (the water reading differs by a few kVp between neighbouring voltages when
    // bone is in the disc; without it the loop could swing between them for ever).
    // Not at the end of the curve, whose top voltage must be reachable.
    let kvp = if limited_by.is_none() && (kv_c - (f64::from(current.kvp) + 2.5)).abs() <= 5.0 {
        current.kvp
    } else {
        floor5(kv_c)
    };
    // At a rounded voltage the current makes up the difference; when a limit stops it, higher
    // voltages (up to the top) are tried at their highest current.
    let per_ma = |kvp: u32| open(f64::from(kvp), 1.0) * water_transmission(kvp, t_w);
    let mut best: Option<(Technique, f64, Option<Limit>)> = None;
    let mut kv = kvp;
    while kv <= KVP_RANGE.1 {
        let want = target / per_ma(kv);
        let (cap, limit) = max_current(kv, limits, exposure);
        let ma = want.min(cap).max(MIN_MA.min(cap));
        let out = per_ma(kv) * ma;
        let held = (want > cap).then_some(limit);
        if best.is_none_or(|(_, o, _)| out > o) {
            best = Some((Technique { kvp: kv, ma }, out, held));
        }
        if held.is_none() {
            break;
        }
        kv += 5;
    }
    let (technique, predicted_ngy, held) = best.expect("at least the rounded voltage");
    let cap = max_current(technique.kvp, limits, exposure).0;
    // The limit that holds the current below what the curve asks is the one that binds.
    if held.is_some() {
        limited_by = held;
    }
    Step {
        technique: Technique {
            kvp: technique.kvp,
            // Centi-mA steps: what a console shows, and exact in the log; down when a limit
            // set the current, so that the step stays within it.
            // Never below 0.01 mA (a current of zero would leave nothing to meter) nor, by the
            // rounding, above the cap.
            ma: if held.is_some() {
                (technique.ma * 100.0).floor() / 100.0
            } else {
                (technique.ma * 100.0).round() / 100.0
            }
            .min((cap * 100.0).floor() / 100.0)
            .max(0.01),
        },
        predicted_ngy,
        water_equivalent_mm: t_w,
        limited_by,
    }
}

#[cfg(test)]
mod tests;
