//! The named landmarks of the phantom: body centres, interlaminar windows, facet joints, foramina
//! and injection targets.

use glam::DVec3;
use serde::{Deserialize, Serialize};

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

use super::dims::{LEFT, RIGHT};
use super::sacrum::{sacral_canal_point, sacral_foramina};
use super::spine::Spine;

/// How far along the joint line from a facet joint's centre its posterior opening lies, mm: the
/// articular face's 7 mm half-length less 1.5 mm (inside the face's end, within the space).
const JOINT_HALF_LENGTH_IN_MM: f64 = 5.5;
/// How far below a facet joint's centre its inferior recess lies, mm: the face's 8 mm half-height
/// less 1.5 mm.
const JOINT_HALF_HEIGHT_IN_MM: f64 = 6.5;

/// Collects landmarks in order.
#[derive(Default)]
struct Landmarks(Vec<Landmark>);

impl Landmarks {
    fn add(&mut self, name: &str, pos: DVec3, description: &str, inside: Option<&str>) {
        self.0.push(Landmark {
            name: name.to_string(),
            position_mm: pos.to_array(),
            description: description.to_string(),
            inside_structure: inside.map(str::to_string),
        });
    }
}

/// All landmarks: per lumbar level first, then joints, foramina and targets.
pub(super) fn landmarks(spine: &Spine) -> Vec<Landmark> {
    let mut out = Landmarks::default();
    level_landmarks(&mut out, spine);
    joint_and_target_landmarks(&mut out, spine);
    pedicle_landmarks(&mut out, spine);
    out.0
}

/// The isthmus centre of every lumbar pedicle (where the AP view shows its "eye").
fn pedicle_landmarks(out: &mut Landmarks, spine: &Spine) {
    for f in super::frames::level_frames(spine).iter().take(5) {
        for (c, side) in f.pedicle_centre_mm.iter().zip(["left", "right"]) {
            out.add(
                &format!("{}_pedicle_{side}", f.name),
                *c,
                "isthmus centre of the pedicle",
                None,
            );
        }
    }
}

/// Body centre of each lumbar vertebra and, for each lumbar interspace, the interlaminar window
/// centre and the posterior epidural space in front of it.
fn level_landmarks(out: &mut Landmarks, spine: &Spine) {
    let v = &spine.lumbar;
    for (i, vert) in v.iter().enumerate() {
        out.add(
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
            out.add(
                &format!(
                    "{}_{}_interlaminar_window_centre",
                    vert.dims.name, lo.dims.name
                ),
                0.5 * (a + b) + vert.frame.rotation.y_axis * -2.5,
                "midline centre of the interlaminar window, in the ligamentum flavum",
                Some("ligamentum_flavum"),
            );
            out.add(
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
}

/// L5-S1 and L4-L5 facet joint centres, S1 anterior foramina, L4 transforaminal targets, the
/// sacral hiatus and the L5 spinous tip.
fn joint_and_target_landmarks(out: &mut Landmarks, spine: &Spine) {
    let joints = &spine.facets;
    let sf = &spine.sacral;
    let l4 = &spine.lumbar[3];
    let l5 = &spine.lumbar[4];
    let l5s1 = [joints[4][0], joints[4][1]];
    out.add(
        "L5_S1_facet_joint_left",
        l5s1[0].centre,
        "centre of the left L5-S1 facet joint space",
        None,
    );
    out.add(
        "L5_S1_facet_joint_right",
        l5s1[1].centre,
        "centre of the right L5-S1 facet joint space",
        None,
    );
    out.add(
        "L4_L5_facet_joint_left",
        joints[3][0].centre,
        "centre of the left L4-L5 facet joint space",
        None,
    );
    out.add(
        "L4_L5_facet_joint_right",
        joints[3][1].centre,
        "centre of the right L4-L5 facet joint space",
        None,
    );
    // The joint's margins in its plane, where facet injections aim: the posterior opening (the
    // joint line an ultrasound transverse view shows) and the inferior recess (the capsule's
    // lower pouch, the usual fluoroscopic entry into the joint). The articular faces are 14 mm
    // along the joint line and 16 mm tall with 2.5 mm rounded edges (`vertebra::articular_block`);
    // the points lie in the joint space 1.5 mm inside the faces' ends.
    for (segment, level) in [(3, "L4_L5"), (4, "L5_S1")] {
        for (k, side) in [(0, "left"), (1, "right")] {
            let j = &joints[segment][k];
            let along = j.up.cross(j.normal).normalize();
            let posterior = if along.y < 0.0 { along } else { -along };
            out.add(
                &format!("{level}_facet_posterior_joint_line_{side}"),
                j.centre + posterior * JOINT_HALF_LENGTH_IN_MM,
                "posterior opening of the facet joint space (the joint line of a transverse view)",
                None,
            );
            out.add(
                &format!("{level}_facet_inferior_recess_{side}"),
                j.centre - j.up * JOINT_HALF_HEIGHT_IN_MM,
                "inferior recess of the facet joint space (the entry of an intra-articular needle)",
                None,
            );
        }
    }
    let foramina = sacral_foramina();
    for (k, side) in [(0, "left"), (1, "right")] {
        let (a, b, _) = foramina[k];
        out.add(
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
    out.add(
        "L4_transforaminal_target_left",
        l4.w(LEFT * (l4.pedicle_x() + 2.0), l4.canal_y() - 0.5, zp - 3.0),
        "left L4 transforaminal target below the pedicle (safe triangle)",
        None,
    );
    out.add(
        "L4_transforaminal_target_right",
        l4.w(RIGHT * (l4.pedicle_x() + 2.0), l4.canal_y() - 0.5, zp - 3.0),
        "right L4 transforaminal target below the pedicle (safe triangle)",
        None,
    );
    let hiatus = sf.to_world(sacral_canal_point(4) + DVec3::new(0.0, -4.0, 0.0));
    out.add(
        "sacral_hiatus",
        hiatus,
        "sacral hiatus opening at S4-S5 (caudal epidural entry)",
        None,
    );
    out.add(
        "L5_spinous_tip",
        {
            let sp = l5.spinous();
            l5.w(0.0, sp.tip.y - 0.5, sp.tip.z)
        },
        "tip of the L5 spinous process, half a millimetre inside the bone",
        None,
    );
}
