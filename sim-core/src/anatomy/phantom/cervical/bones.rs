//! The cervical vertebrae as implicit solids: the atlas (ring, lateral masses, no body), the axis
//! (body and dens) and C3-T1 (bodies with uncinate processes, pedicles, articular pillars with
//! their facet joints, laminae, spinous processes, transverse processes with foramina
//! transversaria), and the discs C2-C3 .. C7-T1.

use glam::DVec3;

use super::dims::{
    ADI_MM, ATLAS_WIDTH_MM, DENS_HEIGHT_MM, DENS_RADIUS_MM, DISC_MM, FORAMEN_RADIUS_MM,
    VERTEBRAL_ARTERY_RADIUS_MM,
};
use super::skeleton::{Atlas, Joint, PILLAR_HALF, Skeleton, Vert, c2_joint_z, rot_x};
use crate::anatomy::phantom::model::{LEFT, RIGHT};
use crate::anatomy::phantom::sdf::{Rigid, Sdf};

/// The far side of a joint within 12 mm of its centre: removed from a bone so the joint space
/// stays open after smooth blending. `sign` +1 removes the side the normal points to (for the
/// lower bone), -1 the other side (for the upper bone).
fn keepout(j: &Joint, sign: f64, gap: f64) -> Sdf {
    let n = j.normal * sign;
    Sdf::Intersect(vec![
        Sdf::HalfSpace {
            normal: -n,
            offset: -(n.dot(j.centre) - 0.5 * gap),
        },
        Sdf::Sphere { radius: 12.0 }.at(j.centre),
    ])
}

/// Half-space below (`sign` = -1: the lower bone's side) or above (+1) a joint plane, each half a
/// gap away from it.
fn joint_side(j: &Joint, sign: f64, gap: f64) -> Sdf {
    let n = j.normal * sign;
    Sdf::HalfSpace {
        normal: -n,
        offset: -(n.dot(j.centre) + 0.5 * gap),
    }
}

/// The foramina transversaria: both vertebral arteries grown by the foramen's clearance.
pub(super) fn foramina(sk: &Skeleton) -> Sdf {
    let r = FORAMEN_RADIUS_MM;
    Sdf::Union(
        [LEFT, RIGHT]
            .map(|s| {
                let pts = sk.vertebral_artery(s);
                Sdf::Tube {
                    radii: vec![r; pts.len()],
                    points: pts,
                }
            })
            .to_vec(),
    )
}

/// The vertebral artery of side `s`.
pub(super) fn vertebral_artery(sk: &Skeleton, s: f64) -> Sdf {
    let pts = sk.vertebral_artery(s);
    Sdf::Tube {
        radii: vec![VERTEBRAL_ARTERY_RADIUS_MM; pts.len()],
        points: pts,
    }
}

/// The canal of `v` (local elliptic cylinder), removed from bones.
pub(super) fn canal(v: &Vert) -> Sdf {
    Sdf::EllipticCylinder {
        rx: 0.5 * v.d.canal_width,
        ry: 0.5 * v.d.canal_depth,
        half_h: 2.0 * v.d.body_height,
        round: 0.0,
    }
    .at(DVec3::new(0.0, v.canal_y(), 0.0))
    .placed(v.frame)
}

/// The articular pillar of vertebra `k` (index into the skeleton's C2..T1) on side `k_side`:
/// a column between the joint planes above and below (C2's is cut at its mid-height, where its
/// superior articular mass takes over; T1's bottom is a plane 3 mm below its body).
fn pillar(sk: &Skeleton, k: usize, side: usize, gap: f64) -> Sdf {
    let v = &sk.verts[k];
    let s = [LEFT, RIGHT][side];
    let column = Sdf::RoundBox {
        half: PILLAR_HALF,
        round: 2.0,
    }
    .placed(
        v.frame
            .compose(&Rigid::at(DVec3::new(s * v.pillar_x(), v.pillar_y(), 0.0))),
    );
    let mut cut = vec![column];
    if k > 0 {
        cut.push(joint_side(&sk.facets[k - 1][side], -1.0, gap));
    } else {
        cut.push(Sdf::HalfSpace {
            normal: v.up(),
            offset: v.up().dot(v.w(0.0, 0.0, 2.0)),
        });
    }
    if k + 1 < sk.verts.len() {
        cut.push(joint_side(&sk.facets[k][side], 1.0, gap));
    } else {
        cut.push(Sdf::HalfSpace {
            normal: -v.up(),
            offset: -v.up().dot(v.w(0.0, 0.0, -0.5 * v.d.body_height - 3.0)),
        });
    }
    Sdf::Intersect(cut)
}

/// Whole-bone solid of C2..T1 (index `k`), before the canal, foramina and joints are carved.
fn vertebra_parts(sk: &Skeleton, k: usize, gap: f64) -> Vec<Sdf> {
    let v = &sk.verts[k];
    let d = v.d;
    let f = v.frame;
    let mut parts = vec![
        Sdf::EllipticCylinder {
            rx: 0.5 * d.body_width,
            ry: 0.5 * d.body_depth,
            half_h: 0.5 * d.body_height,
            round: 1.5,
        }
        .placed(f),
    ];
    for (side, s) in [LEFT, RIGHT].into_iter().enumerate() {
        // Uncinate process (C3-C7): a ridge on the posterolateral rim of the superior endplate,
        // 1.5 mm short of the vertebra above (our choice; Panjabi 1991 give 4-6 mm).
        if k > 0 && d.name != "T1" {
            let uh = DISC_MM[k - 1] - 1.5;
            parts.push(
                Sdf::RoundBox {
                    half: DVec3::new(1.6, 5.0, 0.5 * uh + 1.0),
                    round: 1.2,
                }
                .placed(f.compose(&Rigid::at(DVec3::new(
                    s * (0.5 * d.body_width - 1.4),
                    -1.5,
                    0.5 * d.body_height + 0.5 * uh - 1.0,
                )))),
            );
        }
        let pz = v.pedicle_z();
        // Pedicle: posterolateral from the body to the pillar, about 45 degrees medial (Panjabi).
        let a = v.w(
            s * (0.5 * d.body_width - 2.5),
            -0.5 * d.body_depth + 3.0,
            pz,
        );
        let b = v.w(s * (v.pillar_x() - 2.0), v.pillar_y() + 3.0, pz);
        parts.push(Sdf::slab_between(
            a,
            b,
            v.up(),
            0.5 * d.pedicle_width,
            0.5 * d.pedicle_height,
            0.45 * d.pedicle_width.min(d.pedicle_height),
        ));
        // Transverse process: anterior and posterior roots around the foramen transversarium,
        // a flat bar from the body's side to the tip (our choice of section, 11 x 7 mm).
        let fo = v.foramen(s);
        let root = v.w(s * (0.5 * d.body_width - 1.0), fo.y, pz);
        let tip = v.w(s * (0.5 * d.tp_span - 3.0), fo.y - 2.0, pz - 1.0);
        parts.push(Sdf::slab_between(root, tip, v.up(), 5.5, 3.5, 2.5));
        // Articular pillar.
        parts.push(pillar(sk, k, side, gap));
        // Lamina: from the pillar's posteromedial corner to the midline behind the canal.
        let zc = v.lamina_z();
        let a = v.w(
            s * (v.pillar_x() - PILLAR_HALF.x + 2.0),
            v.pillar_y() - PILLAR_HALF.y + 3.0,
            zc,
        );
        let m = v.w(0.0, v.canal_back_y() - 2.5, zc);
        parts.push(Sdf::slab_between(a, m, v.up(), 2.5, d.lamina_half_h, 2.0));
    }
    // Spinous process: bifid at C2-C6, a single long tip at C7 and T1.
    let zc = v.lamina_z();
    let drop = if d.bifid { 3.0 } else { 8.0 };
    let root = v.w(0.0, v.canal_back_y() - 2.0, zc);
    let tip = v.w(0.0, v.canal_back_y() - d.sp_length, zc - drop);
    let half_h = if d.bifid { 4.0 } else { 5.0 };
    parts.push(Sdf::slab_between(root, tip, v.up(), 2.8, half_h, 2.5));
    if d.bifid {
        for s in [LEFT, RIGHT] {
            parts.push(
                Sdf::Ellipsoid {
                    radii: DVec3::new(2.8, 3.5, half_h + 0.5),
                }
                .placed(Rigid {
                    rotation: f.rotation,
                    translation: tip + f.rotation * DVec3::new(s * 3.5, 1.0, 0.0),
                }),
            );
        }
    } else {
        parts.push(
            Sdf::Ellipsoid {
                radii: DVec3::new(4.5, 4.5, half_h + 1.0),
            }
            .placed(Rigid {
                rotation: f.rotation,
                translation: tip + f.rotation * DVec3::new(0.0, 2.0, 0.0),
            }),
        );
    }
    if k == 0 {
        // The axis: dens and the superior articular masses for the atlas.
        parts.push(Sdf::capsule(
            v.w(0.0, 1.0, 0.5 * d.body_height - 2.0),
            v.w(
                0.0,
                1.0,
                0.5 * d.body_height + DENS_HEIGHT_MM - DENS_RADIUS_MM,
            ),
            DENS_RADIUS_MM,
        ));
        let zj = c2_joint_z(v);
        for s in [LEFT, RIGHT] {
            parts.push(
                Sdf::RoundBox {
                    half: DVec3::new(6.0, 7.5, 5.0),
                    round: 2.0,
                }
                .placed(f.compose(&Rigid::at(DVec3::new(
                    s * (Atlas::MASS_X - 0.5),
                    Atlas::MASS_Y + 1.0,
                    zj - 5.0,
                )))),
            );
        }
    }
    parts
}

/// Vertebra `k` of C2..T1 with its joints, canal and foramina carved.
pub(super) fn vertebra(sk: &Skeleton, k: usize, gap: f64, foramina: &Sdf) -> Sdf {
    let v = &sk.verts[k];
    let mut out = vec![canal(v), foramina.clone()];
    for side in 0..2 {
        if k > 0 {
            out.push(keepout(&sk.facets[k - 1][side], 1.0, gap));
        } else {
            out.push(keepout(&sk.atlanto_axial[side], 1.0, gap));
        }
        if k + 1 < sk.verts.len() {
            out.push(keepout(&sk.facets[k][side], -1.0, gap));
        }
    }
    Sdf::SmoothUnion(vertebra_parts(sk, k, gap), 2.0).minus(Sdf::Union(out))
}

/// The atlas: anterior and posterior arches, lateral masses and transverse processes, with the
/// dens (plus the atlanto-dental interval), the foramina and the C1-C2 joints carved.
pub(super) fn atlas(sk: &Skeleton, gap: f64, foramina: &Sdf) -> Sdf {
    let a = &sk.atlas;
    let f = a.frame;
    let pts = |p: &[[f64; 3]]| p.iter().map(|q| a.w(q[0], q[1], q[2])).collect::<Vec<_>>();
    // Anterior arch: its back 1.5 mm in front of the dens (ADI, Hinck and Hopkins 1960).
    let front = DENS_RADIUS_MM + ADI_MM + 3.5;
    let mut parts = vec![Sdf::Tube {
        points: pts(&[
            [-14.0, 3.0, 0.0],
            [-8.0, front - 1.0, 0.0],
            [0.0, front, 0.0],
            [8.0, front - 1.0, 0.0],
            [14.0, 3.0, 0.0],
        ]),
        radii: vec![3.5; 5],
    }];
    // Posterior arch: its front at the back of the canal, 30 mm behind the anterior arch's back.
    let back = DENS_RADIUS_MM + ADI_MM - super::dims::ATLAS_CANAL_DEPTH_MM - 4.5;
    parts.push(Sdf::Tube {
        points: pts(&[
            [-17.0, -8.0, 0.0],
            [-15.0, -17.0, 1.0],
            [-8.0, back + 1.5, 2.0],
            [0.0, back, 2.0],
            [8.0, back + 1.5, 2.0],
            [15.0, -17.0, 1.0],
            [17.0, -8.0, 0.0],
        ]),
        radii: vec![4.0, 3.5, 3.5, 4.5, 3.5, 3.5, 4.0],
    });
    for s in [LEFT, RIGHT] {
        parts.push(
            Sdf::RoundBox {
                half: Atlas::MASS_HALF,
                round: 2.5,
            }
            .placed(f.compose(&Rigid::at(DVec3::new(
                s * Atlas::MASS_X,
                Atlas::MASS_Y,
                0.0,
            )))),
        );
        // Transverse process out to the atlas's 78 mm width (Doherty and Heggeness 1994).
        parts.push(Sdf::slab_between(
            a.w(s * 22.0, -1.5, 0.0),
            a.w(s * (0.5 * ATLAS_WIDTH_MM - 3.5), -3.0, 0.0),
            f.rotation.z_axis,
            5.0,
            4.5,
            3.0,
        ));
    }
    let dens = Sdf::Tube {
        points: pts(&[[0.0, 0.0, -30.0], [0.0, 0.0, 30.0]]),
        radii: vec![DENS_RADIUS_MM + ADI_MM; 2],
    };
    let mut out = vec![dens, foramina.clone()];
    for j in &sk.atlanto_axial {
        out.push(keepout(j, -1.0, gap));
    }
    Sdf::SmoothUnion(parts, 2.0).minus(Sdf::Union(out))
}

/// Discs C2-C3 .. C7-T1: between adjacent endplates, bulging 0.5 mm past the bodies.
pub(super) fn discs(sk: &Skeleton) -> Vec<(String, Sdf)> {
    sk.verts
        .windows(2)
        .map(|w| {
            let (up, lo) = (&w[0], &w[1]);
            let top = up.w(0.0, 0.0, -0.5 * up.d.body_height);
            let bottom = lo.w(0.0, 0.0, 0.5 * lo.d.body_height);
            let rot = rot_x(0.5 * (up.d.tilt_deg + lo.d.tilt_deg));
            let radii = [
                0.5 * up.d.body_width.max(lo.d.body_width) + 0.5,
                0.5 * up.d.body_depth.max(lo.d.body_depth) + 0.5,
            ];
            let disc = Sdf::disc_between(radii, 15.0, rot, (top, up.up()), (bottom, lo.up()))
                .minus(canal(up));
            (format!("disc_{}_{}", up.d.name, lo.d.name), disc)
        })
        .collect()
}
