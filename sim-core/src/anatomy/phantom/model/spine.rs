//! The placed skeleton: each vertebra's frame along the lordotic curve, the sacral frame and the
//! facet joints of every motion segment, which every part of the model is built around.

use glam::{DMat3, DVec3};

use super::dims::{DISC_HEIGHT_MM, FACET_ANGLE_DEG, LEFT, LUMBAR, LevelDims, RIGHT, S1};
use crate::anatomy::phantom::sdf::Rigid;

/// A placed vertebra: its frame (origin at the body centre) and dimensions.
#[derive(Debug, Clone, Copy)]
pub(super) struct Placed {
    pub(super) dims: LevelDims,
    pub(super) frame: Rigid,
}

impl Placed {
    pub(super) fn w(&self, x: f64, y: f64, z: f64) -> DVec3 {
        self.frame.to_world(DVec3::new(x, y, z))
    }
    pub(super) fn up(&self) -> DVec3 {
        self.frame.rotation.z_axis
    }
    /// Canal centre y (local).
    pub(super) fn canal_y(&self) -> f64 {
        -0.5 * self.dims.body_depth - 0.5 * self.dims.canal_depth
    }
    /// Pedicle centre height (local z): the pedicle sits in the upper part of the body.
    pub(super) fn pedicle_z(&self) -> f64 {
        0.5 * self.dims.body_height - 0.5 * self.dims.pedicle_height - 1.5
    }
    /// Pedicle isthmus centre x (left side; mirror for right).
    pub(super) fn pedicle_x(&self) -> f64 {
        0.5 * self.dims.canal_width + 0.5 * self.dims.pedicle_width
    }
    /// The pedicle-lamina junction (local), side `s` ([`LEFT`] or [`RIGHT`]).
    pub(super) fn junction(&self, s: f64) -> DVec3 {
        let d = self.dims;
        let len = 0.8 * d.canal_depth + 4.0;
        let x = self.pedicle_x() + 0.5 * len * d.pedicle_angle_deg.to_radians().tan();
        DVec3::new(
            s * x,
            -0.5 * d.body_depth - 0.8 * d.canal_depth,
            self.pedicle_z(),
        )
    }
    /// Lamina top and bottom heights (local z): the laminae shingle, the upper border at the
    /// pedicles' mid-height and the lower one 3 mm below the inferior endplate's level, which
    /// leaves the interlaminar window open in AP (our assumption after radiographic anatomy).
    pub(super) fn lamina_z(&self) -> (f64, f64) {
        let d = self.dims;
        (self.pedicle_z(), -0.5 * d.body_height - 3.0)
    }
    /// The spinous process (local): as tall as the laminae it rises from (at most `sp_height`),
    /// centred on them, so the interspinous gap of a motion segment stays open in AP over the
    /// interlaminar window (our assumption after radiographic anatomy); its tip `sp_length`
    /// behind the canal and 3 mm lower than its root.
    pub(super) fn spinous(&self) -> Spinous {
        let d = self.dims;
        let (zt, zb) = self.lamina_z();
        let half_height = (0.5 * d.sp_height).min(0.5 * (zt - zb));
        let zc = 0.5 * (zt + zb);
        Spinous {
            root: DVec3::new(0.0, self.canal_back_y() - 2.0, zc),
            tip: DVec3::new(0.0, self.canal_back_y() - d.sp_length, zc - 3.0),
            half_height,
        }
    }
    /// Posterior canal wall y (local).
    pub(super) fn canal_back_y(&self) -> f64 {
        -0.5 * self.dims.body_depth - self.dims.canal_depth
    }
}

/// A spinous process in its vertebra's frame (mm).
#[derive(Debug, Clone, Copy)]
pub(super) struct Spinous {
    /// Centre of its root at the laminae.
    pub(super) root: DVec3,
    /// Centre of its tip.
    pub(super) tip: DVec3,
    /// Half of its height.
    pub(super) half_height: f64,
}

pub(super) fn rot_x(deg: f64) -> DMat3 {
    // Rotation about x that tilts +z towards +y by `deg`.
    DMat3::from_rotation_x(-deg.to_radians())
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
pub(super) struct Spine {
    /// L1..L5.
    pub(super) lumbar: Vec<Placed>,
    /// The lower vertebra of each motion segment L1-L2 .. L5-S1: L2..L5, then S1.
    pub(super) below: Vec<Placed>,
    /// The sacral frame (see [`sacral_frame`]).
    pub(super) sacral: Rigid,
    /// Left and right facet joints of each motion segment L1-L2 .. L5-S1.
    pub(super) facets: Vec<[Joint; 2]>,
}

impl Spine {
    pub(super) fn new() -> Spine {
        let (lumbar, s1) = place_spine();
        let below: Vec<Placed> = lumbar[1..]
            .iter()
            .copied()
            .chain(std::iter::once(s1))
            .collect();
        let facets = facet_joints(&lumbar, &below);
        Spine {
            sacral: sacral_frame(&s1),
            lumbar,
            below,
            facets,
        }
    }
}

/// Sacral frame: origin at the centre of the S1 superior endplate, z along its normal.
pub(super) fn sacral_frame(s1: &Placed) -> Rigid {
    Rigid {
        rotation: s1.frame.rotation,
        translation: s1.w(0.0, 0.0, 0.5 * s1.dims.body_height),
    }
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
pub(super) struct Joint {
    pub(super) centre: DVec3,
    pub(super) normal: DVec3,
    pub(super) up: DVec3,
}

/// Both facet joints (left, right) of each motion segment L1-L2 .. L5-S1; `below[i]` is the lower
/// vertebra of segment `i` (S1 for the last).
pub(super) fn facet_joints(v: &[Placed], below: &[Placed]) -> Vec<[Joint; 2]> {
    let mut joints: Vec<[Joint; 2]> = Vec::new();
    for i in 0..5 {
        let (up, lo) = (&v[i], &below[i]);
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
    joints
}
