//! The meshing and labelling pipeline shared by the procedural phantom and real-CT import.
//!
//! Input: a CT volume in HU on an axis-aligned grid in the region's model frame, and one occupancy
//! mask per structure on the same lattice. Output: a [`RegionAsset`] (meshes, 8-bit CT underlay,
//! label volume, provenance) ready for [`RegionAsset::write_to`].
//!
//! Per structure: crop the mask to its non-zero box, pad it with two empty voxels on every side
//! (so a structure cut by the volume boundary still gives a closed surface), extract the 0.5
//! iso-surface by marching tetrahedra (optionally up-sampled). Then, for all structures together
//! ([`super::interfaces`]): weld the vertices that touching structures share, split the surfaces
//! into patches (shared with another structure, or free), optionally Taubin-smooth them with a
//! displacement cap and a volume guard, optionally decimate each patch once with its borders
//! locked, reassemble every structure and check the result is closed, consistently wound and of
//! positive volume. A structure that also comes as a signed distance bound (the procedural
//! phantoms when built with `PhantomParams::level_set_meshed`, [`build_region_on_level_sets`]) is sampled and extracted from the bound instead of
//! its mask, every vertex root-found onto its zero set ([`super::level_set_mesh`]), and after
//! decimation its edges are split onto the surface where their midpoints stray from it.
//! Touching structures thus share their interface exactly (the same vertices and
//! triangles, opposite winding): the meshes form a laminar family (any two disjoint or nested),
//! which is what a renderer summing per-mesh chords needs. A structure that fails is an error,
//! never a silently broken mesh.
//!
//! ```
//! use sim_core::anatomy::pipeline::{build_region, PipelineParams, SourceInfo, StructureMask};
//! use sim_core::anatomy::asset::Source;
//! use sim_core::material::MaterialClass;
//! use sim_core::volume::{Volume, VolumeGrid};
//!
//! let grid = VolumeGrid { dims: [12, 12, 12], spacing_mm: [1.0; 3], origin_mm: [0.0; 3] };
//! let ct = Volume::filled(grid, 40.0f32);
//! let mut mask = Volume::filled(grid, 0.0f32);
//! for k in 3..9 { for j in 3..9 { for i in 3..9 { mask.set(i, j, k, 1.0); } } }
//! let source = SourceInfo {
//!     source: Source::Phantom { generator: "doc-example".into(), parameters: serde_json::json!({}) },
//!     licence: "Apache-2.0".into(),
//!     attribution: "generated".into(),
//!     notes: vec![],
//! };
//! let cube = StructureMask { name: "cube".into(), material: MaterialClass::Disc, mask };
//! let region = build_region("example", &ct, vec![cube], &PipelineParams::default(), source, &mut |_| {}).unwrap();
//! let mesh = &region.structure("cube").unwrap().mesh;
//! assert!(mesh.topology_report().is_closed_and_consistent());
//! // 6 x 6 x 6 voxels of 1 mm: the 0.5 iso-surface of a binary box bounds 216 mm^3 minus the
//! // chamfered edges and corners (the box is extracted from a 0/1 field, not partial volumes).
//! assert!((mesh.signed_volume_mm3() - 216.0).abs() < 216.0 * 0.1);
//! ```

use super::asset::{Provenance, RegionAsset, Source, StructureAsset, encode_hu};
use super::error::AnatomyError;
use super::interfaces::{ExtractedSurface, lattice_edge_key, mesh_family};
use super::labels::label_volume;
use super::level_set_mesh::{LevelSetFn, LevelSetSurface, extract_level_set};
use super::mask::{mask_offset, nonzero_box};
use super::mesher::{EdgeCrossing, ScalarField, extract_isosurface_keyed};
use crate::mesh::TriMesh;
use crate::par::par_map_heaviest_first_told;
use crate::volume::{Volume, VolumeGrid};

// The per-structure input, the knobs and the final mesh checks live in modules of their own (the
// asset format and the labelling need them too); they stay reachable here, where callers look.
pub use super::mask::StructureMask;
pub use super::params::PipelineParams;
pub use super::solid::check_solid;

/// Where the input came from, and under which terms the derived asset may be shared.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceInfo {
    /// Phantom parameters, or CT and mask files.
    pub source: Source,
    /// Licence of the derived asset (SPDX identifier where one exists).
    pub licence: String,
    /// Attribution text that must travel with the asset.
    pub attribution: String,
    /// Notes from the caller (import decisions, skipped inputs), copied into the provenance.
    pub notes: Vec<String>,
}

/// Version of the meshing steps, part of [`pipeline_version`]: 3 meshes structures given as
/// level sets from them (vertices on the zero set, edges refined onto it); 2 shares the
/// interfaces of touching structures (`interfaces`); 1 meshed every structure on its own.
pub const MESHING_VERSION: u32 = 3;

/// Pipeline version recorded in provenance (and in the phantom's cache key): crate version, asset
/// format version and meshing version.
pub fn pipeline_version() -> String {
    format!(
        "sim-core {} / anatomy format {} / meshing {MESHING_VERSION}",
        env!("CARGO_PKG_VERSION"),
        super::asset::FORMAT_VERSION
    )
}

/// A progress report from [`build_region`].
#[derive(Debug, Clone, PartialEq)]
pub struct Progress {
    /// Stage name: `"labels"`, `"mesh"`, ...
    pub stage: &'static str,
    /// Work done in this stage, in the stage's units (items; for `"mesh"` per mille of the
    /// structures' surface voxels, for `"interfaces"` the steps' measured costs), so that
    /// `done / total` follows the stage's time.
    pub done: usize,
    /// Work in this stage, in the same units.
    pub total: usize,
    /// The item being worked on (a structure name), if any.
    pub item: String,
}

/// Units of the `"mesh"` stage's progress: per mille of the surface voxels.
const MESH_UNITS: usize = 1000;

/// Empty voxels padded around each structure's non-zero box before extraction, so that a
/// structure cut by the volume boundary still gives a closed surface.
const PAD: usize = 2;

/// Crops a mask to its non-zero box, pads it and extracts its 0.5 iso-surface, keying every vertex
/// by its edge of the region's sample lattice. `offset` is the voxel index of the mask grid's
/// origin in the region's grid, whose dimensions are `region_dims`.
fn extract_structure(
    mask: &StructureMask,
    level_set: Option<LevelSetFn<'_>>,
    params: &PipelineParams,
    offset: [usize; 3],
    region_dims: [usize; 3],
) -> Result<ExtractedSurface, AnatomyError> {
    let Some((lo, hi)) = nonzero_box(&mask.mask) else {
        return Err(AnatomyError::Mesh {
            structure: mask.name.clone(),
            message: "empty mask".into(),
        });
    };
    let g = mask.mask.grid;
    let dims: [usize; 3] = std::array::from_fn(|a| hi[a] - lo[a] + 1 + 2 * PAD);
    let origin: [f64; 3] =
        std::array::from_fn(|a| g.origin_mm[a] + (lo[a] as f64 - PAD as f64) * g.spacing_mm[a]);
    let fgrid = VolumeGrid {
        dims,
        spacing_mm: g.spacing_mm,
        origin_mm: origin,
    };
    let u = params.upsample.max(1);
    let (mesh, crossings, interpolated) = match level_set {
        Some(f) => {
            let mut s = extract_from_level_set(&mask.name, f, &fgrid, u)?;
            if u == 1 {
                mask_fallbacks(&mut s, mask, &fgrid, lo, hi);
            }
            (s.mesh, s.crossings, s.interpolated_mm)
        }
        None => {
            let (mesh, crossings) = extract_from_mask(mask, params, &fgrid, lo, hi)?;
            (mesh, crossings, Vec::new())
        }
    };
    check_solid(&mask.name, &mesh, "extraction")?;
    // Fine lattice index in the region: the padded box starts PAD voxels below `offset + lo`,
    // and keys are shifted by PAD voxels so that they are never negative.
    let u64u = u64::from(u);
    let extent: [u64; 3] = std::array::from_fn(|a| (region_dims[a] + 2 * PAD + 1) as u64 * u64u);
    let edges = crossings
        .iter()
        .map(|c| {
            let lower: [u64; 3] =
                std::array::from_fn(|a| (offset[a] + lo[a]) as u64 * u64u + c.lower[a] as u64);
            (lattice_edge_key(lower, c.axes, extent), c.s)
        })
        .collect();
    Ok(ExtractedSurface {
        name: mask.name.clone(),
        mesh,
        edges,
        mask_volume_mm3: mask.volume_mm3(),
        interpolated_mm: interpolated,
    })
}

/// On the voxel lattice itself (no up-sampling), the fallback of every vertex whose lattice edge
/// the mask crosses too is where the mask path puts it (the 0.5 crossing of the mask's values):
/// those positions are what the masks' meshes always had, and touching structures' masks sum
/// to one, so their surfaces meet without crossing. Elsewhere (a lattice point whose mask value
/// disagrees with the level set's sign by rounding) the interpolated bound stays.
fn mask_fallbacks(
    s: &mut LevelSetSurface,
    mask: &StructureMask,
    fgrid: &VolumeGrid,
    lo: [usize; 3],
    hi: [usize; 3],
) {
    let value = |p: [usize; 3]| -> f32 {
        let inside = (0..3).all(|a| p[a] >= PAD && p[a] - PAD + lo[a] <= hi[a]);
        if !inside {
            return 0.0;
        }
        let v = mask
            .mask
            .get(p[0] - PAD + lo[0], p[1] - PAD + lo[1], p[2] - PAD + lo[2]);
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    for (pos, c) in s.interpolated_mm.iter_mut().zip(&s.crossings) {
        let q: [usize; 3] = std::array::from_fn(|a| c.lower[a] + usize::from((c.axes >> a) & 1));
        let (fp, fq) = (value(c.lower), value(q));
        if (fp > 0.5) == (fq > 0.5) {
            continue;
        }
        let t = (f64::from(0.5 - fp) / f64::from(fq - fp)).clamp(1e-3, 1.0 - 1e-3);
        let a = fgrid.voxel_center_mm(c.lower[0], c.lower[1], c.lower[2]);
        let b = fgrid.voxel_center_mm(q[0], q[1], q[2]);
        *pos = std::array::from_fn(|k| a[k] + t * (b[k] - a[k]));
    }
}

/// The 0.5 iso-surface of the mask's values in the padded box `fgrid` (mask voxels `lo..=hi`
/// at `PAD`), trilinearly up-sampled by the pipeline's factor.
fn extract_from_mask(
    mask: &StructureMask,
    params: &PipelineParams,
    fgrid: &VolumeGrid,
    lo: [usize; 3],
    hi: [usize; 3],
) -> Result<(TriMesh, Vec<EdgeCrossing>), AnatomyError> {
    let fgrid = *fgrid;
    let mut values = vec![0.0f32; fgrid.len()];
    for k in lo[2]..=hi[2] {
        for j in lo[1]..=hi[1] {
            for i in lo[0]..=hi[0] {
                let v = mask.mask.get(i, j, k);
                values[fgrid.index(i - lo[0] + PAD, j - lo[1] + PAD, k - lo[2] + PAD)] =
                    if v.is_finite() {
                        v.clamp(0.0, 1.0)
                    } else {
                        0.0
                    };
            }
        }
    }
    let field = ScalarField {
        grid: fgrid,
        values: &values,
    };
    extract_isosurface_keyed(&field, params.iso_level, params.upsample.max(1)).ok_or_else(|| {
        AnatomyError::Mesh {
            structure: mask.name.clone(),
            message: "padding failed to enclose the mask".into(),
        }
    })
}

/// The zero set of `f` on the padded box `fgrid` up-sampled by `u` (the lattice the mask path
/// interpolates to), with every vertex on the zero set (see [`super::level_set_mesh`]). The
/// bound is clipped to the box's outermost lattice points, so a sliver of the solid beyond the
/// padding is cut off rather than left open.
fn extract_from_level_set(
    name: &str,
    f: LevelSetFn<'_>,
    fgrid: &VolumeGrid,
    u: u32,
) -> Result<LevelSetSurface, AnatomyError> {
    let u = u as usize;
    let spacing: [f64; 3] = std::array::from_fn(|a| fgrid.spacing_mm[a] / u as f64);
    let fine = VolumeGrid {
        dims: std::array::from_fn(|a| fgrid.dims[a] * u),
        spacing_mm: spacing,
        origin_mm: std::array::from_fn(|a| {
            fgrid.origin_mm[a] - 0.5 * fgrid.spacing_mm[a] + 0.5 * spacing[a]
        }),
    };
    let first = fine.voxel_center_mm(0, 0, 0);
    let last = fine.voxel_center_mm(fine.dims[0] - 1, fine.dims[1] - 1, fine.dims[2] - 1);
    let clipped = |p: [f64; 3]| {
        let mut g = f(p);
        for a in 0..3 {
            g = g.max(first[a] - p[a]).max(p[a] - last[a]);
        }
        g
    };
    extract_level_set(&clipped, &fine).ok_or_else(|| AnatomyError::Mesh {
        structure: name.to_string(),
        message: "the level set reaches the faces of its clipped box".into(),
    })
}

/// Meshes one mask on its own: crop, pad, extract, smooth, decimate, check. Returns the mesh and
/// notes. (A region's structures go through [`build_region`], which also shares the interfaces
/// of touching structures.)
pub fn mesh_structure(
    mask: &StructureMask,
    params: &PipelineParams,
) -> Result<(TriMesh, Vec<String>), AnatomyError> {
    let item = extract_structure(mask, None, params, [0; 3], mask.mask.grid.dims)?;
    let mut out = mesh_family(
        std::slice::from_ref(&item),
        params.smoothing.as_ref(),
        params.decimation.as_ref(),
        &[],
        None,
        &mut |_, _, _| {},
    )?;
    Ok(out.meshes.remove(0))
}

/// Builds a region: validates the inputs, derives the label volume and the 8-bit CT underlay,
/// and meshes every non-empty structure (empty ones are skipped with a note in the provenance).
///
/// `ct_hu` defines the model-frame grid of the region; every mask must lie on it (same spacing,
/// origin on the lattice, possibly a sub-box). Where masks overlap, the later one in `structures`
/// takes the label (so list enclosing structures, such as skin and fat, first).
pub fn build_region(
    name: &str,
    ct_hu: &Volume<f32>,
    structures: Vec<StructureMask>,
    params: &PipelineParams,
    source: SourceInfo,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    let none = vec![None; structures.len()];
    build_region_on_level_sets(name, ct_hu, structures, &none, params, source, progress)
}

/// [`build_region`] for structures that also come as signed distance bounds (`level_sets`, one
/// per structure, in the same order; `None` meshes that structure from its mask): a structure
/// with a bound is meshed from it, every vertex on its zero set (see [`super::level_set_mesh`]),
/// on the lattice the masks would be up-sampled to, so the shared interfaces of touching
/// structures are welded as before. Its mask still gives the labels, the CT underlay's extent and
/// the box it is meshed in (padded by two voxels). The procedural phantoms mesh this way
/// when built with `PhantomParams::level_set_meshed`; the shipped ones still mesh their masks.
pub fn build_region_on_level_sets(
    name: &str,
    ct_hu: &Volume<f32>,
    structures: Vec<StructureMask>,
    level_sets: &[Option<LevelSetFn<'_>>],
    params: &PipelineParams,
    source: SourceInfo,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    if level_sets.len() != structures.len() {
        return Err(AnatomyError::invalid(
            name,
            format!(
                "{} level sets for {} structures",
                level_sets.len(),
                structures.len()
            ),
        ));
    }
    let grid = ct_hu.grid;
    if grid.is_empty() || ct_hu.data.len() != grid.len() {
        return Err(AnatomyError::invalid(
            name,
            "CT volume is empty or its data does not match its grid",
        ));
    }
    if grid
        .spacing_mm
        .iter()
        .chain(&grid.origin_mm)
        .any(|x| !x.is_finite())
        || grid.spacing_mm.iter().any(|&s| s <= 0.0)
    {
        return Err(AnatomyError::invalid(
            name,
            format!("CT grid has invalid spacing or origin: {grid:?}"),
        ));
    }
    if params.upsample == 0 || params.upsample > 8 {
        return Err(AnatomyError::invalid(
            name,
            format!("upsample must be 1..=8, got {}", params.upsample),
        ));
    }
    let mut notes = source.notes.clone();
    let mut kept = Vec::with_capacity(structures.len());
    let mut kept_sets = Vec::with_capacity(structures.len());
    let mut seen = std::collections::BTreeSet::new();
    for (s, set) in structures.into_iter().zip(level_sets) {
        mask_offset(&grid, &s)?;
        if !seen.insert(s.name.clone()) {
            return Err(AnatomyError::invalid(
                &s.name,
                "two structures with this name",
            ));
        }
        // Cropping to the non-zero box first keeps the labelling and meshing memory proportional
        // to the structure, not to the region.
        match s.cropped() {
            Some(c) => {
                kept.push(c);
                kept_sets.push(*set);
            }
            None => notes.push(format!("{}: empty mask skipped", s.name)),
        }
    }
    progress(&Progress {
        stage: "labels",
        done: 0,
        total: 1,
        item: String::new(),
    });
    let (labels, label_notes) = label_volume(ct_hu, &kept, params.cortical_shell_mm)?;
    notes.extend(label_notes);
    let ct_u8 = Volume {
        grid,
        data: ct_hu
            .data
            .iter()
            .map(|&hu| encode_hu(f64::from(hu)))
            .collect(),
    };
    progress(&Progress {
        stage: "labels",
        done: 1,
        total: 1,
        item: String::new(),
    });
    // Structures are extracted in parallel (one worker per core, each taking the next
    // structure, those with the most partial-volume voxels, the most surface, first, so that no
    // large one starts last), then smoothed and decimated together so that touching structures
    // share their interfaces (`interfaces`); every step writes by index, so the asset is
    // identical whatever the thread count.
    let total = kept.len();
    let offsets: Vec<[usize; 3]> = kept
        .iter()
        .map(|s| mask_offset(&grid, s))
        .collect::<Result<_, _>>()?;
    let surface: Vec<usize> = kept
        .iter()
        .map(|s| s.mask.data.iter().filter(|&&v| v > 0.0 && v < 1.0).count())
        .collect();
    // Progress in per mille of the surface voxels extracted (a structure's time grows with its
    // surface; the largest go first, so a count of structures would run far ahead of the time:
    // 8 of the default phantom's 49 took 4.7 of its 8 s).
    let surface_total = surface.iter().sum::<usize>().max(1);
    let mut surface_done = 0;
    let per_mille = |n: usize| (n as u128 * MESH_UNITS as u128 / surface_total as u128) as usize;
    let extracted = par_map_heaviest_first_told(
        &surface,
        &|i| extract_structure(&kept[i], kept_sets[i], params, offsets[i], grid.dims),
        &mut |i| {
            surface_done += surface[i];
            progress(&Progress {
                stage: "mesh",
                done: per_mille(surface_done),
                total: MESH_UNITS,
                item: kept[i].name.clone(),
            });
        },
    );
    let extracted: Vec<ExtractedSurface> = extracted.into_iter().collect::<Result<_, _>>()?;
    progress(&Progress {
        stage: "mesh",
        done: MESH_UNITS,
        total: MESH_UNITS,
        item: String::new(),
    });
    // The family steps (welding, decimation, refinement) take most of a build: 20 of 27 s for the
    // default phantom's mask meshes and 44 of 63 s for its level-set meshes on 2 cores.
    let meshed = mesh_family(
        &extracted,
        params.smoothing.as_ref(),
        params.decimation.as_ref(),
        &kept_sets,
        params.surface_tolerance_mm,
        &mut |step, done, total| {
            progress(&Progress {
                stage: "interfaces",
                done,
                total,
                item: step.to_string(),
            });
        },
    )?;
    drop(extracted);
    let mut out = Vec::with_capacity(total);
    for (s, (mesh, mesh_notes)) in kept.into_iter().zip(meshed.meshes) {
        notes.extend(mesh_notes);
        out.push(StructureAsset {
            name: s.name.clone(),
            material: s.material,
            mask_volume_mm3: s.volume_mm3(),
            mesh,
        });
    }
    notes.extend(meshed.notes);
    Ok(RegionAsset {
        name: name.to_string(),
        structures: out,
        ct_u8,
        labels,
        provenance: Provenance {
            source: source.source,
            licence: source.licence,
            attribution: source.attribution,
            pipeline_version: pipeline_version(),
            parameters: params.clone(),
            notes,
            files_sha256: Default::default(),
        },
        landmarks: Vec::new(),
    })
}
