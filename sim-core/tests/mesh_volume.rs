//! Thin structures meshed from their level sets (`PhantomParams::level_set_meshed`): every
//! phantom structure's mesh volume against its analytic volume (the octree integral of its
//! solids, `phantom::level_set`), on the default grid and at 3 mm; and the same comparison for
//! mask meshes (what the phantom shipped before), which shows what the level sets change.

use sim_core::anatomy::asset::RegionAsset;
use sim_core::anatomy::phantom::{self, PhantomParams, cervical, level_set};

/// Per structure (name, analytic mm^3, mesh mm^3, relative error), printed as a table.
fn compare(region: &RegionAsset, params: &PhantomParams) -> Vec<(String, f64, f64, f64)> {
    compare_anatomy(region, params, &phantom::anatomy(params))
}

fn compare_anatomy(
    region: &RegionAsset,
    params: &PhantomParams,
    anatomy: &phantom::model::Anatomy,
) -> Vec<(String, f64, f64, f64)> {
    let t = std::time::Instant::now();
    let exact = level_set::structure_volumes_mm3(anatomy, &params.grid());
    eprintln!(
        "analytic volumes on the {} mm grid in {:.1?}",
        params.voxel_mm,
        t.elapsed()
    );
    assert_eq!(exact.len(), region.structures.len());
    eprintln!("| structure | analytic ml | mesh ml | mesh error |");
    eprintln!("|---|---:|---:|---:|");
    exact
        .into_iter()
        .zip(&region.structures)
        .map(|((name, v), s)| {
            assert_eq!(name, s.name);
            let m = s.mesh.signed_volume_mm3();
            let rel = (m - v) / v;
            eprintln!(
                "| {name} | {:.2} | {:.2} | {:+.2} % |",
                v / 1000.0,
                m / 1000.0,
                100.0 * rel
            );
            (name, v, m, rel)
        })
        .collect()
}

fn assert_within(rows: &[(String, f64, f64, f64)], limit: f64, flavum: &str) {
    let worst = rows
        .iter()
        .max_by(|a, b| a.3.abs().total_cmp(&b.3.abs()))
        .expect("structures");
    eprintln!("worst: {} {:+.2} %", worst.0, 100.0 * worst.3);
    let outside: Vec<String> = rows
        .iter()
        .filter(|r| r.3.abs() >= limit)
        .map(|r| format!("{} {:+.2} %", r.0, 100.0 * r.3))
        .collect();
    assert!(outside.is_empty(), "beyond {limit}: {outside:?}");
    assert!(
        rows.iter().any(|r| r.0 == flavum),
        "the flavum is among them"
    );
}

/// The goal on the grid learners get is every structure within 5 % of its analytic volume, the
/// ligamentum flavum included. The shipped phantom (the default parameters, meshed from level
/// sets; the build the morphometry tests share): the worst is the L5 cortex at -4.39 % and the
/// flavum is at -3.92 % (-5.40 % while the triangles beside its junctions kept their chords;
/// -9.1 % for mask meshes).
#[test]
fn mesh_volume_of_every_structure_is_within_5_percent_on_the_default_grid() {
    let params = PhantomParams::default();
    assert!(
        params.mesh_from_level_sets,
        "the shipped phantom meshes its level sets"
    );
    let region = crate::morphometry::default_phantom();
    let triangles: usize = region
        .structures
        .iter()
        .map(|s| s.mesh.triangle_count())
        .sum();
    eprintln!("{triangles} triangles");
    let rows = compare(region, &params);
    assert_within(&rows, 0.05, "ligamentum_flavum");
}

/// What mask meshes (the masks' 0.5 levels, as the phantom was meshed before) give on the same
/// grid against the same analytic volumes: the flavum loses more than 5 % (-9.1 % measured; the
/// L5 roots -6 to -9 %), which is what the level sets mend (and a check that the comparison can
/// fail).
#[test]
fn mesh_volume_of_the_mask_meshes_misses_the_goal_on_thin_structures() {
    let params = PhantomParams::with_voxel_mm(1.5);
    assert!(!params.mesh_from_level_sets);
    let region = phantom::build(&params, &mut |_| {}).expect("mask phantom builds");
    let rows = compare(&region, &params);
    let flavum = rows
        .iter()
        .find(|r| r.0 == "ligamentum_flavum")
        .expect("flavum");
    assert!(flavum.3 < -0.06, "{flavum:?}");
}

/// The goal at 3 mm: every structure within 10 % (the 3 mm grid meshes on a 1.5 mm lattice, see
/// `PhantomParams::with_voxel_mm`).
#[test]
fn mesh_volume_of_every_structure_is_within_10_percent_at_3_mm() {
    let params = PhantomParams::level_set_meshed(3.0);
    let region = phantom::build(&params, &mut |_| {}).expect("3 mm phantom builds");
    let rows = compare(&region, &params);
    assert_within(&rows, 0.10, "ligamentum_flavum");
}

/// The other procedural phantom, the neck as shipped (default 1 mm grid, level sets): every
/// structure within 5 %.
/// Its 2.5 mm flavum is the worst at -4.91 % (close to the goal: its extraction alone loses
/// 5.6 %, where its rims and the wedges between it and the laminae are thinner than the
/// lattice, and refinement wins back 1.6 points less the splits that would cross the laminae).
#[test]
fn mesh_volume_of_every_cervical_structure_is_within_5_percent() {
    let params = cervical::default_params();
    assert!(
        params.mesh_from_level_sets,
        "the shipped neck meshes its level sets"
    );
    let region = crate::cervical::default_cervical();
    let rows = compare_anatomy(region, &params, &cervical::anatomy(&params));
    let flavum = rows
        .iter()
        .find(|r| r.0.contains("flavum"))
        .map(|r| r.0.clone())
        .expect("the neck has a flavum");
    assert_within(&rows, 0.05, &flavum);
}

/// The reference itself: halving the octree's smallest cell from the one the reference uses
/// moves the thinnest structures' analytic volumes (the flavum, a nerve root, a cortical shell,
/// the iliac marrow, the epidural space) by under 0.5 %, and the volumes are positive.
#[test]
fn analytic_mesh_volume_reference_converges() {
    let params = PhantomParams::level_set_meshed(1.5);
    let anatomy = phantom::anatomy(&params);
    let sets = level_set::level_sets(&anatomy, &params.grid());
    for name in [
        "ligamentum_flavum",
        "nerve_root_L5_left",
        "L4_cortical",
        "ilium_left_cancellous",
        "epidural_space",
    ] {
        let i = anatomy
            .parts
            .iter()
            .position(|p| p.name == name)
            .expect(name);
        let coarse = sets[i].volume_mm3(params.voxel_mm / 4.0);
        let leaf = level_set::reference_leaf_mm(params.voxel_mm, coarse);
        let (a, b) = (sets[i].volume_mm3(leaf), sets[i].volume_mm3(0.5 * leaf));
        let rel = (a - b) / b;
        eprintln!(
            "{name}: {a:.1} mm^3 at {leaf} mm, {b:.1} at {} mm ({:+.3} %)",
            0.5 * leaf,
            100.0 * rel
        );
        assert!(b > 0.0 && rel.abs() < 0.005, "{name}: {a} vs {b}");
    }
}
