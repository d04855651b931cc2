//! The neck's soft tissues: the envelope (skin, subcutaneous fat, deep soft tissue), posterior
//! neck muscles and longus colli, the canal contents (epidural space, ligamentum flavum, dural
//! sac, spinal cord) and the carotid sheaths (common carotid artery, internal jugular vein).

use glam::DVec3;

use super::dims::{
    ANTERIOR_EPIDURAL_MM, CORD_HALF_DEPTH_MM, CORD_HALF_WIDTH_MM, FLAVUM_MM, LATERAL_EPIDURAL_MM,
    POSTERIOR_EPIDURAL_MM,
};
use super::skeleton::{Skeleton, Vert};
use crate::anatomy::phantom::model::Parts;
use crate::anatomy::phantom::model::{AnatomyParams, LEFT, RIGHT};
use crate::anatomy::phantom::sdf::{Rigid, Sdf};
use crate::material::MaterialClass;

/// Centre of the neck outline in y (model frame), mm: the posterior skin 25 mm behind the C5
/// spinous tip and the anterior skin 40 mm in front of the C5 body (our choice).
const NECK_CENTRE_Y_MM: f64 = -10.0;

/// Pushes skin, subcutaneous fat and deep soft tissue; returns the solid under the skin.
/// The neck is an elliptic cylinder of `body_half_width_mm` x `body_half_depth_mm` (our choice:
/// 120 x 116 mm, a 37 cm collar), taller than the grid.
pub(super) fn push_envelope(parts: &mut Parts, p: &AnatomyParams) -> Sdf {
    let neck = Sdf::EllipticCylinder {
        rx: p.body_half_width_mm,
        ry: p.body_half_depth_mm,
        half_h: 400.0,
        round: 0.0,
    }
    .at(DVec3::new(0.0, NECK_CENTRE_Y_MM, 0.0));
    parts.push("skin", MaterialClass::SoftTissue, neck.clone());
    let under_skin = neck.clone().offset(-p.skin_mm);
    parts.push("subcutaneous_fat", MaterialClass::Fat, under_skin.clone());
    parts.push(
        "deep_soft_tissue",
        MaterialClass::SoftTissue,
        neck.offset(-p.skin_mm - p.subcutaneous_fat_mm),
    );
    under_skin
}

/// A centre-line through every vertebra's local point `(x, y, 0)`, extended 40 mm above C2 and
/// below T1 (past the grid).
fn column_line(sk: &Skeleton, x: f64, y: impl Fn(&Vert) -> f64) -> Vec<DVec3> {
    let v = &sk.verts;
    let mut pts: Vec<DVec3> = v.iter().map(|q| q.w(x, y(q), 0.0)).collect();
    let top = pts[0] + v[0].up() * 40.0;
    let bottom = pts[pts.len() - 1] - v[v.len() - 1].up() * 40.0;
    pts.insert(0, top);
    pts.push(bottom);
    pts
}

/// Pushes the posterior neck muscles (semispinalis, splenius and trapezius lumped: an elliptic
/// column each side behind the laminae and pillars, about 12 cm^2; our choice), then the longus
/// colli in front of the bodies.
pub(super) fn push_muscles(parts: &mut Parts, sk: &Skeleton, under_skin: &Sdf) {
    for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
        let pts = column_line(sk, 0.0, |v| v.canal_back_y() - 14.0);
        let n = pts.len();
        let column = Sdf::Scaled(
            Box::new(Sdf::Tube {
                points: pts,
                radii: vec![14.0; n],
            }),
            DVec3::new(1.4, 1.0, 1.0),
        )
        .at(DVec3::new(s * 22.0, 0.0, 0.0));
        parts.push(
            &format!("posterior_neck_muscles_{side}"),
            MaterialClass::Muscle,
            Sdf::Intersect(vec![column, under_skin.clone()]),
        );
    }
    for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
        let pts: Vec<DVec3> = sk
            .verts
            .iter()
            .map(|v| v.w(s * 7.5, 0.5 * v.d.body_depth + 3.0, 0.0))
            .collect();
        let n = pts.len();
        parts.push(
            &format!("longus_colli_{side}"),
            MaterialClass::Muscle,
            Sdf::Tube {
                points: pts,
                radii: vec![3.5; n],
            },
        );
    }
}

/// A tube with elliptic section about a mid-sagittal centre-line (x = 0): a round tube of the
/// half-depths `ry`, stretched along x by the mean width-to-depth ratio.
fn sagittal_tube(points: Vec<DVec3>, rx: &[f64], ry: Vec<f64>) -> Sdf {
    let ratio = rx.iter().zip(&ry).map(|(a, b)| a / b).sum::<f64>() / rx.len() as f64;
    Sdf::Scaled(
        Box::new(Sdf::Tube { points, radii: ry }),
        DVec3::new(ratio, 1.0, 1.0),
    )
}

/// The canal's centre-line: the atlas canal behind the dens, every vertebra's canal centre and
/// the midpoints between them, extended 40 mm past C1 and T1; with the canal half-width and
/// half-depth at each node.
pub(super) fn canal_line(sk: &Skeleton) -> (Vec<DVec3>, Vec<f64>, Vec<f64>) {
    let v = &sk.verts;
    let a = &sk.atlas;
    // Atlas canal behind the dens: from the dens's back to the posterior arch (30 mm sagittal
    // canal minus the dens and the ADI), 24 mm between the lateral masses.
    let atlas_ry = 0.5
        * (super::dims::ATLAS_CANAL_DEPTH_MM
            - 2.0 * super::dims::DENS_RADIUS_MM
            - super::dims::ADI_MM);
    let atlas_c = a.w(0.0, -super::dims::DENS_RADIUS_MM - atlas_ry, 0.0);
    let mut pts = vec![atlas_c + a.frame.rotation.z_axis * 40.0, atlas_c];
    let mut rx = vec![12.0, 12.0];
    let mut ry = vec![atlas_ry, atlas_ry];
    let c2 = v[0].w(0.0, v[0].canal_y(), 0.0);
    pts.push(0.5 * (atlas_c + c2));
    rx.push(0.5 * (12.0 + 0.5 * v[0].d.canal_width));
    ry.push(0.5 * (atlas_ry + 0.5 * v[0].d.canal_depth));
    for (i, q) in v.iter().enumerate() {
        pts.push(q.w(0.0, q.canal_y(), 0.0));
        rx.push(0.5 * q.d.canal_width);
        ry.push(0.5 * q.d.canal_depth);
        if let Some(n) = v.get(i + 1) {
            pts.push(0.5 * (q.w(0.0, q.canal_y(), 0.0) + n.w(0.0, n.canal_y(), 0.0)));
            rx.push(0.25 * (q.d.canal_width + n.d.canal_width));
            ry.push(0.25 * (q.d.canal_depth + n.d.canal_depth));
        }
    }
    let last = v[v.len() - 1];
    pts.push(last.w(0.0, last.canal_y(), 0.0) - last.up() * 40.0);
    rx.push(0.5 * last.d.canal_width);
    ry.push(0.5 * last.d.canal_depth);
    (pts, rx, ry)
}

/// Pushes epidural space, ligamentum flavum, dural sac and spinal cord.
pub(super) fn push_canal_contents(parts: &mut Parts, sk: &Skeleton) {
    let (pts, rx, ry) = canal_line(sk);
    let canal = sagittal_tube(pts.clone(), &rx, ry.clone());
    parts.push(
        "epidural_space",
        MaterialClass::EpiduralSpace,
        canal.clone(),
    );
    parts.push(
        "ligamentum_flavum",
        MaterialClass::LigamentumFlavum,
        ligamentum_flavum(sk, &canal),
    );
    // The sac sits forwards in the canal: 2.5 mm of posterior and 1 mm of anterior epidural space.
    let shift = 0.5 * (POSTERIOR_EPIDURAL_MM - ANTERIOR_EPIDURAL_MM);
    let sac_pts: Vec<DVec3> = pts.iter().map(|p| *p + DVec3::Y * shift).collect();
    let sac_rx: Vec<f64> = rx.iter().map(|r| r - LATERAL_EPIDURAL_MM).collect();
    let sac_ry: Vec<f64> = ry
        .iter()
        .map(|r| r - 0.5 * (POSTERIOR_EPIDURAL_MM + ANTERIOR_EPIDURAL_MM))
        .collect();
    parts.push(
        "dural_sac",
        MaterialClass::DuraCsf,
        sagittal_tube(sac_pts.clone(), &sac_rx, sac_ry),
    );
    let n = sac_pts.len();
    parts.push(
        "spinal_cord",
        MaterialClass::Nerve,
        sagittal_tube(
            sac_pts,
            &vec![CORD_HALF_WIDTH_MM; n],
            vec![CORD_HALF_DEPTH_MM; n],
        ),
    );
}

/// Ligamentum flavum: a [`FLAVUM_MM`] layer on the posterior wall of the canal between the
/// laminae of each segment C2-C3 .. C7-T1; bone overwrites it at the laminae.
fn ligamentum_flavum(sk: &Skeleton, canal: &Sdf) -> Sdf {
    let shell = canal.clone().offset(FLAVUM_MM).minus(canal.clone());
    Sdf::Union(
        sk.verts
            .windows(2)
            .map(|w| {
                let (up, lo) = (&w[0], &w[1]);
                let a = up.w(0.0, up.canal_y(), up.lamina_z() - up.d.lamina_half_h);
                let b = lo.w(0.0, lo.canal_y(), lo.lamina_z() + lo.d.lamina_half_h);
                let mid = 0.5 * (a + b);
                let back = -up.front();
                Sdf::Intersect(vec![
                    shell.clone(),
                    Sdf::HalfSpace {
                        normal: -back,
                        offset: -back.dot(mid) - 3.0,
                    },
                    Sdf::RoundBox {
                        half: DVec3::new(14.0, 20.0, 0.5 * a.distance(b) + 4.0),
                        round: 2.0,
                    }
                    .placed(Rigid::from_axes(mid, DVec3::X, a - b)),
                ])
            })
            .collect(),
    )
}

/// Pushes the carotid sheaths' vessels: the common carotid artery (7 mm across; Krejza J et al.,
/// Stroke 2006;37:1103-1105) in front of the transverse processes, 24 mm from the midline, and the
/// internal jugular vein (11 mm across, our choice) lateral to it; left before right.
pub(super) fn push_carotid_sheaths(parts: &mut Parts, sk: &Skeleton) {
    // (name, distance from the midline, depth in front of the body's centre, radius), mm.
    for (name, x, y, r) in [
        ("carotid_artery", 24.0, 6.0, 3.5),
        ("internal_jugular_vein", 34.0, 4.0, 5.5),
    ] {
        for (s, side) in [(LEFT, "left"), (RIGHT, "right")] {
            let pts = column_line(sk, s * x, |v| 0.5 * v.d.body_depth + y);
            let n = pts.len();
            parts.push(
                &format!("{name}_{side}"),
                MaterialClass::Vessel,
                Sdf::Tube {
                    points: pts,
                    radii: vec![r; n],
                },
            );
        }
    }
}
