//! The procedural lumbosacral phantom: the default anatomy, built from our own code on first run.
//!
//! L1 to the sacrum and the iliac wings, with the canal contents, exiting roots, great vessels,
//! paraspinal muscles, fat and skin, are written as smooth implicit solids ([`sdf`], [`model`]) with
//! dimensions from published adult morphometry (cited in [`model`]). The solids are painted into a
//! label grid ([`voxelize`]), which gives one disjoint binary mask per structure and a CT volume in
//! HU (tissue values, a CT-like blur and seeded noise). Masks and CT then go through the same
//! [`pipeline::build_region`] as real CT, which meshes every structure and writes the region.
//!
//! Determinism: everything is a pure function of [`PhantomParams`]. Threads split the grid into
//! z-slabs whose results do not depend on the split, noise is a hash of (seed, voxel index), and
//! the pipeline is deterministic, so the same parameters give the same files byte for byte.
//! [`ensure_built`] keys its cache on the SHA-256 of the parameters and the pipeline version.
//!
//! # Structures (painting order; later ones own their overlap with earlier ones)
//! - `skin` (soft tissue; the whole body envelope, meshed whole: everything else is nested in it),
//!   `subcutaneous_fat` (the 15 mm layer under the 2 mm skin), `deep_soft_tissue` (the envelope
//!   interior, meshed whole; viscera, ligaments and everything not modelled);
//! - `psoas_left/right`, `erector_spinae_left/right` (muscle);
//! - `epidural_space`, `ligamentum_flavum`, `dural_sac` (dura and CSF), `conus_medullaris`,
//!   `cauda_equina`, `nerve_root_{L1..L5,S1,S2}_{left,right}` (exiting roots with ganglia);
//! - `inferior_vena_cava` (with the common iliac veins), `aorta` (with the common iliac arteries);
//! - `disc_L1_L2` .. `disc_L5_S1`;
//! - `{L1..L5,sacrum,ilium_left,ilium_right}_cortical` (the cortical shell) and `_cancellous`
//!   (the interior): pedicles, laminae, spinous, transverse and articular processes with 2 mm
//!   facet joints and open interlaminar windows; sacral canal, anterior and posterior foramina,
//!   hiatus; iliac wings with arched crests and a 2.5 mm sacroiliac joint.
//!
//! Except for the two whole-envelope solids, masks (and so meshes) are disjoint: a mesh bounds
//! exactly the voxels its structure owns, so a renderer may sum per-material chord lengths
//! without nesting rules, and one that nests by priority gets the same answer as long as soft
//! tissue has the lowest priority (as in `crate::fluoro::scene`).
//!
//! # Landmarks
//! [`landmarks`] lists named points: body centres, interlaminar window centres and the posterior
//! epidural space at each lumbar level, L4-L5 and L5-S1 facet joint centres, S1 anterior foramina,
//! L4 transforaminal (subpedicular) targets, the sacral hiatus and the L5 spinous tip. Each says
//! which structure it lies in where that is defined; the tests check them against the solids.
//!
//! Model frame: the platform's RAS frame (x = patient right, y = anterior, z = cranial, millimetres,
//! right-handed, as in `crate::fluoro::geometry`), origin at the centre of the L3 vertebral body
//! (see [`model`]).
//!
//! ```no_run
//! use sim_core::anatomy::phantom;
//! let region = phantom::ensure_built(std::path::Path::new("assets/lumbar-phantom")).unwrap();
//! assert!(region.structure("L4_cortical").is_some());
//! let target = phantom::landmark(&phantom::PhantomParams::default(), "L4_transforaminal_target_left");
//! assert!(target.is_some());
//! ```

pub mod cervical;
pub mod habitus;
pub mod level_set;
pub mod model;
pub mod morphometry;
pub mod sdf;
pub mod voxelize;

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::asset::{RegionAsset, Source};
use super::decimate::DecimationParams;
use super::error::AnatomyError;
use super::level_set_mesh::LevelSetFn;
use super::pipeline::{
    PipelineParams, Progress, SourceInfo, StructureMask, build_region, build_region_on_level_sets,
    pipeline_version,
};
use crate::material::MaterialClass;
use crate::volume::{Volume, VolumeGrid};

pub use model::{AnatomyParams, Landmark};

/// The coarsest mesh lattice that keeps every structure within 10 % of its analytic volume,
/// mm: the nerve roots (1.5-3 mm radius) and the 3.5 mm flavum lose up to 14 % on a 3 mm
/// lattice even with every vertex on the surface (measured), at most 6 % on a 1.5 mm one.
const THIN_STRUCTURE_LATTICE_MM: f64 = 1.5;

/// The coarsest grid meshed on a finer lattice than its own, mm. Coarser grids exist for quick
/// tests, which do not need the thin structures' volumes and would pay a 1.5 mm build for them.
const FINEST_COARSE_GRID_MM: f64 = 3.0;

/// The pipeline's up-sampling for a grid of `voxel_mm`: grids up to [`FINEST_COARSE_GRID_MM`]
/// mesh on the lattice nearest to [`THIN_STRUCTURE_LATTICE_MM`] (the 3 mm grid on 1.5 mm, the
/// default 1.5 mm grid on its own), coarser grids on their own lattice.
pub fn mesh_upsample(voxel_mm: f64) -> u32 {
    if voxel_mm > FINEST_COARSE_GRID_MM * (1.0 + 1e-9) {
        1
    } else {
        (voxel_mm / THIN_STRUCTURE_LATTICE_MM)
            .round()
            .clamp(1.0, 8.0) as u32
    }
}

/// The thickest cortex [`PhantomParams::effective_anatomy`] makes on a coarse grid, mm.
const MAX_THICKENED_CORTEX_MM: f64 = 7.5;

/// Generator identifier recorded in the provenance; bump the number when the model changes shape.
pub const GENERATOR: &str = "lumbosacral-phantom/5";

/// Region name and default folder name under `assets/`.
pub const REGION_NAME: &str = "lumbar-phantom";

/// A cortical shell thickness larger than any bone, which keeps every voxel of a cortical mask
/// cortical in the pipeline's label volume.
pub const PIPELINE_SPLIT_OFF_MM: f64 = 1000.0;

/// CT number of each tissue class in the phantom, HU.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TissueHu {
    /// Cortical bone: 1000-1900 HU in adults (e.g. Schneider et al. 1996, Phys Med Biol
    /// 41:111); the 8-bit underlay clips it at 700 HU anyway.
    pub cortical_bone: f64,
    /// Lumbar trabecular bone of a young adult: about 200-270 HU (Pickhardt et al. 2013, Ann Intern
    /// Med 158:588, L1 attenuation by age).
    pub cancellous: f64,
    /// Intervertebral disc: 70-100 HU (annulus denser than nucleus; our assumption in that range).
    pub disc: f64,
    /// Skeletal muscle: 40-60 HU (Kalender, Computed Tomography, 3rd ed.).
    pub muscle: f64,
    /// Adipose tissue: -70 to -120 HU (Kalender).
    pub fat: f64,
    /// Skin and deep soft tissue (viscera, ligaments): 30-50 HU (our assumption).
    pub soft_tissue: f64,
    /// Unenhanced blood: 35-50 HU (our assumption; set about 200 HU for a contrast-enhanced scan).
    pub vessel: f64,
    /// Nerve roots and cauda: 30-40 HU (our assumption).
    pub nerve: f64,
    /// CSF in the dural sac: 0-15 HU.
    pub dura_csf: f64,
    /// Epidural space, mostly fat with a venous plexus: -80 HU (our assumption).
    pub epidural_space: f64,
    /// Ligamentum flavum: 60-80 HU, denser than muscle (our assumption).
    pub ligamentum_flavum: f64,
    /// Air outside the body.
    pub air: f64,
}

impl Default for TissueHu {
    fn default() -> Self {
        TissueHu {
            cortical_bone: 1200.0,
            cancellous: 250.0,
            disc: 85.0,
            muscle: 50.0,
            fat: -100.0,
            soft_tissue: 40.0,
            vessel: 45.0,
            nerve: 35.0,
            dura_csf: 8.0,
            epidural_space: -80.0,
            ligamentum_flavum: 70.0,
            air: -1000.0,
        }
    }
}

impl TissueHu {
    /// The CT number of a material class.
    pub fn of(&self, m: MaterialClass) -> f64 {
        match m {
            MaterialClass::CorticalBone => self.cortical_bone,
            MaterialClass::Cancellous => self.cancellous,
            MaterialClass::Disc => self.disc,
            MaterialClass::Muscle => self.muscle,
            MaterialClass::Fat => self.fat,
            MaterialClass::SoftTissue => self.soft_tissue,
            MaterialClass::Vessel => self.vessel,
            MaterialClass::Nerve => self.nerve,
            MaterialClass::DuraCsf => self.dura_csf,
            MaterialClass::EpiduralSpace => self.epidural_space,
            MaterialClass::LigamentumFlavum => self.ligamentum_flavum,
        }
    }
}

/// Everything the phantom depends on. Same parameters, same bytes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PhantomParams {
    /// Shape parameters.
    pub anatomy: AnatomyParams,
    /// Isotropic voxel size of the CT underlay and masks, mm.
    pub voxel_mm: f64,
    /// Lower corner of the region covered by the grid (outer voxel faces), mm, model frame.
    pub extent_min_mm: [f64; 3],
    /// Upper corner of the region covered by the grid, mm.
    pub extent_max_mm: [f64; 3],
    /// CT numbers per tissue.
    pub hu: TissueHu,
    /// Standard deviation of the Gaussian blur applied to the CT (a CT point-spread function),
    /// mm. 0.6 mm is about 1.4 mm FWHM, typical of a body reconstruction kernel (our assumption).
    pub blur_sigma_mm: f64,
    /// Standard deviation of the CT noise, HU (10 HU: a standard-dose abdominal scan; our
    /// assumption).
    pub noise_sd_hu: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// Meshing parameters handed to the pipeline.
    pub pipeline: PipelineParams,
    /// Whether the meshes follow the solids' level sets (vertices on their zero sets, see
    /// [`level_set`] and [`PhantomParams::level_set_meshed`]) rather than the masks' 0.5 levels.
    /// Absent (false) in regions built before it existed.
    #[serde(default)]
    pub mesh_from_level_sets: bool,
}

impl Default for PhantomParams {
    /// What the platform ships: the 1.5 mm grid meshed from the solids' level sets
    /// ([`PhantomParams::level_set_meshed`]).
    fn default() -> Self {
        PhantomParams::level_set_meshed(1.5)
    }
}

impl PhantomParams {
    /// Default anatomy and extent on a grid of `voxel_mm`, meshed from the masks' 0.5 levels
    /// (tests use coarser grids: a mask build is several times faster than a level-set one).
    pub fn with_voxel_mm(voxel_mm: f64) -> PhantomParams {
        PhantomParams {
            anatomy: AnatomyParams::default(),
            voxel_mm,
            // The body envelope is 330 x 234 mm; z covers T12-L1 down to below the sacral apex
            // and the iliac bones' lower columns (our assumption for the field of view).
            extent_min_mm: [-171.0, -96.0, -222.0],
            extent_max_mm: [171.0, 146.0, 102.0],
            hu: TissueHu::default(),
            blur_sigma_mm: 0.6,
            noise_sd_hu: 10.0,
            seed: 0x0005_eed1_u64,
            pipeline: PipelineParams {
                upsample: 1,
                iso_level: 0.5,
                // No smoothing: the masks carry partial volumes from the exact solids, so the
                // extracted surface has no voxel staircase to remove.
                smoothing: None,
                // A quarter of the triangles with at most a fifth of a voxel of deviation.
                decimation: Some(DecimationParams {
                    max_error_mm: 0.2 * voxel_mm,
                    ..DecimationParams::default()
                }),
                // The phantom supplies separate cortical and cancellous masks, so the pipeline's
                // depth split of bone masks (meant for whole-bone masks of real CT) is switched
                // off by a shell thicker than any bone.
                cortical_shell_mm: PIPELINE_SPLIT_OFF_MM,
                surface_tolerance_mm: None,
            },
            mesh_from_level_sets: false,
        }
    }

    /// [`PhantomParams::with_voxel_mm`] meshed from the solids' level sets: every vertex on the
    /// surface of the structure it bounds (where surfaces would cross, at the masks' positions),
    /// edges split onto the surface where their midpoints stray from it, grids up to 3 mm on a
    /// lattice of about 1.5 mm ([`mesh_upsample`]), and layers thickened to one voxel instead of
    /// one and a half (see [`PhantomParams::effective_anatomy`]). Every lumbar structure's mesh
    /// is then within 5 % of its analytic volume on the 1.5 mm grid and within 10 % at 3 mm (the
    /// tests' `mesh_volume`). What the platform ships on the 1.5 mm grid
    /// ([`PhantomParams::default`]); its meshes are laminar to round-off, as the mask meshes are
    /// (the tests' `laminar`).
    pub fn level_set_meshed(voxel_mm: f64) -> PhantomParams {
        PhantomParams::with_voxel_mm(voxel_mm).meshed_from_level_sets()
    }

    /// These parameters meshed from level sets as [`PhantomParams::level_set_meshed`] does (for
    /// another region's parameters, such as the neck's).
    pub fn meshed_from_level_sets(self) -> PhantomParams {
        let mut p = self;
        let voxel_mm = p.voxel_mm;
        p.mesh_from_level_sets = true;
        p.pipeline.upsample = mesh_upsample(voxel_mm);
        // Edges whose midpoints sit more than a twenty-fifth of a voxel off the solids' surfaces
        // are split onto them (simulator choice: on the default grid 3.7 M triangles and every
        // structure within 4.5 % of its analytic volume, against 3.5 M and 4.6 % at 0.06 voxel;
        // 3.8 M since refinement also splits beside junctions).
        p.pipeline.surface_tolerance_mm = Some(0.04 * voxel_mm);
        p
    }

    /// The grid: voxel faces span the extent (rounded up to whole voxels).
    pub fn grid(&self) -> VolumeGrid {
        let dims: [usize; 3] = std::array::from_fn(|a| {
            ((self.extent_max_mm[a] - self.extent_min_mm[a]) / self.voxel_mm)
                .ceil()
                .max(1.0) as usize
        });
        VolumeGrid {
            dims,
            spacing_mm: [self.voxel_mm; 3],
            origin_mm: std::array::from_fn(|a| self.extent_min_mm[a] + 0.5 * self.voxel_mm),
        }
    }

    /// SHA-256 (hex) of the generator name, pipeline version and parameters: the cache key.
    pub fn hash_hex(&self) -> String {
        self.hash_hex_for(GENERATOR)
    }

    /// [`Self::hash_hex`] for the phantom made by `generator` (another region's generator, such
    /// as [`cervical::GENERATOR`], keys its own cache).
    pub fn hash_hex_for(&self, generator: &str) -> String {
        let json = serde_json::to_string(self).unwrap_or_default();
        crate::hash::sha256_hex(format!("{generator}\n{}\n{json}", pipeline_version()).as_bytes())
    }
}

/// The implicit anatomy used on the grid of `params` (solids in painting order and landmarks).
pub fn anatomy(params: &PhantomParams) -> model::Anatomy {
    model::Anatomy::new(&params.effective_anatomy())
}

/// The phantom's named structures in painting order (name, material).
pub fn structure_list(params: &PhantomParams) -> Vec<(String, MaterialClass)> {
    model::Anatomy::new(&params.effective_anatomy())
        .parts
        .into_iter()
        .map(|p| (p.name, p.material))
        .collect()
}

/// The named landmarks of the phantom (model frame, mm).
pub fn landmarks(params: &PhantomParams) -> Vec<Landmark> {
    model::Anatomy::new(&params.effective_anatomy()).landmarks
}

/// One landmark by name.
pub fn landmark(params: &PhantomParams, name: &str) -> Option<Landmark> {
    landmarks(params).into_iter().find(|l| l.name == name)
}

/// The voxelized phantom before meshing.
#[derive(Debug, Clone)]
pub struct PhantomVolumes {
    /// Structure index + 1 per voxel under the painting order, sampled at voxel centres (0 = air
    /// outside the body); indices into `structures`.
    pub structure_ids: Volume<u8>,
    /// Partial volumes of the voxels near a boundary (sorted by voxel); everywhere else a voxel is
    /// wholly its `structure_ids` structure.
    pub fractions: Vec<voxelize::Fraction>,
    /// CT in HU (partial-volume tissue values, blur, noise).
    pub ct_hu: Volume<f32>,
    /// Structures in painting order (name, material).
    pub structures: Vec<(String, MaterialClass)>,
    /// For nested structures, the centre labels (1 inside) and boundary fractions of their whole
    /// solid; `None` for the others.
    pub nested: Vec<Option<(Volume<u8>, Vec<voxelize::Fraction>)>>,
    /// The implicit solids painted, whose level sets ([`level_set`]) the meshes follow.
    pub anatomy: model::Anatomy,
}

impl PhantomVolumes {
    /// Voxel count of each structure by centre sampling (same order as `structures`).
    pub fn voxel_counts(&self) -> Vec<usize> {
        let mut counts = vec![0usize; self.structures.len() + 1];
        for &l in &self.structure_ids.data {
            counts[usize::from(l)] += 1;
        }
        counts[1..].to_vec()
    }

    /// Volume of each structure from its partial-volume occupancies, mm^3.
    pub fn volumes_mm3(&self) -> Vec<f64> {
        let mut vol = vec![0f64; self.structures.len() + 1];
        let mut in_band = vec![false; self.structure_ids.data.len()];
        for f in &self.fractions {
            in_band[f.voxel as usize] = true;
            vol[usize::from(f.label)] += f64::from(f.occupancy);
        }
        for (&l, &b) in self.structure_ids.data.iter().zip(&in_band) {
            if !b {
                vol[usize::from(l)] += 1.0;
            }
        }
        let v = self.structure_ids.grid.voxel_volume_mm3();
        vol[1..].iter().map(|n| n * v).collect()
    }

    /// Occupancy masks (partial volumes in `0..=1`) of every structure, each cropped to its own
    /// bounding box on the CT lattice; an empty structure gives a 1-voxel empty mask (the pipeline
    /// skips it with a note). Nested structures (see [`model::PhantomPart::nested`]) get the mask
    /// of their whole solid, the others the part the painting order leaves to them.
    pub fn masks(&self) -> Vec<StructureMask> {
        // The painted structures share one band of fraction voxels; the structures are made in
        // parallel (each scans the whole label volume).
        let band = in_band(&self.structure_ids, &self.fractions);
        crate::par::par_map(
            self.structures.len(),
            &|s| {
                let (name, material) = self.structures[s].clone();
                let mask = match &self.nested[s] {
                    Some((ids, fr)) => occupancy_mask(ids, fr, &in_band(ids, fr), 1),
                    None => {
                        occupancy_mask(&self.structure_ids, &self.fractions, &band, s as u8 + 1)
                    }
                };
                StructureMask {
                    name,
                    material,
                    mask,
                }
            },
            &mut |_| {},
        )
    }
}

/// Whether each voxel of `ids` has boundary fractions.
fn in_band(ids: &Volume<u8>, fractions: &[voxelize::Fraction]) -> Vec<bool> {
    let mut band = vec![false; ids.data.len()];
    for f in fractions {
        band[f.voxel as usize] = true;
    }
    band
}

/// The occupancy of `label` from centre labels plus boundary fractions (`in_band`: the voxels
/// that have some), cropped to its box.
fn occupancy_mask(
    ids: &Volume<u8>,
    fractions: &[voxelize::Fraction],
    in_band: &[bool],
    label: u8,
) -> Volume<f32> {
    let g = ids.grid;
    let mut lo = [usize::MAX; 3];
    let mut hi = [0usize; 3];
    let mut grow = |ijk: [usize; 3]| {
        for a in 0..3 {
            lo[a] = lo[a].min(ijk[a]);
            hi[a] = hi[a].max(ijk[a]);
        }
    };
    for k in 0..g.dims[2] {
        for j in 0..g.dims[1] {
            let row = &ids.data[g.index(0, j, k)..][..g.dims[0]];
            for (i, &l) in row.iter().enumerate() {
                if l == label {
                    grow([i, j, k]);
                }
            }
        }
    }
    let mut mine = Vec::new();
    for f in fractions {
        if f.label == label {
            mine.push((f.voxel as usize, f.occupancy));
            grow(g.ijk(f.voxel as usize));
        }
    }
    if lo[0] == usize::MAX {
        let grid = VolumeGrid {
            dims: [1, 1, 1],
            spacing_mm: g.spacing_mm,
            origin_mm: g.origin_mm,
        };
        return Volume::filled(grid, 0.0);
    }
    let dims: [usize; 3] = std::array::from_fn(|a| hi[a] - lo[a] + 1);
    let grid = VolumeGrid {
        dims,
        spacing_mm: g.spacing_mm,
        origin_mm: g.voxel_center_mm(lo[0], lo[1], lo[2]),
    };
    let mut mask = Volume::filled(grid, 0f32);
    for k in lo[2]..=hi[2] {
        for j in lo[1]..=hi[1] {
            let base = g.index(0, j, k);
            let out = grid.index(0, j - lo[1], k - lo[2]);
            for i in lo[0]..=hi[0] {
                if ids.data[base + i] == label && !in_band[base + i] {
                    mask.data[out + i - lo[0]] = 1.0;
                }
            }
        }
    }
    for (v, occ) in mine {
        let [i, j, k] = g.ijk(v);
        mask.set(i - lo[0], j - lo[1], k - lo[2], occ);
    }
    mask
}

impl PhantomParams {
    /// The anatomy parameters actually used on this grid: layers thinner than 1.5 voxels (the
    /// cortical shell and the skin) are thickened to 1.5 voxels. With partial volumes a layer a
    /// voxel thick already has a connected 0.5 level, but its mesh encloses about 12 % less than
    /// its mask (measured on the default grid); at 1.5 voxels the meshes of the shells agree with
    /// their masks within 6 % (simulator choice; on the default 1.5 mm grid the 1.5 mm cortex
    /// becomes 2.25 mm, the skin is unchanged).
    ///
    /// Meshed from level sets ([`PhantomParams::level_set_meshed`]), layers are thickened to one
    /// voxel only, so that the label volume (sampled at voxel centres) still shows them: the
    /// level-set meshes keep a layer one lattice spacing thick within 5 % of its volume (the
    /// default grid's 1.5 mm cortex: -2.0 to -4.5 %, measured), and a thicker cortex would leave
    /// the thin iliac wing a marrow core thinner than the lattice, which no lattice mesh holds
    /// (-7 % with 1.5 voxels of cortex).
    ///
    /// The cortex is thickened to `MAX_THICKENED_CORTEX_MM` at most (coarse test grids): a
    /// thicker one would leave the smallest body (L1, waisted, 26 mm tall) no marrow at all.
    pub fn effective_anatomy(&self) -> AnatomyParams {
        let min_layer = if self.mesh_from_level_sets {
            self.voxel_mm
        } else {
            1.5 * self.voxel_mm
        };
        AnatomyParams {
            cortical_thickness_mm: self
                .anatomy
                .cortical_thickness_mm
                .max(min_layer.min(MAX_THICKENED_CORTEX_MM)),
            skin_mm: self.anatomy.skin_mm.max(min_layer),
            ..self.anatomy
        }
    }
}

/// Paints the phantom into its grid, computes partial volumes and makes the CT (no meshing).
pub fn voxelize(params: &PhantomParams) -> PhantomVolumes {
    voxelize_anatomy(params, model::Anatomy::new(&params.effective_anatomy()))
}

/// [`voxelize`] for any implicit anatomy (another region's generator) on the grid of `params`.
pub fn voxelize_anatomy(params: &PhantomParams, anatomy: model::Anatomy) -> PhantomVolumes {
    let grid = params.grid();
    let workers = voxelize::worker_count(8);
    let solids: Vec<&sdf::Sdf> = anatomy.parts.iter().map(|p| &p.sdf).collect();
    let structure_ids = voxelize::paint_labels(&grid, &solids, workers, false);
    let fractions = voxelize::partial_volumes(&grid, &solids, &structure_ids, workers);
    let hu_of: Vec<f64> = std::iter::once(params.hu.air)
        .chain(anatomy.parts.iter().map(|p| params.hu.of(p.material)))
        .collect();
    let mut sharp = Volume {
        grid,
        data: structure_ids
            .data
            .iter()
            .map(|&l| hu_of[usize::from(l)] as f32)
            .collect(),
    };
    // Partial-volume CT numbers in boundary voxels; what the structures leave is air.
    let mut start = 0;
    while start < fractions.len() {
        let v = fractions[start].voxel;
        let mut end = start;
        let (mut hu, mut occ) = (0.0, 0.0);
        while end < fractions.len() && fractions[end].voxel == v {
            hu += f64::from(fractions[end].occupancy) * hu_of[usize::from(fractions[end].label)];
            occ += f64::from(fractions[end].occupancy);
            end += 1;
        }
        let value = if occ >= 1.0 {
            hu / occ
        } else {
            hu + (1.0 - occ) * params.hu.air
        };
        sharp.data[v as usize] = value as f32;
        start = end;
    }
    let mut ct_hu = voxelize::gaussian_blur(&sharp, params.blur_sigma_mm, workers);
    if params.noise_sd_hu > 0.0 {
        for (i, v) in ct_hu.data.iter_mut().enumerate() {
            *v += (params.noise_sd_hu * voxelize::voxel_gaussian(params.seed, i as u64)) as f32;
        }
    }
    let nested = anatomy
        .parts
        .iter()
        .map(|p| {
            p.nested.then(|| {
                let own = voxelize::paint_labels(&grid, &[&p.sdf], workers, false);
                let fr = voxelize::partial_volumes(&grid, &[&p.sdf], &own, workers);
                (own, fr)
            })
        })
        .collect();
    PhantomVolumes {
        structure_ids,
        fractions,
        ct_hu,
        structures: anatomy
            .parts
            .iter()
            .map(|p| (p.name.clone(), p.material))
            .collect(),
        nested,
        anatomy,
    }
}

/// Builds the phantom region in memory: voxelize, then mesh through the shared pipeline.
pub fn build(
    params: &PhantomParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    let source = phantom_source(
        GENERATOR,
        params,
        "Procedural lumbosacral phantom generated by sim-core (no patient data); dimensions from \
         published adult morphometry cited in sim_core::anatomy::phantom::model.",
        "L3 body centre",
    );
    build_anatomy(REGION_NAME, params, || voxelize(params), source, progress)
}

/// The provenance of a phantom made by `generator` from `params`: the parameters and their
/// hash, Apache-2.0, `attribution`, and the model frame with its origin at `origin`.
pub fn phantom_source(
    generator: &str,
    params: &PhantomParams,
    attribution: &str,
    origin: &str,
) -> SourceInfo {
    SourceInfo {
        source: Source::Phantom {
            generator: generator.to_string(),
            parameters: serde_json::json!({
                "params": params,
                "params_sha256": params.hash_hex_for(generator),
            }),
        },
        licence: "Apache-2.0".to_string(),
        attribution: attribution.to_string(),
        notes: vec![format!(
            "model frame: RAS (x = patient right, y = anterior, z = cranial), mm; origin at the \
             {origin}"
        )],
    }
}

/// Builds a phantom region named `name` from the volumes `vols` makes (voxelize, then mesh
/// through the shared pipeline), recording `source` as its provenance.
pub fn build_anatomy(
    name: &str,
    params: &PhantomParams,
    vols: impl FnOnce() -> PhantomVolumes,
    source: SourceInfo,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    progress(&Progress {
        stage: "voxelize",
        done: 0,
        total: 1,
        item: String::new(),
    });
    let vols = vols();
    progress(&Progress {
        stage: "voxelize",
        done: 1,
        total: 1,
        item: String::new(),
    });
    let masks = vols.masks();
    let PhantomVolumes { ct_hu, anatomy, .. } = vols;
    if !params.mesh_from_level_sets {
        return build_region(name, &ct_hu, masks, &params.pipeline, source, progress);
    }
    // Every structure is meshed from its level set: vertices on the solids' surfaces, not on
    // the masks' interpolated 0.5 levels (which lose a third of a 3.5 mm ligament at 3 mm).
    let sets = level_set::level_sets(&anatomy, &ct_hu.grid);
    let fns: Vec<Box<dyn Fn([f64; 3]) -> f64 + Sync + '_>> = sets
        .iter()
        .map(|s| Box::new(move |p: [f64; 3]| s.eval(glam::DVec3::from(p))) as Box<_>)
        .collect();
    let refs: Vec<Option<LevelSetFn<'_>>> =
        fns.iter().map(|f| Some(&**f as LevelSetFn<'_>)).collect();
    build_region_on_level_sets(
        name,
        &ct_hu,
        masks,
        &refs,
        &params.pipeline,
        source,
        progress,
    )
}

/// Whether the region folder `dir` holds a phantom built with exactly `params` (and this pipeline
/// version). Only reads the provenance; hashes are verified when the region is loaded.
pub fn is_cached(dir: &Path, params: &PhantomParams) -> bool {
    is_cached_for(dir, GENERATOR, params)
}

/// [`is_cached`] for the phantom made by `generator`.
pub fn is_cached_for(dir: &Path, generator_name: &str, params: &PhantomParams) -> bool {
    let Ok(bytes) = std::fs::read(dir.join(super::asset::PROVENANCE_FILE)) else {
        return false;
    };
    let Ok(prov) = serde_json::from_slice::<super::asset::Provenance>(&bytes) else {
        return false;
    };
    match prov.source {
        Source::Phantom {
            generator,
            parameters,
        } => {
            generator == generator_name
                && prov.pipeline_version == pipeline_version()
                && parameters.get("params_sha256").and_then(|v| v.as_str())
                    == Some(params.hash_hex_for(generator_name).as_str())
        }
        Source::Ct { .. } => false,
    }
}

/// Returns the phantom region stored in `dir`, building and writing it first if `dir` is missing,
/// was built with other parameters or another pipeline version, or fails its hash check.
pub fn ensure_built_with(
    dir: &Path,
    params: &PhantomParams,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    ensure_built_by(dir, GENERATOR, params, build, progress)
}

/// A phantom generator's build function (as [`build`]).
pub type BuildFn =
    fn(&PhantomParams, &mut dyn FnMut(&Progress)) -> Result<RegionAsset, AnatomyError>;

/// [`ensure_built_with`] for the phantom made by `generator` with its `build` function.
pub fn ensure_built_by(
    dir: &Path,
    generator: &str,
    params: &PhantomParams,
    build: BuildFn,
    progress: &mut dyn FnMut(&Progress),
) -> Result<RegionAsset, AnatomyError> {
    if is_cached_for(dir, generator, params) {
        if let Ok(region) = RegionAsset::load(dir) {
            return Ok(region);
        }
    }
    let region = build(params, progress)?;
    region.write_to(dir)?;
    // Return what was stored (f32 mesh positions), so a fresh build and a cache hit are identical.
    RegionAsset::load(dir)
}

/// [`ensure_built_with`] using the default parameters and no progress reporting.
pub fn ensure_built(dir: &Path) -> Result<RegionAsset, AnatomyError> {
    ensure_built_with(dir, &PhantomParams::default(), &mut |_| {})
}
