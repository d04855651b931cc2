//! Material classes shared by the anatomy assets, the label volumes and every modality.
//!
//! A structure's mesh carries exactly one class; a label volume stores [`MaterialClass::label`]
//! per voxel (0 = background / air). The physical properties of a class (X-ray attenuation,
//! acoustic impedance, diffusivity) belong to the modality that uses them, not to this enum.

use serde::{Deserialize, Serialize};

/// Tissue class of an anatomical structure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaterialClass {
    /// Cortical (compact) bone: the outer shell of a bone.
    CorticalBone,
    /// Cancellous (trabecular) bone and marrow: the interior of a bone.
    Cancellous,
    /// Intervertebral disc (annulus and nucleus).
    Disc,
    /// Skeletal muscle.
    Muscle,
    /// Adipose tissue (subcutaneous and deep fat).
    Fat,
    /// Skin and generic soft tissue (the body envelope).
    SoftTissue,
    /// Blood vessel (arteries and veins, blood-filled lumen).
    Vessel,
    /// Nerve (roots, cauda equina, peripheral nerves).
    Nerve,
    /// Dural sac and the cerebrospinal fluid it holds.
    DuraCsf,
    /// Epidural space (fat and venous plexus between ligamentum flavum and dura).
    EpiduralSpace,
    /// Ligamentum flavum.
    LigamentumFlavum,
}

impl MaterialClass {
    /// Every class, in label order.
    pub const ALL: [MaterialClass; 11] = [
        MaterialClass::CorticalBone,
        MaterialClass::Cancellous,
        MaterialClass::Disc,
        MaterialClass::Muscle,
        MaterialClass::Fat,
        MaterialClass::SoftTissue,
        MaterialClass::Vessel,
        MaterialClass::Nerve,
        MaterialClass::DuraCsf,
        MaterialClass::EpiduralSpace,
        MaterialClass::LigamentumFlavum,
    ];

    /// Label value used in categorical label volumes (1-based; 0 is background).
    pub fn label(self) -> u8 {
        // The index in `ALL` is stable: new classes are appended, never inserted.
        Self::ALL.iter().position(|&m| m == self).map_or(0, |i| i as u8 + 1)
    }

    /// The class stored under a label value, or `None` for background or an unknown label.
    pub fn from_label(label: u8) -> Option<MaterialClass> {
        Self::ALL.get(usize::from(label).checked_sub(1)?).copied()
    }

    /// Stable snake_case name, as used in asset files.
    pub fn name(self) -> &'static str {
        match self {
            MaterialClass::CorticalBone => "cortical_bone",
            MaterialClass::Cancellous => "cancellous",
            MaterialClass::Disc => "disc",
            MaterialClass::Muscle => "muscle",
            MaterialClass::Fat => "fat",
            MaterialClass::SoftTissue => "soft_tissue",
            MaterialClass::Vessel => "vessel",
            MaterialClass::Nerve => "nerve",
            MaterialClass::DuraCsf => "dura_csf",
            MaterialClass::EpiduralSpace => "epidural_space",
            MaterialClass::LigamentumFlavum => "ligamentum_flavum",
        }
    }

    /// Parses a name written by [`MaterialClass::name`].
    pub fn from_name(name: &str) -> Option<MaterialClass> {
        Self::ALL.into_iter().find(|m| m.name() == name)
    }

    /// Whether the class is bone (cortical or cancellous): needles cannot pass through it.
    pub fn is_bone(self) -> bool {
        matches!(self, MaterialClass::CorticalBone | MaterialClass::Cancellous)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_and_names_round_trip() {
        for m in MaterialClass::ALL {
            assert_eq!(MaterialClass::from_label(m.label()), Some(m));
            assert_eq!(MaterialClass::from_name(m.name()), Some(m));
            let json = serde_json::to_string(&m).unwrap();
            assert_eq!(json, format!("\"{}\"", m.name()));
        }
        assert_eq!(MaterialClass::from_label(0), None);
        assert_eq!(MaterialClass::from_label(200), None);
    }
}
