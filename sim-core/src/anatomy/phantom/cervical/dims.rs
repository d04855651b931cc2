//! The cervical phantom's dimensions, each with its source, and the table the tests compare the
//! built solids against.
//!
//! Sources (adult means, rounded to the nearest 0.5 mm; SD as published, rounded):
//! - Body endplate width and depth, posterior body height, canal width, pedicle width and height,
//!   pedicle transverse angle of C3-C7: Panjabi MM, Duranceau J, Goel V, Oxland T, Takata K,
//!   "Cervical human vertebrae: quantitative three-dimensional anatomy of the middle and lower
//!   regions", Spine 1991;16(8):861-869 (approximate level means read from its tables).
//! - Sagittal (AP) canal diameter C1-C7: Gilad I, Nissan M, "Sagittal evaluation of elemental
//!   geometrical dimensions of human vertebrae", J Anat 1985;143:115-120, and "A study of
//!   vertebra and disc geometric relations of the human cervical and lumbar spine", Spine
//!   1986;11(2):154-157; cross-checked against the MRI reference values of Nell C et al.,
//!   PLOS ONE 2019;14(9):e0222682.
//! - Cord and dural sac sections: Kameyama T, Hashizume Y, Ando T, Takahashi A, "Morphometry of
//!   the normal cadaveric cervical spinal cord", Spine 1994;19(18):2077-2081; Tominaga T et al.,
//!   "Quantitative three-dimensional anatomy of the cervical spinal canal", 1995 (dural sac 11-13
//!   mm AP); Nell et al. 2019.
//! - Posterior epidural space at C7-T1 about 1.5-3 mm deep: Hogan QH, "Epidural anatomy examined
//!   by cryomicrotome section: influence of age, vertebral level, and disease", Reg Anesth
//!   1996;21(5):395-406 (posterior epidural fat is absent or thin above C7 and 1.5-2 mm at
//!   C7-T1; deeper with flexion).
//! - Foramen transversarium about 5.5-6.5 mm across: Taitz C, Nathan H, Arensburg B, "Anatomical
//!   observations of the foramina transversaria", J Neurol Neurosurg Psychiatry 1978;41:170-176;
//!   vertebral artery 3-5 mm across, entering at C6 in about 90 %: Bruneau M et al., "Anatomical
//!   variations of the V2 segment of the vertebral artery", Neurosurgery 2006;59(1 Suppl 1):
//!   ONS20-ONS24.
//! - Facet joints inclined about 45 degrees to the axial plane, facing backwards and upwards:
//!   Panjabi MM et al., "Articular facets of the human spine", Spine 1993;18(10):1298-1310; Pal GP
//!   et al., J Anat 2001;198(4):431-441.
//! - C2-C7 lordosis 15-25 degrees in asymptomatic adults: Gore DR, Sepic SB, Gardner GM, "Roentgenographic
//!   findings of the cervical spine in asymptomatic people", Spine 1986;11(6):521-524.
//! - Atlas outer width about 78 mm: Doherty BJ, Heggeness MH, "The quantitative anatomy of the
//!   atlas", Spine 1994;19(22):2497-2500. Dens about 10 mm across: Schaffler MB et al., "Morphology
//!   of the dens", Spine 1992;17(7):738-743. Atlanto-dental interval up to 3 mm in adults: Hinck VC,
//!   Hopkins CE, Am J Roentgenol 1960;84:945-951.
//!
//! Everything else (disc heights, lamina and spinous-process sizes, soft-tissue thicknesses, the
//! neck outline, muscle sections, the carotid sheath's place and calibre) is **our choice**, sized to
//! typical adult CT appearance and said so where it is set.

/// Per-level dimensions of C2-T1 (mm, degrees).
#[derive(Debug, Clone, Copy)]
pub(super) struct Level {
    pub(super) name: &'static str,
    /// Endplate width (x), without the uncinate processes.
    pub(super) body_width: f64,
    /// Endplate depth (y).
    pub(super) body_depth: f64,
    /// Posterior body height (z).
    pub(super) body_height: f64,
    /// Canal width (x) between the pedicles.
    pub(super) canal_width: f64,
    /// Canal depth (y), the sagittal diameter.
    pub(super) canal_depth: f64,
    /// Pedicle width and height.
    pub(super) pedicle_width: f64,
    pub(super) pedicle_height: f64,
    /// Transverse-process tip-to-tip span (our choice after Panjabi 1991's figures).
    pub(super) tp_span: f64,
    /// Spinous process length behind the canal (our choice; C7 the vertebra prominens).
    pub(super) sp_length: f64,
    /// Whether the spinous tip is bifid (C2-C6: our choice, the common pattern).
    pub(super) bifid: bool,
    /// Lamina half-height (our choice).
    pub(super) lamina_half_h: f64,
    /// Sagittal tilt of the body axis from vertical, + tilts the top anteriorly: 19 degrees of
    /// C2-C7 lordosis (Gore et al. 1986 range 15-25 degrees); our choice for the split per level.
    pub(super) tilt_deg: f64,
}

/// C2..T1. C2's height is of its body without the dens (our choice after common atlases).
pub(super) const LEVELS: [Level; 7] = [
    lvl(
        "C2", 17.0, 15.5, 20.0, 23.5, 15.5, 5.5, 7.5, 50.0, 26.0, true, 6.0, -10.0,
    ),
    lvl(
        "C3", 15.5, 15.5, 11.5, 23.5, 15.0, 5.5, 7.0, 50.0, 18.0, true, 5.0, -6.0,
    ),
    lvl(
        "C4", 16.5, 15.5, 11.5, 24.0, 14.5, 5.5, 7.0, 52.0, 18.0, true, 5.0, -2.0,
    ),
    lvl(
        "C5", 17.5, 16.0, 11.0, 24.5, 14.5, 6.0, 7.0, 54.0, 20.0, true, 5.0, 0.0,
    ),
    lvl(
        "C6", 19.5, 16.5, 11.0, 24.5, 14.5, 6.0, 7.0, 58.0, 24.0, true, 5.0, 4.0,
    ),
    lvl(
        "C7", 21.0, 16.5, 12.5, 24.0, 14.5, 6.5, 7.0, 70.0, 32.0, false, 5.5, 9.0,
    ),
    lvl(
        "T1", 25.0, 17.5, 14.5, 21.5, 14.5, 7.5, 9.5, 76.0, 34.0, false, 5.5, 15.0,
    ),
];

#[expect(clippy::too_many_arguments, reason = "one table row per call")]
const fn lvl(
    name: &'static str,
    body_width: f64,
    body_depth: f64,
    body_height: f64,
    canal_width: f64,
    canal_depth: f64,
    pedicle_width: f64,
    pedicle_height: f64,
    tp_span: f64,
    sp_length: f64,
    bifid: bool,
    lamina_half_h: f64,
    tilt_deg: f64,
) -> Level {
    Level {
        name,
        body_width,
        body_depth,
        body_height,
        canal_width,
        canal_depth,
        pedicle_width,
        pedicle_height,
        tp_span,
        sp_length,
        bifid,
        lamina_half_h,
        tilt_deg,
    }
}

/// Mid-sagittal disc heights C2-C3 .. C7-T1, mm: our choice within the 4-6 mm of radiographic
/// studies (Gilad and Nissan 1986 report cervical disc-to-body height ratios of about 0.4).
pub(super) const DISC_MM: [f64; 6] = [4.5, 5.0, 5.5, 5.5, 5.5, 5.0];

/// Facet joint inclination to the axial plane (degrees), C2-C3 .. C7-T1: about 45 degrees
/// (Panjabi 1993, Pal 2001), steepening towards T1 (our choice for the per-level values).
pub(super) const FACET_INCLINATION_DEG: [f64; 6] = [40.0, 45.0, 45.0, 45.0, 50.0, 55.0];

/// Atlas: outer width over the transverse processes (Doherty and Heggeness 1994, 78 mm).
pub(super) const ATLAS_WIDTH_MM: f64 = 78.0;
/// Atlas sagittal canal diameter from the back of the anterior arch to the front of the posterior
/// arch: about 30 mm (Gilad and Nissan 1986, C1).
pub(super) const ATLAS_CANAL_DEPTH_MM: f64 = 30.0;
/// Dens radius (Schaffler et al. 1992: about 10 mm across) and height above the C2 body (our choice).
pub(super) const DENS_RADIUS_MM: f64 = 5.0;
pub(super) const DENS_HEIGHT_MM: f64 = 15.0;
/// Atlanto-dental interval (Hinck and Hopkins 1960: under 3 mm in adults).
pub(super) const ADI_MM: f64 = 1.5;

/// Foramen transversarium radius: 3 mm (6 mm across; Taitz et al. 1978).
pub(super) const FORAMEN_RADIUS_MM: f64 = 3.0;
/// Vertebral artery radius: 2 mm (4 mm across; Bruneau et al. 2006 give 3-5 mm).
pub(super) const VERTEBRAL_ARTERY_RADIUS_MM: f64 = 2.0;

/// Dural sac: the canal minus 2.5 mm behind and 1 mm in front (our choice within Hogan 1996's
/// 1.5-3 mm posterior epidural depth at C7-T1), and 2 mm each side.
pub(super) const POSTERIOR_EPIDURAL_MM: f64 = 2.5;
pub(super) const ANTERIOR_EPIDURAL_MM: f64 = 1.0;
pub(super) const LATERAL_EPIDURAL_MM: f64 = 2.0;
/// Cord half-width and half-depth at C5 (Kameyama et al. 1994: about 12-13 x 7-8 mm).
pub(super) const CORD_HALF_WIDTH_MM: f64 = 6.25;
pub(super) const CORD_HALF_DEPTH_MM: f64 = 3.75;
/// Ligamentum flavum thickness in the cervical spine: 2.5 mm (our choice, 1.5-3 mm on MRI).
pub(super) const FLAVUM_MM: f64 = 2.5;

/// Articular pillar (lateral mass) half-width (x) and half-depth (y), mm: 12 x 13 mm (our choice
/// after Ebraheim NA et al., "Quantitative anatomy of the cervical facet and the posterior
/// projection of its inferior facet", J Spinal Disord 1997;10:308-316).
pub(super) const PILLAR_HALF_WIDTH_MM: f64 = 6.0;
pub(super) const PILLAR_HALF_DEPTH_MM: f64 = 6.5;

/// One published dimension of the phantom: name, level, published mean and SD (mm), source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PublishedDim {
    /// Dimension, as the test names it (e.g. `canal_depth`).
    pub dimension: &'static str,
    /// Vertebra (`C5`).
    pub level: &'static str,
    /// Published mean, mm.
    pub mean_mm: f64,
    /// Published standard deviation, mm.
    pub sd_mm: f64,
    /// Short citation.
    pub source: &'static str,
}

/// Published means and SDs the built phantom is checked against (level means read from the
/// cited tables, rounded to 0.5 mm; SDs rounded up to 0.5 mm).
pub const PUBLISHED: [PublishedDim; 12] = [
    pd("body_width", "C4", 16.5, 1.5, "Panjabi 1991"),
    pd("body_width", "C6", 19.5, 2.0, "Panjabi 1991"),
    pd("body_depth", "C4", 15.5, 1.5, "Panjabi 1991"),
    pd("body_depth", "C6", 16.5, 1.5, "Panjabi 1991"),
    pd("body_height", "C5", 11.0, 1.0, "Panjabi 1991"),
    pd("canal_width", "C4", 24.0, 1.5, "Panjabi 1991"),
    pd("canal_width", "C6", 24.5, 1.5, "Panjabi 1991"),
    pd("canal_depth", "C4", 14.5, 1.5, "Gilad and Nissan 1986"),
    pd("canal_depth", "C6", 14.5, 1.5, "Gilad and Nissan 1986"),
    pd("canal_depth", "C1", 30.0, 2.5, "Gilad and Nissan 1986"),
    pd("cord_depth", "C5", 7.5, 1.0, "Kameyama 1994"),
    pd("posterior_epidural", "C7_T1", 2.25, 0.75, "Hogan 1996"),
];

const fn pd(
    dimension: &'static str,
    level: &'static str,
    mean_mm: f64,
    sd_mm: f64,
    source: &'static str,
) -> PublishedDim {
    PublishedDim {
        dimension,
        level,
        mean_mm,
        sd_mm,
        source,
    }
}
