//! Draft scenes: a coarser copy of a scene for the cheap preview frame shown while the C-arm is
//! being moved (the full frame of the real scene follows once the input settles).
//!
//! Each entry's mesh is rebuilt from its BVH's triangles (corners welded where their
//! coordinates are bit-identical, which is how they were copied from one indexed mesh) and
//! reduced by [`crate::anatomy::decimate::decimate`] (quadric edge collapse with topology and
//! volume checks, so each draft mesh stays closed and within the volume bound of its original).
//! Materials, priorities and the entry order are kept, so a renderer treats the draft exactly as
//! the scene it stands for. Deterministic: the same scene always gives the same draft, so a
//! replay reproduces a preview frame bit for bit.
//!
//! What a draft costs in fidelity is measured, not bounded here: meshes reduced independently
//! may cross where their originals touched (the GPU's L-buffer counts such an overlap twice).
//! The `fluoro_gpu` benchmark reports the draft frame's time and its `ln T` difference from the
//! full frame on the same pose.

use rustc_hash::FxHashMap;

use std::path::Path;

use super::scene::{Scene, SceneEntry};
use super::scene_store::{Miss, StoreOutcome, store_after_miss, trees_from};
use crate::anatomy::decimate::{DecimationParams, decimate};
use crate::geom::Bvh;
use crate::mesh::TriMesh;
use crate::par::par_map_heaviest_first;

/// How far a draft scene is reduced.
#[derive(Debug, Clone, PartialEq)]
pub struct DraftParams {
    /// The reduction of every entry (target fraction, largest deviation, volume bound).
    pub decimation: DecimationParams,
    /// Entries with fewer triangles than this are copied unreduced (a needle, small boxes).
    pub min_triangles: usize,
}

impl Default for DraftParams {
    /// A twelfth of the triangles and up to 2 mm deviation (under two detector pixels of the
    /// draft frame at the isocentre of a 300 mm, 256-pixel field at 1.3x magnification), volume
    /// within 5 %. Simulator choices, measured on the default lumbar phantom (3.85 M
    /// triangles) on 2 cores: 0.32 M triangles in 1.7-1.8 s, and a C-arm-moved draft at
    /// 256 x 256 costs 16-19 ms on lavapipe against 71-97 ms for the full frame at 512 x 512,
    /// 0.7-0.8 grey levels from it on average over 8 x 8 blocks (99th percentile 3.4-3.5;
    /// `fluoro_draft` bench). (While the decimator refused edges shared by four triangles,
    /// half the phantom's triangles stayed unreduced: 2.04 M in 8 s, drafts of 28-30 ms.)
    fn default() -> Self {
        DraftParams {
            decimation: DecimationParams {
                target_fraction: 1.0 / 12.0,
                max_error_mm: 2.0,
                max_volume_change: 0.05,
            },
            min_triangles: 64,
        }
    }
}

/// The indexed mesh of a triangle soup whose shared corners are bit-identical.
pub fn weld(triangles_mm: &[[[f64; 3]; 3]]) -> TriMesh {
    let mut index: FxHashMap<[u64; 3], u32> =
        FxHashMap::with_capacity_and_hasher(triangles_mm.len() / 2 + 3, Default::default());
    let mut mesh = TriMesh {
        vertices_mm: Vec::with_capacity(triangles_mm.len() / 2 + 3),
        triangles: Vec::with_capacity(triangles_mm.len()),
    };
    for t in triangles_mm {
        let mut ids = [0u32; 3];
        for (id, v) in ids.iter_mut().zip(t) {
            *id = *index.entry(v.map(f64::to_bits)).or_insert_with(|| {
                mesh.vertices_mm.push(*v);
                (mesh.vertices_mm.len() - 1) as u32
            });
        }
        mesh.triangles.push(ids);
    }
    mesh
}

/// Version of the drafts [`draft_scene`] makes of a scene with given [`DraftParams`]: a stored
/// draft ([`draft_scene_stored`]) is reused only under the version that made it. Raise it
/// whenever [`weld`], the decimator or this module's reduction changes.
pub const DRAFT_VERSION: u32 = 1;

/// The draft of `scene` (see the module doc): same entries, names, materials and priorities,
/// each mesh reduced.
///
/// Entries are reduced on every core, largest first; each alone, so the draft does not depend
/// on the number of cores.
pub fn draft_scene(scene: &Scene, params: &DraftParams) -> Scene {
    draft_with_meshes(scene, params).0
}

/// The draft and its reduced meshes, in entry order.
fn draft_with_meshes(scene: &Scene, params: &DraftParams) -> (Scene, Vec<TriMesh>) {
    let entries = scene.entries();
    let weights: Vec<usize> = entries.iter().map(|e| e.bvh.triangle_count()).collect();
    let reduced = par_map_heaviest_first(&weights, &|i| {
        let e = &entries[i];
        let mesh = weld(e.bvh.triangles_mm());
        let mesh = if mesh.triangles.len() < params.min_triangles {
            mesh
        } else {
            decimate(&mesh, &params.decimation).0
        };
        let entry = SceneEntry {
            name: e.name.clone(),
            material: e.material,
            priority: e.priority,
            bvh: Bvh::new(&mesh),
        };
        (entry, mesh)
    });
    let mut draft = Scene::new();
    let mut meshes = Vec::with_capacity(reduced.len());
    for (entry, mesh) in reduced {
        draft.push_entry(entry);
        meshes.push(mesh);
    }
    (draft, meshes)
}

/// [`draft_scene`], taken from the file at `store` when it holds the draft of this scene under
/// `key` (a description of the scene's meshes that changes whenever they could; the draft
/// parameters and [`DRAFT_VERSION`] are added here), else made and stored there. The draft is
/// the same either way, bit for bit; a stale or corrupt file is never served.
pub fn draft_scene_stored(
    scene: &Scene,
    params: &DraftParams,
    store: &Path,
    key: &str,
) -> (Scene, StoreOutcome) {
    let key = draft_key(params, key);
    let bytes = std::fs::read(store).ok();
    match reuse_draft(bytes.as_deref(), &key, scene) {
        Ok(draft) => (draft, StoreOutcome::Reused),
        Err(miss) => {
            let (draft, meshes) = draft_with_meshes(scene, params);
            let topologies: Vec<_> = draft.entries().iter().map(|e| e.bvh.topology()).collect();
            let entries: Vec<_> = topologies
                .iter()
                .zip(&meshes)
                .map(|(t, m)| (t, Some(m)))
                .collect();
            (draft, store_after_miss(store, &key, &entries, miss))
        }
    }
}

/// The key of the draft of the scene with meshes named by `key`, made with `params`.
fn draft_key(params: &DraftParams, key: &str) -> String {
    format!("draft {DRAFT_VERSION} {params:?} of {key}")
}

/// The stored draft of `scene`, entry by entry.
fn reuse_draft(stored: Option<&[u8]>, key: &str, scene: &Scene) -> Result<Scene, Miss> {
    let names: Vec<&str> = scene.entries().iter().map(|e| e.name.as_str()).collect();
    let trees = trees_from(stored, key, &names, None)?;
    let mut draft = Scene::new();
    for (e, bvh) in scene.entries().iter().zip(trees) {
        draft.push_entry(SceneEntry {
            name: e.name.clone(),
            material: e.material,
            priority: e.priority,
            bvh,
        });
    }
    Ok(draft)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluoro::FluoroMaterial;
    use crate::material::MaterialClass;

    /// The BVH keeps triangles in tree order; welding them back gives the same closed solid.
    #[test]
    fn weld_rebuilds_a_closed_mesh_of_the_same_volume() {
        let sphere = TriMesh::icosphere([1.0, 2.0, 3.0], 20.0, 4);
        let mut scene = Scene::new();
        scene.add("s", FluoroMaterial::Tissue(MaterialClass::Muscle), &sphere);
        let welded = weld(scene.entries()[0].bvh.triangles_mm());
        assert_eq!(welded.vertices_mm.len(), sphere.vertices_mm.len());
        assert_eq!(welded.triangles.len(), sphere.triangles.len());
        assert!(welded.topology_report().is_closed_and_consistent());
        let (a, b) = (welded.signed_volume_mm3(), sphere.signed_volume_mm3());
        assert!((a - b).abs() <= 1e-9 * b.abs(), "{a} vs {b}");
    }

    /// A draft keeps the entries in order with their materials and priorities, reduces the
    /// large meshes (closed, volume within the bound) and copies the small ones.
    #[test]
    fn a_draft_reduces_large_meshes_and_keeps_the_rest() {
        let big = TriMesh::icosphere([0.0; 3], 40.0, 5);
        let small = TriMesh::icosphere([0.0; 3], 5.0, 1);
        let mut scene = Scene::new();
        scene.add("outer", FluoroMaterial::Tissue(MaterialClass::Muscle), &big);
        scene.add_with_priority("inner", FluoroMaterial::Steel, 7, &small);
        let params = DraftParams::default();
        let draft = draft_scene(&scene, &params);
        assert_eq!(draft.entries().len(), 2);
        for (d, e) in draft.entries().iter().zip(scene.entries()) {
            assert_eq!(
                (&d.name, d.material, d.priority),
                (&e.name, e.material, e.priority)
            );
        }
        let reduced = weld(draft.entries()[0].bvh.triangles_mm());
        assert!(reduced.topology_report().is_closed_and_consistent());
        assert!(
            reduced.triangles.len() * 4 < big.triangles.len(),
            "{} of {}",
            reduced.triangles.len(),
            big.triangles.len()
        );
        let change = reduced.signed_volume_mm3() / big.signed_volume_mm3() - 1.0;
        assert!(
            change.abs() <= params.decimation.max_volume_change,
            "{change}"
        );
        assert_eq!(
            draft.entries()[1].bvh.triangle_count(),
            small.triangles.len(),
            "a mesh under min_triangles is copied"
        );
        // Deterministic: the same scene gives the same draft.
        let again = draft_scene(&scene, &params);
        assert_eq!(
            again.entries()[0].bvh.triangles_mm(),
            draft.entries()[0].bvh.triangles_mm()
        );
    }

    /// A stored draft is the made one bit for bit; another key (other parameters) or a spoiled
    /// file is made again and stored, never served.
    #[test]
    fn a_stored_draft_is_the_made_one_and_a_bad_store_is_remade() {
        let big = TriMesh::icosphere([0.0; 3], 40.0, 4);
        let small = TriMesh::icosphere([3.0, 0.0, 0.0], 5.0, 1);
        let mut scene = Scene::new();
        scene.add("outer", FluoroMaterial::Tissue(MaterialClass::Muscle), &big);
        scene.add(
            "inner",
            FluoroMaterial::Tissue(MaterialClass::CorticalBone),
            &small,
        );
        let params = DraftParams::default();
        let made: Vec<Bvh> = draft_scene(&scene, &params)
            .entries()
            .iter()
            .map(|e| e.bvh.clone())
            .collect();
        let bvhs = |s: &Scene| {
            s.entries()
                .iter()
                .map(|e| e.bvh.clone())
                .collect::<Vec<_>>()
        };
        let dir = std::env::temp_dir().join(format!(
            "draft-store-{}",
            crate::anatomy::asset::unique_suffix()
        ));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let store = dir.join("draft.bin");
        let (d, outcome) = draft_scene_stored(&scene, &params, &store, "k");
        assert!(
            matches!(outcome, StoreOutcome::Built { stored: Ok(()), .. }),
            "{outcome:?}"
        );
        assert_eq!(bvhs(&d), made);
        let (d, outcome) = draft_scene_stored(&scene, &params, &store, "k");
        assert_eq!(outcome, StoreOutcome::Reused);
        assert_eq!(bvhs(&d), made);
        for (e, m) in d.entries().iter().zip(scene.entries()) {
            assert_eq!(
                (&e.name, e.material, e.priority),
                (&m.name, m.material, m.priority)
            );
        }
        let good = std::fs::read(&store).expect("stored");
        // Other parameters: stale.
        let other = DraftParams {
            min_triangles: 10_000,
            ..DraftParams::default()
        };
        let (_, outcome) = draft_scene_stored(&scene, &other, &store, "k");
        assert!(matches!(outcome, StoreOutcome::Built { ref why, .. } if why.contains("other")));
        std::fs::write(&store, &good).expect("restore");
        // A flipped byte in a vertex, in a triangle, or a truncation: corrupt, remade.
        for at in [good.len() / 3, good.len() - 40] {
            let mut bad = good.clone();
            bad[at] ^= 0x10;
            std::fs::write(&store, &bad).expect("spoil");
            let (d, outcome) = draft_scene_stored(&scene, &params, &store, "k");
            assert!(
                matches!(outcome, StoreOutcome::Built { ref why, .. } if why.contains("corrupt")),
                "{outcome:?}"
            );
            assert_eq!(bvhs(&d), made);
            assert_eq!(std::fs::read(&store).expect("rewritten"), good);
        }
        // A checksummed file of the right key whose mesh names a missing vertex: refused.
        let (draft, meshes) = draft_with_meshes(&scene, &params);
        let mut broken = meshes[1].clone();
        broken.triangles[0][0] = broken.vertices_mm.len() as u32;
        let topologies: Vec<_> = draft.entries().iter().map(|e| e.bvh.topology()).collect();
        let key = draft_key(&params, "k");
        let bytes = super::super::scene_store::encode(
            &key,
            &[
                (&topologies[0], Some(&meshes[0])),
                (&topologies[1], Some(&broken)),
            ],
        );
        assert!(matches!(
            reuse_draft(Some(&bytes), &key, &scene),
            Err(Miss::Corrupt(_))
        ));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
