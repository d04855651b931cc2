//! Lumbar vertebrae (body, pedicles, laminae, transverse and spinous processes), their facet
//! joints and articular processes, and the intervertebral discs.

use glam::DVec3;

use super::dims::{LEFT, RIGHT};
use super::parts::Parts;
use super::spine::{Joint, Placed, Spine, rot_x};
use crate::anatomy::phantom::sdf::{Rigid, Sdf};
use crate::material::MaterialClass;

/// Articular-process block on one side of a joint: `sign` -1 for the superior process (below the
/// plane along -normal), +1 for the inferior process.
pub(super) fn articular_block(j: &Joint, sign: f64, gap: f64) -> Sdf {
    // Half-extents: 3 mm thick (along the normal), 7 mm along the joint line, 8 mm tall (our
    // assumption: lumbar facets are about 15 x 15 mm).
    let half = DVec3::new(3.0, 7.0, 8.0);
    let centre = j.centre + j.normal * sign * (0.5 * gap + half.x);
    let rigid = Rigid::from_axes(centre, j.normal, j.up);
    Sdf::RoundBox { half, round: 2.5 }.placed(rigid)
}

/// The region within 14 mm of a joint on the far side of its space: removed from a bone so the
/// joint space stays open after smooth blending.
pub(super) fn joint_keepout(j: &Joint, sign: f64, gap: f64) -> Sdf {
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

/// Half-height of each endplate rim of a vertebral body, mm (our assumption: the ring
/// apophysis is 3-5 mm tall).
const RIM_HALF_MM: f64 = 2.0;
/// How much narrower than the endplates the body's waist is on every side, mm (our assumption:
/// the concavity of a lumbar body's sides is 1-3 mm deep on radiographs).
const WAIST_MM: f64 = 2.0;

/// Whole-bone solid of a lumbar vertebra (before the canal and joints are carved).
fn lumbar_bone(v: &Placed, is_l5: bool) -> Sdf {
    let d = v.dims;
    let f = v.frame;
    let mut parts = Vec::new();
    // Body: endplate rims of the full endplate size joined by a waist 2 mm narrower all round
    // (the concave sides of a lumbar body; our assumption for the depth of the concavity),
    // blended into one solid with rounded rim edges, and a 1.5 mm posterior concavity (the
    // kidney shape of the endplate; our assumption within the 1-3 mm seen on axial CT).
    let rim = |z: f64| {
        Sdf::EllipticCylinder {
            rx: 0.5 * d.body_width,
            ry: 0.5 * d.body_depth,
            half_h: RIM_HALF_MM,
            round: 1.5,
        }
        .at(DVec3::new(0.0, 0.0, z))
    };
    let waist = Sdf::EllipticCylinder {
        rx: 0.5 * d.body_width - WAIST_MM,
        ry: 0.5 * d.body_depth - WAIST_MM,
        // Up to the rims' mid-planes: the endplate faces are the rims' own, so the smooth blend
        // (which swells a union by up to k/4 where two surfaces meet) stays off them.
        half_h: 0.5 * d.body_height - RIM_HALF_MM,
        round: 1.5,
    };
    let top = 0.5 * d.body_height - RIM_HALF_MM;
    let body = Sdf::SmoothUnion(vec![waist, rim(top), rim(-top)], 4.0).smooth_minus(
        Sdf::EllipticCylinder {
            rx: 20.0,
            ry: 20.0,
            half_h: d.body_height,
            round: 0.0,
        }
        .at(DVec3::new(0.0, -0.5 * d.body_depth - 18.5, 0.0)),
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
    // Spinous process: a sagittal plate from the laminae backwards, rounded all round and
    // thickening into a club-shaped tip, sloping 3 mm caudally (see `Placed::spinous`).
    let sp = v.spinous();
    parts.push(Sdf::slab_between(
        sp.root,
        sp.tip,
        DVec3::Z,
        4.0,
        sp.half_height,
        3.5,
    ));
    parts.push(
        Sdf::Ellipsoid {
            radii: DVec3::new(4.5, 4.0, sp.half_height - 1.0),
        }
        .at(sp.tip + DVec3::new(0.0, 2.0, 0.0)),
    );
    Sdf::SmoothUnion(parts, 4.0).placed(f)
}

/// Canal of a lumbar vertebra in its own frame, removed from the bone.
pub(super) fn lumbar_canal(v: &Placed) -> Sdf {
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

/// Lumbar vertebra `i` (0 = L1) with its articular processes: the superior ones meet the
/// vertebra above (L1's are plain processes, T12 being above the grid), the inferior ones the
/// vertebra or sacrum below; the canal and the far side of every joint space are carved out.
pub(super) fn lumbar_vertebra(spine: &Spine, i: usize, gap: f64) -> Sdf {
    let vert = &spine.lumbar[i];
    let joints = &spine.facets;
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
    Sdf::SmoothUnion(all, 2.0).minus(Sdf::Union(keepout))
}

/// Discs L1-L2 .. L5-S1: between adjacent endplates, bulging 1 mm past the bodies.
pub(super) fn push_discs(parts: &mut Parts, spine: &Spine) {
    for (i, (up, lo)) in spine.lumbar.iter().zip(&spine.below).enumerate() {
        let top = up.w(0.0, 0.0, -0.5 * up.dims.body_height);
        let bottom = lo.w(0.0, 0.0, 0.5 * lo.dims.body_height);
        let mid_rot = rot_x(0.5 * (up.dims.tilt_deg + lo.dims.tilt_deg));
        let rx = 0.5 * up.dims.body_width.max(lo.dims.body_width) + 1.0;
        let ry = 0.5 * up.dims.body_depth.max(lo.dims.body_depth) + 1.0;
        let disc = Sdf::disc_between([rx, ry], 20.0, mid_rot, (top, up.up()), (bottom, lo.up()))
            .minus(lumbar_canal(up));
        let lo_name = if i < 4 { lo.dims.name } else { "S1" };
        parts.push(
            &format!("disc_{}_{}", up.dims.name, lo_name),
            MaterialClass::Disc,
            disc,
        );
    }
}
