//! Where each lumbar level's parts are meant to be, for measuring the built meshes
//! ([`crate::anatomy::phantom::morphometry`]): the measurements aim their rays with these points
//! and read every value from the meshes, so a shape that misses its intended dimension shows.

use glam::DVec3;

use super::dims::{LEFT, RIGHT};
use super::spine::{Placed, Spine};

/// A level's frame and aiming points (model frame, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct LevelFrame {
    /// `L1`..`L5`, or `S1` (the sacral base, for lordosis).
    pub name: String,
    /// Body centre (midway between the endplates, mid-sagittal).
    pub centre_mm: DVec3,
    /// Unit axes of the body: patient right, anterior, cranial (along the body's axis).
    pub right: DVec3,
    /// Anterior unit axis.
    pub anterior: DVec3,
    /// Cranial unit axis.
    pub up: DVec3,
    /// Intended body height and depth, mm (only to place the aiming points inside the body).
    pub body_height_mm: f64,
    /// Intended endplate depth, mm.
    pub body_depth_mm: f64,
    /// Centre of the canal at pedicle height.
    pub canal_centre_mm: DVec3,
    /// Pedicle isthmus centre, left then right.
    pub pedicle_centre_mm: [DVec3; 2],
    /// Unit axis of each pedicle, from the lamina junction towards the body.
    pub pedicle_axis: [DVec3; 2],
    /// A mid-sagittal point at the height and depth of the transverse processes' roots.
    pub transverse_level_mm: DVec3,
}

fn frame_of(v: &Placed) -> LevelFrame {
    let d = v.dims;
    let pedicle = |s: f64| {
        let j = v.junction(s);
        let a = DVec3::new(
            s * (v.pedicle_x() - 2.0),
            -0.5 * d.body_depth + 5.0,
            v.pedicle_z(),
        );
        // The isthmus: a third of the way from the body to the lamina junction, in front of the
        // articular processes that rise from the junction.
        (
            v.frame.to_world(a + 0.35 * (j - a)),
            v.frame.rotation * (a - j).normalize(),
        )
    };
    let (pl, al) = pedicle(LEFT);
    let (pr, ar) = pedicle(RIGHT);
    let j = v.junction(RIGHT);
    LevelFrame {
        name: d.name.to_string(),
        centre_mm: v.frame.translation,
        right: v.frame.rotation.x_axis,
        anterior: v.frame.rotation.y_axis,
        up: v.frame.rotation.z_axis,
        body_height_mm: d.body_height,
        body_depth_mm: d.body_depth,
        canal_centre_mm: v.w(0.0, v.canal_y(), v.pedicle_z()),
        pedicle_centre_mm: [pl, pr],
        pedicle_axis: [al, ar],
        transverse_level_mm: v.w(0.0, j.y + 1.0, v.pedicle_z() - 1.0),
    }
}

/// L1..L5 then S1.
pub(super) fn level_frames(spine: &Spine) -> Vec<LevelFrame> {
    spine
        .lumbar
        .iter()
        .chain(spine.below.last())
        .map(frame_of)
        .collect()
}
