//! The canal contents (epidural space, ligamentum flavum, dural sac, conus medullaris, cauda
//! equina) and the exiting nerve roots.

use glam::DVec3;

use super::dims::{LEFT, RIGHT};
use super::parts::Parts;
use super::sacrum::{sacral_canal_point, sacral_foramina};
use super::spine::{Placed, Spine};
use crate::anatomy::phantom::sdf::{Rigid, Sdf};
use crate::material::MaterialClass;

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

/// Pushes the canal contents in painting order: epidural space, ligamentum flavum, dural sac,
/// conus medullaris, cauda equina.
pub(super) fn push_canal_contents(parts: &mut Parts, spine: &Spine) {
    let line = canal_line(&spine.lumbar, &spine.sacral);
    let canal = epidural_space(&line);
    parts.push(
        "epidural_space",
        MaterialClass::EpiduralSpace,
        canal.clone(),
    );
    parts.push(
        "ligamentum_flavum",
        MaterialClass::LigamentumFlavum,
        ligamentum_flavum(spine, &canal),
    );
    let sac_pts = dural_sac_line(&line);
    parts.push("dural_sac", MaterialClass::DuraCsf, dural_sac(&sac_pts));
    parts.push(
        "conus_medullaris",
        MaterialClass::Nerve,
        conus_medullaris(&line),
    );
    parts.push("cauda_equina", MaterialClass::Nerve, cauda_equina(&sac_pts));
}

/// Epidural space: fills the bony canal (bone and ligaments overwrite it), continuing to the
/// sacral hiatus.
fn epidural_space(line: &[DVec3]) -> Sdf {
    let n = line.len();
    sagittal_tube(
        line,
        &canal_radii(n, 13.0, 13.0, 1.8),
        &canal_radii(n, 9.5, 7.0, 0.9),
    )
}

/// Radii for the `n` nodes of the canal line: `lumbar` down to S1, then over the five sacral
/// nodes `sacral` at S1 shrinking by `step` per node.
fn canal_radii(n: usize, lumbar: f64, sacral: f64, step: f64) -> Vec<f64> {
    (0..n)
        .map(|i| {
            if i < n - 5 {
                lumbar
            } else {
                sacral - step * (i + 5 - n) as f64
            }
        })
        .collect()
}

/// Ligamentum flavum: a 3.5 mm layer on the posterior wall of the epidural `canal` between the
/// laminae (our assumption within the 2-5 mm normal range); bone overwrites it at the laminae.
fn ligamentum_flavum(spine: &Spine, canal: &Sdf) -> Sdf {
    let v = &spine.lumbar;
    let sf = &spine.sacral;
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
    Sdf::Union(lf)
}

/// Centre-line of the dural sac: the canal line down to S2, moved to the front of the canal.
fn dural_sac_line(line: &[DVec3]) -> Vec<DVec3> {
    let n = line.len();
    let sac_end = 2 + 5 * 2 + 1; // nodes: top, 5 levels x (centre, half-step), then S1, S2
    line[..sac_end.min(n)]
        .iter()
        .enumerate()
        .map(|(i, q)| *q + DVec3::new(0.0, if i + 1 == sac_end { 1.0 } else { 1.8 }, 0.0))
        .collect()
}

/// Dural sac: about 18 x 13 mm, in the front of the canal, ending at S2 (our assumption for the
/// section; termination per Macdonald et al. 1999).
fn dural_sac(sac_pts: &[DVec3]) -> Sdf {
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
    sagittal_tube(sac_pts, &sac_rx, &sac_ry)
}

/// Conus medullaris: the cord tapering to a tip at the L1-L2 disc (Saifuddin et al. 1998).
fn conus_medullaris(line: &[DVec3]) -> Sdf {
    let conus_tip = line[2] + DVec3::new(0.0, 1.8, 0.0);
    let conus_tip = 0.5 * (conus_tip + line[3]) + DVec3::new(0.0, 1.8, 0.0);
    Sdf::Tube {
        points: vec![
            line[0] + DVec3::new(0.0, 1.8, 0.0),
            line[1] + DVec3::new(0.0, 1.8, 0.0),
            conus_tip,
        ],
        radii: vec![4.0, 3.8, 1.0],
    }
}

/// Cauda equina: a bundle in the dorsal half of the sac from the conus to S2.
fn cauda_equina(sac_pts: &[DVec3]) -> Sdf {
    let m = sac_pts.len();
    let cauda_pts: Vec<DVec3> = sac_pts[2..m - 1]
        .iter()
        .map(|q| *q + DVec3::new(0.0, -2.0, 0.0))
        .collect();
    let cm = cauda_pts.len();
    let cauda_ry: Vec<f64> = (0..cm)
        .map(|i| 3.2 - 1.6 * i as f64 / (cm - 1) as f64)
        .collect();
    let cauda_rx: Vec<f64> = cauda_ry.iter().map(|r| r * 1.8).collect();
    sagittal_tube(&cauda_pts, &cauda_rx, &cauda_ry)
}

/// Pushes the exiting nerve roots L1..L5 (below each pedicle), then S1 and S2 (through the
/// anterior foramina), left before right. Root sleeve 1.5 mm radius, dorsal root ganglion 3 mm
/// radius in the foramen (our assumption, DRG 5-7 mm across).
pub(super) fn push_nerve_roots(parts: &mut Parts, spine: &Spine) {
    for vert in &spine.lumbar {
        for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
            parts.push(
                &format!("nerve_root_{}_{side}", vert.dims.name),
                MaterialClass::Nerve,
                lumbar_root(vert, s),
            );
        }
    }
    let foramina = sacral_foramina();
    for (k, lvl) in ["S1", "S2"].iter().enumerate() {
        for (j, (s, side)) in [(LEFT, "left"), (RIGHT, "right")].into_iter().enumerate() {
            let (a, b, _) = foramina[2 * k + j];
            let sf = &spine.sacral;
            let inside = sf.to_world(sacral_canal_point(k) + DVec3::new(s * 3.0, 1.0, 8.0));
            let pts = vec![
                inside,
                sf.to_world(a),
                sf.to_world(b),
                sf.to_world(b + DVec3::new(s * 10.0, 12.0, -12.0)),
            ];
            parts.push(
                &format!("nerve_root_{lvl}_{side}"),
                MaterialClass::Nerve,
                Sdf::Tube {
                    points: pts,
                    radii: vec![1.5, 2.2, 2.2, 2.0],
                },
            );
        }
    }
}

/// The root exiting below the pedicle of `vert` on side `s`, from the sac through the foramen.
fn lumbar_root(vert: &Placed, s: f64) -> Sdf {
    let d = vert.dims;
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
    Sdf::Tube {
        points: pts,
        radii: vec![1.5, 2.0, 3.0, 2.6, 2.2],
    }
}
