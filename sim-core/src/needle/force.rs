//! Axial insertion force along the needle path: what the hand feels while feeding.
//!
//! # Model
//! After Okamura, Simone & O'Leary (2004, "Force modeling for needle insertion into soft
//! tissue", IEEE Trans Biomed Eng 51(10):1707-1716), the axial force is the sum of three parts:
//! - **Capsule stiffness** before a membrane is punctured: `a1 z + a2 z^2`, with `z` the
//!   indentation since the tip met the layer. When it reaches the layer's puncture force the
//!   membrane tears (a "pop") and the tip force drops to the cutting force.
//! - **Cutting**: a constant force per tissue at the tip once the tip cuts through it.
//! - **Friction** along the buried shaft: per tissue, proportional to the length of shaft in
//!   that tissue (Okamura et al. fit a modified Karnopp model; at the quasi-static feed of a
//!   hand-held needle we keep its Coulomb part, a force per unit buried length).
//!
//! Layers with a capsule in our use: skin, ligamentum flavum and the dura (entering
//! [`Tissue::Intrathecal`]). A capsule layer punctures when the stiffness force reaches the
//! puncture force or, if the layer is thinner than the indentation at puncture, when the tip
//! reaches its far side (simulator choice: the tented layer tears as the tip emerges).
//!
//! The caller reports only the tissue at the tip after each substep, so the indentation counts
//! the whole substep in which the tip entered the layer: the sampled puncture leads the exact
//! one by less than one substep when a boundary falls inside a substep.
//!
//! Simulator choices beyond Okamura et al.: while indenting a capsule the tip force is at least
//! the cutting force of the layer the tip came from (the tip does not suddenly get easier to
//! push on meeting a membrane); a **pop** is reported on the sample where a puncture happens or
//! where the tip changes layer and the total force drops by more than [`POP_DROP_N`] (the
//! ligamentum flavum into the epidural fat, a ligament into fat). The ligamentum flavum pop
//! therefore always appears as a force drop at the latest on the first sample in the epidural
//! space.
//!
//! # Parameters
//! Published in vivo force data for the layers of a lumbar approach are scarce and spread
//! widely (needle gauge, tip, speed, species). Every value in [`ForceModel::literature`] says
//! where it comes from; most are our choice inside the published ranges quoted there, chosen
//! for an 18 G Tuohy needle. The model is a teaching model of the force's shape (rise, pop,
//! cutting level, friction slope), not a device prediction.

use serde::{Deserialize, Serialize};

use super::tissue::Tissue;

/// Smallest drop of the total force, newtons, between consecutive samples at a change of layer
/// that counts as a pop. Our choice, judged from 0.5 to 2 N: larger than every cutting-force step
/// between soft layers here (at most 0.5 N, fat to muscle), smaller than the flavum-to-epidural
/// drop (about 2.3 N), so only a dense layer giving way counts.
pub const POP_DROP_N: f64 = 1.0;

/// Axial force the tip reports against bone, newtons. Simulator choice: a rigid stop has no
/// tissue force of its own; the force is whatever the hand pushes with, and we report the level
/// at which a physician stops pushing a 18-22 G needle (judged from 5 to 15 N, the range of the
/// ligamentum flavum peaks a Tuohy needle is pushed through without bending).
pub const BONE_STOP_N: f64 = 10.0;

/// Force parameters of one tissue.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForceParams {
    /// Linear capsule stiffness `a1`, N/mm (ignored without a capsule).
    pub a1_n_per_mm: f64,
    /// Quadratic capsule stiffness `a2`, N/mm^2 (ignored without a capsule).
    pub a2_n_per_mm2: f64,
    /// Capsule puncture force, N; `None`: no capsule, the tip cuts from first contact.
    pub puncture_n: Option<f64>,
    /// Cutting force at the tip once the tissue is being cut, N.
    pub cutting_n: f64,
    /// Friction per millimetre of shaft buried in this tissue, N/mm.
    pub friction_n_per_mm: f64,
}

impl ForceParams {
    /// A tissue without a capsule.
    pub const fn cut(cutting_n: f64, friction_n_per_mm: f64) -> Self {
        Self {
            a1_n_per_mm: 0.0,
            a2_n_per_mm2: 0.0,
            puncture_n: None,
            cutting_n,
            friction_n_per_mm,
        }
    }

    /// A tissue with a capsule: stiffness `a1 z + a2 z^2` up to `puncture_n`, then cutting.
    pub const fn capsule(
        a1_n_per_mm: f64,
        a2_n_per_mm2: f64,
        puncture_n: f64,
        cutting_n: f64,
        friction_n_per_mm: f64,
    ) -> Self {
        Self {
            a1_n_per_mm,
            a2_n_per_mm2,
            puncture_n: Some(puncture_n),
            cutting_n,
            friction_n_per_mm,
        }
    }

    /// Capsule stiffness force at indentation `z_mm`, N.
    pub fn stiffness_n(&self, z_mm: f64) -> f64 {
        self.a1_n_per_mm * z_mm + self.a2_n_per_mm2 * z_mm * z_mm
    }

    /// Indentation at which the capsule punctures, mm (`None` without a capsule): the positive
    /// root of `a1 z + a2 z^2 = puncture`.
    pub fn puncture_depth_mm(&self) -> Option<f64> {
        let p = self.puncture_n?;
        let (a1, a2) = (self.a1_n_per_mm, self.a2_n_per_mm2);
        Some(if a2 > 0.0 {
            (-a1 + (a1 * a1 + 4.0 * a2 * p).sqrt()) / (2.0 * a2)
        } else {
            p / a1
        })
    }
}

/// Per-tissue force parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ForceModel {
    table: Vec<ForceParams>,
}

// Literature values (18 G Tuohy needle). Forces in N, lengths in mm.

/// Skin. Puncture: our choice 3.0 N. van Gerwen, Dankelman & van den Dobbelsteen (2012,
/// "Needle-tissue interaction forces - a survey of experimental data", Med Eng Phys
/// 34(6):665-680) collect puncture forces from 0.5 mN to 19.2 N over needles, tissues and
/// species, median 1.22 N; an 18 G Tuohy tip is larger and blunter than most needles surveyed,
/// so we take 3 N. Stiffness: our choice, reaching 3 N at 4.2 mm of tenting (skin tents several
/// millimetres before a blunt needle punctures it). Cutting 1.0 N and friction 0.02 N/mm: our
/// choice, judged from the 0.5-2 N post-puncture levels of the same survey.
const SKIN: ForceParams = ForceParams::capsule(0.3, 0.1, 3.0, 1.0, 0.02);
/// Fat: our choice, the softest solid layer (0.1-0.5 N cutting judged from the survey above).
const FAT: ForceParams = ForceParams::cut(0.3, 0.005);
/// Muscle: our choice, between fat and ligament (0.5-1.5 N judged from the survey above).
const MUSCLE: ForceParams = ForceParams::cut(0.8, 0.015);
/// Supraspinous/interspinous ligament: our choice 2.5 N cutting, dense collagen that a Tuohy
/// needle grips ("the needle stands up in the ligament"); the loss-of-resistance pressure there is
/// lower than in the ligamentum flavum (Vaughan et al. 2012 below), so the force stays under the
/// flavum's puncture force.
const INTERSPINOUS: ForceParams = ForceParams::cut(2.5, 0.03);
/// Ligamentum flavum. Puncture 6.0 N: our choice, "several newtons" for a Tuohy needle. Our
/// searches found no direct measurement of the needle force through human flavum: Vaughan,
/// Dubey, Wee & Isaacs (2012, "Measuring Tuohy needle insertion force on a porcine spine",
/// conference paper, Bournemouth University) measured the flavum peak as a loss-of-resistance
/// syringe pressure, 62.7-66.7 kPa (11.1-11.8 N on the plunger, not on the needle); Naemura &
/// Saito (2009, "Needle insertion test by porcine ligamentum flavum", IFMBE Proc 25/6) measured
/// porcine flavum peak forces that depend on needle and speed. Stiffness: our choice, 6 N at
/// 2.65 mm of indentation so that a 3-5 mm lumbar flavum punctures inside the layer and a
/// thinner one at its far side. Cutting 2.5 N, friction 0.03 N/mm: our choice, as the
/// interspinous ligament.
const FLAVUM: ForceParams = ForceParams::capsule(1.2, 0.4, 6.0, 2.5, 0.03);
/// Epidural fat: our choice, loose fat and veins (as subcutaneous fat, slightly lower cutting).
const EPIDURAL: ForceParams = ForceParams::cut(0.2, 0.005);
/// Dura (entering the dural sac). Lewis, Lafferty, Sacks, Pallares & TerRiet (2000, "How much
/// work is required to puncture dura with Tuohy needles?", Br J Anaesth 85(2):238-241) measured
/// the peak force and the tenting of cadaveric dura punctured by a 17 G Tuohy needle, with an
/// abrupt drop on penetration (their figures were not available to us). Puncture 1.5 N at 3 mm
/// of tenting: our choice, well under the flavum so that the dural click is the smaller one.
/// CSF: no cutting to speak of; 0.05 N, 0.002 N/mm: our choice.
const DURA: ForceParams = ForceParams::capsule(0.2, 0.1, 1.5, 0.05, 0.002);
/// Nerve root: our choice (a firm cord; the physician should feel it as a soft resistance).
const NERVE: ForceParams = ForceParams::cut(0.5, 0.01);
/// Vessel: our choice (a thin wall, then blood).
const VESSEL: ForceParams = ForceParams::cut(0.3, 0.005);
/// Disc annulus: our choice 4.0 N, dense fibrocartilage, firmer than ligament.
const DISC: ForceParams = ForceParams::cut(4.0, 0.05);
/// Bone: handled by `ForceState::bone_stop`; these values apply only if a caller cuts it anyway.
const BONE: ForceParams = ForceParams::cut(BONE_STOP_N, 0.05);
/// Other soft tissue: our choice, as muscle but softer.
const SOFT: ForceParams = ForceParams::cut(0.5, 0.01);

impl ForceModel {
    /// The parameters of the module docs (18 G Tuohy needle).
    pub fn literature() -> Self {
        let table = Tissue::ALL
            .iter()
            .map(|t| match t {
                Tissue::Air => ForceParams::cut(0.0, 0.0),
                Tissue::Skin => SKIN,
                Tissue::SubcutaneousFat => FAT,
                Tissue::Muscle => MUSCLE,
                Tissue::InterspinousLigament => INTERSPINOUS,
                Tissue::LigamentumFlavum => FLAVUM,
                Tissue::EpiduralFat => EPIDURAL,
                Tissue::Intrathecal => DURA,
                Tissue::NerveRoot => NERVE,
                Tissue::Vessel => VESSEL,
                Tissue::Disc => DISC,
                Tissue::Bone => BONE,
                Tissue::SoftTissue => SOFT,
            })
            .collect();
        Self { table }
    }

    /// The parameters of one tissue.
    pub fn params(&self, t: Tissue) -> ForceParams {
        self.table[t.index()]
    }

    /// The same model with one tissue's parameters replaced.
    pub fn with_params(mut self, t: Tissue, p: ForceParams) -> Self {
        self.table[t.index()] = p;
        self
    }

    /// Shaft friction, N: the sum over `shaft` of buried length times the tissue's friction.
    /// Non-finite or negative lengths count as zero.
    pub fn friction_n(&self, shaft: &[(Tissue, f64)]) -> f64 {
        shaft
            .iter()
            .map(|&(t, mm)| clean_mm(mm) * self.params(t).friction_n_per_mm)
            .sum()
    }
}

/// What the force at the tip is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ForcePhase {
    /// Outside the body, or not yet moved.
    #[default]
    Free,
    /// Indenting an intact capsule.
    Indenting,
    /// Cutting tissue (after a puncture, or in a layer without a capsule).
    Cutting,
    /// Moving along an existing channel: friction only.
    Retrace,
    /// Stopped by bone.
    BoneStop,
}

/// One force sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForceSample {
    /// Axial force at the tip (stiffness or cutting), N.
    pub tip_n: f64,
    /// Friction along the buried shaft, N.
    pub friction_n: f64,
    /// `tip_n + friction_n`, N.
    pub total_n: f64,
    /// Highest total force within the substep, N: at a puncture, the force just before the tear
    /// (the puncture force plus friction); otherwise `total_n`.
    pub peak_n: f64,
    /// A puncture happened in this substep, or the force dropped by more than [`POP_DROP_N`] at
    /// a change of layer.
    pub pop: bool,
    /// What the tip force is doing at the end of the substep.
    pub phase: ForcePhase,
}

/// The serializable force state of one needle (deterministic: a function of the calls).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ForceState {
    /// Tissue at the tip after the last call (`None`: out of the body / reset).
    pub tip: Option<Tissue>,
    /// Indentation into the current capsule layer, mm.
    pub indent_mm: f64,
    /// Whether the tip has punctured (or has no capsule to puncture in) its current layer.
    pub punctured: bool,
    /// Cutting force of the layer the tip came from, N (floor of the indentation force).
    pub carry_n: f64,
    /// Total force of the last sample, N.
    pub last_total_n: f64,
}

fn clean_mm(mm: f64) -> f64 {
    if mm.is_finite() && mm > 0.0 { mm } else { 0.0 }
}

impl ForceState {
    /// A fresh state (needle out of the body).
    pub fn new() -> Self {
        Self::default()
    }

    /// The tip cut `advance_mm` of new tissue and is now in `tip`; `shaft` = buried length per
    /// tissue along the shaft (mm). Non-finite or negative lengths count as zero.
    pub fn cut(
        &mut self,
        model: &ForceModel,
        tip: Tissue,
        advance_mm: f64,
        shaft: &[(Tissue, f64)],
    ) -> ForceSample {
        let advance = clean_mm(advance_mm);
        let params = model.params(tip);
        let mut pop = false;
        let changed = self.tip != Some(tip);
        if changed {
            if let Some(prev) = self.tip {
                let prev_params = model.params(prev);
                // Leaving an intact capsule: the tented layer tears as the tip emerges.
                if !self.punctured && prev_params.puncture_n.is_some() {
                    pop = true;
                }
                self.carry_n = prev_params.cutting_n;
            } else {
                self.carry_n = 0.0;
            }
            self.tip = Some(tip);
            self.indent_mm = 0.0;
            self.punctured = params.puncture_n.is_none();
        }
        let friction_n = model.friction_n(shaft);
        let (tip_n, peak_tip_n, phase) = if tip == Tissue::Air {
            (0.0, 0.0, ForcePhase::Free)
        } else if self.punctured {
            (params.cutting_n, params.cutting_n, ForcePhase::Cutting)
        } else {
            self.indent_mm += advance;
            let puncture = params.puncture_n.unwrap_or(0.0);
            let f = params.stiffness_n(self.indent_mm);
            if f >= puncture {
                self.punctured = true;
                pop = true;
                (
                    params.cutting_n,
                    self.carry_n.max(puncture),
                    ForcePhase::Cutting,
                )
            } else {
                let f = self.carry_n.max(f);
                (f, f, ForcePhase::Indenting)
            }
        };
        let total_n = tip_n + friction_n;
        if changed && self.last_total_n - total_n > POP_DROP_N {
            pop = true;
        }
        let peak_n = (peak_tip_n + friction_n).max(total_n);
        self.last_total_n = total_n;
        ForceSample {
            tip_n,
            friction_n,
            total_n,
            peak_n,
            pop,
            phase,
        }
    }

    /// The tip moved along an existing channel (re-advance after a withdrawal, or a
    /// withdrawal) and is now in `tip`: friction only. The layer at the tip counts as punctured
    /// (the channel goes through it).
    pub fn retrace(
        &mut self,
        model: &ForceModel,
        tip: Tissue,
        shaft: &[(Tissue, f64)],
    ) -> ForceSample {
        let friction_n = model.friction_n(shaft);
        if self.tip != Some(tip) {
            self.carry_n = 0.0;
        }
        self.tip = if tip == Tissue::Air { None } else { Some(tip) };
        self.indent_mm = 0.0;
        self.punctured = true;
        self.last_total_n = friction_n;
        ForceSample {
            tip_n: 0.0,
            friction_n,
            total_n: friction_n,
            peak_n: friction_n,
            pop: false,
            phase: ForcePhase::Retrace,
        }
    }

    /// Bone stopped the tip: a hard stop. The tip force is [`BONE_STOP_N`]; the layer state is
    /// unchanged (the tip did not move).
    pub fn bone_stop(&mut self, model: &ForceModel, shaft: &[(Tissue, f64)]) -> ForceSample {
        let friction_n = model.friction_n(shaft);
        let total_n = BONE_STOP_N + friction_n;
        self.last_total_n = total_n;
        ForceSample {
            tip_n: BONE_STOP_N,
            friction_n,
            total_n,
            peak_n: total_n,
            pop: false,
            phase: ForcePhase::BoneStop,
        }
    }

    /// The needle left the body.
    pub fn reset(&mut self) {
        *self = Self::default();
    }
}
