//! The cervical phantom's named landmarks: body centres, interlaminar windows and the posterior
//! epidural space of each segment, facet joints, medial branch targets, the foramina
//! transversaria and the C7 spinous tip.

use glam::DVec3;

use super::dims::POSTERIOR_EPIDURAL_MM;
use super::skeleton::{PILLAR_HALF, Skeleton};
use crate::anatomy::phantom::model::{LEFT, Landmark, RIGHT};

/// Collects landmarks in order.
#[derive(Default)]
struct Out(Vec<Landmark>);

impl Out {
    fn add(&mut self, name: String, pos: DVec3, description: &str, inside: Option<String>) {
        self.0.push(Landmark {
            name,
            position_mm: pos.to_array(),
            description: description.to_string(),
            inside_structure: inside,
        });
    }
}

const SIDES: [(f64, &str); 2] = [(LEFT, "left"), (RIGHT, "right")];

/// Every landmark of the cervical phantom.
pub(super) fn landmarks(sk: &Skeleton) -> Vec<Landmark> {
    let mut out = Out::default();
    let v = &sk.verts;
    for q in v {
        let n = q.d.name;
        out.add(
            format!("{n}_body_centre"),
            q.frame.translation,
            "centre of the vertebral body",
            Some(format!("{n}_cancellous")),
        );
    }
    for (i, w) in v.windows(2).enumerate() {
        let (up, lo) = (&w[0], &w[1]);
        let seg = format!("{}_{}", up.d.name, lo.d.name);
        let a = up.w(0.0, up.canal_back_y(), up.lamina_z() - up.d.lamina_half_h);
        let b = lo.w(0.0, lo.canal_back_y(), lo.lamina_z() + lo.d.lamina_half_h);
        let mid = 0.5 * (a + b);
        let front = up.front();
        out.add(
            format!("{seg}_interlaminar_window_centre"),
            mid - front * 1.25,
            "midline centre of the interlaminar window, in the ligamentum flavum",
            Some("ligamentum_flavum".into()),
        );
        out.add(
            format!("{seg}_posterior_epidural_space"),
            mid + front * (0.5 * POSTERIOR_EPIDURAL_MM),
            "midline posterior epidural space just in front of the ligamentum flavum",
            Some("epidural_space".into()),
        );
        for (k, (_, side)) in SIDES.iter().enumerate() {
            out.add(
                format!("{seg}_facet_joint_{side}"),
                sk.facets[i][k].centre,
                "centre of the facet joint space",
                None,
            );
        }
    }
    // Medial branch targets C3-C6: the centroid of the articular pillar's rhomboid in the lateral
    // view (midway between the joints above and below), 1 mm off its lateral surface (Barnsley L,
    // Bogduk N, "Medial branch blocks are specific for the diagnosis of cervical zygapophyseal
    // joint pain", Reg Anesth 1993;18(6):343-350; the medial branch crosses the waist of the
    // pillar there).
    for (k, q) in v.iter().enumerate().take(5).skip(1) {
        for (j, (s, side)) in SIDES.iter().enumerate() {
            let c = 0.5 * (sk.facets[k - 1][j].centre + sk.facets[k][j].centre);
            let local = q.frame.to_local(c);
            let pos = q.w(s * (q.pillar_x() + PILLAR_HALF.x + 1.0), local.y, local.z);
            out.add(
                format!("{}_medial_branch_target_{side}", q.d.name),
                pos,
                "medial branch block target: the centroid of the articular pillar in the lateral \
                 view, 1 mm lateral to the bone",
                None,
            );
        }
    }
    // Foramina transversaria C1-C6 on the vertebral artery's course.
    for (s, side) in SIDES {
        for q in &v[..5] {
            let f = q.foramen(s);
            out.add(
                format!("{}_foramen_transversarium_{side}", q.d.name),
                q.w(f.x, f.y, f.z),
                "centre of the foramen transversarium, on the vertebral artery",
                Some(format!("vertebral_artery_{side}")),
            );
        }
        let f = sk.atlas.foramen(s);
        out.add(
            format!("C1_foramen_transversarium_{side}"),
            sk.atlas.w(f.x, f.y, f.z),
            "centre of the atlas's foramen transversarium, on the vertebral artery",
            Some(format!("vertebral_artery_{side}")),
        );
    }
    let c5 = &v[3];
    out.add(
        "C5_spinal_cord_centre".into(),
        c5.w(0.0, c5.canal_y() + 0.75, 0.0),
        "centre of the spinal cord at C5",
        Some("spinal_cord".into()),
    );
    let c7 = &v[5];
    out.add(
        "C7_spinous_tip".into(),
        c7.w(
            0.0,
            c7.canal_back_y() - c7.d.sp_length - 2.0,
            c7.lamina_z() - 8.0,
        ),
        "tip of the C7 spinous process (vertebra prominens), inside the bone",
        Some("C7_cortical".into()),
    );
    out.0
}
