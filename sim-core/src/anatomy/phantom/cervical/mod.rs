//! The procedural cervical phantom (region `cervical-phantom`): C1 to T1 with the canal contents,
//! the vertebral arteries in their foramina transversaria, the carotid sheaths, the posterior neck
//! muscles, fat and skin, built like the lumbar phantom ([`super`]): implicit solids with
//! dimensions from published morphometry ([`dims`], cited per dimension), painted into a label
//! grid with partial volumes, a CT made from it, and every structure meshed by the shared pipeline.
//! A pure function of its [`PhantomParams`] ([`default_params`]).
//!
//! # Structures (painting order)
//! `skin`, `subcutaneous_fat`, `deep_soft_tissue` (nested envelope layers, as in the lumbar
//! phantom); `posterior_neck_muscles_{left,right}`, `longus_colli_{left,right}` (muscle);
//! `epidural_space`, `ligamentum_flavum`, `dural_sac`, `spinal_cord`;
//! `carotid_artery_{left,right}`, `internal_jugular_vein_{left,right}`,
//! `vertebral_artery_{left,right}` (vessels); `disc_C2_C3` .. `disc_C7_T1`;
//! `{C1..C7,T1}_cortical` and `_cancellous`.
//!
//! Not modelled: the skull base (the grid ends above the atlas), nerve roots, the trachea,
//! oesophagus and thyroid (part of the deep soft tissue), the shoulders.
//!
//! # Model frame
//! RAS (x = patient right, y = anterior, z = cranial), millimetres; origin at the centre of the C5
//! vertebral body.
//!
//! # Landmarks
//! See [`landmarks`]: `{C2..T1}_body_centre`, `{C2_C3..C7_T1}_interlaminar_window_centre`,
//! `..._posterior_epidural_space`, `..._facet_joint_{left,right}`,
//! `{C3..C6}_medial_branch_target_{left,right}`, `{C1..C6}_foramen_transversarium_{left,right}`,
//! `C5_spinal_cord_centre`, `C7_spinous_tip`.

pub mod dims;

mod bones;
mod landmarks;
mod skeleton;
mod soft;

use std::path::Path;

use super::model::Parts;
use super::model::{Anatomy, AnatomyParams, Landmark};
use super::{PhantomParams, PhantomVolumes};
use crate::anatomy::asset::RegionAsset;
use crate::anatomy::error::AnatomyError;
use crate::anatomy::pipeline::Progress;
use crate::material::MaterialClass;

/// Generator identifier recorded in the provenance; bump the number when the model changes shape.
pub const GENERATOR: &str = "cervical-phantom/2";

/// Region name and default folder name under `assets/`.
pub const REGION_NAME: &str = "cervical-phantom";

/// Default voxel size, mm: 1 mm resolves the 1.5 mm cervical cortex, the 2.5 mm flavum and the
/// 2.5 mm posterior epidural space that the lumbar phantom's 1.5 mm grid would blur (our choice).
pub const DEFAULT_VOXEL_MM: f64 = 1.0;

/// The default parameters, what the platform ships: the default grid meshed from the solids'
/// level sets ([`PhantomParams::meshed_from_level_sets`]).
pub fn default_params() -> PhantomParams {
    params_with_voxel_mm(DEFAULT_VOXEL_MM).meshed_from_level_sets()
}

/// Default anatomy and extent of the neck on a grid of `voxel_mm` (tests use coarser grids).
pub fn params_with_voxel_mm(voxel_mm: f64) -> PhantomParams {
    let mut p = PhantomParams::with_voxel_mm(voxel_mm);
    p.anatomy = AnatomyParams {
        // Cervical cortex is under 1 mm; 1.5 mm lets a 1 mm grid resolve it (simulator choice).
        cortical_thickness_mm: 1.5,
        // Cervical facet joint space about 2 mm on CT (our choice).
        facet_gap_mm: 2.0,
        // No sacroiliac joint in the neck: unused.
        si_gap_mm: 0.0,
        // Posterior neck: 7 mm of subcutaneous fat under 2 mm of skin (our choice).
        subcutaneous_fat_mm: 7.0,
        skin_mm: 2.0,
        // A 120 x 116 mm neck (our choice).
        body_half_width_mm: 60.0,
        body_half_depth_mm: 58.0,
        ..AnatomyParams::default()
    };
    // The neck outline plus 6 mm; from 25 mm below T1's body to 15 mm above the atlas.
    p.extent_min_mm = [-66.0, -74.0, -85.0];
    p.extent_max_mm = [66.0, 54.0, 95.0];
    p
}

/// The implicit anatomy on the grid of `params`: solids in painting order and landmarks.
pub fn anatomy(params: &PhantomParams) -> Anatomy {
    let p = params.effective_anatomy();
    let sk = skeleton::Skeleton::new(p.facet_gap_mm);
    let mut parts = Parts::default();
    let under_skin = soft::push_envelope(&mut parts, &p);
    soft::push_muscles(&mut parts, &sk, &under_skin);
    soft::push_canal_contents(&mut parts, &sk);
    soft::push_carotid_sheaths(&mut parts, &sk);
    for (s, side) in [(super::model::LEFT, "left"), (super::model::RIGHT, "right")] {
        parts.push(
            &format!("vertebral_artery_{side}"),
            MaterialClass::Vessel,
            bones::vertebral_artery(&sk, s),
        );
    }
    for (name, disc) in bones::discs(&sk) {
        parts.push(&name, MaterialClass::Disc, disc);
    }
    let foramina = bones::foramina(&sk);
    let gap = p.facet_gap_mm;
    let mut bones = vec![("C1".to_string(), bones::atlas(&sk, gap, &foramina))];
    for k in 0..sk.verts.len() {
        bones.push((
            sk.verts[k].d.name.to_string(),
            bones::vertebra(&sk, k, gap, &foramina),
        ));
    }
    for (name, bone) in bones {
        parts.push_bone(&name, bone, &under_skin, p.cortical_thickness_mm);
    }
    Anatomy {
        parts: parts.0,
        landmarks: landmarks::landmarks(&sk),
    }
}

/// The named structures in painting order (name, material).
pub fn structure_list(params: &PhantomParams) -> Vec<(String, MaterialClass)> {
    anatomy(params)
        .parts
        .into_iter()
        .map(|p| (p.name, p.material))
        .collect()
}

/// The named landmarks (model frame, mm).
pub fn landmarks(params: &PhantomParams) -> Vec<Landmark> {
    anatomy(params).landmarks
}

/// One landmark by name.
pub fn landmark(params: &PhantomParams, name: &str) -> Option<Landmark> {
    landmarks(params).into_iter().find(|l| l.name == name)
}

/// Paints the phantom into its grid, computes partial volumes and makes the CT (no meshing).
pub fn voxelize(params: &PhantomParams) -> PhantomVolumes {
    super::voxelize_anatomy(params, anatomy(params))
}

/// Builds the cervical region in memory: voxelize, then mesh through the shared pipeline.
pub fn build(
    params: &PhantomParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    let source = super::phantom_source(
        GENERATOR,
        params,
        "Procedural cervical phantom generated by sim-core (no patient data); dimensions from \
         published adult morphometry cited in sim_core::anatomy::phantom::cervical::dims.",
        "C5 body centre",
    );
    super::build_anatomy(REGION_NAME, params, || voxelize(params), source, progress)
}

/// Whether `dir` holds a cervical phantom built with exactly `params`.
pub fn is_cached(dir: &Path, params: &PhantomParams) -> bool {
    super::is_cached_for(dir, GENERATOR, params)
}

/// Returns the cervical region stored in `dir`, building and writing it first when missing or
/// stale (as [`super::ensure_built_with`]).
pub fn ensure_built_with(
    dir: &Path,
    params: &PhantomParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    super::ensure_built_by(dir, GENERATOR, params, build, progress)
}
