//! The anatomy a session runs in, loaded once per worker and shared (read-only) by its sessions.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use sim_core::anatomy::asset::{MESHES_FILE, RegionAsset, Source, StructureAsset};
use sim_core::anatomy::phantom;
use sim_core::fluoro::scene_store::{STORE_FILE, StoreOutcome};
use sim_core::fluoro::{FluoroMaterial, Scene};
use sim_core::material::MaterialClass;
use sim_core::needle::{BoneSurface, RayHit, Tissue};

/// A region ready for simulation: the fluoroscopy scene of its structures (one BVH each, built
/// once), which of them are bone for needle contact, named landmarks, and the hashes that
/// identify the asset in reproducibility records.
#[derive(Debug)]
pub struct Region {
    /// Region name (e.g. `lumbar-phantom`).
    pub name: String,
    /// Every structure as a scene entry, in asset order (entry `i` is structure `i`).
    pub scene: Scene,
    /// Indices of the cortical-bone entries (the outer bone surface the needle meets).
    pub bone_entries: Vec<usize>,
    /// Named points, model frame, mm.
    pub landmarks: BTreeMap<String, [f64; 3]>,
    /// SHA-256 of every asset file (from the provenance), by file name.
    pub asset_sha256: BTreeMap<String, String>,
    /// Where the anatomy came from, in words (generator or CT file).
    pub source: String,
    /// The parameters of a procedural phantom region (the phantom is a pure function of them),
    /// from which the contrast modality builds its transport domains; `None` for other regions.
    pub phantom: Option<phantom::PhantomParams>,
    /// Where the region's derived scenes are stored, and the key that names its meshes there
    /// (regions read from a folder; `None` for regions made in memory).
    pub store: Option<SceneStore>,
}

/// A region folder's stored scenes ([`STORE_FILE`] for the scene's trees, [`DRAFT_STORE_FILE`]
/// for the draft scene) and the key of the meshes they were made from.
#[derive(Debug, Clone, PartialEq)]
pub struct SceneStore {
    /// The region's folder.
    pub dir: PathBuf,
    /// Names the meshes: the mesh file's SHA-256 and each structure's name, material and size.
    pub key: String,
}

/// File name of a region's stored draft scene (see
/// [`sim_core::fluoro::draft::draft_scene_stored`]).
pub const DRAFT_STORE_FILE: &str = "draft-scene.bin";

/// Logs what became of `region`'s stored `what` (its scene trees, its draft scene): reused
/// quietly, made and stored, or made and not stored (a warning: every start makes it again).
pub(crate) fn log_store_outcome(region: &str, what: &str, outcome: &StoreOutcome) {
    match outcome {
        StoreOutcome::Reused => tracing::debug!(region, "{what} reused"),
        StoreOutcome::Built {
            why,
            stored: Ok(()),
        } => tracing::info!(region, "{what} made and stored ({why})"),
        StoreOutcome::Built {
            why,
            stored: Err(e),
        } => tracing::warn!(region, "{what} made ({why}), not stored: {e}"),
    }
}

impl Region {
    /// Builds the scene of `structures` (this is where BVHs are built, on every core: 1.7 s on
    /// one core for the default lumbar phantom, 0.9 s on two).
    pub fn from_structures(
        name: &str,
        structures: &[StructureAsset],
        landmarks: BTreeMap<String, [f64; 3]>,
        asset_sha256: BTreeMap<String, String>,
        source: String,
    ) -> Region {
        Region::from_structures_with(name, structures, landmarks, asset_sha256, source, None).0
    }

    /// [`Region::from_structures`], the trees taken from (or stored in) `store`'s
    /// [`STORE_FILE`] when given, which the region then keeps.
    fn from_structures_with(
        name: &str,
        structures: &[StructureAsset],
        landmarks: BTreeMap<String, [f64; 3]>,
        asset_sha256: BTreeMap<String, String>,
        source: String,
        store: Option<SceneStore>,
    ) -> (Region, Option<StoreOutcome>) {
        let mut scene = Scene::new();
        let meshes: Vec<_> = structures
            .iter()
            .map(|s| (s.name.clone(), FluoroMaterial::Tissue(s.material), &s.mesh))
            .collect();
        let (first, outcome) = match &store {
            Some(st) => {
                let (first, outcome) =
                    scene.add_all_stored(&meshes, &st.dir.join(STORE_FILE), &st.key);
                (first, Some(outcome))
            }
            None => (scene.add_all(&meshes), None),
        };
        let bone_entries = structures
            .iter()
            .enumerate()
            .filter(|(_, s)| s.material == MaterialClass::CorticalBone)
            .map(|(k, _)| first + k)
            .collect();
        let region = Region {
            name: name.to_string(),
            scene,
            bone_entries,
            landmarks,
            asset_sha256,
            source,
            phantom: None,
            store,
        };
        (region, outcome)
    }

    /// A loaded asset; for a phantom region the landmarks are recomputed from the parameters
    /// recorded in its provenance (the phantom is a pure function of them); a CT region's come
    /// from its manifest (computed from the masks when it was built).
    pub fn from_asset(asset: &RegionAsset) -> Region {
        Region::from_asset_with(asset, None).0
    }

    /// [`Region::from_asset`] for the asset read from `dir`: its trees come from the
    /// [`STORE_FILE`] there when that holds them for these meshes (keyed by the mesh file's
    /// SHA-256, verified when the asset was read, and the structures' names and sizes), else
    /// they are built and stored there. The region is the same either way.
    pub fn from_asset_in(asset: &RegionAsset, dir: &Path) -> (Region, StoreOutcome) {
        let Some(meshes_sha256) = asset.provenance.files_sha256.get(MESHES_FILE) else {
            let why = format!("no SHA-256 of {MESHES_FILE} to key stored trees by");
            let outcome = StoreOutcome::Built {
                stored: Err(why.clone()),
                why,
            };
            return (Region::from_asset(asset), outcome);
        };
        let mut key = format!("{} {MESHES_FILE} sha256 {meshes_sha256};", asset.name);
        for s in &asset.structures {
            key.push_str(&format!(
                " {} {} {} {};",
                s.name,
                s.material.name(),
                s.mesh.vertices_mm.len(),
                s.mesh.triangles.len()
            ));
        }
        let store = SceneStore {
            dir: dir.to_path_buf(),
            key,
        };
        let (region, outcome) = Region::from_asset_with(asset, Some(store));
        (region, outcome.expect("a store was given"))
    }

    fn from_asset_with(
        asset: &RegionAsset,
        store: Option<SceneStore>,
    ) -> (Region, Option<StoreOutcome>) {
        let mut params_of_phantom = None;
        let (landmarks, source) = match &asset.provenance.source {
            Source::Phantom {
                generator,
                parameters,
            } => {
                let params: Option<phantom::PhantomParams> = parameters
                    .get("params")
                    .and_then(|p| serde_json::from_value(p.clone()).ok());
                // The cervical phantom shares the parameter type but not the anatomy: its
                // landmarks come from its own generator, and no lumbar-phantom parameters are
                // recorded for it (the contrast and ultrasound media rebuild the lumbar anatomy).
                let cervical = generator == phantom::cervical::GENERATOR;
                if !cervical {
                    params_of_phantom.clone_from(&params);
                }
                let landmarks = params
                    .map(|p| {
                        let all = if cervical {
                            phantom::cervical::landmarks(&p)
                        } else {
                            phantom::landmarks(&p)
                        };
                        all.into_iter().map(|l| (l.name, l.position_mm)).collect()
                    })
                    .unwrap_or_default();
                (landmarks, generator.clone())
            }
            // A CT region carries the landmarks computed from its masks when it was built.
            Source::Ct { ct_file, .. } => (
                asset
                    .landmarks
                    .iter()
                    .map(|l| (l.name.clone(), l.position_mm))
                    .collect(),
                format!("ct:{ct_file}"),
            ),
        };
        let (mut region, outcome) = Region::from_structures_with(
            &asset.name,
            &asset.structures,
            landmarks,
            asset.provenance.files_sha256.clone(),
            source,
            store,
        );
        region.phantom = params_of_phantom;
        (region, outcome)
    }

    /// Entry index of a structure by name.
    pub fn entry(&self, name: &str) -> Option<usize> {
        self.scene.entries().iter().position(|e| e.name == name)
    }

    /// Whether `p` lies inside the named structure (`None` when the region has no such structure).
    pub fn contains(&self, structure: &str, p_mm: [f64; 3]) -> Option<bool> {
        self.entry(structure)
            .map(|i| self.scene.entries()[i].bvh.contains(p_mm))
    }

    /// The structure owning `p`: the last one in painting order whose mesh contains it (masks
    /// are disjoint except the two whole-envelope solids, `skin` and `deep_soft_tissue`, which
    /// come first), or `None` outside the body.
    pub fn structure_at(&self, p_mm: [f64; 3]) -> Option<&str> {
        self.scene.entries().iter().rev().find_map(|e| {
            let (lo, hi) = e.bvh.bounds_mm()?;
            let inside_box = (0..3).all(|a| p_mm[a] >= lo[a] && p_mm[a] <= hi[a]);
            (inside_box && e.bvh.contains(p_mm)).then_some(e.name.as_str())
        })
    }

    /// The tissue at `p` as the needle feels it (air outside the body).
    pub fn tissue_at(&self, p_mm: [f64; 3]) -> Tissue {
        self.structure_at(p_mm)
            .map_or(Tissue::Air, Tissue::of_structure)
    }

    /// Where a line meets the skin first, coming along `dir` from `far_mm` (a point outside the
    /// body), within `max_t_mm`.
    pub fn skin_entry(&self, far_mm: DVec3, dir: DVec3, max_t_mm: f64) -> Option<DVec3> {
        let skin = self.entry("skin")?;
        let dir = dir.normalize_or_zero();
        self.first_hit(skin, far_mm.to_array(), dir.to_array(), max_t_mm)
            .map(|h| far_mm + dir * h.t_mm)
    }

    /// The bone surface the needle is steered against.
    pub fn bones(&self) -> RegionBones<'_> {
        RegionBones { region: self }
    }

    /// First crossing of a ray with one structure, with the surface normal there.
    pub fn first_hit(
        &self,
        structure: usize,
        origin_mm: [f64; 3],
        dir: [f64; 3],
        max_t_mm: f64,
    ) -> Option<RayHit> {
        self.scene.entries()[structure]
            .bvh
            .first_hit(origin_mm, dir, 0.0, max_t_mm)
            .map(|h| RayHit {
                t_mm: h.hit.t_mm,
                normal: DVec3::from_array(h.normal),
            })
    }
}

/// Every cortical-bone structure of a region as one [`BoneSurface`] (the nearest hit of any).
#[derive(Debug, Clone, Copy)]
pub struct RegionBones<'a> {
    region: &'a Region,
}

impl BoneSurface for RegionBones<'_> {
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit> {
        let mut best: Option<RayHit> = None;
        for &i in &self.region.bone_entries {
            let limit = best.map_or(max_t_mm, |b| b.t_mm);
            if let Some(h) = self
                .region
                .first_hit(i, origin.to_array(), dir.to_array(), limit)
            {
                if best.is_none_or(|b| h.t_mm < b.t_mm) {
                    best = Some(h);
                }
            }
        }
        best
    }

    fn contains(&self, p: DVec3) -> bool {
        self.region
            .bone_entries
            .iter()
            .any(|&i| self.region.scene.entries()[i].bvh.contains(p.to_array()))
    }
}
