//! The body envelope (skin, subcutaneous fat, deep soft tissue), the psoas and erector spinae
//! muscles, and the great vessels.

use glam::DVec3;

use super::dims::{AnatomyParams, LEFT, RIGHT};
use super::parts::Parts;
use super::spine::{Placed, Spine};
use crate::anatomy::phantom::sdf::Sdf;
use crate::material::MaterialClass;

/// Pushes skin, subcutaneous fat and deep soft tissue, and returns the solid under the skin, to
/// which solids that would reach beyond the envelope are clipped.
///
/// The envelope is our assumption: an elliptic cylinder widening over the pelvis, taller than any
/// grid.
pub(super) fn push_envelope(parts: &mut Parts, p: &AnatomyParams) -> Sdf {
    let waist = Sdf::EllipticCylinder {
        rx: p.body_half_width_mm,
        ry: p.body_half_depth_mm,
        half_h: 600.0,
        round: 0.0,
    }
    .at(DVec3::new(0.0, p.body_centre_y_mm, 0.0));
    let hips = Sdf::Ellipsoid {
        radii: DVec3::new(
            p.body_half_width_mm + 12.0,
            p.body_half_depth_mm - 5.0,
            140.0,
        ),
    }
    .at(DVec3::new(0.0, p.body_centre_y_mm, -200.0));
    let envelope = Sdf::SmoothUnion(vec![waist, hips], 30.0);
    // Everything inside the body lies under the skin: the erector spinae column and the
    // iliac wings reach beyond the envelope otherwise (a few cm^3 each), which no anatomy
    // has and which would leave them outside the skin mesh that every renderer nests the
    // body in. Their solids are clipped to the inner surface of the skin.
    let under_skin = envelope.clone().offset(-p.skin_mm);
    parts.push("skin", MaterialClass::SoftTissue, envelope.clone());
    parts.push(
        "subcutaneous_fat",
        MaterialClass::Fat,
        envelope.clone().offset(-p.skin_mm),
    );
    parts.push(
        "deep_soft_tissue",
        MaterialClass::SoftTissue,
        envelope.offset(-p.skin_mm - p.subcutaneous_fat_mm),
    );
    under_skin
}

/// Pushes the psoas muscles, then the erector spinae, left before right.
pub(super) fn push_muscles(parts: &mut Parts, spine: &Spine, under_skin: &Sdf) {
    for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
        parts.push(
            &format!("psoas_{side}"),
            MaterialClass::Muscle,
            psoas(spine, s),
        );
    }
    for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
        parts.push(
            &format!("erector_spinae_{side}"),
            MaterialClass::Muscle,
            Sdf::Intersect(vec![erector_spinae(spine, s), under_skin.clone()]),
        );
    }
}

/// Psoas of side `s`: a tapered tube along the lateral vertebral bodies into the pelvis
/// (cross-section about 12 cm^2 at L4-L5; our assumption).
fn psoas(spine: &Spine, s: f64) -> Sdf {
    let mut pts = Vec::new();
    let mut radii = Vec::new();
    for (i, vert) in spine.lumbar.iter().enumerate() {
        let r = 9.0 + 3.0 * i as f64;
        pts.push(vert.w(s * (0.5 * vert.dims.body_width + r - 3.0), 2.0, 0.0));
        radii.push(r);
    }
    let c = spine.sacral.to_world(DVec3::new(s * 58.0, 30.0, -20.0));
    pts.push(c);
    radii.push(20.0);
    pts.push(c + DVec3::new(s * 18.0, 30.0, -80.0));
    radii.push(18.0);
    pts.push(c + DVec3::new(s * 24.0, 40.0, -160.0));
    radii.push(17.0);
    let top = pts[0] + DVec3::new(0.0, 0.0, 15.0);
    pts.insert(0, top);
    radii.insert(0, 7.0);
    Sdf::Tube { points: pts, radii }
}

/// Erector spinae with multifidus of side `s`: an elliptic column behind the laminae and
/// transverse processes, beside the spinous processes (about 20 cm^2 per side at L3; our
/// assumption). Not yet clipped to the skin.
fn erector_spinae(spine: &Spine, s: f64) -> Sdf {
    let v = &spine.lumbar;
    let sf = &spine.sacral;
    let mut pts = vec![v[0].w(s * 36.0, v[0].canal_back_y() - 20.0, 60.0)];
    for vert in v {
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
    Sdf::Scaled(Box::new(shape), DVec3::new(1.45, 1.0, 1.0)).at(DVec3::new(s * 36.0, 0.0, 0.0))
}

/// A point in front of the body of `vert`: `x` lateral, `extra` mm anterior to the body, at the
/// body's mid-height.
fn in_front(vert: &Placed, x: f64, extra: f64) -> DVec3 {
    vert.w(x, 0.5 * vert.dims.body_depth + extra, 0.0)
}

/// Pushes the inferior vena cava and the aorta.
///
/// Aorta (about 18 mm, left of midline) bifurcating at L4 into the common iliac arteries; IVC
/// (right, flattened) formed at L4-L5 from the common iliac veins. Diameters: our assumption
/// within normal adult ranges.
pub(super) fn push_vessels(parts: &mut Parts, v: &[Placed]) {
    let mut ivc_pts = vec![in_front(&v[0], RIGHT * 20.0, 13.0) + DVec3::new(0.0, 0.0, 40.0)];
    ivc_pts.extend(v[..4].iter().map(|q| in_front(q, RIGHT * 20.0, 13.0)));
    ivc_pts.push(in_front(&v[4], RIGHT * 14.0, 14.0) + DVec3::new(0.0, 0.0, 8.0));
    let ivc = forked_vessel(
        ivc_pts,
        10.5,
        [
            [
                DVec3::new(RIGHT * 30.0, 8.0, -45.0),
                DVec3::new(RIGHT * 45.0, 25.0, -110.0),
            ],
            [
                DVec3::new(LEFT * 28.0, 0.0, -40.0),
                DVec3::new(LEFT * 58.0, 22.0, -110.0),
            ],
        ],
        [7.5, 7.0, 6.5],
    );
    parts.push("inferior_vena_cava", MaterialClass::Vessel, ivc);
    let mut ao_pts = vec![in_front(&v[0], LEFT * 14.0, 12.0) + DVec3::new(0.0, 0.0, 40.0)];
    ao_pts.extend(v[..3].iter().map(|q| in_front(q, LEFT * 14.0, 12.0)));
    ao_pts.push(in_front(&v[3], LEFT * 6.0, 14.0) + DVec3::new(0.0, 0.0, -4.0));
    let aorta = forked_vessel(
        ao_pts,
        9.0,
        [
            [
                DVec3::new(LEFT * 30.0, 8.0, -40.0),
                DVec3::new(LEFT * 52.0, 30.0, -110.0),
            ],
            [
                DVec3::new(RIGHT * 28.0, 12.0, -40.0),
                DVec3::new(RIGHT * 56.0, 34.0, -110.0),
            ],
        ],
        [5.5, 5.0, 4.5],
    );
    parts.push("aorta", MaterialClass::Vessel, aorta);
}

/// A vessel trunk of radius `trunk_r` along `trunk`, forking at its last point into two
/// branches; each branch runs through two points given as offsets from the fork, with radii
/// `branch_r` from the fork on.
fn forked_vessel(
    trunk: Vec<DVec3>,
    trunk_r: f64,
    branches: [[DVec3; 2]; 2],
    branch_r: [f64; 3],
) -> Sdf {
    let fork = *trunk.last().expect("a trunk has points");
    let mut tubes = vec![Sdf::Tube {
        radii: vec![trunk_r; trunk.len()],
        points: trunk,
    }];
    tubes.extend(branches.map(|[a, b]| Sdf::Tube {
        points: vec![fork, fork + a, fork + b],
        radii: branch_r.to_vec(),
    }));
    Sdf::Union(tubes)
}
