//! The procedural cervical phantom: landmarks where their names say, the vertebral
//! arteries in their foramina transversaria, the cord in the sac, a morphometry table against the
//! published means, and closed meshes from the shared pipeline.

use glam::DVec3;
use sim_core::anatomy::asset::RegionAsset;
use sim_core::anatomy::phantom::cervical::{self, dims::PUBLISHED};
use sim_core::anatomy::phantom::model::Anatomy;
use sim_core::anatomy::pipeline::check_solid;

use crate::stations::{bone_of, name_at};

/// Distance from `p` along `dir` to the first point whose structure fails `keep`, in steps of
/// 0.05 mm (the solids are exact to well below that), up to `max_mm`.
fn run_length(a: &Anatomy, p: DVec3, dir: DVec3, max_mm: f64, keep: impl Fn(&str) -> bool) -> f64 {
    let d = dir.normalize();
    let mut t = 0.0;
    while t < max_mm && keep(&name_at(a, p + d * t)) {
        t += 0.05;
    }
    t
}

struct Frame {
    lm: std::collections::BTreeMap<String, DVec3>,
}

impl Frame {
    fn new(a: &Anatomy) -> Frame {
        Frame {
            lm: a
                .landmarks
                .iter()
                .map(|l| (l.name.clone(), DVec3::from_array(l.position_mm)))
                .collect(),
        }
    }
    fn get(&self, n: &str) -> DVec3 {
        *self.lm.get(n).unwrap_or_else(|| panic!("landmark {n}"))
    }
    /// Up (cranial) and anterior unit vectors at a level, from the body centres around it.
    fn axes(&self, upper: &str, lower: &str) -> (DVec3, DVec3) {
        let up = (self.get(&format!("{upper}_body_centre"))
            - self.get(&format!("{lower}_body_centre")))
        .normalize();
        (up, up.cross(DVec3::X).normalize())
    }
}

#[test]
fn cervical_landmarks_lie_where_their_names_say() {
    let params = cervical::default_params();
    let a = cervical::anatomy(&params);
    let f = Frame::new(&a);
    assert!(a.landmarks.len() >= 50, "{} landmarks", a.landmarks.len());
    for lm in &a.landmarks {
        let p = DVec3::from_array(lm.position_mm);
        if let Some(s) = &lm.inside_structure {
            assert_eq!(&name_at(&a, p), s, "{}", lm.name);
        }
        if lm.name.ends_with("_left") {
            assert!(p.x < -5.0, "{} at {p}", lm.name);
        }
        if lm.name.ends_with("_right") {
            assert!(p.x > 5.0, "{} at {p}", lm.name);
        }
    }
    let levels = ["C2", "C3", "C4", "C5", "C6", "C7", "T1"];
    for w in levels.windows(2) {
        for side in ["left", "right"] {
            // Facet joints: the centre is in the joint space, both articular processes within
            // 3 mm along the joint normal (the 2 mm space plus a millimetre into each).
            let j = f.get(&format!("{}_{}_facet_joint_{side}", w[0], w[1]));
            assert!(
                bone_of(&name_at(&a, j)).is_none(),
                "{j} in {}",
                name_at(&a, j)
            );
            let (up, front) = f.axes(w[0], w[1]);
            let bones_near: Vec<String> = (0..=36)
                .flat_map(|k| {
                    let t = f64::from(k) * 10f64.to_radians();
                    let d = up * t.cos() + front * t.sin();
                    [j + d * 3.0, j - d * 3.0]
                })
                .filter_map(|p| bone_of(&name_at(&a, p)).map(str::to_string))
                .collect();
            for v in w {
                assert!(
                    bones_near.iter().any(|b| b == v),
                    "{w:?} {side}: {bones_near:?}"
                );
            }
        }
    }
    // Medial branch targets: off the bone, the pillar of their vertebra within 1.5 mm medially.
    for v in ["C3", "C4", "C5", "C6"] {
        for (side, s) in [("left", -1.0), ("right", 1.0)] {
            let p = f.get(&format!("{v}_medial_branch_target_{side}"));
            assert!(bone_of(&name_at(&a, p)).is_none());
            let to_bone = run_length(&a, p, DVec3::X * -s, 10.0, |n| bone_of(n) != Some(v));
            // 1 mm by construction; 0.5 mm more for the smooth blend of the pillar's rounded box.
            assert!(to_bone <= 1.5, "{v} {side}: pillar {to_bone} mm medial");
        }
    }
    // Vertebral arteries C6-C1: the foramen centre is in the artery, and the vertebra's bone
    // closes around it in the axial plane (every one of 12 directions meets it within 7 mm: the
    // 3 mm foramen radius plus the 4 mm the thinnest ring wall may be set back).
    for v in ["C1", "C2", "C3", "C4", "C5", "C6"] {
        for side in ["left", "right"] {
            let p = f.get(&format!("{v}_foramen_transversarium_{side}"));
            assert_eq!(name_at(&a, p), format!("vertebral_artery_{side}"));
            let (up, front) = if v == "C1" {
                f.axes("C2", "C3")
            } else {
                f.axes(v, if v == "C6" { "C7" } else { "C6" })
            };
            let right = front.cross(up);
            for k in 0..12 {
                let t = f64::from(k) * 30f64.to_radians();
                let d = right * t.cos() + front * t.sin();
                let r = run_length(&a, p, d, 7.0, |n| bone_of(n) != Some(v));
                assert!(
                    r < 7.0,
                    "{v} {side}: no {v} bone within 7 mm at {}°",
                    k * 30
                );
            }
        }
    }
    // The cord inside the dural sac, inside the epidural space, on every side at C5.
    let c = f.get("C5_spinal_cord_centre");
    let (up, front) = f.axes("C4", "C6");
    for d in [front, -front, DVec3::X, -DVec3::X] {
        let cord = run_length(&a, c, d, 20.0, |n| n == "spinal_cord");
        let sac = run_length(&a, c + d * cord, d, 20.0, |n| n == "dural_sac");
        assert!(cord > 3.0 && sac > 0.5, "cord {cord} sac {sac} along {d}");
    }
    assert!(up.z > 0.9);
}

/// Each dimension measured on the solids, against the published mean and SD: within 2 SD.
#[test]
fn cervical_morphometry_is_within_two_sd_of_published_means() {
    let params = cervical::default_params();
    let a = cervical::anatomy(&params);
    let f = Frame::new(&a);
    let is_bone = |v: &'static str| move |n: &str| bone_of(n) == Some(v);
    let not_bone = |v: &'static str| move |n: &str| bone_of(n) != Some(v);
    let measure = |dim: &str, level: &'static str| -> f64 {
        if level == "C1" {
            // Back of the anterior arch to the front of the posterior arch, midline.
            let (_, front) = f.axes("C2", "C3");
            let c = 0.5
                * (f.get("C1_foramen_transversarium_left")
                    + f.get("C1_foramen_transversarium_right"));
            let fwd = run_length(&a, c, front, 30.0, not_bone("C1"));
            let back = run_length(&a, c, -front, 40.0, not_bone("C1"));
            return fwd + back;
        }
        if level == "C7_T1" {
            let p = f.get("C7_T1_posterior_epidural_space");
            let (_, front) = f.axes("C7", "T1");
            let e = |n: &str| n == "epidural_space";
            return run_length(&a, p, front, 10.0, e) + run_length(&a, p, -front, 10.0, e);
        }
        let lower = match level {
            "C4" => "C5",
            "C5" => "C6",
            _ => "C7",
        };
        let (up, front) = f.axes(level, lower);
        let c = f.get(&format!("{level}_body_centre"));
        let body_back = run_length(&a, c, -front, 30.0, is_bone(level));
        match dim {
            "body_width" => {
                // Endplate width, 1.5 mm above the inferior endplate (below the pedicles and
                // transverse processes, which join the body's sides higher up).
                let h = run_length(&a, c, -up, 30.0, is_bone(level));
                let p = c - up * (h - 1.5);
                run_length(&a, p, DVec3::X, 30.0, is_bone(level))
                    + run_length(&a, p, -DVec3::X, 30.0, is_bone(level))
            }
            "body_depth" => run_length(&a, c, front, 30.0, is_bone(level)) + body_back,
            "body_height" => {
                let p = c - front * (body_back - 2.0);
                run_length(&a, p, up, 30.0, is_bone(level))
                    + run_length(&a, p, -up, 30.0, is_bone(level))
            }
            "canal_depth" | "canal_width" => {
                let start = c - front * (body_back + 0.1);
                let depth = run_length(&a, start, -front, 40.0, not_bone(level));
                if dim == "canal_depth" {
                    depth
                } else {
                    let m = start - front * (0.5 * depth);
                    run_length(&a, m, DVec3::X, 30.0, not_bone(level))
                        + run_length(&a, m, -DVec3::X, 30.0, not_bone(level))
                }
            }
            "cord_depth" => {
                let p = f.get("C5_spinal_cord_centre");
                let k = |n: &str| n == "spinal_cord";
                run_length(&a, p, front, 10.0, k) + run_length(&a, p, -front, 10.0, k)
            }
            other => panic!("unknown dimension {other}"),
        }
    };
    eprintln!("| dimension | level | phantom mm | published mean (SD) mm | source |");
    let mut failures = Vec::new();
    for d in PUBLISHED {
        let m = measure(d.dimension, d.level);
        eprintln!(
            "| {} | {} | {m:.1} | {} ({}) | {} |",
            d.dimension, d.level, d.mean_mm, d.sd_mm, d.source
        );
        if (m - d.mean_mm).abs() > 2.0 * d.sd_mm {
            failures.push(format!("{} {}: {m:.2}", d.dimension, d.level));
        }
    }
    assert!(failures.is_empty(), "outside 2 SD: {failures:?}");
}

/// A coarse build (2 mm): every structure meshed, every mesh closed and outward, the bulky soft
/// tissues' meshes within 3 % of their masks (the lumbar phantom's bound for the same layers),
/// and a rebuild byte-identical.
#[test]
fn coarse_cervical_build_is_deterministic_and_closed() {
    let params = cervical::params_with_voxel_mm(2.0);
    let t0 = std::time::Instant::now();
    let region = cervical::build(&params, &mut |_| {}).unwrap();
    eprintln!(
        "cervical phantom at 2 mm: {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    assert_eq!(region.name, cervical::REGION_NAME);
    assert_eq!(
        region.structures.len(),
        cervical::structure_list(&params).len()
    );
    for s in &region.structures {
        check_solid(&s.name, &s.mesh, "cervical").unwrap();
        if [
            "skin",
            "subcutaneous_fat",
            "deep_soft_tissue",
            "posterior_neck_muscles_left",
            "posterior_neck_muscles_right",
        ]
        .contains(&s.name.as_str())
        {
            let rel = (s.mesh.signed_volume_mm3() - s.mask_volume_mm3) / s.mask_volume_mm3;
            assert!(rel.abs() < 0.03, "{}: mesh/mask {rel:+.3}", s.name);
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let a = cervical::ensure_built_with(dir.path(), &params, &mut |_| {}).unwrap();
    assert!(cervical::is_cached(dir.path(), &params));
    assert!(!sim_core::anatomy::phantom::is_cached(dir.path(), &params));
    let b = region.write_to(&dir.path().join("b")).unwrap();
    assert_eq!(
        a.provenance.files_sha256, b.files_sha256,
        "same parameters, same bytes"
    );
}

/// The cervical phantom every learner gets (default parameters: 1 mm grid, meshed from level
/// sets), built once per test binary (the mesh-volume tests read it too).
pub(crate) fn default_cervical() -> &'static RegionAsset {
    static A: std::sync::OnceLock<RegionAsset> = std::sync::OnceLock::new();
    A.get_or_init(|| {
        let t0 = std::time::Instant::now();
        let region = cervical::build(&cervical::default_params(), &mut |_| {}).unwrap();
        eprintln!(
            "default cervical phantom: {:.1} s",
            t0.elapsed().as_secs_f64()
        );
        region
    })
}

/// The default cervical phantom: every mesh closed; prints the structure table. A check of
/// what ships, so it runs with the suite.
#[test]
fn default_cervical_build() {
    let region = default_cervical();
    for s in &region.structures {
        check_solid(&s.name, &s.mesh, "cervical").unwrap();
        eprintln!(
            "| {} | {:.2} | {:.2} | {} |",
            s.name,
            s.mask_volume_mm3 / 1000.0,
            s.mesh.signed_volume_mm3() / 1000.0,
            s.mesh.triangle_count()
        );
    }
}

/// Every cervical structure has the needle feel of its tissue (the names drive
/// `Tissue::of_structure`, hence loss of resistance and vascular warnings).
#[test]
fn cervical_structures_map_to_their_tissues() {
    use sim_core::needle::Tissue;
    for (name, _) in cervical::structure_list(&cervical::params_with_voxel_mm(2.0)) {
        let t = Tissue::of_structure(&name);
        let expected = if bone_of(&name).is_some() {
            Tissue::Bone
        } else if name.contains("artery") || name.contains("vein") {
            Tissue::Vessel
        } else if name.contains("muscle") || name.starts_with("longus_colli") {
            Tissue::Muscle
        } else if name == "dural_sac" || name == "spinal_cord" {
            Tissue::Intrathecal
        } else if name == "epidural_space" {
            Tissue::EpiduralFat
        } else if name.starts_with("disc_") {
            Tissue::Disc
        } else {
            continue;
        };
        assert_eq!(t, expected, "{name}");
    }
}
