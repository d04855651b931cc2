//! The sacrum (body, lateral masses, canal, hiatus and foramina, superior articular processes)
//! and the iliac bones with their sacroiliac joints.

use glam::DVec3;

use super::dims::{LEFT, RIGHT};
use super::spine::Spine;
use super::vertebra::{articular_block, joint_keepout};
use crate::anatomy::phantom::sdf::{Rigid, Sdf};

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
pub(super) fn sacral_canal_point(i: usize) -> DVec3 {
    let (y, z, _, r) = SACRAL_LEVELS[i];
    DVec3::new(0.0, y - r - 8.0 + i as f64 * 0.5, z)
}

/// The sacrum's solid before any opening (sacral frame): S1 body and endplate, the tapering body,
/// lateral masses and alae, median sacral crest.
fn sacrum_solid() -> Sdf {
    let mut parts = Vec::new();
    let body_pts: Vec<DVec3> = SACRAL_LEVELS
        .iter()
        .map(|&(y, z, _, _)| DVec3::new(0.0, y, z))
        .collect();
    let body_r: Vec<f64> = SACRAL_LEVELS.iter().map(|&(_, _, _, r)| r).collect();
    let mut top = body_pts.clone();
    // The S1 endplate is the elliptic body's flat top (z = 0): the tube starts low enough that
    // its rounded end (radius 16.5 mm) stays 0.5 mm under it, not a dome into the L5-S1 disc.
    top[0] = DVec3::new(0.0, 0.0, -17.0);
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
    Sdf::SmoothUnion(parts, 8.0)
}

/// Sacral canal (sacral frame): a flattened tube (about 28 x 12 mm at S1, narrowing; our
/// assumption).
fn sacral_canal() -> Sdf {
    let canal_pts: Vec<DVec3> = (0..6).map(sacral_canal_point).collect();
    Sdf::Scaled(
        Box::new(Sdf::Tube {
            points: canal_pts
                .iter()
                .map(|p| DVec3::new(p.x / 2.2, p.y, p.z))
                .chain(std::iter::once(DVec3::new(0.0, -30.0, 20.0)))
                .collect(),
            radii: vec![6.5, 6.0, 5.0, 4.0, 3.5, 3.0, 6.5],
        }),
        DVec3::new(2.2, 1.0, 1.0),
    )
}

/// Sacral hiatus (sacral frame): the canal's posterior wall is open at S4-S5 (our assumption:
/// hiatus apex at S4).
fn sacral_hiatus() -> Sdf {
    let hiatus = Sdf::Tube {
        points: vec![
            sacral_canal_point(3) + DVec3::new(0.0, -2.0, 2.0),
            sacral_canal_point(5) + DVec3::new(0.0, -3.0, -6.0),
        ],
        radii: vec![4.0, 5.0],
    }
    .placed(Rigid::IDENTITY);
    Sdf::Union(vec![
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
    ])
}

/// The sacrum in the world: its solid less the canal, hiatus and anterior and posterior foramina.
fn sacrum_bone(sf: &Rigid) -> Sdf {
    let solid = sacrum_solid();
    let mut holes = vec![sacral_canal(), sacral_hiatus()];
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
pub(super) fn sacral_foramina() -> Vec<(DVec3, DVec3, f64)> {
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

/// The sacrum with its superior articular processes, which meet L5's inferior ones.
pub(super) fn sacrum_with_processes(spine: &Spine, gap: f64) -> Sdf {
    let sf = &spine.sacral;
    let joints = &spine.facets;
    let mut sac_extra = vec![sacrum_bone(sf)];
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
    Sdf::SmoothUnion(sac_extra, 3.0).minus(Sdf::Union(sac_keep))
}

/// Radius of the dome that shapes the iliac crest, mm: the crest follows a sphere of this radius
/// whose top is the crest's highest point, so it falls by `d^2 / 2R` (roughly) at a horizontal
/// distance `d` from that point: about 40 mm at the posterior end of the wing (which meets the
/// posterior superior iliac spine, centred 57 mm below the crest top here) and 30 mm at the
/// anterior end (towards the anterior superior spine). Our assumption, giving the arched crest
/// of an AP film, highest postero-laterally and falling towards both iliac spines.
const CREST_DOME_RADIUS_MM: f64 = 150.0;

/// Angle of the crest's highest point on the wing's rim, radians from its lateral-most point
/// (negative: posterior). Our assumption: the highest point lies a little behind the iliac
/// tubercle, as the intercristal (Tuffier's) line is drawn through the crests' posterior tops.
const CREST_APEX_ANGLE_RAD: f64 = -0.35;

/// Iliac bone of side `s`: a bowl-shaped wing (shell of an ellipsoid) with an auricular part
/// against the sacrum and a column towards the acetabulum; the SI joint is kept open by removing
/// the sacrum grown by the joint width `si_gap` (our assumption for all dimensions: inter-crest
/// width about 270 mm, crest top at the L4 level).
///
/// The wing ends at an arched crest, not at a horizontal plane: a plane cuts the shell along a
/// level ring, which in every view projects to a straight edge across the whole field at one
/// height (a bright-to-dark step of about 20 grey levels through both flanks of the AP image).
pub(super) fn ilium(spine: &Spine, sacrum: &Sdf, s: f64, si_gap: f64) -> Sdf {
    let v = &spine.lumbar;
    let sf = &spine.sacral;
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
    // The crest's top: a dome (a sphere over everything below its centre) whose highest point,
    // at height `crest_top`, lies over the rim at `CREST_APEX_ANGLE_RAD`.
    let crest_top = crest_z + 3.0;
    let r_dome = CREST_DOME_RADIUS_MM;
    let apex = DVec3::new(
        c.x + s * 80.0 * CREST_APEX_ANGLE_RAD.cos(),
        c.y + 62.0 * CREST_APEX_ANGLE_RAD.sin(),
        crest_top - r_dome,
    );
    let dome = Sdf::Union(vec![
        Sdf::Sphere { radius: r_dome }.at(apex),
        Sdf::HalfSpace {
            normal: DVec3::Z,
            offset: apex.z,
        },
    ]);
    let dome_top = |q: DVec3| {
        let d2 = (q.x - apex.x).powi(2) + (q.y - apex.y).powi(2);
        apex.z + (r_dome * r_dome - d2).max(0.0).sqrt()
    };
    // Iliac crest: a thickened rim along the top of the wing, its centre a radius under the dome.
    let crest_pts: Vec<DVec3> = (0..=10)
        .map(|k| {
            let t = -1.75 + 2.9 * f64::from(k) / 10.0;
            let q = DVec3::new(c.x + s * 76.5 * t.cos(), c.y + 59.0 * t.sin(), 0.0);
            DVec3::new(q.x, q.y, dome_top(q) - 6.0)
        })
        .filter(|q| q.y <= 55.0 && s * q.x >= 28.0)
        .collect();
    let crest = Sdf::Tube {
        radii: vec![6.0; crest_pts.len()],
        points: crest_pts,
    };
    let wing = Sdf::Intersect(vec![Sdf::SmoothUnion(vec![wing, crest], 4.0), dome]);
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
    Sdf::SmoothUnion(vec![wing, auricular, psis, column], 10.0).minus(sacrum.clone().offset(si_gap))
}
