//! Morphometry of the built phantom: lumbar dimensions measured on its meshes by ray casting, and
//! the published population values (mean and standard deviation) they are compared with.
//!
//! Every value is read from the meshes (cortical plus cancellous surface of each bone, as the
//! platform renders them); the model's intended positions ([`LevelFrame`]) only aim the rays, so
//! a shape that blends, rounds or clips away from its intended size shows in the table.
//!
//! Ray conventions: a chord is the length of the bone interval that contains the aiming point; a
//! gap is the length of the bone-free interval that contains it (the canal).

use glam::DVec3;

use super::model::{LevelFrame, level_frames};
use crate::anatomy::asset::RegionAsset;
use crate::geom::{Bvh, inside_intervals};

/// A measured dimension.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Dimension {
    /// Width (transverse) of the superior endplate, 1.5 mm below it, through the body's axis.
    EndplateWidth,
    /// Depth (sagittal "length") of the superior endplate, 1.5 mm below it, mid-sagittal.
    EndplateDepth,
    /// Anterior body height, 3 mm behind the anterior cortex, mid-sagittal.
    BodyHeightAnterior,
    /// Posterior body height, 3 mm in front of the posterior cortex, mid-sagittal.
    BodyHeightPosterior,
    /// Pedicle isthmus width, perpendicular to the pedicle axis in the body's transverse plane.
    PedicleWidth,
    /// Pedicle height along the body axis through the isthmus centre.
    PedicleHeight,
    /// Medial convergence of the pedicle axis from the sagittal plane, degrees.
    PedicleTransverseAngle,
    /// Canal width between the pedicles (interpedicular distance).
    CanalWidth,
    /// Mid-sagittal canal depth at pedicle height (back of the body to the front of the arch).
    CanalDepth,
    /// Tip-to-tip span of the transverse processes.
    TransverseProcessSpan,
    /// Mid-disc height between this level's inferior endplate and the next one's superior.
    DiscHeight,
    /// Lordosis between the L1 superior endplate and the S1 superior endplate, degrees.
    LordosisL1S1,
    /// Segmental lordosis of a motion segment (upper to lower superior endplate), degrees.
    SegmentalLordosis,
    /// Ligamentum flavum thickness on the midline at an interlaminar window, along the body's
    /// anterior axis.
    FlavumThickness,
}

impl Dimension {
    /// Unit of the value.
    pub fn unit(self) -> &'static str {
        match self {
            Dimension::PedicleTransverseAngle
            | Dimension::LordosisL1S1
            | Dimension::SegmentalLordosis => "deg",
            _ => "mm",
        }
    }
}

/// One value measured on the meshes.
#[derive(Debug, Clone, PartialEq)]
pub struct Measured {
    /// `L1`..`L5` (for a disc, its upper level; for lordosis `L1-S1`).
    pub level: String,
    /// What.
    pub dimension: Dimension,
    /// Value in [`Dimension::unit`].
    pub value: f64,
}

/// Half-length of every measuring ray, mm: longer than any bone of the region.
const REACH_MM: f64 = 250.0;

/// Bone intervals closer than this are one: the cortical and cancellous meshes share their
/// interface up to the decimation's error bound (a fifth of a voxel, 0.3 mm on the default
/// 1.5 mm grid; `PhantomParams::with_voxel_mm`), and no real gap of the model (joint spaces of
/// 2 mm and more, discs) is that thin.
const MERGE_GAP_MM: f64 = 0.5;

/// A solid as ray-castable surfaces: a bone's cortical and (when present) cancellous meshes,
/// or one soft-tissue mesh.
struct Solid {
    surfaces: Vec<Bvh>,
}

impl Solid {
    fn bone(asset: &RegionAsset, name: &str) -> Option<Solid> {
        let surfaces: Vec<Bvh> = [format!("{name}_cortical"), format!("{name}_cancellous")]
            .iter()
            .filter_map(|n| asset.structures.iter().find(|s| &s.name == n))
            .map(|s| Bvh::new(&s.mesh))
            .collect();
        (!surfaces.is_empty()).then_some(Solid { surfaces })
    }

    /// The bone intervals (union of every surface's inside) along `p + t dir`, `t` in
    /// `[-REACH_MM, REACH_MM]`, as parameters relative to `p`.
    fn intervals(&self, p: DVec3, dir: DVec3) -> Vec<(f64, f64)> {
        let dir = dir.normalize();
        let origin = (p - dir * REACH_MM).to_array();
        let mut all = Vec::new();
        let mut hits = Vec::new();
        for s in &self.surfaces {
            s.all_hits(origin, dir.to_array(), 0.0, 2.0 * REACH_MM, &mut hits);
            all.extend(
                inside_intervals(&hits, 2.0 * REACH_MM)
                    .into_iter()
                    .map(|(a, b)| (a - REACH_MM, b - REACH_MM)),
            );
        }
        all.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut merged: Vec<(f64, f64)> = Vec::new();
        for (a, b) in all {
            match merged.last_mut() {
                // Touching or overlapping intervals (cortex over cancellous) are one piece; a
                // sliver thinner than MERGE_GAP_MM between them is the two meshes' own error.
                Some(last) if a <= last.1 + MERGE_GAP_MM => last.1 = last.1.max(b),
                _ => merged.push((a, b)),
            }
        }
        merged
    }

    /// Length of the bone interval through `p` along `dir` (0 when `p` is not in bone).
    fn chord(&self, p: DVec3, dir: DVec3) -> f64 {
        self.chord_span(p, dir).map_or(0.0, |(a, b)| b - a)
    }

    /// Interval (relative parameters) of bone through `p` along `dir`.
    fn chord_span(&self, p: DVec3, dir: DVec3) -> Option<(f64, f64)> {
        self.intervals(p, dir)
            .into_iter()
            .find(|(a, b)| *a <= 0.0 && 0.0 <= *b)
    }

    /// Length of the bone-free gap around `p` along `dir`, bounded by bone on both sides
    /// (`None` when `p` is in bone or the gap is open on a side).
    fn gap(&self, p: DVec3, dir: DVec3) -> Option<f64> {
        let iv = self.intervals(p, dir);
        let before = iv
            .iter()
            .filter(|(_, b)| *b < 0.0)
            .map(|(_, b)| *b)
            .reduce(f64::max)?;
        let after = iv
            .iter()
            .filter(|(a, _)| *a > 0.0)
            .map(|(a, _)| *a)
            .reduce(f64::min)?;
        let inside = iv.iter().any(|(a, b)| *a <= 0.0 && 0.0 <= *b);
        (!inside).then_some(after - before)
    }

    /// Overall extent (first entry to last exit) along `dir` through `p`.
    fn extent(&self, p: DVec3, dir: DVec3) -> Option<f64> {
        let iv = self.intervals(p, dir);
        Some(iv.last()?.1 - iv.first()?.0)
    }
}

/// Why the morphometry could not be measured or compared: the bone, structure, level or
/// dimension at fault.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MorphometryError {
    /// The asset has no meshes of this bone.
    #[error("no {0} meshes")]
    MissingBone(String),
    /// The asset has no mesh of this soft-tissue structure.
    #[error("no {0} mesh")]
    MissingStructure(String),
    /// A measuring ray that must cross bone found none.
    #[error("{level} {what}: the measuring ray found no bone")]
    NoBone {
        /// Level or segment (`L3`, `L4-L5`).
        level: String,
        /// The dimension being measured.
        what: &'static str,
    },
    /// The rays found no interval to measure (a gap open on one side, a missing chord).
    #[error("{level} {what}: no interval to measure on the meshes")]
    Unmeasurable {
        /// Level or segment.
        level: String,
        /// What was being measured.
        what: &'static str,
    },
    /// A published reference has no measurement to compare with.
    #[error("no measurement of {level} {dimension:?}")]
    NoMeasurement {
        /// Level or segment of the reference.
        level: &'static str,
        /// Its dimension.
        dimension: Dimension,
    },
}

/// Measures every [`Dimension`] of L1..L5 (and the L1-S1 lordosis) on `asset`, a built
/// lumbosacral phantom. Errors name a missing bone or a ray that found no bone where one must be.
pub fn measure(asset: &RegionAsset) -> Result<Vec<Measured>, MorphometryError> {
    let frames = level_frames();
    let mut out = Vec::new();
    let mut push = |level: &str, dimension: Dimension, value: f64| {
        out.push(Measured {
            level: level.to_string(),
            dimension,
            value,
        });
    };
    let lumbar = &frames[..5];
    let bones: Vec<Solid> = lumbar
        .iter()
        .map(|f| {
            Solid::bone(asset, &f.name).ok_or_else(|| MorphometryError::MissingBone(f.name.clone()))
        })
        .collect::<Result<_, _>>()?;
    let sacrum = Solid::bone(asset, "sacrum")
        .ok_or_else(|| MorphometryError::MissingBone("sacrum".into()))?;
    let nonzero = |v: f64, what: &'static str, level: &str| {
        if v > 0.0 {
            Ok(v)
        } else {
            Err(MorphometryError::NoBone {
                level: level.to_owned(),
                what,
            })
        }
    };
    let unmeasurable = |level: &str, what: &'static str| MorphometryError::Unmeasurable {
        level: level.to_owned(),
        what,
    };
    for (i, (f, bone)) in lumbar.iter().zip(&bones).enumerate() {
        let l = f.name.as_str();
        let top = f.centre_mm + f.up * (0.5 * f.body_height_mm - 1.5);
        // The body's mid-height sagittal chord finds its anterior and posterior cortex (the
        // posterior wall is concave, so the intended depth would aim outside it).
        let (t_back, t_front) = bone
            .chord_span(f.centre_mm, f.anterior)
            .ok_or_else(|| unmeasurable(l, "body centre chord"))?;
        let front = f.centre_mm + f.anterior * (t_front - 3.0);
        let back = f.centre_mm + f.anterior * (t_back + 3.0);
        for (dimension, what, p, dir) in [
            (Dimension::EndplateWidth, "endplate width", top, f.right),
            (Dimension::EndplateDepth, "endplate depth", top, f.anterior),
            (
                Dimension::BodyHeightAnterior,
                "anterior height",
                front,
                f.up,
            ),
            (
                Dimension::BodyHeightPosterior,
                "posterior height",
                back,
                f.up,
            ),
        ] {
            push(l, dimension, nonzero(bone.chord(p, dir), what, l)?);
        }
        let (mut widths, mut heights, mut angles) = (Vec::new(), Vec::new(), Vec::new());
        for (c, axis) in f.pedicle_centre_mm.iter().zip(&f.pedicle_axis) {
            let across = f.up.cross(*axis).normalize();
            widths.push(bone.chord(*c, across));
            heights.push(bone.chord(*c, f.up));
            angles.push(pedicle_angle_deg(bone, f, *c, *axis));
        }
        push(
            l,
            Dimension::PedicleWidth,
            nonzero(mean(&widths), "pedicle width", l)?,
        );
        push(
            l,
            Dimension::PedicleHeight,
            nonzero(mean(&heights), "pedicle height", l)?,
        );
        let angles: Vec<f64> = angles
            .into_iter()
            .collect::<Option<_>>()
            .ok_or_else(|| unmeasurable(l, "pedicle axis"))?;
        push(l, Dimension::PedicleTransverseAngle, mean(&angles));
        let c = f.canal_centre_mm;
        push(
            l,
            Dimension::CanalWidth,
            bone.gap(c, f.right)
                .ok_or_else(|| unmeasurable(l, "canal width"))?,
        );
        push(
            l,
            Dimension::CanalDepth,
            bone.gap(c, f.anterior)
                .ok_or_else(|| unmeasurable(l, "canal depth"))?,
        );
        // The processes run laterally and backwards: the widest of several transverse rays
        // around their level.
        let span = [-6.0, -4.0, -2.0, 0.0, 2.0]
            .iter()
            .flat_map(|dy| [-2.0, 0.0, 2.0].map(|dz| (dy, dz)))
            .filter_map(|(dy, dz)| {
                bone.extent(
                    f.transverse_level_mm + f.anterior * *dy + f.up * dz,
                    f.right,
                )
            })
            .reduce(f64::max);
        push(
            l,
            Dimension::TransverseProcessSpan,
            span.ok_or_else(|| unmeasurable(l, "transverse processes"))?,
        );
        // Disc: from this body's inferior endplate to the next body's superior one, along the
        // line joining the body centres.
        let below = if i + 1 < 5 { &bones[i + 1] } else { &sacrum };
        let next = &frames[i + 1];
        let axis = (f.centre_mm - next.centre_mm).normalize();
        let (lo_this, _) = bone
            .chord_span(f.centre_mm, axis)
            .ok_or_else(|| unmeasurable(l, "body axis"))?;
        let bottom = f.centre_mm + axis * lo_this;
        let gap = below
            .intervals(bottom, axis)
            .into_iter()
            .filter(|(_, b)| *b < 0.0)
            .map(|(_, b)| -b)
            .reduce(f64::min);
        push(
            l,
            Dimension::DiscHeight,
            gap.ok_or_else(|| unmeasurable(l, "disc below"))?,
        );
    }
    let mut slopes = Vec::new();
    for (f, bone) in frames
        .iter()
        .zip(bones.iter().chain(std::iter::once(&sacrum)))
    {
        slopes.push(
            endplate_angle_deg(bone, f)
                .ok_or_else(|| unmeasurable(&f.name, "superior endplate"))?,
        );
    }
    for (i, pair) in frames.windows(2).enumerate() {
        let segment = format!("{}-{}", pair[0].name, pair[1].name);
        push(
            &segment,
            Dimension::SegmentalLordosis,
            slopes[i] - slopes[i + 1],
        );
    }
    push("L1-S1", Dimension::LordosisL1S1, slopes[0] - slopes[5]);
    let flavum = asset
        .structures
        .iter()
        .find(|s| s.name == "ligamentum_flavum")
        .ok_or_else(|| MorphometryError::MissingStructure("ligamentum_flavum".into()))?;
    let flavum = Solid {
        surfaces: vec![Bvh::new(&flavum.mesh)],
    };
    for pair in lumbar.windows(2) {
        // The flavum's midline chords along the upper body's anterior axis over the window's
        // height (from one canal centre to the next); their median is its thickness (the
        // longest ones graze the sheet where it curves onto the laminae).
        let (upper, lower) = (&pair[0], &pair[1]);
        let segment = format!("{}-{}", upper.name, lower.name);
        let mut chords: Vec<f64> = (0..=40)
            .filter_map(|k| {
                let c = upper
                    .canal_centre_mm
                    .lerp(lower.canal_centre_mm, f64::from(k) / 40.0);
                // Behind the canal centre: the flavum lies on the canal's back wall.
                flavum
                    .intervals(c, -upper.anterior)
                    .into_iter()
                    .find(|(a, _)| *a > 0.0)
                    .map(|(a, b)| b - a)
            })
            .collect();
        chords.sort_by(f64::total_cmp);
        let thickness = chords.get(chords.len() / 2).copied().unwrap_or(0.0);
        push(
            &segment,
            Dimension::FlavumThickness,
            nonzero(thickness, "flavum", &segment)?,
        );
    }
    Ok(out)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Angle of the pedicle's measured axis from the sagittal plane (medial convergence), degrees:
/// the midpoints of its width chords 4 mm before and after the isthmus centre.
fn pedicle_angle_deg(bone: &Solid, f: &LevelFrame, c: DVec3, axis: DVec3) -> Option<f64> {
    let across = f.up.cross(axis).normalize();
    let mid = |p: DVec3| {
        bone.chord_span(p, across)
            .map(|(a, b)| p + across * (0.5 * (a + b)))
    };
    let (a, b) = (mid(c - axis * 4.0)?, mid(c + axis * 4.0)?);
    let d = b - a;
    let lateral = d.dot(f.right).abs();
    let forward = d.dot(f.anterior).abs();
    Some(lateral.atan2(forward).to_degrees())
}

/// Sagittal slope of a superior endplate in degrees from the model's horizontal, positive when
/// its anterior edge is higher: the top of the bone along the body's axis 8 mm in front of and
/// behind the body centre.
fn endplate_angle_deg(bone: &Solid, f: &LevelFrame) -> Option<f64> {
    let top = |y: f64| {
        let p = f.centre_mm + f.anterior * y;
        bone.chord_span(p, f.up).map(|(_, b)| p + f.up * b)
    };
    let d = top(8.0)? - top(-8.0)?;
    Some(d.z.atan2(d.y.hypot(d.x)).to_degrees())
}

/// A published population value a measured dimension is compared with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// Level or segment, as [`Measured::level`].
    pub level: &'static str,
    /// What.
    pub dimension: Dimension,
    /// Population mean.
    pub mean: f64,
    /// Population standard deviation; `None` where the source gives a mean only.
    pub sd: Option<f64>,
    /// Key into [`SOURCES`].
    pub source: &'static str,
}

/// Where no standard deviation was published (in what we could retrieve), a measured value may
/// differ from the mean by this fraction of it: two coefficients of variation, taking the median
/// coefficient of the nine dimensions of Cook and Baker 2021, Table 6 (10.2 %).
pub const MEAN_ONLY_TOLERANCE: f64 = 2.0 * 0.102;

/// A value published with its standard deviation.
const fn r(
    level: &'static str,
    dimension: Dimension,
    mean: f64,
    sd: f64,
    source: &'static str,
) -> Reference {
    Reference {
        level,
        dimension,
        mean,
        sd: Some(sd),
        source,
    }
}

/// A value published as a mean only.
const fn m(
    level: &'static str,
    dimension: Dimension,
    mean: f64,
    source: &'static str,
) -> Reference {
    Reference {
        sd: None,
        ..r(level, dimension, mean, 0.0, source)
    }
}

/// The published values (whole-population means where given), each with its source key.
pub const PUBLISHED: &[Reference] = &[
    r("L5", Dimension::EndplateDepth, 35.7, 3.5, "COOK21"),
    r("L5", Dimension::BodyHeightAnterior, 30.3, 1.9, "COOK21"),
    r("L5", Dimension::BodyHeightPosterior, 26.3, 1.9, "COOK21"),
    r("L5", Dimension::PedicleHeight, 12.9, 1.9, "COOK21"),
    r("L5", Dimension::PedicleWidth, 16.1, 2.3, "COOK21"),
    r("L5", Dimension::CanalDepth, 15.6, 2.1, "COOK21"),
    r("L5", Dimension::CanalWidth, 28.2, 3.1, "COOK21"),
    r("L2", Dimension::PedicleWidth, 8.5, 1.5, "CHNPED94"),
    r("L3", Dimension::PedicleWidth, 9.2, 2.2, "CHNPED94"),
    r("L4", Dimension::PedicleWidth, 11.9, 2.4, "CHNPED94"),
    r("L5", Dimension::PedicleWidth, 17.0, 2.8, "CHNPED94"),
    r(
        "L2",
        Dimension::PedicleTransverseAngle,
        13.9,
        4.9,
        "CHNPED94",
    ),
    r(
        "L3",
        Dimension::PedicleTransverseAngle,
        13.4,
        5.1,
        "CHNPED94",
    ),
    r(
        "L4",
        Dimension::PedicleTransverseAngle,
        16.2,
        5.9,
        "CHNPED94",
    ),
    r(
        "L5",
        Dimension::PedicleTransverseAngle,
        27.8,
        7.2,
        "CHNPED94",
    ),
    r("L1-L2", Dimension::SegmentalLordosis, 1.2, 3.6, "SCIREP22"),
    r("L2-L3", Dimension::SegmentalLordosis, 5.9, 4.1, "SCIREP22"),
    r("L3-L4", Dimension::SegmentalLordosis, 9.1, 4.2, "SCIREP22"),
    r("L4-L5", Dimension::SegmentalLordosis, 12.7, 5.1, "SCIREP22"),
    r("L5-S1", Dimension::SegmentalLordosis, 21.6, 7.7, "SCIREP22"),
    r("L1-S1", Dimension::LordosisL1S1, 49.8, 11.2, "ASJ627"),
    r("L3-L4", Dimension::FlavumThickness, 3.38, 0.94, "KOLTE15"),
    r("L4-L5", Dimension::FlavumThickness, 3.70, 1.16, "KOLTE15"),
    m("L1", Dimension::PedicleTransverseAngle, 16.0, "CHEUNG94"),
    m("L1", Dimension::CanalDepth, 18.7, "ABBAS21"),
    m("L2", Dimension::CanalDepth, 17.8, "ABBAS21"),
    m("L3", Dimension::CanalDepth, 16.9, "ABBAS21"),
    m("L4", Dimension::CanalDepth, 17.6, "ABBAS21"),
    m("L1", Dimension::EndplateWidth, 36.3, "GUJ12"),
    m("L5", Dimension::EndplateWidth, 46.0, "GUJ12"),
    m("L1", Dimension::DiscHeight, 8.37, "SHUKRI13"),
    m("L2", Dimension::DiscHeight, 9.64, "SHUKRI13"),
    m("L3", Dimension::DiscHeight, 10.71, "SHUKRI13"),
    m("L4", Dimension::DiscHeight, 11.44, "SHUKRI13"),
    m("L5", Dimension::DiscHeight, 10.56, "SHUKRI13"),
];

/// The sources of [`PUBLISHED`], by key.
pub const SOURCES: &[(&str, &str)] = &[
    (
        "COOK21",
        "Cook WH, Baker JF. Comparative analysis of lumbar spine vertebral morphology between Maori and New Zealand Europeans: a CT study. Int J Spine Surg 2021;15(6):1072-1081, Table 6 (L5, n = 196, all patients).",
    ),
    (
        "CHNPED94",
        "Measurement of Chinese lumbar pedicles: with special reference to transpedicular screw fixation (CT, 100 volunteers), PubMed 8087710, abstract.",
    ),
    (
        "CHEUNG94",
        "Cheung KM, Ruan D, Chan FL, Fang D. Computed tomographic osteometry of Asian lumbar pedicles. Spine 1994;19(13):1495-1498 (means only).",
    ),
    (
        "SCIREP22",
        "Segmental lumbar lordosis by pelvic incidence group, Sci Rep 2022, doi:10.1038/s41598-022-21840-x, Table 2 (n = 324, all subjects).",
    ),
    (
        "ASJ627",
        "Lumbar sagittal alignment in 627 asymptomatic volunteers, PMC6680033: standing T12-S1 lordosis (compared here with L1-S1).",
    ),
    (
        "KOLTE15",
        "Kolte VS, Khambatta S, Ambiye MV. Thickness of the ligamentum flavum. Asian Spine J 2015;9(2):245-253 (MRI, n = 200, right side).",
    ),
    (
        "ABBAS21",
        "Abbas J, Peled N, Hershkovitz I, Hamoud K. Vertebral morphometry in degenerative lumbar spinal stenosis. Biomed Res Int 2021:7093745 (CT, control males, means only).",
    ),
    (
        "GUJ12",
        "Canal/body ratio of lumbar vertebrae in dried vertebrae, Gujarat 2012 (63 dry spines, males, means only).",
    ),
    (
        "SHUKRI13",
        "Shukri IG, Mahmood KA, Abdulrahman SA. Morphometry of the lumbar spine in asymptomatic subjects by MRI. J Sulaimani Med Coll 2013;3(1) (n = 106, mid-sagittal disc heights, means only).",
    ),
];

/// One row of the morphometry table: a reference and the value measured on the phantom.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// The published value.
    pub reference: Reference,
    /// Measured on the meshes.
    pub measured: f64,
}

impl Comparison {
    /// Distance from the published mean in standard deviations (`None` for a mean-only source).
    pub fn z(&self) -> Option<f64> {
        self.reference
            .sd
            .map(|sd| (self.measured - self.reference.mean) / sd)
    }

    /// Within two standard deviations, or within [`MEAN_ONLY_TOLERANCE`] of a mean-only value.
    pub fn agrees(&self) -> bool {
        match self.z() {
            Some(z) => z.abs() <= 2.0,
            None => {
                (self.measured - self.reference.mean).abs()
                    <= MEAN_ONLY_TOLERANCE * self.reference.mean
            }
        }
    }
}

/// Pairs every [`PUBLISHED`] value with its measurement; errors name a reference that has no
/// measurement.
pub fn compare(measured: &[Measured]) -> Result<Vec<Comparison>, MorphometryError> {
    PUBLISHED
        .iter()
        .map(|r| {
            measured
                .iter()
                .find(|m| m.level == r.level && m.dimension == r.dimension)
                .map(|m| Comparison {
                    reference: *r,
                    measured: m.value,
                })
                .ok_or(MorphometryError::NoMeasurement {
                    level: r.level,
                    dimension: r.dimension,
                })
        })
        .collect()
}

/// The comparison as a Markdown table (level, dimension, measured, published mean and SD, z,
/// source).
pub fn table_markdown(rows: &[Comparison]) -> String {
    let mut s = String::from(
        "| level | dimension | measured | published mean | SD | z | source |\n|---|---|---|---|---|---|---|\n",
    );
    for c in rows {
        let r = c.reference;
        let unit = r.dimension.unit();
        s += &format!(
            "| {} | {:?} | {:.1} {unit} | {:.1} | {} | {} | {} |\n",
            r.level,
            r.dimension,
            c.measured,
            r.mean,
            r.sd.map_or("(mean only)".into(), |sd| format!("{sd:.1}")),
            c.z().map_or(
                format!("{:+.0} %", 100.0 * (c.measured / r.mean - 1.0)),
                |z| format!("{z:+.2}")
            ),
            r.source
        );
    }
    s
}
