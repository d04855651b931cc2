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

mod canal;
mod landmarks;
mod sacrum;
mod soft_tissue;
mod vertebra;

use vertebra::Joint;

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

/// The placed skeleton every part is built around.
struct Spine {
    /// L1..L5.
    lumbar: Vec<Placed>,
    /// The lower vertebra of each motion segment L1-L2 .. L5-S1: L2..L5, then S1.
    below: Vec<Placed>,
    /// The sacral frame (see [`sacrum::sacral_frame`]).
    sacral: Rigid,
    /// Left and right facet joints of each motion segment L1-L2 .. L5-S1.
    facets: Vec<[Joint; 2]>,
}

impl Spine {
    fn new() -> Spine {
        let (lumbar, s1) = place_spine();
        let below: Vec<Placed> = lumbar[1..]
            .iter()
            .copied()
            .chain(std::iter::once(s1))
            .collect();
        let facets = vertebra::facet_joints(&lumbar, &below);
        Spine {
            sacral: sacrum::sacral_frame(&s1),
            lumbar,
            below,
            facets,
        }
    }
}

/// The parts list under construction, in painting order.
#[derive(Default)]
struct Parts(Vec<PhantomPart>);

impl Parts {
    fn push(&mut self, name: &str, material: MaterialClass, sdf: Sdf) {
        // The two envelope solids that contain everything are meshed whole (nested): their
        // exclusive parts would be a thin shell (skin) and a surface wrapped round every organ
        // (deep soft tissue), both slow to mesh and of no use to a renderer that nests.
        let nested = name == "skin" || name == "deep_soft_tissue";
        self.0.push(PhantomPart {
            name: name.to_string(),
            material,
            sdf,
            nested,
        });
    }
}

/// Pushes every bone (L1..L5, sacrum, left and right ilium) as its cortical solid followed by its
/// cancellous inset, each clipped to `under_skin` before the split so the cortex covers the cut
/// as well.
fn push_bones(parts: &mut Parts, spine: &Spine, p: &AnatomyParams, under_skin: &Sdf) {
    let gap = p.facet_gap_mm;
    let mut bones: Vec<(String, Sdf)> = spine
        .lumbar
        .iter()
        .enumerate()
        .map(|(i, vert)| {
            let bone = vertebra::lumbar_vertebra(spine, i, gap);
            (vert.dims.name.to_string(), bone)
        })
        .collect();
    let sacrum = sacrum::sacrum_with_processes(spine, gap);
    let ilia: Vec<(String, Sdf)> = [(LEFT, "left"), (RIGHT, "right")]
        .into_iter()
        .map(|(s, side)| {
            let ilium = sacrum::ilium(spine, &sacrum, s, p.si_gap_mm);
            (format!("ilium_{side}"), ilium)
        })
        .collect();
    bones.push(("sacrum".to_string(), sacrum));
    bones.extend(ilia);
    let t = p.cortical_thickness_mm;
    for (name, bone) in bones {
        let bone = Sdf::Intersect(vec![bone, under_skin.clone()]);
        parts.push(
            &format!("{name}_cortical"),
            MaterialClass::CorticalBone,
            bone.clone(),
        );
        parts.push(
            &format!("{name}_cancellous"),
            MaterialClass::Cancellous,
            bone.offset(-t),
        );
    }
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

    /// Builds the default lumbosacral phantom: the body envelope, muscles, canal contents, nerve
    /// roots, vessels, discs and bones, in painting order (see the module docs), and the
    /// landmarks.
    pub fn new(p: &AnatomyParams) -> Anatomy {
        let spine = Spine::new();
        let mut parts = Parts::default();
        let under_skin = soft_tissue::push_envelope(&mut parts, p);
        soft_tissue::push_muscles(&mut parts, &spine, &under_skin);
        canal::push_canal_contents(&mut parts, &spine);
        canal::push_nerve_roots(&mut parts, &spine);
        soft_tissue::push_vessels(&mut parts, &spine.lumbar);
        vertebra::push_discs(&mut parts, &spine);
        push_bones(&mut parts, &spine, p, &under_skin);
        Anatomy {
            parts: parts.0,
            landmarks: landmarks::landmarks(&spine),
        }
    }
}
