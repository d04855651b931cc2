//! The phantom's dimensions: per-level vertebral sizes from the morphometry cited in [`super`],
//! disc heights, facet angles, side signs and the parameters a user may vary.

use serde::{Deserialize, Serialize};

/// Side sign of the patient's left in the RAS model frame (x points to the patient's right).
pub const LEFT: f64 = -1.0;
/// Side sign of the patient's right.
pub const RIGHT: f64 = 1.0;

/// Per-level lumbar dimensions (mm, degrees).
#[derive(Debug, Clone, Copy)]
pub(super) struct LevelDims {
    pub(super) name: &'static str,
    /// Endplate width (x).
    pub(super) body_width: f64,
    /// Endplate depth (y).
    pub(super) body_depth: f64,
    /// Posterior body height (z).
    pub(super) body_height: f64,
    /// Pedicle isthmus width (Zindrick 1987).
    pub(super) pedicle_width: f64,
    /// Pedicle height (Zindrick 1987).
    pub(super) pedicle_height: f64,
    /// Pedicle transverse angle, medial convergence (Zindrick 1987; L1 raised from 11 to 14
    /// degrees, between Zindrick's mean and the 16 degrees of Cheung et al. 1994).
    pub(super) pedicle_angle_deg: f64,
    /// Spinal canal width (x) and depth (y). The depth is the intended gap between the body's
    /// nominal posterior wall and the laminae; the built canal is 1.5-2 mm deeper in the
    /// mid-sagittal plane (the body's posterior concavity), which `phantom::morphometry`
    /// measures: 2 mm under Panjabi's means, so the measured depths meet the CT means of Cook and
    /// Baker 2021 (L5 15.6 +- 2.1 mm) and Abbas et al. 2021 (L1-L5 17-19 mm).
    pub(super) canal_width: f64,
    pub(super) canal_depth: f64,
    /// Transverse process tip-to-tip span.
    pub(super) tp_span: f64,
    /// Spinous process length behind the canal and its height (our assumption, after Panjabi).
    pub(super) sp_length: f64,
    pub(super) sp_height: f64,
    /// Sagittal tilt of the body axis from vertical, + tilts the top anteriorly. Chosen to give
    /// 52 degrees of L1-S1 lordosis (within the 40-60 degree adult range), with 60 % of it at
    /// L4-S1 (Bernhardt and Bridwell 1989); our assumption for the individual numbers.
    pub(super) tilt_deg: f64,
}

/// L1..L5 (Panjabi 1992 and Zindrick 1987 means, rounded; see the module docs). The L5 body is
/// 28 mm tall, the mean of its anterior (30.3 +- 1.9 mm) and posterior (26.3 +- 1.9 mm) CT
/// heights (Cook and Baker 2021, Table 6), rounded: the model's bodies are not wedged, so one
/// height serves both, each within 1.3 SD on the meshes. (At 26 mm the anterior height measured
/// 26.50 mm on the level-set meshes, exactly 2 SD below its mean.)
pub(super) const LUMBAR: [LevelDims; 5] = [
    LevelDims {
        name: "L1",
        body_width: 40.0,
        body_depth: 32.0,
        body_height: 26.0,
        pedicle_width: 8.7,
        pedicle_height: 15.4,
        pedicle_angle_deg: 14.0,
        canal_width: 22.0,
        canal_depth: 16.0,
        tp_span: 72.0,
        sp_length: 30.0,
        sp_height: 24.0,
        tilt_deg: -12.0,
    },
    LevelDims {
        name: "L2",
        body_width: 42.0,
        body_depth: 33.0,
        body_height: 27.0,
        pedicle_width: 8.9,
        pedicle_height: 15.0,
        pedicle_angle_deg: 12.0,
        canal_width: 22.5,
        canal_depth: 15.5,
        tp_span: 80.0,
        sp_length: 31.0,
        sp_height: 25.0,
        tilt_deg: -7.0,
    },
    LevelDims {
        name: "L3",
        body_width: 45.0,
        body_depth: 34.0,
        body_height: 27.0,
        pedicle_width: 10.3,
        pedicle_height: 14.9,
        pedicle_angle_deg: 14.0,
        canal_width: 23.0,
        canal_depth: 15.0,
        tp_span: 90.0,
        sp_length: 31.0,
        sp_height: 25.0,
        tilt_deg: 0.0,
    },
    LevelDims {
        name: "L4",
        body_width: 47.0,
        body_depth: 35.0,
        body_height: 27.0,
        pedicle_width: 12.9,
        pedicle_height: 14.8,
        pedicle_angle_deg: 18.0,
        canal_width: 23.5,
        canal_depth: 15.0,
        tp_span: 86.0,
        sp_length: 29.0,
        sp_height: 23.0,
        tilt_deg: 7.0,
    },
    LevelDims {
        name: "L5",
        body_width: 49.0,
        body_depth: 35.0,
        body_height: 28.0,
        pedicle_width: 18.0,
        pedicle_height: 14.0,
        pedicle_angle_deg: 30.0,
        canal_width: 26.0,
        canal_depth: 15.5,
        tp_span: 90.0,
        sp_length: 25.0,
        sp_height: 19.0,
        tilt_deg: 20.0,
    },
];

/// The S1 "level" used to place the sacrum and its articular processes. Endplate 50 x 33 mm
/// (our assumption, close to the L5 inferior endplate); the sacral slope of 40 degrees is the
/// adult mean of Legaye et al. 1998.
pub(super) const S1: LevelDims = LevelDims {
    name: "S1",
    body_width: 50.0,
    body_depth: 33.0,
    body_height: 26.0,
    pedicle_width: 20.0,
    pedicle_height: 14.0,
    pedicle_angle_deg: 30.0,
    canal_width: 28.0,
    canal_depth: 15.0,
    tp_span: 0.0,
    sp_length: 18.0,
    sp_height: 14.0,
    tilt_deg: 40.0,
};

/// Mid-sagittal disc heights L1-L2 .. L5-S1 (mm). Our assumption within the 8-12 mm adult range
/// of radiographic studies; the anterior/posterior difference follows from the tilts above.
pub(super) const DISC_HEIGHT_MM: [f64; 5] = [9.0, 10.0, 11.0, 11.5, 11.5];

/// Facet-joint angle from the sagittal plane for L1-L2 .. L5-S1 (degrees), rounded after
/// Masharawi et al. 2004.
pub(super) const FACET_ANGLE_DEG: [f64; 5] = [25.0, 30.0, 37.0, 45.0, 50.0];

/// Parameters of the anatomy (not of the grid): what a user might want to vary.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AnatomyParams {
    /// Cortical shell thickness, mm. Real lumbar body cortex is 0.4-0.7 mm thick; it is
    /// thickened here so that a 1-1.5 mm CT grid resolves it (simulator choice).
    pub cortical_thickness_mm: f64,
    /// Facet joint space, mm (our assumption; normal lumbar facet joints are about 2 mm wide
    /// on CT).
    pub facet_gap_mm: f64,
    /// Sacroiliac joint space, mm (our assumption, normal adult SI joints are 2-4 mm on CT).
    pub si_gap_mm: f64,
    /// Subcutaneous fat thickness, mm (our assumption for a normal body-mass index).
    pub subcutaneous_fat_mm: f64,
    /// Skin thickness, mm (dermis of the back is 2-3 mm; our assumption).
    pub skin_mm: f64,
    /// Half-width (x) and half-depth (y) of the body envelope at the waist, mm (our assumption:
    /// a 330 x 234 mm adult abdomen).
    pub body_half_width_mm: f64,
    /// Half-depth of the body envelope, mm.
    pub body_half_depth_mm: f64,
    /// Centre of the body envelope in y, mm ([`BODY_CENTRE_Y_MM`] unless a habitus moves the
    /// anterior wall more than the posterior one). Left out of the serialized parameters at its
    /// default, so the average body's cache key is what it was before habitus existed.
    #[serde(
        default = "default_body_centre_y_mm",
        skip_serializing_if = "is_default_body_centre_y_mm"
    )]
    pub body_centre_y_mm: f64,
}

fn default_body_centre_y_mm() -> f64 {
    BODY_CENTRE_Y_MM
}

fn is_default_body_centre_y_mm(y: &f64) -> bool {
    *y == BODY_CENTRE_Y_MM
}

impl Default for AnatomyParams {
    fn default() -> Self {
        AnatomyParams {
            cortical_thickness_mm: 1.5,
            facet_gap_mm: 2.0,
            si_gap_mm: 2.5,
            subcutaneous_fat_mm: 15.0,
            skin_mm: 2.0,
            body_half_width_mm: 165.0,
            body_half_depth_mm: 117.0,
            body_centre_y_mm: BODY_CENTRE_Y_MM,
        }
    }
}

/// Centre of the body envelope in y, mm: puts the posterior skin about 28 mm behind the L3
/// spinous tip and the anterior abdominal wall 142 mm in front of the L3 body centre (our
/// assumption).
pub const BODY_CENTRE_Y_MM: f64 = 25.0;
