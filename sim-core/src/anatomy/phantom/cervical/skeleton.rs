//! The placed cervical skeleton: every vertebra's frame along the lordotic curve, the facet
//! joints, the atlas frame and the course of the vertebral arteries.

use glam::{DMat3, DVec3};

use super::dims::{
    DISC_MM, FACET_INCLINATION_DEG, LEVELS, Level, PILLAR_HALF_DEPTH_MM, PILLAR_HALF_WIDTH_MM,
};
use crate::anatomy::phantom::model::{LEFT, RIGHT};
use crate::anatomy::phantom::sdf::Rigid;

/// Index of C5 in [`LEVELS`]: the model frame's origin is the C5 body centre.
const ORIGIN_LEVEL: usize = 3;

/// A placed vertebra C2..T1: its frame (origin at the body centre) and dimensions.
#[derive(Debug, Clone, Copy)]
pub(super) struct Vert {
    pub(super) d: Level,
    pub(super) frame: Rigid,
}

impl Vert {
    /// Local point to world.
    pub(super) fn w(&self, x: f64, y: f64, z: f64) -> DVec3 {
        self.frame.to_world(DVec3::new(x, y, z))
    }
    /// The body axis (cranial).
    pub(super) fn up(&self) -> DVec3 {
        self.frame.rotation.z_axis
    }
    /// The anterior direction of the vertebra.
    pub(super) fn front(&self) -> DVec3 {
        self.frame.rotation.y_axis
    }
    /// Canal centre y (local).
    pub(super) fn canal_y(&self) -> f64 {
        -0.5 * self.d.body_depth - 0.5 * self.d.canal_depth
    }
    /// Posterior canal wall y (local).
    pub(super) fn canal_back_y(&self) -> f64 {
        -0.5 * self.d.body_depth - self.d.canal_depth
    }
    /// Articular pillar centre x (right side; mirror for left): lateral to the canal.
    pub(super) fn pillar_x(&self) -> f64 {
        0.5 * self.d.canal_width + PILLAR_HALF_WIDTH_MM - 1.0
    }
    /// Articular pillar centre y (local): level with the back half of the canal.
    pub(super) fn pillar_y(&self) -> f64 {
        self.canal_y() - 1.0
    }
    /// Pedicle and transverse-process height (local z).
    pub(super) fn pedicle_z(&self) -> f64 {
        0.5 * self.d.body_height - 0.5 * self.d.pedicle_height - 1.0
    }
    /// Foramen transversarium centre (local), side `s`: lateral to the pedicle, level with the
    /// back of the body (Taitz et al. 1978 put the foramina about 28-30 mm apart); C2's is in the
    /// lower part of its L-shaped tunnel, which turns out under the superior articular facet.
    pub(super) fn foramen(&self, s: f64) -> DVec3 {
        let dz = if self.d.name == "C2" { -2.5 } else { 0.0 };
        DVec3::new(
            s * (0.5 * self.d.canal_width + 2.5),
            -0.5 * self.d.body_depth + 2.5,
            self.pedicle_z() + dz,
        )
    }
    /// Lamina centre height (local z).
    pub(super) fn lamina_z(&self) -> f64 {
        -1.5
    }
}

/// Rotation about x that tilts +z towards +y by `deg`.
pub(super) fn rot_x(deg: f64) -> DMat3 {
    DMat3::from_rotation_x(-deg.to_radians())
}

/// The atlas frame: origin on the dens axis at the mid-height of the lateral masses.
#[derive(Debug, Clone, Copy)]
pub(super) struct Atlas {
    pub(super) frame: Rigid,
}

impl Atlas {
    pub(super) fn w(&self, x: f64, y: f64, z: f64) -> DVec3 {
        self.frame.to_world(DVec3::new(x, y, z))
    }
    /// Lateral mass centre x and y (local) and half-extents: 13 x 17 x 14 mm (our choice after
    /// Doherty and Heggeness 1994).
    pub(super) const MASS_X: f64 = 18.5;
    pub(super) const MASS_Y: f64 = -1.0;
    pub(super) const MASS_HALF: DVec3 = DVec3::new(6.5, 8.5, 7.0);
    /// Foramen transversarium (local), side `s`.
    pub(super) fn foramen(&self, s: f64) -> DVec3 {
        DVec3::new(s * 29.0, -2.0, 0.0)
    }
}

/// One facet joint: centre and unit normal pointing from the lower vertebra's superior
/// articular facet to the upper one's inferior facet (upwards and backwards).
#[derive(Debug, Clone, Copy)]
pub(super) struct Joint {
    pub(super) centre: DVec3,
    pub(super) normal: DVec3,
}

/// The whole placed skeleton.
pub(super) struct Skeleton {
    /// C2..T1.
    pub(super) verts: Vec<Vert>,
    pub(super) atlas: Atlas,
    /// Facet joints C2-C3 .. C7-T1, `[left, right]`.
    pub(super) facets: Vec<[Joint; 2]>,
    /// Atlanto-axial (C1-C2 lateral) joints, `[left, right]`: horizontal in the C2 frame.
    pub(super) atlanto_axial: [Joint; 2],
}

/// The C1-C2 joint level above the C2 body centre (local z of C2), mm (our choice).
pub(super) fn c2_joint_z(c2: &Vert) -> f64 {
    0.5 * c2.d.body_height + 0.5
}

impl Skeleton {
    pub(super) fn new(gap_mm: f64) -> Skeleton {
        let verts = place();
        let facets = (0..verts.len() - 1)
            .map(|i| [LEFT, RIGHT].map(|s| facet(&verts[i], &verts[i + 1], i, s)))
            .collect();
        let c2 = verts[0];
        let zj = c2_joint_z(&c2);
        let atlas = Atlas {
            frame: Rigid {
                rotation: c2.frame.rotation,
                translation: c2.w(0.0, 1.0, zj + 0.5 * gap_mm + Atlas::MASS_HALF.z),
            },
        };
        let atlanto_axial = [LEFT, RIGHT].map(|s| Joint {
            centre: c2.w(s * Atlas::MASS_X, Atlas::MASS_Y + 1.0, zj + 0.5 * gap_mm),
            normal: c2.up(),
        });
        Skeleton {
            verts,
            atlas,
            facets,
            atlanto_axial,
        }
    }

    /// Centre-line of the vertebral artery of side `s`: anterior to the C7 transverse process,
    /// through the foramina transversaria C6..C1 (Bruneau et al. 2006: entry at C6), then over the
    /// posterior arch of the atlas towards the foramen magnum, leaving the grid above and below.
    pub(super) fn vertebral_artery(&self, s: f64) -> Vec<DVec3> {
        let v = &self.verts;
        let t1 = &v[6];
        let c7 = &v[5];
        let c2 = &v[0];
        let mut pts = Vec::new();
        let f7 = c7.foramen(s);
        // From the subclavian artery below the grid, in front of T1's and C7's transverse processes.
        pts.push(t1.w(f7.x, f7.y + 10.0, -40.0));
        pts.push(t1.w(f7.x, f7.y + 9.0, 0.0));
        pts.push(c7.w(f7.x, f7.y + 8.0, f7.z));
        for vert in v[1..5].iter().rev() {
            let f = vert.foramen(s);
            pts.push(vert.w(f.x, f.y, f.z));
        }
        // C2: up through the body's side, then out laterally under the superior facet.
        let f2 = c2.foramen(s);
        pts.push(c2.w(f2.x, f2.y, f2.z));
        pts.push(c2.w(f2.x, f2.y, f2.z + 4.5));
        pts.push(c2.w(f2.x + s * 5.0, f2.y, c2_joint_z(c2) - 2.5));
        let a = &self.atlas;
        let fa = a.foramen(s);
        pts.push(a.w(fa.x, fa.y, fa.z - 9.0));
        pts.push(a.w(fa.x, fa.y, fa.z));
        pts.push(a.w(fa.x, fa.y, fa.z + 6.0));
        // The sulcus on the posterior arch, then up into the skull (above the grid).
        pts.push(a.w(s * 24.0, -14.0, 9.0));
        pts.push(a.w(s * 14.0, -22.0, 10.0));
        pts.push(a.w(s * 8.0, -18.0, 40.0));
        pts
    }
}

/// Places C2..T1 along the lordotic curve, C5 at the origin.
fn place() -> Vec<Vert> {
    let n = LEVELS.len();
    let mut out: Vec<Option<Vert>> = vec![None; n];
    out[ORIGIN_LEVEL] = Some(Vert {
        d: LEVELS[ORIGIN_LEVEL],
        frame: Rigid {
            rotation: rot_x(LEVELS[ORIGIN_LEVEL].tilt_deg),
            translation: DVec3::ZERO,
        },
    });
    for i in (0..ORIGIN_LEVEL).rev() {
        let lower = out[i + 1].expect("placed");
        let d = LEVELS[i];
        let top = lower.w(0.0, 0.0, 0.5 * lower.d.body_height);
        let mid = rot_x(0.5 * (d.tilt_deg + lower.d.tilt_deg));
        let bottom = top + mid * DVec3::new(0.0, 0.0, DISC_MM[i]);
        let rot = rot_x(d.tilt_deg);
        out[i] = Some(Vert {
            d,
            frame: Rigid {
                rotation: rot,
                translation: bottom + rot * DVec3::new(0.0, 0.0, 0.5 * d.body_height),
            },
        });
    }
    for i in ORIGIN_LEVEL + 1..n {
        let upper = out[i - 1].expect("placed");
        let d = LEVELS[i];
        let bottom = upper.w(0.0, 0.0, -0.5 * upper.d.body_height);
        let mid = rot_x(0.5 * (d.tilt_deg + upper.d.tilt_deg));
        let top = bottom - mid * DVec3::new(0.0, 0.0, DISC_MM[i - 1]);
        let rot = rot_x(d.tilt_deg);
        out[i] = Some(Vert {
            d,
            frame: Rigid {
                rotation: rot,
                translation: top - rot * DVec3::new(0.0, 0.0, 0.5 * d.body_height),
            },
        });
    }
    out.into_iter().map(|v| v.expect("placed")).collect()
}

/// The facet joint of segment `i` (between `up` and `lo`) on side `s`: centred between the two
/// pillars at the disc level, inclined [`FACET_INCLINATION_DEG`] to the axial plane of the
/// segment, its normal pointing up and back.
fn facet(up: &Vert, lo: &Vert, i: usize, s: f64) -> Joint {
    let half_disc = 0.5 * DISC_MM[i];
    let a = up.w(
        s * up.pillar_x(),
        up.pillar_y(),
        -0.5 * up.d.body_height - half_disc,
    );
    let b = lo.w(
        s * lo.pillar_x(),
        lo.pillar_y(),
        0.5 * lo.d.body_height + half_disc,
    );
    let t = FACET_INCLINATION_DEG[i].to_radians();
    let rot = rot_x(0.5 * (up.d.tilt_deg + lo.d.tilt_deg));
    Joint {
        centre: 0.5 * (a + b),
        normal: (rot * DVec3::new(0.0, -t.sin(), t.cos())).normalize(),
    }
}

/// Half-depth of the pillar column used by the bones (re-exported for the landmarks).
pub(super) const PILLAR_HALF: DVec3 = DVec3::new(PILLAR_HALF_WIDTH_MM, PILLAR_HALF_DEPTH_MM, 16.0);
