//! A lumbar region from a real CT and its TotalSegmentator masks: landmarks computed from the
//! vertebra masks, and the tissues the masks lack, authored and marked as such.
//!
//! # Landmarks ([`spine_landmarks`], a pure function of the masks)
//! - The **canal** of every axial slice is the enclosed hole of the vertebral ring: the pixels
//!   of the slice that are not bone (any vertebra or the sacrum) and cannot be reached from the
//!   slice border through non-bone pixels (4-connected); of several holes the largest is the
//!   canal. Where the ring is open (between the laminae of two vertebrae, at the disc) the canal
//!   is the nearest closed slice's canal, shifted by the linearly interpolated centroid
//!   ([`canal`]).
//! - `{V}_body_centre`: centroid of the voxel centres of vertebra `V` anterior to the anterior
//!   wall of its canal (the vertebral body); `{V}_canal_centre`: centroid of its canal voxels.
//! - `{U}_{L}_posterior_epidural_space` (and `_interlaminar_window_centre` one voxel behind it,
//!   in the ligamentum flavum): between the body centres of `U` and `L`, the slice where the
//!   midline posterior to the canal is free of bone the longest way back (the interlaminar
//!   window), the most posterior canal voxel of the midline column there (the authored epidural
//!   layer, see below).
//!
//! # Authored tissues ([`authored_structures`])
//! All of them are our construction at the CT's voxel size, listed in the provenance notes with
//! the word "authored"; mask voxels (bone first) are never given to them:
//! - `dural_sac` (dura and CSF): the canal eroded by one pixel in plane; `epidural_space`: the
//!   rest of the canal (a one-voxel layer); `ligamentum_flavum`: the first non-bone voxel behind
//!   the canal in every column, between the body centres of two adjacent levels (so it fills
//!   the gaps between the laminae); `interspinous_ligament`: the midline column behind the
//!   flavum, in soft tissue, at the lumbar levels.
//! - From the CT by HU (bands of [`super::labels`], after Kalender, *Computed Tomography*):
//!   `skin` = the body (the largest connected component above [`BODY_FROM_HU`], holes filled per
//!   slice), meshed whole; `deep_soft_tissue` = the body less its outer voxel layer (the skin,
//!   one voxel thick), meshed whole; `subcutaneous_fat` = fat voxels (-190..-30 HU) connected
//!   through fat to the skin layer; `muscle_other` = soft-tissue voxels (-30..150 HU) posterior
//!   to the canal centre (paraspinal and quadratus muscles beyond the autochthon masks; organs
//!   lie anterior). Components under [`MIN_COMPONENT_VOXELS`] are dropped.
//!
//! The pieces: `masks` (boolean voxel masks and their morphology), `landmarks` (the canal and
//! the landmarks) and `authored` (the authored tissues); this module crops the import and puts
//! them together ([`import_lumbar_ct`]).

mod authored;
mod landmarks;
mod masks;

use std::collections::BTreeMap;

use super::error::AnatomyError;
use super::mask::crop_box as crop;
use crate::volume::Volume;

pub use authored::{
    FAT_HU, MIN_COMPONENT_VOXELS, MUSCLE_HU, SUBCUTANEOUS_MAX_DEPTH_VOXELS, authored_structures,
};
pub use landmarks::{LEVELS, MIN_CANAL_PIXELS, WINDOW_DEPTH_VOXELS, canal, spine_landmarks};
pub use masks::{BODY_FROM_HU, BoolVolume, body_mask};

/// Voxels of margin kept behind the body's back when the region is cropped; our choice.
pub const CROP_MARGIN_VOXELS: usize = 2;
/// Half width of the crop, either side of the spine's centre, mm: takes in the paraspinal
/// muscles, the psoas and the posterior iliac crests that a lumbar fluoroscopy field shows; our
/// choice.
pub const SPINE_HALF_WIDTH_MM: f64 = 90.0;
/// How far the crop reaches below the lowest voxel of L5, mm: S1 to S3 and the posterior iliac
/// crests; our choice.
pub const BELOW_L5_MM: f64 = 60.0;
/// How far the crop reaches in front of the vertebral bodies, mm: the aorta and the inferior
/// vena cava lie directly in front of them; our choice.
pub const ANTERIOR_MARGIN_MM: f64 = 45.0;

/// A real-CT lumbar region: the TotalSegmentator import ([`super::totalseg::read_ct_and_masks`]),
/// cropped in plane to the body's box, with landmarks from the vertebra masks and the authored
/// tissues of the module docs, meshed by [`super::pipeline::build_region`].
pub fn import_lumbar_ct(
    ct_path: &std::path::Path,
    masks: &super::totalseg::MaskSource,
    options: &super::totalseg::ImportOptions,
    progress: &mut dyn FnMut(&super::pipeline::Progress),
) -> Result<super::asset::RegionAsset, AnatomyError> {
    let imported = super::totalseg::read_ct_and_masks(ct_path, masks, options, progress)?;
    let full = imported.ct_hu.grid;
    // In-plane crop around the spine (z is kept whole): see [`SPINE_HALF_WIDTH_MM`].
    let body = body_mask(&imported.ct_hu);
    let mut spine_lo = [usize::MAX; 3];
    let mut spine_hi = [0usize; 3];
    let mut l5_bottom = None;
    for st in &imported.structures {
        if st.name == "vertebrae_L5" {
            let b = BoolVolume::of_mask(full, st)?;
            l5_bottom = (0..full.len()).find(|&i| b.data[i]).map(|i| full.ijk(i)[2]);
        }
        if st.name.starts_with("vertebrae_") || st.name == "sacrum" {
            let b = BoolVolume::of_mask(full, st)?;
            for (idx, &x) in b.data.iter().enumerate() {
                if x {
                    let ijk = full.ijk(idx);
                    for a in 0..3 {
                        spine_lo[a] = spine_lo[a].min(ijk[a]);
                        spine_hi[a] = spine_hi[a].max(ijk[a]);
                    }
                }
            }
        }
    }
    if spine_lo[0] == usize::MAX {
        return Err(AnatomyError::invalid(
            &options.region_name,
            "no vertebra or sacrum mask among the structures",
        ));
    }
    let body_back = (0..full.len())
        .filter(|&i| body.data[i])
        .map(|i| full.ijk(i)[1])
        .min()
        .unwrap_or(0);
    let h = full.spacing_mm;
    let mid_i = 0.5 * (spine_lo[0] + spine_hi[0]) as f64;
    let half_i = SPINE_HALF_WIDTH_MM / h[0];
    let lo = [
        (mid_i - half_i).max(0.0).round() as usize,
        body_back.saturating_sub(CROP_MARGIN_VOXELS),
        l5_bottom.map_or(0, |k| {
            (k as f64 - BELOW_L5_MM / full.spacing_mm[2])
                .max(0.0)
                .round() as usize
        }),
    ];
    let hi = [
        ((mid_i + half_i).round() as usize).min(full.dims[0] - 1),
        ((spine_hi[1] as f64 + ANTERIOR_MARGIN_MM / h[1]).round() as usize).min(full.dims[1] - 1),
        full.dims[2] - 1,
    ];
    let ct_hu = crop(&imported.ct_hu, lo, hi);
    let g = ct_hu.grid;
    let mut notes = imported.source.notes.clone();
    notes.push(format!(
        "cropped around the spine (from {BELOW_L5_MM} mm below L5 up, {SPINE_HALF_WIDTH_MM} mm either side of its centre, \
         {ANTERIOR_MARGIN_MM} mm in front of it, the body's back plus {CROP_MARGIN_VOXELS} voxels): \
         voxels {lo:?}..={hi:?} of the resampled grid, dims {:?}",
        g.dims
    ));
    let mut structures = Vec::new();
    for s in imported.structures {
        let full_mask = BoolVolume::of_mask(full, &s)?;
        let cropped = BoolVolume {
            grid: g,
            data: crop(
                &Volume {
                    grid: full,
                    data: full_mask.data,
                },
                lo,
                hi,
            )
            .data,
        };
        match cropped.to_structure(&s.name, s.material).cropped() {
            Some(c) => structures.push(c),
            None => notes.push(format!("{}: outside the crop; skipped", s.name)),
        }
    }
    let mut vertebrae = BTreeMap::new();
    let mut bone = BoolVolume::empty(g);
    for s in &structures {
        if s.name.starts_with("vertebrae_") || s.name == "sacrum" {
            let b = BoolVolume::of_mask(g, s)?;
            for (x, &y) in bone.data.iter_mut().zip(&b.data) {
                *x |= y;
            }
            if let Some((level, _)) = LEVELS.iter().find(|(_, n)| *n == s.name) {
                vertebrae.insert(level.to_string(), b);
            }
        }
    }
    let canal_mask = canal(&bone);
    let landmarks = spine_landmarks(&vertebrae, &bone, &canal_mask);
    let (mut all, authored_notes) =
        authored_structures(&ct_hu, &structures, &canal_mask, &landmarks)?;
    notes.extend(authored_notes);
    notes.push(format!(
        "{} landmarks computed from the vertebra masks (canal = enclosed hole of the bone ring)",
        landmarks.len()
    ));
    all.extend(structures);
    let source = super::pipeline::SourceInfo {
        notes,
        ..imported.source
    };
    let mut region = super::pipeline::build_region(
        &options.region_name,
        &ct_hu,
        all,
        &options.params,
        source,
        progress,
    )?;
    region.landmarks = landmarks;
    Ok(region)
}
