//! Real-CT import in the TotalSegmentator layout: a CT plus either a folder of per-structure masks
//! (`segmentations/<structure>.nii.gz`) or one multilabel file with a label map.
//!
//! Structure names map to material classes by [`material_for_structure`]; names with no class
//! (lungs, trachea: air-filled, left to the CT's HU) are skipped with a note, as are empty masks.
//! Everything is resampled into world RAS (see [`super::nifti_import`]) and goes through
//! [`build_region`].

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use super::asset::{RegionAsset, Source, sha256_file};
use super::error::AnatomyError;
use super::nifti_import::{NiftiImage, RasResampler, check_same_grid, read_nifti};
use super::pipeline::{PipelineParams, Progress, SourceInfo, StructureMask, build_region};
use crate::material::MaterialClass;
use crate::volume::Volume;

/// HU given to resampled CT voxels outside the source volume (air).
pub const OUTSIDE_HU: f32 = -1024.0;

/// The tissue class of a TotalSegmentator structure name (v1 or v2 naming), or `None` for
/// structures the simulator has no class for.
pub fn material_for_structure(name: &str) -> Option<MaterialClass> {
    let n = name.to_ascii_lowercase();
    let starts = |p: &str| n.starts_with(p);
    if starts("lung_") || n == "trachea" || starts("kidney_cyst") {
        return None;
    }
    if starts("vertebrae_")
        || n == "sacrum"
        || starts("hip_")
        || starts("femur_")
        || starts("rib_")
        || n == "sternum"
        || starts("humerus_")
        || starts("scapula_")
        || starts("clavicula_")
        || n == "skull"
    {
        return Some(MaterialClass::CorticalBone);
    }
    if n == "costal_cartilages" || starts("intervertebral_disc") {
        // Cartilage: the disc class carries the nearest acoustic and X-ray behaviour.
        return Some(MaterialClass::Disc);
    }
    if n == "aorta"
        || n == "inferior_vena_cava"
        || n == "superior_vena_cava"
        || starts("iliac_")
        || n == "portal_vein_and_splenic_vein"
        || n == "pulmonary_artery"
        || n == "pulmonary_vein"
        || n == "brachiocephalic_trunk"
        || starts("subclavian_artery")
        || starts("common_carotid_artery")
        || starts("brachiocephalic_vein")
        || starts("heart")
        || n == "atrial_appendage_left"
    {
        return Some(MaterialClass::Vessel);
    }
    if starts("iliopsoas_") || starts("autochthon_") || starts("gluteus_") || starts("face") {
        return Some(MaterialClass::Muscle);
    }
    if n == "spinal_cord" {
        // The cord is inside the dural sac; at CT resolution the mask is the thecal contents.
        return Some(MaterialClass::DuraCsf);
    }
    if n == "brain" || starts("sciatic") || starts("nerve") {
        return Some(MaterialClass::Nerve);
    }
    // Solid and hollow organs (liver, spleen, kidneys, bowel, bladder, prostate, ...).
    const ORGANS: [&str; 17] = [
        "spleen",
        "kidney_right",
        "kidney_left",
        "gallbladder",
        "liver",
        "stomach",
        "pancreas",
        "adrenal_gland_right",
        "adrenal_gland_left",
        "esophagus",
        "thyroid_gland",
        "small_bowel",
        "duodenum",
        "colon",
        "urinary_bladder",
        "prostate",
        "face",
    ];
    ORGANS
        .contains(&n.as_str())
        .then_some(MaterialClass::SoftTissue)
}

/// TotalSegmentator v2 `total` task label ids (class map of the TotalSegmentator package,
/// `map_to_binary.py`, 117 classes).
pub const TOTAL_V2_LABELS: [&str; 117] = [
    "spleen",
    "kidney_right",
    "kidney_left",
    "gallbladder",
    "liver",
    "stomach",
    "pancreas",
    "adrenal_gland_right",
    "adrenal_gland_left",
    "lung_upper_lobe_left",
    "lung_lower_lobe_left",
    "lung_upper_lobe_right",
    "lung_middle_lobe_right",
    "lung_lower_lobe_right",
    "esophagus",
    "trachea",
    "thyroid_gland",
    "small_bowel",
    "duodenum",
    "colon",
    "urinary_bladder",
    "prostate",
    "kidney_cyst_left",
    "kidney_cyst_right",
    "sacrum",
    "vertebrae_S1",
    "vertebrae_L5",
    "vertebrae_L4",
    "vertebrae_L3",
    "vertebrae_L2",
    "vertebrae_L1",
    "vertebrae_T12",
    "vertebrae_T11",
    "vertebrae_T10",
    "vertebrae_T9",
    "vertebrae_T8",
    "vertebrae_T7",
    "vertebrae_T6",
    "vertebrae_T5",
    "vertebrae_T4",
    "vertebrae_T3",
    "vertebrae_T2",
    "vertebrae_T1",
    "vertebrae_C7",
    "vertebrae_C6",
    "vertebrae_C5",
    "vertebrae_C4",
    "vertebrae_C3",
    "vertebrae_C2",
    "vertebrae_C1",
    "heart",
    "aorta",
    "pulmonary_vein",
    "brachiocephalic_trunk",
    "subclavian_artery_right",
    "subclavian_artery_left",
    "common_carotid_artery_right",
    "common_carotid_artery_left",
    "brachiocephalic_vein_left",
    "brachiocephalic_vein_right",
    "atrial_appendage_left",
    "superior_vena_cava",
    "inferior_vena_cava",
    "portal_vein_and_splenic_vein",
    "iliac_artery_left",
    "iliac_artery_right",
    "iliac_vena_left",
    "iliac_vena_right",
    "humerus_left",
    "humerus_right",
    "scapula_left",
    "scapula_right",
    "clavicula_left",
    "clavicula_right",
    "femur_left",
    "femur_right",
    "hip_left",
    "hip_right",
    "spinal_cord",
    "gluteus_maximus_left",
    "gluteus_maximus_right",
    "gluteus_medius_left",
    "gluteus_medius_right",
    "gluteus_minimus_left",
    "gluteus_minimus_right",
    "autochthon_left",
    "autochthon_right",
    "iliopsoas_left",
    "iliopsoas_right",
    "brain",
    "skull",
    "rib_left_1",
    "rib_left_2",
    "rib_left_3",
    "rib_left_4",
    "rib_left_5",
    "rib_left_6",
    "rib_left_7",
    "rib_left_8",
    "rib_left_9",
    "rib_left_10",
    "rib_left_11",
    "rib_left_12",
    "rib_right_1",
    "rib_right_2",
    "rib_right_3",
    "rib_right_4",
    "rib_right_5",
    "rib_right_6",
    "rib_right_7",
    "rib_right_8",
    "rib_right_9",
    "rib_right_10",
    "rib_right_11",
    "rib_right_12",
    "sternum",
    "costal_cartilages",
];

/// The built-in v2 map: label id -> structure name.
pub fn total_v2_label_map() -> BTreeMap<u32, String> {
    TOTAL_V2_LABELS
        .iter()
        .enumerate()
        .map(|(i, n)| (i as u32 + 1, (*n).to_string()))
        .collect()
}

/// Reads a JSON label map: either `{"1": "spleen", ...}` (id -> name) or `{"spleen": 1, ...}`.
pub fn read_label_map(path: &Path) -> Result<BTreeMap<u32, String>, AnatomyError> {
    let text = fs::read_to_string(path).map_err(|e| AnatomyError::io(path, e))?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| AnatomyError::bad_file(path, format!("not JSON: {e}")))?;
    let obj = v
        .as_object()
        .ok_or_else(|| AnatomyError::bad_file(path, "label map must be a JSON object"))?;
    let mut map = BTreeMap::new();
    for (k, val) in obj {
        let (id, name) = match (k.parse::<u32>(), val) {
            (Ok(id), serde_json::Value::String(name)) => (id, name.clone()),
            (Err(_), serde_json::Value::Number(n)) => {
                let id = n
                    .as_u64()
                    .and_then(|x| u32::try_from(x).ok())
                    .ok_or_else(|| AnatomyError::bad_file(path, format!("bad label id for {k}")))?;
                (id, k.clone())
            }
            _ => {
                return Err(AnatomyError::bad_file(
                    path,
                    format!("entry {k}: expected \"id\": \"name\" or \"name\": id"),
                ));
            }
        };
        if id == 0 {
            return Err(AnatomyError::bad_file(
                path,
                "label 0 is background and cannot name a structure",
            ));
        }
        if map.insert(id, name).is_some() {
            return Err(AnatomyError::bad_file(
                path,
                format!("label {id} given twice"),
            ));
        }
    }
    Ok(map)
}

/// Where the masks come from.
#[derive(Debug, Clone, PartialEq)]
pub enum MaskSource {
    /// A folder of per-structure NIfTI masks named `<structure>.nii[.gz]`.
    Folder(PathBuf),
    /// One multilabel NIfTI file; `label_map` is a JSON map, or `None` for the built-in
    /// TotalSegmentator v2 `total` map.
    Multilabel {
        /// The multilabel file.
        file: PathBuf,
        /// Optional JSON label map.
        label_map: Option<PathBuf>,
    },
}

/// Options of [`import_ct`].
#[derive(Debug, Clone, PartialEq)]
pub struct ImportOptions {
    /// Region name (conventionally the output folder name).
    pub region_name: String,
    /// Meshing and labelling parameters.
    pub params: PipelineParams,
    /// Only these structures (by name), or all mapped structures when `None`.
    pub include: Option<Vec<String>>,
    /// Licence of the derived asset.
    pub licence: String,
    /// Attribution that must travel with the asset.
    pub attribution: String,
}

fn structure_name(path: &Path) -> Option<String> {
    let f = path.file_name()?.to_str()?;
    f.strip_suffix(".nii.gz")
        .or_else(|| f.strip_suffix(".nii"))
        .map(str::to_string)
}

/// A CT and its masks read and resampled into world RAS, not yet meshed: what
/// [`import_ct`] hands to [`build_region`], for callers that add structures first (see
/// [`super::lumbar_ct`]).
#[derive(Debug, Clone)]
pub struct ImportedCt {
    /// The CT in HU on the region grid.
    pub ct_hu: Volume<f32>,
    /// One mask per mapped, non-empty structure, cropped to its non-zero box.
    pub structures: Vec<StructureMask>,
    /// Source files, licence, attribution and import notes.
    pub source: SourceInfo,
}

/// Imports a CT and its masks into a region (not yet written; see [`RegionAsset::write_to`]).
pub fn import_ct(
    ct_path: &Path,
    masks: &MaskSource,
    options: &ImportOptions,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    let imported = read_ct_and_masks(ct_path, masks, options, progress)?;
    build_region(
        &options.region_name,
        &imported.ct_hu,
        imported.structures,
        &options.params,
        imported.source,
        progress,
    )
}

/// Reads a CT and its masks and resamples them into world RAS (the first half of
/// [`import_ct`]).
pub fn read_ct_and_masks(
    ct_path: &Path,
    masks: &MaskSource,
    options: &ImportOptions,
    progress: &mut dyn FnMut(&Progress),
) -> Result<ImportedCt, AnatomyError> {
    let mut notes = Vec::new();
    progress(&Progress {
        stage: "read CT",
        done: 0,
        total: 1,
        item: ct_path.display().to_string(),
    });
    let ct = read_nifti(ct_path)?;
    let resampler = RasResampler::new(&ct.affine, ct.dims);
    notes.push(format!(
        "CT {} ({}, dims {:?}) resampled to world RAS grid dims {:?}, spacing {:?} mm ({})",
        ct_path.display(),
        ct.datatype,
        ct.dims,
        resampler.grid.dims,
        resampler.grid.spacing_mm,
        if resampler.exact {
            "exact re-indexing"
        } else {
            "trilinear, oblique affine"
        }
    ));
    let ct_ras = resampler.apply(&ct.data, OUTSIDE_HU);
    let wanted = |name: &str| {
        options
            .include
            .as_ref()
            .is_none_or(|inc| inc.iter().any(|n| n == name))
    };
    let mut structures = Vec::new();
    let mut mask_files = BTreeMap::new();
    let mut add = |name: String,
                   image: &NiftiImage,
                   indicator: &dyn Fn(f32) -> f32,
                   notes: &mut Vec<String>| {
        let Some(material) = material_for_structure(&name) else {
            notes.push(format!(
                "{name}: no material class (air-filled or not simulated); skipped"
            ));
            return;
        };
        let occ: Vec<f32> = image.data.iter().map(|&v| indicator(v)).collect();
        if occ.iter().all(|&v| v <= 0.0) {
            notes.push(format!("{name}: empty mask skipped"));
            return;
        }
        let mask = StructureMask {
            name: name.clone(),
            material,
            mask: resampler.apply(&occ, 0.0),
        };
        match mask.cropped() {
            Some(c) => structures.push(c),
            None => notes.push(format!("{name}: empty after resampling; skipped")),
        }
    };
    let label_map_name;
    match masks {
        MaskSource::Folder(dir) => {
            label_map_name = None;
            let rd = fs::read_dir(dir).map_err(|e| AnatomyError::io(dir, e))?;
            let mut files: Vec<PathBuf> = Vec::new();
            for entry in rd {
                let entry = entry.map_err(|e| AnatomyError::io(dir, e))?;
                let p = entry.path();
                if structure_name(&p).is_some() {
                    files.push(p);
                }
            }
            files.sort();
            if files.is_empty() {
                return Err(AnatomyError::bad_file(
                    dir,
                    "no .nii or .nii.gz masks in this folder",
                ));
            }
            let total = files.len();
            for (n, f) in files.iter().enumerate() {
                let name = structure_name(f).unwrap_or_default();
                if !wanted(&name) {
                    continue;
                }
                progress(&Progress {
                    stage: "read masks",
                    done: n,
                    total,
                    item: name.clone(),
                });
                let img = read_nifti(f)?;
                check_same_grid(&ct, &img)?;
                mask_files.insert(f.display().to_string(), sha256_file(f)?);
                // Binary masks: any value of 0.5 or more is inside (float masks store 0.0/1.0).
                add(
                    name,
                    &img,
                    &|v| if v >= 0.5 { 1.0 } else { 0.0 },
                    &mut notes,
                );
            }
            progress(&Progress {
                stage: "read masks",
                done: total,
                total,
                item: String::new(),
            });
        }
        MaskSource::Multilabel { file, label_map } => {
            let map = match label_map {
                Some(p) => read_label_map(p)?,
                None => total_v2_label_map(),
            };
            label_map_name = Some(match label_map {
                Some(p) => p.display().to_string(),
                None => "built-in TotalSegmentator v2 'total' class map".to_string(),
            });
            if let Some(p) = label_map {
                mask_files.insert(p.display().to_string(), sha256_file(p)?);
            }
            progress(&Progress {
                stage: "read masks",
                done: 0,
                total: 1,
                item: file.display().to_string(),
            });
            let img = read_nifti(file)?;
            check_same_grid(&ct, &img)?;
            mask_files.insert(file.display().to_string(), sha256_file(file)?);
            let mut present: BTreeMap<u32, usize> = BTreeMap::new();
            for &v in &img.data {
                if v > 0.5 {
                    *present.entry(v.round() as u32).or_default() += 1;
                }
            }
            for &id in present.keys() {
                let Some(name) = map.get(&id) else {
                    notes.push(format!("label {id}: not in the label map; skipped"));
                    continue;
                };
                if !wanted(name) {
                    continue;
                }
                let idf = id as f32;
                add(
                    name.clone(),
                    &img,
                    &|v| if (v - idf).abs() < 0.5 { 1.0 } else { 0.0 },
                    &mut notes,
                );
            }
            progress(&Progress {
                stage: "read masks",
                done: 1,
                total: 1,
                item: String::new(),
            });
        }
    }
    if let Some(inc) = &options.include {
        for n in inc {
            if !structures.iter().any(|s| &s.name == n)
                && !notes.iter().any(|x| x.starts_with(&format!("{n}:")))
            {
                return Err(AnatomyError::invalid(
                    n,
                    "requested structure not found among the masks",
                ));
            }
        }
    }
    let source = SourceInfo {
        source: Source::Ct {
            ct_file: ct_path.display().to_string(),
            ct_sha256: sha256_file(ct_path)?,
            mask_files,
            label_map: label_map_name,
        },
        licence: options.licence.clone(),
        attribution: options.attribution.clone(),
        notes,
    };
    Ok(ImportedCt {
        ct_hu: ct_ras,
        structures,
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn class_map_ids_match_the_data_readme() {
        let m = total_v2_label_map();
        assert_eq!(m[&25], "sacrum");
        assert_eq!(m[&26], "vertebrae_S1");
        assert_eq!(m[&29], "vertebrae_L3");
        assert_eq!(m[&33], "vertebrae_T11");
        assert_eq!(m[&52], "aorta");
        assert_eq!(m[&63], "inferior_vena_cava");
        assert_eq!(m[&68], "iliac_vena_right");
        assert_eq!(m[&79], "spinal_cord");
        assert_eq!(m[&89], "iliopsoas_right");
        assert_eq!(m[&117], "costal_cartilages");
    }

    #[test]
    fn label_map_files_in_both_directions_and_bad_ones() {
        let dir = std::env::temp_dir().join(format!("anatomy-label-map-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, text: &str| {
            let p = dir.join(name);
            fs::write(&p, text).unwrap();
            p
        };
        let by_id = read_label_map(&write(
            "a.json",
            r#"{"22": "vertebrae_L3", "7": "pancreas"}"#,
        ))
        .unwrap();
        let by_name =
            read_label_map(&write("b.json", r#"{"vertebrae_L3": 22, "pancreas": 7}"#)).unwrap();
        assert_eq!(by_id, by_name);
        assert_eq!(by_id[&22], "vertebrae_L3");
        for (file, text) in [
            ("c.json", r#"{"0": "x"}"#),
            ("d.json", "[1, 2]"),
            ("e.json", r#"{"a": 1, "b": 1}"#),
            ("f.json", "{"),
        ] {
            let p = write(file, text);
            let e = read_label_map(&p).unwrap_err().to_string();
            assert!(e.contains(file), "{e}");
        }
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn structure_classes() {
        assert_eq!(
            material_for_structure("vertebrae_L3"),
            Some(MaterialClass::CorticalBone)
        );
        assert_eq!(
            material_for_structure("hip_left"),
            Some(MaterialClass::CorticalBone)
        );
        assert_eq!(material_for_structure("aorta"), Some(MaterialClass::Vessel));
        assert_eq!(
            material_for_structure("iliac_vena_left"),
            Some(MaterialClass::Vessel)
        );
        assert_eq!(
            material_for_structure("gluteus_medius_right"),
            Some(MaterialClass::Muscle)
        );
        assert_eq!(
            material_for_structure("spinal_cord"),
            Some(MaterialClass::DuraCsf)
        );
        assert_eq!(
            material_for_structure("liver"),
            Some(MaterialClass::SoftTissue)
        );
        assert_eq!(material_for_structure("lung_upper_lobe_left"), None);
        for name in TOTAL_V2_LABELS {
            if !name.starts_with("lung_") && name != "trachea" && !name.starts_with("kidney_cyst") {
                assert!(
                    material_for_structure(name).is_some(),
                    "{name} has no class"
                );
            }
        }
    }
}
