//! The tissue a needle tip or outlet is in, for the handling models ([`super::force`],
//! [`super::syringe`]): a coarse mechanical class, not an imaging material.
//!
//! Structure names map to tissues by [`Tissue::of_structure`]: the procedural phantom's names
//! (`sim_core::anatomy::phantom`) and TotalSegmentator-style names of imported anatomy.

use serde::{Deserialize, Serialize};

/// Mechanical tissue class along a needle path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Tissue {
    /// Outside the body.
    Air,
    /// Epidermis and dermis.
    Skin,
    /// Subcutaneous fat.
    SubcutaneousFat,
    /// Skeletal muscle (paraspinal, psoas).
    Muscle,
    /// Supraspinous and interspinous ligaments.
    InterspinousLigament,
    /// Ligamentum flavum.
    LigamentumFlavum,
    /// Epidural fat and its venous plexus.
    EpiduralFat,
    /// Inside the dural sac: dura, CSF, cauda equina, conus (the dura is the capsule).
    Intrathecal,
    /// Exiting nerve root and ganglion.
    NerveRoot,
    /// Large vessel (aorta, vena cava, iliac vessels).
    Vessel,
    /// Intervertebral disc.
    Disc,
    /// Cortical or cancellous bone.
    Bone,
    /// Any other soft tissue.
    SoftTissue,
}

impl Tissue {
    /// Number of tissues.
    pub const COUNT: usize = 13;
    /// Every tissue, in declaration (and [`Tissue::index`]) order.
    pub const ALL: [Tissue; Tissue::COUNT] = [
        Tissue::Air,
        Tissue::Skin,
        Tissue::SubcutaneousFat,
        Tissue::Muscle,
        Tissue::InterspinousLigament,
        Tissue::LigamentumFlavum,
        Tissue::EpiduralFat,
        Tissue::Intrathecal,
        Tissue::NerveRoot,
        Tissue::Vessel,
        Tissue::Disc,
        Tissue::Bone,
        Tissue::SoftTissue,
    ];

    /// Position in [`Tissue::ALL`] (for per-tissue tables).
    pub fn index(self) -> usize {
        self as usize
    }

    /// The tissue of a named anatomy structure.
    ///
    /// Procedural phantom names: `skin`, `subcutaneous_fat`, `deep_soft_tissue`,
    /// `psoas_left/right`, `erector_spinae_left/right`, `epidural_space`, `ligamentum_flavum`,
    /// `dural_sac`, `conus_medullaris`, `cauda_equina`, `nerve_root_*`, `aorta`,
    /// `inferior_vena_cava`, `disc_*`, `*_cortical`, `*_cancellous`; the cervical phantom adds
    /// `posterior_neck_muscles_*`, `longus_colli_*` (muscle), `spinal_cord` (intrathecal),
    /// `vertebral_artery_*`, `carotid_artery_*`, `internal_jugular_vein_*` (vessel).
    /// TotalSegmentator-style names:
    /// `vertebrae_*`, `sacrum`, `hip_*`, `rib_*`, `femur_*` (bone), `autochthon_*`,
    /// `iliopsoas_*`, `gluteus_*` (muscle), `spinal_cord`, `spinal_canal` (intrathecal),
    /// `iliac_artery_*`, `iliac_vena_*`, `portal_vein_and_splenic_vein` (vessel),
    /// `intervertebral_discs` (disc). Anything else is [`Tissue::SoftTissue`].
    ///
    /// `deep_soft_tissue` maps to [`Tissue::InterspinousLigament`]: our choice. The phantom's
    /// deep envelope fills the gap between the spinous processes, so on the posterior
    /// (interlaminar) approaches it stands in for the supraspinous and interspinous ligaments
    /// that a midline needle crosses before the ligamentum flavum; on other paths it makes the
    /// deep tissue feel firmer than fat, which is the side we prefer to err on.
    pub fn of_structure(name: &str) -> Tissue {
        let n = name.trim().to_ascii_lowercase();
        let n = n.as_str();
        match n {
            "air" | "outside" => return Tissue::Air,
            "skin" => return Tissue::Skin,
            "subcutaneous_fat" => return Tissue::SubcutaneousFat,
            "deep_soft_tissue" | "supraspinous_ligament" | "interspinous_ligament" => {
                return Tissue::InterspinousLigament;
            }
            "epidural_space" | "epidural_fat" => return Tissue::EpiduralFat,
            "ligamentum_flavum" => return Tissue::LigamentumFlavum,
            "dural_sac" | "conus_medullaris" | "cauda_equina" | "spinal_cord" | "spinal_canal" => {
                return Tissue::Intrathecal;
            }
            "aorta" | "inferior_vena_cava" | "portal_vein_and_splenic_vein" => {
                return Tissue::Vessel;
            }
            "sacrum" => return Tissue::Bone,
            "intervertebral_discs" => return Tissue::Disc,
            _ => {}
        }
        let prefixed = |p: &[&str]| p.iter().any(|p| n.starts_with(p));
        let bone_suffix = n.ends_with("_cortical") || n.ends_with("_cancellous");
        if bone_suffix
            || prefixed(&[
                "vertebrae_",
                "hip_",
                "rib_",
                "femur_",
                "sternum",
                "scapula_",
            ])
        {
            Tissue::Bone
        } else if prefixed(&["disc_"]) {
            Tissue::Disc
        } else if prefixed(&["nerve_root_"]) {
            Tissue::NerveRoot
        } else if prefixed(&[
            "psoas_",
            "erector_spinae_",
            "autochthon_",
            "iliopsoas_",
            "gluteus_",
            "quadratus_lumborum",
            "posterior_neck_muscles_",
            "longus_colli_",
            "muscle_",
        ]) {
            Tissue::Muscle
        } else if prefixed(&[
            "iliac_artery_",
            "iliac_vena_",
            "common_iliac_",
            "vertebral_artery_",
            "carotid_artery_",
            "internal_jugular_vein_",
        ]) {
            Tissue::Vessel
        } else {
            Tissue::SoftTissue
        }
    }
}

/// Flat layers crossed by a straight needle from the skin surface (depth 0): the test and
/// benchmark geometry of the handling models, and a teaching aid. Layer `i` covers depths
/// `[start_i, start_i + thickness_i)`; the last layer extends without end; depth `<= 0` is air.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LayerStack {
    /// `(tissue, thickness_mm)` from the surface inward.
    pub layers: Vec<(Tissue, f64)>,
}

impl LayerStack {
    /// Layers from the surface inward (`(tissue, thickness_mm)`).
    pub fn new(layers: Vec<(Tissue, f64)>) -> Self {
        Self { layers }
    }

    /// Depth at which layer `i` ends, mm (the boundary with layer `i + 1`).
    pub fn end_mm(&self, i: usize) -> f64 {
        self.layers[..=i].iter().map(|l| l.1).sum()
    }

    /// Depth at which the first layer of tissue `t` begins, mm.
    pub fn start_of(&self, t: Tissue) -> Option<f64> {
        let i = self.layers.iter().position(|l| l.0 == t)?;
        Some(if i == 0 { 0.0 } else { self.end_mm(i - 1) })
    }

    /// Depth at which the first layer of tissue `t` ends, mm.
    pub fn end_of(&self, t: Tissue) -> Option<f64> {
        let i = self.layers.iter().position(|l| l.0 == t)?;
        Some(self.end_mm(i))
    }

    /// The tissue at `depth_mm`.
    pub fn tissue_at(&self, depth_mm: f64) -> Tissue {
        if depth_mm.is_nan() || depth_mm <= 0.0 {
            return Tissue::Air;
        }
        let mut end = 0.0;
        for &(t, thick) in &self.layers {
            end += thick;
            if depth_mm < end {
                return t;
            }
        }
        self.layers.last().map_or(Tissue::Air, |l| l.0)
    }

    /// Buried shaft per layer with the tip at `depth_mm`: `(tissue, mm)` for every layer the
    /// shaft lies in, surface first (written into `out`, which is cleared).
    pub fn shaft_into(&self, depth_mm: f64, out: &mut Vec<(Tissue, f64)>) {
        out.clear();
        let mut start = 0.0;
        let n = self.layers.len();
        for (i, &(t, thick)) in self.layers.iter().enumerate() {
            if depth_mm <= start {
                break;
            }
            let end = if i + 1 == n {
                f64::INFINITY
            } else {
                start + thick
            };
            out.push((t, depth_mm.min(end) - start));
            start = end;
        }
    }
}
