//! The loss-of-resistance syringe and aspiration.
//!
//! # Loss of resistance
//! The hand applies a constant pressure [`HAND_PRESSURE_KPA`] to the plunger. Every tissue at
//! the needle outlet has an injection opening pressure ([`opening_pressure_kpa`]): the pressure
//! the syringe must reach before fluid (or air) flows into it. The plunger gives way when the
//! opening pressure is below the hand's pressure; the felt resistance is their ratio, capped at 1
//! (1 = the plunger does not move).
//!
//! Saline is incompressible: against a closed outlet the plunger does not move ("firm"). Air
//! compresses: by Boyle's law the gas column `V` at atmospheric pressure `p0` shrinks to
//! `V p0 / (p0 + p)` under the hand's gauge pressure `p`, so the plunger travels
//! `V p / (p0 + p)` and springs back when released ("springy"); with 5 ml of air and 30 kPa this
//! is 1.1 ml, which is why loss of resistance to air feels less crisp than to saline.
//!
//! False loss of resistance is modelled through opening pressures, not as a random fraction:
//! subcutaneous fat and muscle have opening pressures below the hand's pressure, so the plunger
//! gives way when the outlet lies in them. Sharrock (1979, "Recordings of, and an anatomical
//! explanation for, false positive loss of resistance during lumbar extradural analgesia",
//! Br J Anaesth 51:253-258) recorded such false losses during midline approaches; Lawrence,
//! Llewellyn, Hunt, Cowin, Sturgess & Reutens (2021, Reg Anesth Pain Med, "Anatomy of the lumbar
//! interspinous ligament: findings relevant to epidural insertion using loss of resistance")
//! found fat-filled gaps in 75 % of lumbar interspinous ligaments. [`is_false_loss`] names a
//! give-way outside the epidural space.
//!
//! # Aspiration
//! [`aspirate`] draws back on the syringe with a caller-supplied uniform number (deterministic
//! replay). Blood from a vessel is missed with the published false-negative rate of aspiration
//! [`VASCULAR_ASPIRATION_FALSE_NEGATIVE`]; CSF from the dural sac with
//! [`CSF_ASPIRATION_FALSE_NEGATIVE`].
//!
//! # Absurd inputs
//! Press volumes that are NaN, infinite, zero or negative press nothing (the plunger is not
//! touched; the feel is reported for a zero press, injected 0). Volumes above the contents are
//! clamped to the contents. A uniform draw outside `[0, 1)` or NaN is clamped into `[0, 1)` (NaN
//! counts as 0).

use serde::{Deserialize, Serialize};

use super::tissue::Tissue;

/// Atmospheric pressure, kPa (standard atmosphere, 101.325 kPa).
pub const ATMOSPHERIC_KPA: f64 = 101.325;

/// Gauge pressure the hand applies to the plunger, kPa. Our choice, judged from 20 to 40 kPa:
/// below the interspinous ligament's and the flavum's opening pressures (45 and 61.5 kPa here)
/// so the plunger stalls there, above the epidural space's. On the syringe of Vaughan et al.
/// (2012: 62.7-66.7 kPa corresponded to 11.1-11.8 N on the plunger, an area of about 1.8 cm^2)
/// 30 kPa is a steady thumb force of about 5 N.
pub const HAND_PRESSURE_KPA: f64 = 30.0;

/// Capacity of the loss-of-resistance syringe, ml (the usual 10 ml glass or low-friction
/// plastic LOR syringe; catalogue standard).
pub const SYRINGE_CAPACITY_ML: f64 = 10.0;

/// Contents when attached, ml. Our choice: 5 ml of a 10 ml syringe, judged from the 2 to 10 ml
/// that LOR descriptions fill.
pub const START_CONTENTS_ML: f64 = 5.0;

/// Volume delivered per feed substep while the plunger is held and the outlet gives way, ml.
/// Our choice: a 0.5 mm substep takes a fraction of a second at hand feed rates, in which a
/// 30 kPa push moves about 0.1 ml through an 18 G needle (judged from 0.05 to 0.3 ml).
pub const HOLD_STEP_ML: f64 = 0.1;

/// Fraction of intravascular needle placements in which aspiration (or a flash) shows no blood.
/// Furman et al. (2000, "Incidence of intravascular penetration in transforaminal lumbosacral
/// epidural steroid injections", Spine 25(20):2628-2632): in 761 fluoroscopically guided
/// transforaminal injections, a flash or positive aspiration predicted intravascular injection
/// with 44.7 % sensitivity (97.9 % specificity), so 55.3 % of vascular placements aspirate
/// nothing.
pub const VASCULAR_ASPIRATION_FALSE_NEGATIVE: f64 = 1.0 - 0.447;

/// Fraction of intrathecal needle placements in which aspiration shows no CSF. Our choice 10 %,
/// judged from 0 to 20 %: an open needle in the sac usually drips CSF, but a small-bore needle's
/// opening can be covered by a nerve root or a dural flap.
pub const CSF_ASPIRATION_FALSE_NEGATIVE: f64 = 0.10;

/// Injection opening pressure of a tissue at the needle outlet, kPa (gauge).
///
/// - Ligamentum flavum 61.5 kPa: Wee, Isaacs, Vaughan, Dubey & Parker (2017, Int J Clin Anesth
///   Res 1:024-027) measured 461 mmHg (61.5 kPa) mean peak LOR-syringe pressure in labouring
///   women of BMI 18-24.9 (376-461 mmHg over BMI groups); Vaughan et al. (2012) 62.7-66.7 kPa in
///   porcine flavum.
/// - Interspinous ligament 45 kPa: our choice, below the flavum peak (the resistance reaches its
///   maximum in the flavum) and above the hand pressure.
/// - Epidural space 5 kPa: our choice between the resting lumbar/cervical epidural pressure
///   (Moon et al. 2010, Anesthesiology 113(3):666-671: median 10 mmHg, 1.3 kPa, prone) and the
///   7.4-7.8 kPa McKay et al. (2010, Local Reg Anesth 3:101-107) derived after loss of
///   resistance in stiff formalin-fixed cadavers.
/// - Intrathecal 1.5 kPa: our choice inside the normal lumbar CSF opening pressure (about 1 to 2
///   kPa, 10 to 20 cmH2O lying on the side).
/// - Subcutaneous fat 10 kPa and muscle 15 kPa: our choice, below the hand pressure so they give
///   way (the false loss of resistance of Sharrock 1979 and Lawrence et al. 2021, module docs).
/// - Vessel 2 kPa: our choice (venous pressure of a few kPa; an artery would be higher, but the
///   plunger still gives way against blood).
/// - Nerve root 140 kPa (about 20 psi): our choice; intraneural injection needs far higher
///   opening pressures than perineural (Hadzic et al. 2004, "Combination of intraneural
///   injection and high injection pressure leads to fascicular injury and neurologic deficits
///   in dogs", Reg Anesth Pain Med 29(5):417-423).
/// - Skin 80 kPa, disc 200 kPa, soft tissue 20 kPa: our choice (dense dermis and annulus do not
///   take injectate at hand pressure).
/// - Bone: does not take injectate (infinite). Air (outlet outside the body): 0.
pub fn opening_pressure_kpa(t: Tissue) -> f64 {
    match t {
        Tissue::Air => 0.0,
        Tissue::Skin => 80.0,
        Tissue::SubcutaneousFat => 10.0,
        Tissue::Muscle => 15.0,
        Tissue::InterspinousLigament => 45.0,
        Tissue::LigamentumFlavum => 61.5,
        Tissue::EpiduralFat => 5.0,
        Tissue::Intrathecal => 1.5,
        Tissue::NerveRoot => 140.0,
        Tissue::Vessel => 2.0,
        Tissue::Disc => 200.0,
        Tissue::Bone => f64::INFINITY,
        Tissue::SoftTissue => 20.0,
    }
}

/// What fills the loss-of-resistance syringe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LorMedium {
    /// Saline (incompressible).
    Saline,
    /// Air (compressible: springy against a closed outlet).
    Air,
}

/// The loss-of-resistance syringe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LorSyringe {
    /// What the syringe holds.
    pub medium: LorMedium,
    /// Volume left, ml (at atmospheric pressure for air); never negative.
    contents_ml: f64,
    /// Hand pressure, kPa (gauge).
    pub hand_kpa: f64,
}

/// What the hand feels on one press or one held substep.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LorFeel {
    /// Opening pressure over hand pressure, in [0, 1]; 1 = the plunger does not move.
    pub resistance: f64,
    /// The outlet took injectate: the opening pressure is below the hand's pressure.
    pub gave_way: bool,
    /// Volume delivered into the tissue, ml.
    pub injected_ml: f64,
    /// Plunger travel, ml: the injected volume, or for air against a closed outlet the
    /// compression of the gas column (which springs back).
    pub travel_ml: f64,
    /// What the hand feels; never where the tip is.
    pub text: &'static str,
}

/// Text: the plunger gives way.
pub const TEXT_GIVES_WAY: &str = "the plunger gives way";
/// Text: saline against a closed outlet.
pub const TEXT_FIRM: &str = "firm: the plunger does not move";
/// Text: air against a closed outlet.
pub const TEXT_SPRINGY: &str = "springy: the plunger compresses and bounces back";
/// Text: the syringe is empty.
pub const TEXT_EMPTY: &str = "empty: the plunger is at the bottom of the barrel";

fn clean_ml(ml: f64) -> f64 {
    if ml.is_finite() && ml > 0.0 { ml } else { 0.0 }
}

impl LorSyringe {
    /// A syringe with [`START_CONTENTS_ML`] of `medium` and the hand at [`HAND_PRESSURE_KPA`].
    pub fn new(medium: LorMedium) -> Self {
        Self {
            medium,
            contents_ml: START_CONTENTS_ML,
            hand_kpa: HAND_PRESSURE_KPA,
        }
    }

    /// Volume left, ml.
    pub fn contents_ml(&self) -> f64 {
        self.contents_ml
    }

    /// Plunger travel of the air column against a closed outlet at the hand's pressure
    /// (Boyle's law, isothermal), ml; zero for saline.
    pub fn compression_ml(&self) -> f64 {
        match self.medium {
            LorMedium::Saline => 0.0,
            LorMedium::Air => self.contents_ml * self.hand_kpa / (ATMOSPHERIC_KPA + self.hand_kpa),
        }
    }

    /// Press the plunger by up to `ml` with the outlet in `outlet` (see the module docs for
    /// absurd inputs).
    pub fn press(&mut self, outlet: Tissue, ml: f64) -> LorFeel {
        let ml = clean_ml(ml).min(self.contents_ml);
        let p_open = opening_pressure_kpa(outlet);
        let resistance = if self.hand_kpa > 0.0 {
            (p_open / self.hand_kpa).clamp(0.0, 1.0)
        } else {
            1.0
        };
        if self.contents_ml <= 0.0 {
            return LorFeel {
                resistance: 1.0,
                gave_way: false,
                injected_ml: 0.0,
                travel_ml: 0.0,
                text: TEXT_EMPTY,
            };
        }
        if p_open < self.hand_kpa {
            self.contents_ml = (self.contents_ml - ml).max(0.0);
            LorFeel {
                resistance,
                gave_way: true,
                injected_ml: ml,
                travel_ml: ml,
                text: TEXT_GIVES_WAY,
            }
        } else {
            let (travel_ml, text) = match self.medium {
                LorMedium::Saline => (0.0, TEXT_FIRM),
                LorMedium::Air => (ml.min(self.compression_ml()), TEXT_SPRINGY),
            };
            LorFeel {
                resistance,
                gave_way: false,
                injected_ml: 0.0,
                travel_ml,
                text,
            }
        }
    }

    /// Constant pressure held while the tip moved into `outlet` (one call per feed substep):
    /// a press of [`HOLD_STEP_ML`].
    pub fn hold(&mut self, outlet: Tissue) -> LorFeel {
        self.press(outlet, HOLD_STEP_ML)
    }
}

/// The plunger gave way with the outlet outside the epidural space.
pub fn is_false_loss(outlet: Tissue, feel: &LorFeel) -> bool {
    feel.gave_way && outlet != Tissue::EpiduralFat
}

/// What aspiration draws back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Aspirate {
    /// Blood in the hub.
    Blood,
    /// Cerebrospinal fluid in the hub.
    Csf,
    /// Nothing comes back.
    Nothing,
}

impl Aspirate {
    /// What the hand and eye notice, never where the tip is.
    pub fn text(self) -> &'static str {
        match self {
            Aspirate::Blood => "blood in the hub",
            Aspirate::Csf => "clear fluid drips back",
            Aspirate::Nothing => "nothing comes back",
        }
    }
}

/// Aspirate with the outlet in `outlet`; `u` is a uniform draw in `[0, 1)` supplied by the
/// caller (clamped into `[0, 1)`, NaN counts as 0). A draw below the false-negative rate
/// misses the blood or CSF.
pub fn aspirate(outlet: Tissue, u: f64) -> Aspirate {
    let u = if u.is_nan() { 0.0 } else { u.clamp(0.0, 1.0) };
    match outlet {
        Tissue::Vessel if u >= VASCULAR_ASPIRATION_FALSE_NEGATIVE => Aspirate::Blood,
        Tissue::Intrathecal if u >= CSF_ASPIRATION_FALSE_NEGATIVE => Aspirate::Csf,
        _ => Aspirate::Nothing,
    }
}
