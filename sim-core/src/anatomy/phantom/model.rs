//! The lumbosacral anatomy as implicit solids: dimensions, placement and painting order.
//!
//! # Model frame
//! The platform's RAS frame (see `crate::fluoro::geometry`): millimetres, `x` = patient right,
//! `y` = anterior, `z` = cranial, right-handed; origin at the centre of the L3 vertebral body
//! (midway between its endplates, on its mid-sagittal plane). Left-sided structures have `x < 0`.
//! Inside the model, `s` is the side sign: [`LEFT`] = -1, [`RIGHT`] = +1.
//!
//! # Sources (adult morphometry; values rounded to the nearest 0.5 mm)
//! - Vertebral body endplate width and depth, posterior body height, canal width and depth,
//!   transverse-process span: approximate level means after Panjabi MM et al., "Human lumbar
//!   vertebrae: quantitative three-dimensional anatomy", Spine 1992;17(3):299-306, cross-checked
//!   against the lower-lumbar CT dimensions of Zhou SH et al., Eur Spine J 2000;9(3):242-248.
//! - Pedicle isthmus width, height and transverse angle: Zindrick MR et al., "Analysis of the
//!   morphometric characteristics of the thoracic and lumbar pedicles", Spine 1987;12(2):160-166.
//! - Segmental lordosis concentrated at L4-S1: Bernhardt M, Bridwell KH, Spine 1989;14(7):717-721;
//!   sacral slope about 40 degrees: Legaye J et al., Eur Spine J 1998;7(2):99-103.
//! - Facet-joint orientation growing more coronal caudally: Masharawi Y et al., Spine
//!   2004;29(16):1755-1763 (angles here are rounded approximations).
//! - Conus medullaris at the L1-L2 level and dural sac ending at S2: Saifuddin A et al., J Anat
//!   1998;193(2):273-279; Macdonald A et al., Clin Radiol 1999;54(3):163-166.
//! - Aortic bifurcation at L4 and IVC confluence at L4-L5: Chithriki M et al., Clin Anat
//!   2002;15(4):264-269.
//!
//! Everything else (soft-tissue thicknesses, muscle sections, the pelvis outline, roots' courses)
//! is **our assumption**, sized to typical adult CT appearance and said so where it is set.
//!
//! # Painting order
//! Structures are listed from back to front: a later structure overwrites an earlier one where
//! they overlap, so each voxel belongs to exactly one structure and the masks are disjoint.
//! Shells come out of this for free: the skin is the whole body envelope, overwritten inside by
//! the subcutaneous fat, overwritten by the deep soft tissue; a bone is painted whole as cortical
//! bone and then its inset as cancellous bone.

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use super::sdf::{Rigid, Sdf};
use crate::material::MaterialClass;

/// Side sign of the patient's left in the RAS model frame (x points to the patient's right).
pub const LEFT: f64 = -1.0;
/// Side sign of the patient's right.
pub const RIGHT: f64 = 1.0;

/// One solid of the phantom, in painting order.
#[derive(Debug, Clone)]
pub struct PhantomPart {
    /// Stable structure name (used for mesh names and masks).
    pub name: String,
    /// Tissue class of the structure.
    pub material: MaterialClass,
    /// The solid.
    pub sdf: Sdf,
    /// Whether the structure's mesh bounds its whole solid, with later structures nested inside it
    /// (true for the body envelope layers that contain everything), rather than only the part the
    /// painting order leaves to it. Labels and CT follow the painting order either way.
    pub nested: bool,
}

/// A named point of interest for stations and scorers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Landmark {
    /// Stable snake_case name.
    pub name: String,
    /// Position in the model frame, mm.
    pub position_mm: [f64; 3],
    /// What the point is, in words.
    pub description: String,
    /// The structure the point is expected to lie in (`None` for a point that is defined by
    /// surrounding structures, such as a joint space or a foramen).
    pub inside_structure: Option<String>,
}

/// Per-level lumbar dimensions (mm, degrees).
#[derive(Debug, Clone, Copy)]
struct LevelDims {
    name: &'static str,
    /// Endplate width (x).
    body_width: f64,
    /// Endplate depth (y).
    body_depth: f64,
    /// Posterior body height (z).
    body_height: f64,
    /// Pedicle isthmus width (Zindrick 1987).
    pedicle_width: f64,
    /// Pedicle height (Zindrick 1987).
    pedicle_height: f64,
    /// Pedicle transverse angle, medial convergence (Zindrick 1987).
    pedicle_angle_deg: f64,
    /// Spinal canal width (x) and depth (y).
    canal_width: f64,
    canal_depth: f64,
    /// Transverse process tip-to-tip span.
    tp_span: f64,
    /// Spinous process length behind the canal and its height (our assumption, after Panjabi).
    sp_length: f64,
    sp_height: f64,
    /// Sagittal tilt of the body axis from vertical, + tilts the top anteriorly. Chosen to give
    /// 52 degrees of L1-S1 lordosis (within the 40-60 degree adult range), with 60 % of it at
    /// L4-S1 (Bernhardt and Bridwell 1989); our assumption for the individual numbers.
    tilt_deg: f64,
}

/// L1..L5 (Panjabi 1992 and Zindrick 1987 means, rounded; see the module docs).
const LUMBAR: [LevelDims; 5] = [
    LevelDims {
        name: "L1",
        body_width: 40.0,
        body_depth: 32.0,
        body_height: 26.0,
        pedicle_width: 8.7,
        pedicle_height: 15.4,
        pedicle_angle_deg: 11.0,
        canal_width: 22.0,
        canal_depth: 18.0,
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
        canal_depth: 17.5,
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
        canal_depth: 17.0,
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
        canal_depth: 17.0,
        tp_span: 86.0,
        sp_length: 29.0,
        sp_height: 23.0,
        tilt_deg: 7.0,
    },
    LevelDims {
        name: "L5",
        body_width: 49.0,
        body_depth: 35.0,
        body_height: 25.5,
        pedicle_width: 18.0,
        pedicle_height: 14.0,
        pedicle_angle_deg: 30.0,
        canal_width: 26.0,
        canal_depth: 17.5,
        tp_span: 90.0,
        sp_length: 25.0,
        sp_height: 19.0,
        tilt_deg: 20.0,
    },
];

/// The S1 "level" used to place the sacrum and its articular processes. Endplate 50 x 33 mm
/// (our assumption, close to the L5 inferior endplate); the sacral slope of 40 degrees is the
/// adult mean of Legaye et al. 1998.
const S1: LevelDims = LevelDims {
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
const DISC_HEIGHT_MM: [f64; 5] = [9.0, 10.0, 11.0, 11.5, 11.5];

/// Facet-joint angle from the sagittal plane for L1-L2 .. L5-S1 (degrees), rounded after
/// Masharawi et al. 2004.
const FACET_ANGLE_DEG: [f64; 5] = [25.0, 30.0, 37.0, 45.0, 50.0];

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
        }
    }
}

/// Centre of the body envelope in y, mm: puts the posterior skin about 28 mm behind the L3
/// spinous tip and the anterior abdominal wall 142 mm in front of the L3 body centre (our
/// assumption).
const BODY_CENTRE_Y_MM: f64 = 25.0;

/// A placed vertebra: its frame (origin at the body centre) and dimensions.
#[derive(Debug, Clone, Copy)]
struct Placed {
    dims: LevelDims,
    frame: Rigid,
}

impl Placed {
    fn w(&self, x: f64, y: f64, z: f64) -> DVec3 {
        self.frame.to_world(DVec3::new(x, y, z))
    }
    fn up(&self) -> DVec3 {
        self.frame.rotation.z_axis
    }
    /// Canal centre y (local).
    fn canal_y(&self) -> f64 {
        -0.5 * self.dims.body_depth - 0.5 * self.dims.canal_depth
    }
    /// Pedicle centre height (local z): the pedicle sits in the upper part of the body.
    fn pedicle_z(&self) -> f64 {
        0.5 * self.dims.body_height - 0.5 * self.dims.pedicle_height - 1.5
    }
    /// Pedicle isthmus centre x (left side; mirror for right).
    fn pedicle_x(&self) -> f64 {
        0.5 * self.dims.canal_width + 0.5 * self.dims.pedicle_width
    }
    /// The pedicle-lamina junction (local), side `s` ([`LEFT`] or [`RIGHT`]).
    fn junction(&self, s: f64) -> DVec3 {
        let d = self.dims;
        let len = 0.8 * d.canal_depth + 4.0;
        let x = self.pedicle_x() + 0.5 * len * d.pedicle_angle_deg.to_radians().tan();
        DVec3::new(
            s * x,
            -0.5 * d.body_depth - 0.8 * d.canal_depth,
            self.pedicle_z(),
        )
    }
    /// Lamina top and bottom heights (local z).
    fn lamina_z(&self) -> (f64, f64) {
        let d = self.dims;
        (
            self.pedicle_z() + 0.5 * d.pedicle_height - 2.0,
            -0.5 * d.body_height - 3.0,
        )
    }
    /// Posterior canal wall y (local).
    fn canal_back_y(&self) -> f64 {
        -0.5 * self.dims.body_depth - self.dims.canal_depth
    }
}

fn rot_x(deg: f64) -> DMat3 {
    // Rotation about x that tilts +z towards +y by `deg`.
    DMat3::from_rotation_x(-deg.to_radians())
}

/// The whole phantom: parts in painting order plus landmarks.
#[derive(Debug, Clone)]
pub struct Anatomy {
    /// Solids in painting order (later overwrites earlier).
    pub parts: Vec<PhantomPart>,
    /// Named points.
    pub landmarks: Vec<Landmark>,
}

/// Places L1..L5 and the S1 frame along the lordotic curve, L3 at the origin.
fn place_spine() -> (Vec<Placed>, Placed) {
    let mut frames: Vec<Option<Placed>> = vec![None; 6];
    let all: Vec<LevelDims> = LUMBAR.iter().copied().chain(std::iter::once(S1)).collect();
    frames[2] = Some(Placed {
        dims: all[2],
        frame: Rigid {
            rotation: rot_x(all[2].tilt_deg),
            translation: DVec3::ZERO,
        },
    });
    // Upwards from L3.
    for i in (0..2).rev() {
        let lower = frames[i + 1].expect("placed");
        let d = all[i];
        let top_lower = lower.w(0.0, 0.0, 0.5 * lower.dims.body_height);
        let mid_rot = rot_x(0.5 * (d.tilt_deg + lower.dims.tilt_deg));
        let bottom_upper = top_lower + mid_rot * DVec3::new(0.0, 0.0, DISC_HEIGHT_MM[i]);
        let rot = rot_x(d.tilt_deg);
        let centre = bottom_upper + rot * DVec3::new(0.0, 0.0, 0.5 * d.body_height);
        frames[i] = Some(Placed {
            dims: d,
            frame: Rigid {
                rotation: rot,
                translation: centre,
            },
        });
    }
    // Downwards from L3 to S1.
    for i in 3..6 {
        let upper = frames[i - 1].expect("placed");
        let d = all[i];
        let bottom_upper = upper.w(0.0, 0.0, -0.5 * upper.dims.body_height);
        let mid_rot = rot_x(0.5 * (d.tilt_deg + upper.dims.tilt_deg));
        let top_lower = bottom_upper - mid_rot * DVec3::new(0.0, 0.0, DISC_HEIGHT_MM[i - 1]);
        let rot = rot_x(d.tilt_deg);
        let centre = top_lower - rot * DVec3::new(0.0, 0.0, 0.5 * d.body_height);
        frames[i] = Some(Placed {
            dims: d,
            frame: Rigid {
                rotation: rot,
                translation: centre,
            },
        });
    }
    let frames: Vec<Placed> = frames.into_iter().map(|f| f.expect("placed")).collect();
    (frames[..5].to_vec(), frames[5])
}

/// Where the articular processes of a motion segment meet, side `s`: joint centre and the unit
/// normal pointing from the lower vertebra's superior process to the upper one's inferior process.
fn facet_joint(
    upper: &Placed,
    lower: &Placed,
    disc_mm: f64,
    angle_deg: f64,
    s: f64,
) -> (DVec3, DVec3) {
    let j_lower = lower.w(
        s * (0.5 * lower.dims.canal_width + 5.0),
        lower.canal_y() - 0.25 * lower.dims.canal_depth,
        0.5 * lower.dims.body_height + 0.5 * disc_mm + 2.0,
    );
    let j_upper = upper.w(
        s * (0.5 * upper.dims.canal_width + 5.0),
        upper.canal_y() - 0.25 * upper.dims.canal_depth,
        -0.5 * upper.dims.body_height - 0.5 * disc_mm + 2.0,
    );
    let centre = 0.5 * (j_lower + j_upper);
    let a = angle_deg.to_radians();
    // In the axial plane the joint line runs from anteromedial to posterolateral; the inferior
    // process of the upper vertebra lies posteromedial to the superior process of the lower one.
    let local_n = DVec3::new(-s * a.cos(), -a.sin(), 0.0);
    let rot = rot_x(0.5 * (upper.dims.tilt_deg + lower.dims.tilt_deg));
    (centre, (rot * local_n).normalize())
}

/// The joint geometry shared by the two articular processes of one facet joint.
#[derive(Debug, Clone, Copy)]
struct Joint {
    centre: DVec3,
    normal: DVec3,
    up: DVec3,
}

/// Articular-process block on one side of a joint: `sign` -1 for the superior process (below the
/// plane along -normal), +1 for the inferior process.
fn articular_block(j: &Joint, sign: f64, gap: f64) -> Sdf {
    // Half-extents: 3 mm thick (along the normal), 7 mm along the joint line, 8 mm tall (our
    // assumption: lumbar facets are about 15 x 15 mm).
    let half = DVec3::new(3.0, 7.0, 8.0);
    let centre = j.centre + j.normal * sign * (0.5 * gap + half.x);
    let rigid = Rigid::from_axes(centre, j.normal, j.up);
    Sdf::RoundBox { half, round: 2.5 }.placed(rigid)
}

/// The region within 14 mm of a joint on the far side of its space: removed from a bone so the
/// joint space stays open after smooth blending.
fn joint_keepout(j: &Joint, sign: f64, gap: f64) -> Sdf {
    // sign +1: remove everything beyond -gap/2 on the +normal side (for the lower vertebra).
    let n = j.normal * sign;
    Sdf::Intersect(vec![
        Sdf::HalfSpace {
            normal: -n,
            offset: -(n.dot(j.centre) - 0.5 * gap),
        },
        Sdf::Sphere { radius: 14.0 }.at(j.centre),
    ])
}

/// Whole-bone solid of a lumbar vertebra (before the canal and joints are carved).
fn lumbar_bone(v: &Placed, is_l5: bool) -> Sdf {
    let d = v.dims;
    let f = v.frame;
    let mut parts = Vec::new();
    // Body: elliptic cylinder with rounded rims, slightly kidney-shaped behind.
    let body = Sdf::EllipticCylinder {
        rx: 0.5 * d.body_width,
        ry: 0.5 * d.body_depth,
        half_h: 0.5 * d.body_height,
        round: 2.5,
    }
    .smooth_minus(
        Sdf::EllipticCylinder {
            rx: 20.0,
            ry: 20.0,
            half_h: d.body_height,
            round: 0.0,
        }
        .at(DVec3::new(0.0, -0.5 * d.body_depth - 16.0, 0.0)),
        3.0,
    );
    parts.push(body);
    for s in [LEFT, RIGHT] {
        let j = v.junction(s);
        // Pedicle: a rounded bar from inside the posterolateral body to the junction.
        let a = DVec3::new(
            s * (v.pedicle_x() - 2.0),
            -0.5 * d.body_depth + 5.0,
            v.pedicle_z(),
        );
        let r = 0.5 * d.pedicle_width.min(d.pedicle_height) * 0.95;
        parts.push(Sdf::slab_between(
            a,
            j,
            DVec3::Z,
            0.5 * d.pedicle_width,
            0.5 * d.pedicle_height,
            r,
        ));
        // Lamina: a plate from the junction to the midline behind the canal.
        let (zt, zb) = v.lamina_z();
        let zc = 0.5 * (zt + zb);
        let m = DVec3::new(0.0, v.canal_back_y() - 3.5, zc);
        let jl = DVec3::new(j.x, j.y, zc);
        parts.push(Sdf::slab_between(
            jl,
            m,
            DVec3::Z,
            3.5,
            0.5 * (zt - zb),
            3.0,
        ));
        // Transverse process: a flat bar from the junction, lateral and slightly backwards.
        if d.tp_span > 0.0 {
            let base = DVec3::new(j.x, j.y + 3.0, v.pedicle_z());
            let tip = DVec3::new(
                s * 0.5 * d.tp_span - s * 4.0,
                j.y - 4.0,
                v.pedicle_z() - 2.0,
            );
            let half_z = if is_l5 { 7.5 } else { 5.5 };
            parts.push(Sdf::slab_between(base, tip, DVec3::Z, 3.0, half_z, 2.8));
        }
    }
    // Spinous process: a sagittal plate from the laminae backwards, with a rounded tip.
    let (zt, zb) = v.lamina_z();
    let zc = 0.5 * (zt + zb) - 1.0;
    let root = DVec3::new(0.0, v.canal_back_y() - 2.0, zc);
    let tip = DVec3::new(0.0, v.canal_back_y() - d.sp_length, zc - 5.0);
    parts.push(Sdf::slab_between(
        root,
        tip,
        DVec3::Z,
        4.0,
        0.5 * d.sp_height,
        3.5,
    ));
    parts.push(
        Sdf::Ellipsoid {
            radii: DVec3::new(5.0, 5.0, 0.5 * d.sp_height + 1.0),
        }
        .at(tip + DVec3::new(0.0, 3.0, 0.0)),
    );
    Sdf::SmoothUnion(parts, 4.0).placed(f)
}

/// Canal of a lumbar vertebra in its own frame, removed from the bone.
fn lumbar_canal(v: &Placed) -> Sdf {
    let d = v.dims;
    Sdf::EllipticCylinder {
        rx: 0.5 * d.canal_width,
        ry: 0.5 * d.canal_depth,
        half_h: d.body_height,
        round: 0.0,
    }
    .at(DVec3::new(0.0, v.canal_y(), 0.0))
    .placed(v.frame)
}

/// Sacral frame: origin at the centre of the S1 superior endplate, z along its normal.
fn sacral_frame(s1: &Placed) -> Rigid {
    Rigid {
        rotation: s1.frame.rotation,
        translation: s1.w(0.0, 0.0, 0.5 * s1.dims.body_height),
    }
}

/// Sacral levels S1..S5 and the apex in the sacral frame: centre-line point (body centre),
/// half-width of the lateral masses, body radius. The sacrum curves anteriorly as it descends
/// (ventral concavity); about 100 mm long and 104 mm wide at the alae (our assumption, typical
/// adult sacral dimensions).
const SACRAL_LEVELS: [(f64, f64, f64, f64); 6] = [
    // (y, z, lateral half-width, body radius)
    (0.0, -13.0, 52.0, 16.5),
    (1.0, -38.0, 45.0, 13.0),
    (4.0, -58.0, 35.0, 10.0),
    (10.0, -75.0, 25.0, 8.0),
    (17.0, -89.0, 16.0, 6.0),
    (25.0, -100.0, 8.0, 4.5),
];

/// Sacral canal centre for level index `i` (sacral frame): behind the body.
fn sacral_canal_point(i: usize) -> DVec3 {
    let (y, z, _, r) = SACRAL_LEVELS[i];
    DVec3::new(0.0, y - r - 8.0 + i as f64 * 0.5, z)
}

fn sacrum_bone(sf: &Rigid) -> Sdf {
    let mut parts = Vec::new();
    let body_pts: Vec<DVec3> = SACRAL_LEVELS
        .iter()
        .map(|&(y, z, _, _)| DVec3::new(0.0, y, z))
        .collect();
    let body_r: Vec<f64> = SACRAL_LEVELS.iter().map(|&(_, _, _, r)| r).collect();
    let mut top = body_pts.clone();
    // Square off the S1 endplate: extend the first node to the endplate plane with a wider body.
    top[0] = DVec3::new(0.0, 0.0, -12.0);
    parts.push(
        Sdf::EllipticCylinder {
            rx: 25.0,
            ry: 16.5,
            half_h: 13.0,
            round: 2.5,
        }
        .at(DVec3::new(0.0, 0.0, -13.0)),
    );
    parts.push(Sdf::Tube {
        points: top,
        radii: body_r,
    });
    // Lateral masses and alae: flattened ellipsoids per level, posterior to the body's front.
    for (i, &(y, z, hw, r)) in SACRAL_LEVELS.iter().enumerate().take(5) {
        let depth = (18.0 - 2.5 * i as f64).max(7.0);
        let height = if i == 0 { 16.0 } else { 12.0 };
        parts.push(
            Sdf::Ellipsoid {
                radii: DVec3::new(hw, depth, height),
            }
            .at(DVec3::new(
                0.0,
                y - r - 4.0,
                z + if i == 0 { -4.0 } else { 0.0 },
            )),
        );
    }
    // Median sacral crest: a ridge behind the canal.
    let crest: Vec<DVec3> = (0..5)
        .map(|i| sacral_canal_point(i) + DVec3::new(0.0, -9.0 + 0.8 * i as f64, 0.0))
        .collect();
    parts.push(Sdf::Tube {
        points: crest,
        radii: vec![6.0, 5.5, 5.0, 4.0, 3.0],
    });
    let solid = Sdf::SmoothUnion(parts, 8.0);
    // Sacral canal: a flattened tube (about 28 x 12 mm at S1, narrowing; our assumption).
    let canal_pts: Vec<DVec3> = (0..6).map(sacral_canal_point).collect();
    let canal = Sdf::Scaled(
        Box::new(Sdf::Tube {
            points: canal_pts
                .iter()
                .map(|p| DVec3::new(p.x / 2.2, p.y, p.z))
                .chain(std::iter::once(DVec3::new(0.0, -30.0, 20.0)))
                .collect(),
            radii: vec![6.5, 6.0, 5.0, 4.0, 3.5, 3.0, 6.5],
        }),
        DVec3::new(2.2, 1.0, 1.0),
    );
    // Sacral hiatus: the canal's posterior wall is open at S4-S5 (our assumption: hiatus apex at S4).
    let hiatus = Sdf::Tube {
        points: vec![
            sacral_canal_point(3) + DVec3::new(0.0, -2.0, 2.0),
            sacral_canal_point(5) + DVec3::new(0.0, -3.0, -6.0),
        ],
        radii: vec![4.0, 5.0],
    }
    .placed(Rigid::IDENTITY);
    let hiatus = Sdf::Union(vec![
        hiatus,
        Sdf::Tube {
            points: vec![
                sacral_canal_point(3) + DVec3::new(0.0, -12.0, 2.0),
                sacral_canal_point(5) + DVec3::new(0.0, -14.0, -6.0),
            ],
            radii: vec![4.0, 5.0],
        },
        Sdf::Tube {
            points: vec![
                sacral_canal_point(3) + DVec3::new(0.0, -2.0, 2.0),
                sacral_canal_point(3) + DVec3::new(0.0, -12.0, 2.0),
            ],
            radii: vec![4.0, 4.0],
        },
        Sdf::Tube {
            points: vec![
                sacral_canal_point(5) + DVec3::new(0.0, -3.0, -6.0),
                sacral_canal_point(5) + DVec3::new(0.0, -14.0, -6.0),
            ],
            radii: vec![5.0, 5.0],
        },
    ]);
    let mut holes = vec![canal, hiatus];
    for (a, b, r) in sacral_foramina() {
        holes.push(Sdf::cone(a, r, b, r * 0.85));
    }
    for i in 0..4 {
        for s in [LEFT, RIGHT] {
            // Posterior foramina: smaller channels from the canal out through the dorsal surface.
            let c = sacral_canal_point(i);
            holes.push(Sdf::cone(
                c + DVec3::new(s * 8.0, 0.0, -4.0),
                3.2 - 0.3 * i as f64,
                c + DVec3::new(s * (20.0 - 2.0 * i as f64), -16.0, -6.0),
                2.6 - 0.2 * i as f64,
            ));
        }
    }
    solid.minus(Sdf::Union(holes)).placed(*sf)
}

/// Anterior sacral foramina S1..S4 (sacral frame): channel from the canal through the anterior
/// surface, with its radius (S1 about 9 mm across, shrinking caudally; our assumption).
fn sacral_foramina() -> Vec<(DVec3, DVec3, f64)> {
    let mut out = Vec::new();
    for (i, &(y, z, hw, r)) in SACRAL_LEVELS.iter().enumerate().take(4) {
        for s in [LEFT, RIGHT] {
            let c = sacral_canal_point(i);
            let lateral = (0.5 * r + 0.3 * hw).max(10.0) + 6.0;
            let front = DVec3::new(s * lateral, y + 14.0, z - 6.0);
            out.push((
                c + DVec3::new(s * 7.0, 0.0, 0.0),
                front,
                4.5 - 0.6 * i as f64,
            ));
        }
    }
    out
}

/// Canal centre-line through L1..S4 (world), used by the dural sac, epidural space, cauda and
/// ligamentum flavum; starts above the grid's top so tubes leave through it.
fn canal_line(v: &[Placed], sf: &Rigid) -> Vec<DVec3> {
    let mut pts = vec![v[0].w(0.0, v[0].canal_y(), 0.5 * v[0].dims.body_height + 30.0)];
    for (i, p) in v.iter().enumerate() {
        pts.push(p.w(0.0, p.canal_y(), 0.0));
        let lower = if i + 1 < v.len() {
            v[i + 1].w(0.0, v[i + 1].canal_y(), 0.0)
        } else {
            sf.to_world(sacral_canal_point(0))
        };
        pts.push(0.5 * (pts[pts.len() - 1] + lower));
    }
    for i in 0..5 {
        pts.push(sf.to_world(sacral_canal_point(i)));
    }
    pts
}

/// A tube with elliptic section (half-width `rx`, half-depth `ry` per node) along a centre-line
/// that lies in the mid-sagittal plane (x = 0), built by stretching a round tube along x.
fn sagittal_tube(points: &[DVec3], rx: &[f64], ry: &[f64]) -> Sdf {
    // Stretch factor: mean ratio; the x-stretch keeps the centre line (x = 0) in place.
    let ratio = rx.iter().zip(ry).map(|(a, b)| a / b).sum::<f64>() / rx.len() as f64;
    Sdf::Scaled(
        Box::new(Sdf::Tube {
            points: points.to_vec(),
            radii: ry.to_vec(),
        }),
        DVec3::new(ratio, 1.0, 1.0),
    )
}

impl Anatomy {
    /// Index of the structure that owns point `p` under the painting order (the last solid that
    /// contains it), or `None` outside the body. This is what the voxelizer computes at voxel
    /// centres, evaluated at an arbitrary point.
    pub fn structure_at(&self, p: [f64; 3]) -> Option<usize> {
        let p = DVec3::from(p);
        self.parts.iter().rposition(|part| part.sdf.eval(p) <= 0.0)
    }

    /// Index of a structure by name.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.parts.iter().position(|part| part.name == name)
    }

    /// Builds the default lumbosacral phantom.
    pub fn new(p: &AnatomyParams) -> Anatomy {
        let (v, s1) = place_spine();
        let sf = sacral_frame(&s1);
        let mut parts: Vec<PhantomPart> = Vec::new();
        let mut landmarks: Vec<Landmark> = Vec::new();
        let mut push = |name: &str, material: MaterialClass, sdf: Sdf| {
            // The two envelope solids that contain everything are meshed whole (nested): their
            // exclusive parts would be a thin shell (skin) and a surface wrapped round every organ
            // (deep soft tissue), both slow to mesh and of no use to a renderer that nests.
            let nested = name == "skin" || name == "deep_soft_tissue";
            parts.push(PhantomPart {
                name: name.to_string(),
                material,
                sdf,
                nested,
            });
        };

        // --- Body envelope: skin, subcutaneous fat, deep soft tissue (our assumption: an
        // elliptic cylinder widening over the pelvis, taller than any grid).
        let waist = Sdf::EllipticCylinder {
            rx: p.body_half_width_mm,
            ry: p.body_half_depth_mm,
            half_h: 600.0,
            round: 0.0,
        }
        .at(DVec3::new(0.0, BODY_CENTRE_Y_MM, 0.0));
        let hips = Sdf::Ellipsoid {
            radii: DVec3::new(
                p.body_half_width_mm + 12.0,
                p.body_half_depth_mm - 5.0,
                140.0,
            ),
        }
        .at(DVec3::new(0.0, BODY_CENTRE_Y_MM, -200.0));
        let envelope = Sdf::SmoothUnion(vec![waist, hips], 30.0);
        // Everything inside the body lies under the skin: the erector spinae column and the
        // iliac wings reach beyond the envelope otherwise (a few cm^3 each), which no anatomy
        // has and which would leave them outside the skin mesh that every renderer nests the
        // body in. Their solids are clipped to the inner surface of the skin.
        let under_skin = envelope.clone().offset(-p.skin_mm);
        push("skin", MaterialClass::SoftTissue, envelope.clone());
        push(
            "subcutaneous_fat",
            MaterialClass::Fat,
            envelope.clone().offset(-p.skin_mm),
        );
        push(
            "deep_soft_tissue",
            MaterialClass::SoftTissue,
            envelope.offset(-p.skin_mm - p.subcutaneous_fat_mm),
        );

        // --- Muscles. Psoas: a tapered tube along the lateral vertebral bodies into the pelvis
        // (cross-section about 12 cm^2 at L4-L5; our assumption).
        for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
            let mut pts = Vec::new();
            let mut radii = Vec::new();
            for (i, vert) in v.iter().enumerate() {
                let r = 9.0 + 3.0 * i as f64;
                pts.push(vert.w(s * (0.5 * vert.dims.body_width + r - 3.0), 2.0, 0.0));
                radii.push(r);
            }
            let c = sf.to_world(DVec3::new(s * 58.0, 30.0, -20.0));
            pts.push(c);
            radii.push(20.0);
            pts.push(c + DVec3::new(s * 18.0, 30.0, -80.0));
            radii.push(18.0);
            pts.push(c + DVec3::new(s * 24.0, 40.0, -160.0));
            radii.push(17.0);
            let top = pts[0] + DVec3::new(0.0, 0.0, 15.0);
            pts.insert(0, top);
            radii.insert(0, 7.0);
            push(
                &format!("psoas_{side}"),
                MaterialClass::Muscle,
                Sdf::Tube { points: pts, radii },
            );
        }
        // Erector spinae with multifidus: an elliptic column behind the laminae and transverse
        // processes, beside the spinous processes (about 20 cm^2 per side at L3; our assumption).
        for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
            let mut pts = vec![v[0].w(s * 36.0, v[0].canal_back_y() - 20.0, 60.0)];
            for vert in &v {
                pts.push(vert.w(s * 36.0, vert.canal_back_y() - 20.0, 0.0));
            }
            pts.push(sf.to_world(DVec3::new(s * 30.0, -48.0, -30.0)));
            pts.push(sf.to_world(DVec3::new(s * 22.0, -40.0, -70.0)));
            let n = pts.len();
            let ry: Vec<f64> = (0..n)
                .map(|i| {
                    if i + 2 < n {
                        20.0
                    } else if i + 1 < n {
                        14.0
                    } else {
                        7.0
                    }
                })
                .collect();
            let shape = Sdf::Tube {
                points: pts
                    .iter()
                    .map(|q| DVec3::new(q.x - s * 36.0, q.y, q.z))
                    .collect(),
                radii: ry,
            };
            let shape = Sdf::Scaled(Box::new(shape), DVec3::new(1.45, 1.0, 1.0)).at(DVec3::new(
                s * 36.0,
                0.0,
                0.0,
            ));
            push(
                &format!("erector_spinae_{side}"),
                MaterialClass::Muscle,
                Sdf::Intersect(vec![shape, under_skin.clone()]),
            );
        }

        // --- Canal contents. Epidural space: fills the bony canal (bone and ligaments overwrite
        // it), continuing to the sacral hiatus.
        let line = canal_line(&v, &sf);
        let n = line.len();
        let canal_rx: Vec<f64> = (0..n)
            .map(|i| {
                if i < n - 5 {
                    13.0
                } else {
                    13.0 - 1.8 * (i + 5 - n) as f64
                }
            })
            .collect();
        let canal_ry: Vec<f64> = (0..n)
            .map(|i| {
                if i < n - 5 {
                    9.5
                } else {
                    7.0 - 0.9 * (i + 5 - n) as f64
                }
            })
            .collect();
        let canal = sagittal_tube(&line, &canal_rx, &canal_ry);
        push(
            "epidural_space",
            MaterialClass::EpiduralSpace,
            canal.clone(),
        );
        // Ligamentum flavum: a 3.5 mm layer on the posterior canal wall between the laminae (our
        // assumption within the 2-5 mm normal range); bone overwrites it at the laminae.
        let mut lf = Vec::new();
        for i in 0..5 {
            let upper = &v[i];
            let lower_top = if i < 4 {
                v[i + 1].w(0.0, v[i + 1].canal_y(), 0.5 * v[i + 1].dims.body_height)
            } else {
                sf.to_world(DVec3::new(0.0, -20.0, 0.0))
            };
            let upper_bottom = upper.w(0.0, upper.canal_y(), -0.5 * upper.dims.body_height);
            let mid = 0.5 * (lower_top + upper_bottom);
            let axis = (upper_bottom - lower_top).normalize();
            let back = upper.frame.rotation.y_axis * -1.0;
            let slab = Sdf::Intersect(vec![
                canal.clone().offset(3.5).minus(canal.clone()),
                Sdf::HalfSpace {
                    normal: -back,
                    offset: -back.dot(mid) - 3.0,
                },
                Sdf::RoundBox {
                    half: DVec3::new(18.0, 30.0, 12.0),
                    round: 2.0,
                }
                .placed(Rigid::from_axes(mid, DVec3::X, axis)),
            ]);
            lf.push(slab);
        }
        push(
            "ligamentum_flavum",
            MaterialClass::LigamentumFlavum,
            Sdf::Union(lf),
        );
        // Dural sac: about 18 x 13 mm, in the front of the canal, ending at S2 (our assumption
        // for the section; termination per Macdonald et al. 1999).
        let sac_end = 2 + 5 * 2 + 1; // nodes: top, 5 levels x (centre, half-step), then S1, S2
        let sac_pts: Vec<DVec3> = line[..sac_end.min(n)]
            .iter()
            .enumerate()
            .map(|(i, q)| *q + DVec3::new(0.0, if i + 1 == sac_end { 1.0 } else { 1.8 }, 0.0))
            .collect();
        let m = sac_pts.len();
        let sac_ry: Vec<f64> = (0..m)
            .map(|i| {
                if i + 1 == m {
                    2.5
                } else if i + 2 == m {
                    5.0
                } else {
                    6.5
                }
            })
            .collect();
        let sac_rx: Vec<f64> = sac_ry.iter().map(|r| r * 1.4).collect();
        let sac = sagittal_tube(&sac_pts, &sac_rx, &sac_ry);
        push("dural_sac", MaterialClass::DuraCsf, sac);
        // Conus medullaris: the cord tapering to a tip at the L1-L2 disc (Saifuddin et al. 1998).
        let conus_tip = line[2] + DVec3::new(0.0, 1.8, 0.0);
        let conus_tip = 0.5 * (conus_tip + line[3]) + DVec3::new(0.0, 1.8, 0.0);
        push(
            "conus_medullaris",
            MaterialClass::Nerve,
            Sdf::Tube {
                points: vec![
                    line[0] + DVec3::new(0.0, 1.8, 0.0),
                    line[1] + DVec3::new(0.0, 1.8, 0.0),
                    conus_tip,
                ],
                radii: vec![4.0, 3.8, 1.0],
            },
        );
        // Cauda equina: a bundle in the dorsal half of the sac from the conus to S2.
        let cauda_pts: Vec<DVec3> = sac_pts[2..m - 1]
            .iter()
            .map(|q| *q + DVec3::new(0.0, -2.0, 0.0))
            .collect();
        let cm = cauda_pts.len();
        let cauda_ry: Vec<f64> = (0..cm)
            .map(|i| 3.2 - 1.6 * i as f64 / (cm - 1) as f64)
            .collect();
        let cauda_rx: Vec<f64> = cauda_ry.iter().map(|r| r * 1.8).collect();
        push(
            "cauda_equina",
            MaterialClass::Nerve,
            sagittal_tube(&cauda_pts, &cauda_rx, &cauda_ry),
        );

        // --- Exiting nerve roots L1..L5 (below each pedicle) and S1, S2 (anterior foramina).
        // Root sleeve 1.5 mm radius, dorsal root ganglion 3 mm radius in the foramen (our
        // assumption, DRG 5-7 mm across).
        for vert in &v {
            let d = vert.dims;
            for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
                let zp = vert.pedicle_z() - 0.5 * d.pedicle_height;
                let pts = vec![
                    vert.w(s * 5.0, vert.canal_y() + 3.5, 0.5 * d.body_height - 2.0),
                    vert.w(
                        s * (0.5 * d.canal_width - 2.5),
                        vert.canal_y() + 5.0,
                        zp - 1.0,
                    ),
                    vert.w(
                        s * vert.pedicle_x(),
                        vert.canal_y() + 0.25 * d.canal_depth + 3.0,
                        zp - 5.0,
                    ),
                    vert.w(
                        s * (vert.pedicle_x() + 0.5 * d.pedicle_width + 12.0),
                        2.0 - 0.5 * d.body_depth,
                        zp - 15.0,
                    ),
                    vert.w(
                        s * (vert.pedicle_x() + 0.5 * d.pedicle_width + 24.0),
                        8.0 - 0.5 * d.body_depth,
                        zp - 30.0,
                    ),
                ];
                push(
                    &format!("nerve_root_{}_{side}", d.name),
                    MaterialClass::Nerve,
                    Sdf::Tube {
                        points: pts,
                        radii: vec![1.5, 2.0, 3.0, 2.6, 2.2],
                    },
                );
            }
        }
        let foramina = sacral_foramina();
        for (k, lvl) in ["S1", "S2"].iter().enumerate() {
            for (j, (s, side)) in [(LEFT, "left"), (RIGHT, "right")].into_iter().enumerate() {
                let (a, b, _) = foramina[2 * k + j];
                let inside = sf.to_world(sacral_canal_point(k) + DVec3::new(s * 3.0, 1.0, 8.0));
                let pts = vec![
                    inside,
                    sf.to_world(a),
                    sf.to_world(b),
                    sf.to_world(b + DVec3::new(s * 10.0, 12.0, -12.0)),
                ];
                push(
                    &format!("nerve_root_{lvl}_{side}"),
                    MaterialClass::Nerve,
                    Sdf::Tube {
                        points: pts,
                        radii: vec![1.5, 2.2, 2.2, 2.0],
                    },
                );
            }
        }

        // --- Vessels: aorta (about 18 mm, left of midline) bifurcating at L4 into the common iliac
        // arteries; IVC (right, flattened) formed at L4-L5 from the common iliac veins. Diameters:
        // our assumption within normal adult ranges.
        let fwd =
            |vert: &Placed, x: f64, extra: f64| vert.w(x, 0.5 * vert.dims.body_depth + extra, 0.0);
        let mut ivc_pts = vec![fwd(&v[0], RIGHT * 20.0, 13.0) + DVec3::new(0.0, 0.0, 40.0)];
        ivc_pts.extend(v[..4].iter().map(|q| fwd(q, RIGHT * 20.0, 13.0)));
        let conf = fwd(&v[4], RIGHT * 14.0, 14.0) + DVec3::new(0.0, 0.0, 8.0);
        ivc_pts.push(conf);
        let ivc = Sdf::Union(vec![
            Sdf::Tube {
                points: ivc_pts.clone(),
                radii: vec![10.5; ivc_pts.len()],
            },
            Sdf::Tube {
                points: vec![
                    conf,
                    conf + DVec3::new(RIGHT * 30.0, 8.0, -45.0),
                    conf + DVec3::new(RIGHT * 45.0, 25.0, -110.0),
                ],
                radii: vec![7.5, 7.0, 6.5],
            },
            Sdf::Tube {
                points: vec![
                    conf,
                    conf + DVec3::new(LEFT * 28.0, 0.0, -40.0),
                    conf + DVec3::new(LEFT * 58.0, 22.0, -110.0),
                ],
                radii: vec![7.5, 7.0, 6.5],
            },
        ]);
        push("inferior_vena_cava", MaterialClass::Vessel, ivc);
        let mut ao_pts = vec![fwd(&v[0], LEFT * 14.0, 12.0) + DVec3::new(0.0, 0.0, 40.0)];
        ao_pts.extend(v[..3].iter().map(|q| fwd(q, LEFT * 14.0, 12.0)));
        let bif = fwd(&v[3], LEFT * 6.0, 14.0) + DVec3::new(0.0, 0.0, -4.0);
        ao_pts.push(bif);
        let aorta = Sdf::Union(vec![
            Sdf::Tube {
                points: ao_pts.clone(),
                radii: vec![9.0; ao_pts.len()],
            },
            Sdf::Tube {
                points: vec![
                    bif,
                    bif + DVec3::new(LEFT * 30.0, 8.0, -40.0),
                    bif + DVec3::new(LEFT * 52.0, 30.0, -110.0),
                ],
                radii: vec![5.5, 5.0, 4.5],
            },
            Sdf::Tube {
                points: vec![
                    bif,
                    bif + DVec3::new(RIGHT * 28.0, 12.0, -40.0),
                    bif + DVec3::new(RIGHT * 56.0, 34.0, -110.0),
                ],
                radii: vec![5.5, 5.0, 4.5],
            },
        ]);
        push("aorta", MaterialClass::Vessel, aorta);

        // --- Discs: between adjacent endplates, bulging 1 mm past the bodies.
        let lower_frames: Vec<Placed> = v[1..].iter().copied().chain(std::iter::once(s1)).collect();
        for i in 0..5 {
            let (up, lo) = (&v[i], &lower_frames[i]);
            let top = up.w(0.0, 0.0, -0.5 * up.dims.body_height);
            let bottom = lo.w(0.0, 0.0, 0.5 * lo.dims.body_height);
            let mid_rot = rot_x(0.5 * (up.dims.tilt_deg + lo.dims.tilt_deg));
            let centre = 0.5 * (top + bottom);
            let rx = 0.5 * up.dims.body_width.max(lo.dims.body_width) + 1.0;
            let ry = 0.5 * up.dims.body_depth.max(lo.dims.body_depth) + 1.0;
            let disc = Sdf::Intersect(vec![
                Sdf::EllipticCylinder {
                    rx,
                    ry,
                    half_h: 20.0,
                    round: 0.0,
                }
                .placed(Rigid {
                    rotation: mid_rot,
                    translation: centre,
                }),
                // Between the upper body's inferior endplate and the lower body's superior one,
                // overlapping each by 0.5 mm (bone is painted over the overlap).
                Sdf::HalfSpace {
                    normal: up.up(),
                    offset: up.up().dot(top) + 0.5,
                },
                Sdf::HalfSpace {
                    normal: -lo.up(),
                    offset: -lo.up().dot(bottom) + 0.5,
                },
            ])
            .minus(lumbar_canal(up));
            let lo_name = if i < 4 { lo.dims.name } else { "S1" };
            push(
                &format!("disc_{}_{}", up.dims.name, lo_name),
                MaterialClass::Disc,
                disc,
            );
        }

        // --- Bones: facet joints first (they are shared by two bones).
        let mut joints: Vec<[Joint; 2]> = Vec::new();
        for i in 0..5 {
            let (up, lo) = (&v[i], &lower_frames[i]);
            let make = |s: f64| {
                let (c, n) = facet_joint(up, lo, DISC_HEIGHT_MM[i], FACET_ANGLE_DEG[i], s);
                Joint {
                    centre: c,
                    normal: n,
                    up: (up.up() + lo.up()).normalize(),
                }
            };
            joints.push([make(LEFT), make(RIGHT)]);
        }
        let gap = p.facet_gap_mm;
        let mut bones: Vec<(String, Sdf)> = Vec::new();
        for (i, vert) in v.iter().enumerate() {
            let mut extra = Vec::new();
            let mut keepout = vec![lumbar_canal(vert)];
            for (k, s) in [LEFT, RIGHT].into_iter().enumerate() {
                let jw = vert.frame.to_world(vert.junction(s));
                if i > 0 {
                    // Superior articular process: joint with the vertebra above.
                    let j = &joints[i - 1][k];
                    let block = articular_block(j, -1.0, gap);
                    let stem = Sdf::capsule(
                        jw + vert.up() * 3.0,
                        j.centre - j.normal * (0.5 * gap + 3.0) - j.up * 3.0,
                        4.5,
                    );
                    extra.push(Sdf::SmoothUnion(vec![block, stem], 3.0));
                    keepout.push(joint_keepout(j, 1.0, gap));
                }
                // Inferior articular process: joint with the vertebra (or sacrum) below.
                let j = &joints[i][k];
                let (_, zb) = vert.lamina_z();
                let lam = vert.w(
                    s * 0.5 * vert.dims.canal_width * 0.8,
                    vert.canal_back_y() - 3.0,
                    zb + 6.0,
                );
                let block = articular_block(j, 1.0, gap);
                let stem = Sdf::capsule(
                    lam,
                    j.centre + j.normal * (0.5 * gap + 3.0) + j.up * 3.0,
                    4.0,
                );
                extra.push(Sdf::SmoothUnion(vec![block, stem], 3.0));
                keepout.push(joint_keepout(j, -1.0, gap));
            }
            if i == 0 {
                // L1 superior processes: articulate with T12 above the grid; modelled as plain
                // processes without a partner.
                for s in [LEFT, RIGHT] {
                    let jw = vert.frame.to_world(vert.junction(s));
                    let top = vert.w(
                        s * (0.5 * vert.dims.canal_width + 6.0),
                        vert.canal_y() - 3.0,
                        0.5 * vert.dims.body_height + 6.0,
                    );
                    extra.push(Sdf::capsule(jw, top, 4.5));
                }
            }
            let mut all = vec![lumbar_bone(vert, i == 4)];
            all.extend(extra);
            let bone = Sdf::SmoothUnion(all, 2.0).minus(Sdf::Union(keepout));
            bones.push((vert.dims.name.to_string(), bone));
        }
        // Sacrum with its superior articular processes.
        let mut sac_extra = vec![sacrum_bone(&sf)];
        let mut sac_keep = Vec::new();
        for (k, s) in [LEFT, RIGHT].into_iter().enumerate() {
            let j = &joints[4][k];
            let base = sf.to_world(DVec3::new(s * 22.0, -26.0, -8.0));
            sac_extra.push(articular_block(j, -1.0, gap));
            sac_extra.push(Sdf::capsule(
                base,
                j.centre - j.normal * (0.5 * gap + 3.0) - j.up * 3.0,
                6.0,
            ));
            sac_keep.push(joint_keepout(j, 1.0, gap));
        }
        let sacrum = Sdf::SmoothUnion(sac_extra, 3.0).minus(Sdf::Union(sac_keep));
        // Iliac bones: a bowl-shaped wing (shell of an ellipsoid) with an auricular part against
        // the sacrum and a column towards the acetabulum; the SI joint is kept open by removing the
        // sacrum grown by the joint width (our assumption for all dimensions: inter-crest width
        // about 270 mm, crest at the L4 level).
        let mut ilia = Vec::new();
        for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
            // Wing: the shell of an ellipsoid centred lateral to the sacrum, cut to the arc that
            // runs from the posterior superior iliac spine round to the anterior superior spine.
            let crest_z = v[3].frame.translation.z + 2.0;
            let c = DVec3::new(s * 50.0, -5.0, crest_z);
            let outer = Sdf::Ellipsoid {
                radii: DVec3::new(80.0, 62.0, 150.0),
            }
            .at(c);
            let shell = outer.clone().minus(outer.offset(-5.0));
            let l = (1.0f64 + 0.81).sqrt();
            let wing = Sdf::Intersect(vec![
                shell,
                Sdf::HalfSpace {
                    normal: DVec3::new(-s, 0.0, 0.0),
                    offset: -28.0,
                },
                // Open in front of the sacral ala: the medial edge moves laterally going forwards.
                Sdf::HalfSpace {
                    normal: DVec3::new(-s / l, 0.9 / l, 0.0),
                    offset: -23.5 / l,
                },
                Sdf::HalfSpace {
                    normal: DVec3::Y,
                    offset: 55.0,
                },
            ]);
            // Iliac crest: a thickened rim along the top of the wing.
            let crest_pts: Vec<DVec3> = (0..=10)
                .map(|k| {
                    let t = -1.75 + 2.9 * f64::from(k) / 10.0;
                    DVec3::new(
                        c.x + s * 76.5 * t.cos(),
                        c.y + 59.0 * t.sin(),
                        crest_z - 3.0,
                    )
                })
                .filter(|q| q.y <= 55.0 && s * q.x >= 28.0)
                .collect();
            let crest = Sdf::Tube {
                radii: vec![6.0; crest_pts.len()],
                points: crest_pts,
            };
            let wing = Sdf::Intersect(vec![
                Sdf::SmoothUnion(vec![wing, crest], 4.0),
                Sdf::HalfSpace {
                    normal: DVec3::Z,
                    offset: crest_z + 3.0,
                },
            ]);
            let auricular = Sdf::Ellipsoid {
                radii: DVec3::new(20.0, 24.0, 32.0),
            }
            .at(sf.to_world(DVec3::new(s * 62.0, -18.0, -35.0)));
            let psis = Sdf::Ellipsoid {
                radii: DVec3::new(14.0, 14.0, 22.0),
            }
            .at(sf.to_world(DVec3::new(s * 52.0, -46.0, -30.0)));
            // Body of the ilium down towards the acetabulum (femoral heads lie about level with
            // the L3 body in y in adult CT; our assumption from the TotalSegmentator example).
            let column_top = sf.to_world(DVec3::new(s * 62.0, -10.0, -40.0));
            let column = Sdf::cone(column_top, 11.0, DVec3::new(s * 88.0, -5.0, -240.0), 15.0);
            let ilium = Sdf::SmoothUnion(vec![wing, auricular, psis, column], 10.0)
                .minus(sacrum.clone().offset(p.si_gap_mm));
            ilia.push((format!("ilium_{side}"), ilium));
        }
        bones.push(("sacrum".to_string(), sacrum));
        bones.extend(ilia);
        let t = p.cortical_thickness_mm;
        for (name, bone) in bones {
            // Clipped before the cortex/marrow split, so the cortex covers the cut as well.
            let bone = Sdf::Intersect(vec![bone, under_skin.clone()]);
            push(
                &format!("{name}_cortical"),
                MaterialClass::CorticalBone,
                bone.clone(),
            );
            push(
                &format!("{name}_cancellous"),
                MaterialClass::Cancellous,
                bone.offset(-t),
            );
        }

        // --- Landmarks.
        let l4 = &v[3];
        let l5 = &v[4];
        let mut add = |name: &str, pos: DVec3, description: &str, inside: Option<&str>| {
            landmarks.push(Landmark {
                name: name.to_string(),
                position_mm: pos.to_array(),
                description: description.to_string(),
                inside_structure: inside.map(str::to_string),
            });
        };
        for (i, vert) in v.iter().enumerate() {
            add(
                &format!("{}_body_centre", vert.dims.name),
                vert.frame.translation,
                "centre of the vertebral body",
                Some(&format!("{}_cancellous", vert.dims.name)),
            );
            if i < 4 {
                let lo = &v[i + 1];
                let (_, zb) = vert.lamina_z();
                let (zt, _) = lo.lamina_z();
                let a = vert.w(0.0, vert.canal_back_y(), zb);
                let b = lo.w(0.0, lo.canal_back_y(), zt);
                add(
                    &format!(
                        "{}_{}_interlaminar_window_centre",
                        vert.dims.name, lo.dims.name
                    ),
                    0.5 * (a + b) + vert.frame.rotation.y_axis * -2.5,
                    "midline centre of the interlaminar window, in the ligamentum flavum",
                    Some("ligamentum_flavum"),
                );
                add(
                    &format!(
                        "{}_{}_posterior_epidural_space",
                        vert.dims.name, lo.dims.name
                    ),
                    0.5 * (a + b) + vert.frame.rotation.y_axis * 1.5,
                    "midline posterior epidural space just in front of the ligamentum flavum",
                    Some("epidural_space"),
                );
            }
        }
        let l5s1 = [joints[4][0], joints[4][1]];
        add(
            "L5_S1_facet_joint_left",
            l5s1[0].centre,
            "centre of the left L5-S1 facet joint space",
            None,
        );
        add(
            "L5_S1_facet_joint_right",
            l5s1[1].centre,
            "centre of the right L5-S1 facet joint space",
            None,
        );
        add(
            "L4_L5_facet_joint_left",
            joints[3][0].centre,
            "centre of the left L4-L5 facet joint space",
            None,
        );
        add(
            "L4_L5_facet_joint_right",
            joints[3][1].centre,
            "centre of the right L4-L5 facet joint space",
            None,
        );
        for (k, side) in [(0, "left"), (1, "right")] {
            let (a, b, _) = foramina[k];
            add(
                &format!("S1_anterior_foramen_{side}"),
                sf.to_world(0.5 * (a + b)),
                "middle of the S1 anterior sacral foramen",
                None,
            );
        }
        // Transforaminal target: the "safe triangle" just below the 6 o'clock position of the L4
        // pedicle, posterolateral to the exiting L4 root.
        let d4 = l4.dims;
        let zp = l4.pedicle_z() - 0.5 * d4.pedicle_height;
        add(
            "L4_transforaminal_target_left",
            l4.w(LEFT * (l4.pedicle_x() + 2.0), l4.canal_y() - 0.5, zp - 3.0),
            "left L4 transforaminal target below the pedicle (safe triangle)",
            None,
        );
        add(
            "L4_transforaminal_target_right",
            l4.w(RIGHT * (l4.pedicle_x() + 2.0), l4.canal_y() - 0.5, zp - 3.0),
            "right L4 transforaminal target below the pedicle (safe triangle)",
            None,
        );
        let hiatus = sf.to_world(sacral_canal_point(4) + DVec3::new(0.0, -4.0, 0.0));
        add(
            "sacral_hiatus",
            hiatus,
            "sacral hiatus opening at S4-S5 (caudal epidural entry)",
            None,
        );
        add(
            "L5_spinous_tip",
            l5.w(
                0.0,
                l5.canal_back_y() - l5.dims.sp_length - 0.5,
                0.5 * (l5.lamina_z().0 + l5.lamina_z().1) - 6.0,
            ),
            "tip of the L5 spinous process, half a millimetre inside the bone",
            None,
        );
        Anatomy { parts, landmarks }
    }
}
