//! The L-buffer's nesting plan (`sim_core::fluoro::nesting`) on simple nested shapes and on the
//! coarse phantom: direct containers, effective materials, the meshes left out, and the linear
//! rule ("own chord to the effective material, minus it from the container's") against the
//! priority rule of `Scene::ray_chords`.

use sim_core::anatomy::phantom::{self, PhantomParams};
use sim_core::fluoro::nesting::{
    NestedMesh, direct_containers, inner_points, nesting_plan, soup_box, soup_volume,
};
use sim_core::fluoro::scene::ChordScratch;
use sim_core::fluoro::{FluoroMaterial, Scene};
use sim_core::geom::{Bvh, capped_cylinder};
use sim_core::material::MaterialClass;
use sim_core::mesh::TriMesh;

const SOFT: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::SoftTissue);
const FAT: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::Fat);
const CORTICAL: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::CorticalBone);
const CANCELLOUS: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::Cancellous);
const DISC: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::Disc);
const VESSEL: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::Vessel);

/// A body sphere holding a bone sphere with marrow, a fat box beside the bone, and a needle.
fn nested_scene() -> Scene {
    let mut scene = Scene::new();
    scene.add("body", SOFT, &TriMesh::icosphere([0.0; 3], 100.0, 3));
    scene.add(
        "bone",
        CORTICAL,
        &TriMesh::icosphere([20.0, 0.0, 0.0], 30.0, 3),
    );
    scene.add(
        "marrow",
        CANCELLOUS,
        &TriMesh::icosphere([20.0, 0.0, 0.0], 20.0, 3),
    );
    scene.add(
        "fat",
        FAT,
        &TriMesh::axis_aligned_box([-70.0, -10.0, -10.0], [-40.0, 10.0, 10.0]),
    );
    scene.add(
        "needle",
        FluoroMaterial::Steel,
        &capped_cylinder([-150.0, 0.0, 0.0], [20.0, 0.0, 0.0], 0.4, 8),
    );
    scene
}

fn mesh(
    entry: usize,
    name: &str,
    effective: FluoroMaterial,
    container: Option<FluoroMaterial>,
) -> (usize, String, FluoroMaterial, Option<FluoroMaterial>) {
    (entry, name.to_owned(), effective, container)
}

fn summary(plan: &[NestedMesh]) -> Vec<(usize, String, FluoroMaterial, Option<FluoroMaterial>)> {
    plan.iter()
        .map(|m| (m.entry, m.name.clone(), m.effective, m.container))
        .collect()
}

#[test]
fn nested_spheres_and_a_box_get_their_direct_containers() {
    let scene = nested_scene();
    // The marrow's direct container is the bone (the smallest mesh holding it), not the body;
    // steel is never contained nor a container.
    assert_eq!(
        direct_containers(&scene),
        [None, Some(0), Some(1), Some(0), None]
    );
    let plan = nesting_plan(&scene);
    assert_eq!(
        summary(&plan),
        [
            mesh(0, "body", SOFT, None),
            mesh(1, "bone", CORTICAL, Some(SOFT)),
            mesh(2, "marrow", CANCELLOUS, Some(CORTICAL)),
            mesh(3, "fat", FAT, Some(SOFT)),
        ]
    );
    let water: Vec<bool> = plan.iter().map(NestedMesh::water_basis_only).collect();
    assert_eq!(water, [true, false, false, true]);
    assert_eq!(plan[3].centre_mm, [-55.0, 0.0, 0.0]);
}

#[test]
fn a_mesh_inside_a_higher_priority_one_is_left_out() {
    // Soft tissue inside bone counts as bone: it adds and removes the same material.
    let mut scene = Scene::new();
    scene.add("bone", CORTICAL, &TriMesh::icosphere([0.0; 3], 30.0, 2));
    scene.add("island", SOFT, &TriMesh::icosphere([0.0; 3], 10.0, 2));
    assert_eq!(direct_containers(&scene), [None, Some(0)]);
    assert_eq!(
        summary(&nesting_plan(&scene)),
        [mesh(0, "bone", CORTICAL, None)]
    );
}

#[test]
fn on_equal_priority_the_later_entry_wins() {
    assert_eq!(DISC.default_priority(), VESSEL.default_priority());
    let outer = TriMesh::icosphere([0.0; 3], 30.0, 2);
    let inner = TriMesh::icosphere([0.0; 3], 10.0, 2);
    let mut later_inner = Scene::new();
    later_inner.add("disc", DISC, &outer);
    later_inner.add("vessel", VESSEL, &inner);
    assert_eq!(
        summary(&nesting_plan(&later_inner)),
        [
            mesh(0, "disc", DISC, None),
            mesh(1, "vessel", VESSEL, Some(DISC))
        ]
    );
    let mut earlier_inner = Scene::new();
    earlier_inner.add("vessel", VESSEL, &inner);
    earlier_inner.add("disc", DISC, &outer);
    assert_eq!(
        summary(&nesting_plan(&earlier_inner)),
        [mesh(1, "disc", DISC, None)]
    );
}

#[test]
fn soup_helpers_measure_a_box() {
    let b = TriMesh::axis_aligned_box([-1.0, 2.0, 3.0], [4.0, 6.0, 9.0]);
    let tris: Vec<[[f64; 3]; 3]> = (0..b.triangle_count()).map(|i| b.triangle(i)).collect();
    assert!((soup_volume(&tris) - 5.0 * 4.0 * 6.0).abs() < 1e-12);
    assert_eq!(soup_box(&tris), ([-1.0, 2.0, 3.0], [4.0, 6.0, 9.0]));
    let pts = inner_points(&tris);
    assert_eq!(pts.len(), tris.len());
    let bvh = Bvh::new(&b);
    assert!(pts.iter().all(|&p| bvh.contains(p)), "{pts:?}");
    // Capped at 48 points on a finer mesh, all inside.
    let sphere = TriMesh::icosphere([1.0, 2.0, 3.0], 5.0, 3);
    let tris: Vec<[[f64; 3]; 3]> = (0..sphere.triangle_count())
        .map(|i| sphere.triangle(i))
        .collect();
    let pts = inner_points(&tris);
    assert_eq!(pts.len(), 48);
    let bvh = Bvh::new(&sphere);
    assert!(pts.iter().all(|&p| bvh.contains(p)));
}

/// Per-material chords of the linear rule along one ray (what an L-buffer sums).
fn linear_chords(
    scene: &Scene,
    plan: &[NestedMesh],
    o: [f64; 3],
    d: [f64; 3],
) -> [f64; FluoroMaterial::COUNT] {
    let raw = scene.ray_entry_chords(o, d, 1e4);
    let mut out = [0.0; FluoroMaterial::COUNT];
    for m in plan {
        out[m.effective.index()] += raw[m.entry];
        if let Some(c) = m.container {
            out[c.index()] -= raw[m.entry];
        }
    }
    out
}

#[test]
fn the_linear_rule_equals_the_priority_rule_on_nested_meshes() {
    let mut scene = nested_scene();
    // No cancellous clamp (it only binds on a marrow chord longer than the bone's run less two
    // shells, which these spheres never have; zero keeps the comparison about nesting only).
    scene.cortical_shell_mm = 0.0;
    let plan = nesting_plan(&scene);
    let needle = FluoroMaterial::Steel.index();
    let mut scratch = ChordScratch::default();
    let mut rays = 0;
    for i in -12..=12 {
        for j in -12..=12 {
            let o = [f64::from(i) * 8.0, -500.0, f64::from(j) * 8.0 + 0.37];
            let d = [0.0, 1.0, 0.0];
            let priority = scene.ray_chords(o, d, 1e4, &mut scratch).chords_mm;
            if priority[needle] != 0.0 {
                continue; // The needle is subtracted by the GPU's own pass, not by the plan.
            }
            let linear = linear_chords(&scene, &plan, o, d);
            for k in 0..FluoroMaterial::COUNT {
                // Both sum the same crossings in a different order: round-off of 1e3 mm chords.
                assert!(
                    (linear[k] - priority[k]).abs() < 1e-9,
                    "ray {o:?}, channel {k}: linear {} priority {}",
                    linear[k],
                    priority[k]
                );
            }
            rays += 1;
        }
    }
    assert!(rays > 600, "{rays}");
}

/// The phantom's structures are disjoint masks inside the soft-tissue envelope (skin holding
/// deep soft tissue): every one is nested in soft tissue, none in another structure, and the
/// deep soft tissue (soft tissue in soft tissue) adds nothing and is left out.
#[test]
fn the_coarse_phantom_nests_every_structure_in_soft_tissue() {
    let params = PhantomParams::with_voxel_mm(6.0);
    let region = phantom::build(&params, &mut |_| {}).expect("phantom builds");
    let mut scene = Scene::new();
    for s in &region.structures {
        scene.add(s.name.clone(), FluoroMaterial::Tissue(s.material), &s.mesh);
    }
    let entries = scene.entries();
    let containers = direct_containers(&scene);
    let plan = nesting_plan(&scene);
    assert_eq!(plan, nesting_plan(&scene), "deterministic");
    let names: Vec<&str> = plan.iter().map(|m| m.name.as_str()).collect();
    let expected: Vec<&str> = entries
        .iter()
        .map(|e| e.name.as_str())
        .filter(|&n| n != "deep_soft_tissue")
        .collect();
    assert_eq!(names, expected);
    for m in &plan {
        let container = containers[m.entry].map(|c| entries[c].name.as_str());
        if m.name == "skin" {
            assert_eq!((container, m.container), (None, None));
        } else {
            assert!(
                matches!(container, Some("skin" | "deep_soft_tissue")),
                "{m:?} in {container:?}"
            );
            assert_eq!(m.container, Some(SOFT), "{m:?}");
        }
    }
    assert!(plan.iter().any(|m| m.effective == CANCELLOUS));
    assert!(plan.iter().any(|m| m.effective == CORTICAL));
}
