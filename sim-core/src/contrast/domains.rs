//! Building the transport domains from the procedural phantom (other regions map their
//! structures by the same [`domain_of`]; see `render-worker`'s contrast modality).
//!
//! The phantom's solids are painted onto a crop grid (any cell size; 1 mm by default) and mapped:
//! - `epidural_space` -> [`Domain::Epidural`]; `dural_sac` and `cauda_equina` ->
//!   [`Domain::Intrathecal`] (the cauda's rootlets lie in CSF), except the sac's outermost cell
//!   layer (cells with a face neighbour outside the sac), which is [`Domain::Subdural`];
//! - `nerve_root_*` -> [`Domain::Intraneural`]; `aorta`, `inferior_vena_cava` and the vessels
//!   added below -> [`Domain::Vascular`];
//! - muscle, fat and soft tissue (skin, subcutaneous fat, deep soft tissue, psoas, erector
//!   spinae) -> [`Domain::Pooling`];
//! - bone, discs, the ligamentum flavum, the conus medullaris (the cord is an obstacle) and air
//!   outside the body -> solid.
//!
//! The phantom has no radicular vessels or epidural veins, and vascular uptake during a
//! transforaminal injection is the danger learners must recognise, so this build adds them (the
//! phantom's meshes and hashes stay as they are): for each lumbar root, a radicular vessel of
//! 0.9 mm radius along the root's foraminal and extraforaminal course, just cranial to it
//! (radicular arteries are 0.5-1 mm across; position and size our choice), and a segment of the
//! anterior epidural venous plexus of 1.2 mm radius from the lateral recess to the foramen,
//! anterior to the root (our choice). They take only cells that would otherwise be epidural or
//! pooling.

use glam::DVec3;

use super::grid::{ContrastGrid, Domain};
use crate::anatomy::phantom::model::Anatomy;
use crate::anatomy::phantom::sdf::Sdf;
use crate::anatomy::phantom::voxelize::{paint_labels, worker_count};
use crate::anatomy::phantom::{self, PhantomParams};
use crate::material::MaterialClass;
use crate::volume::VolumeGrid;

/// Radius of an added radicular vessel, mm (our choice, see the module docs).
pub const RADICULAR_RADIUS_MM: f64 = 0.9;
/// Radius of an added epidural venous plexus segment, mm (our choice).
pub const PLEXUS_RADIUS_MM: f64 = 1.2;

/// A vertebral level's axial span in the model frame (z, mm).
#[derive(Debug, Clone, PartialEq)]
pub struct LevelSpan {
    /// Level name, e.g. `L4`.
    pub name: String,
    /// Lower bound, mm.
    pub z_min_mm: f64,
    /// Upper bound, mm.
    pub z_max_mm: f64,
}

/// The lumbar levels of the phantom: each from the midpoint to the body centre below to the
/// midpoint to the one above (the end levels are symmetric about their centre).
pub fn phantom_levels(params: &PhantomParams) -> Vec<LevelSpan> {
    let lm = phantom::landmarks(params);
    let centres: Vec<(String, f64)> = ["L1", "L2", "L3", "L4", "L5"]
        .iter()
        .filter_map(|n| {
            lm.iter()
                .find(|l| l.name == format!("{n}_body_centre"))
                .map(|l| (n.to_string(), l.position_mm[2]))
        })
        .collect();
    levels_from_centres(&centres)
}

/// Levels from body centres `(name, z_mm)` ordered from cranial to caudal: each from the
/// midpoint to the centre below to the midpoint to the one above (the end levels are symmetric
/// about their centre). Empty without centres.
pub fn levels_from_centres(centres: &[(String, f64)]) -> Vec<LevelSpan> {
    let m = centres.len();
    (0..m)
        .map(|i| {
            let z = centres[i].1;
            let up = if i > 0 {
                0.5 * (centres[i - 1].1 - z)
            } else {
                0.5 * (z - centres[1.min(m - 1)].1)
            };
            let down = if i + 1 < m {
                0.5 * (z - centres[i + 1].1)
            } else {
                up
            };
            LevelSpan {
                name: centres[i].0.clone(),
                z_min_mm: z - down,
                z_max_mm: z + up,
            }
        })
        .collect()
}

/// The added vessels (radicular vessels and plexus segments) of the lumbar roots.
pub fn added_vessels(anatomy: &Anatomy) -> Vec<Sdf> {
    let mut out = Vec::new();
    for part in &anatomy.parts {
        if !part.name.starts_with("nerve_root_L") {
            continue;
        }
        let Sdf::Tube { points, radii } = &part.sdf else {
            continue;
        };
        if points.len() < 4 {
            continue;
        }
        let up = DVec3::Z;
        let radicular: Vec<DVec3> = points[2..]
            .iter()
            .zip(&radii[2..])
            .map(|(p, r)| *p + up * (r + RADICULAR_RADIUS_MM + 0.3))
            .collect();
        out.push(Sdf::Tube {
            radii: vec![RADICULAR_RADIUS_MM; radicular.len()],
            points: radicular,
        });
        let plexus: Vec<DVec3> = points[1..3]
            .iter()
            .zip(&radii[1..3])
            .map(|(p, r)| *p + DVec3::Y * (r + PLEXUS_RADIUS_MM + 0.3))
            .collect();
        out.push(Sdf::Tube {
            radii: vec![PLEXUS_RADIUS_MM; plexus.len()],
            points: plexus,
        });
    }
    out
}

/// The transport domain of a structure by name and class (see the module docs), `None` for
/// solid.
pub fn domain_of(name: &str, material: MaterialClass) -> Option<Domain> {
    match material {
        MaterialClass::EpiduralSpace => Some(Domain::Epidural),
        MaterialClass::DuraCsf => Some(Domain::Intrathecal),
        MaterialClass::Vessel => Some(Domain::Vascular),
        MaterialClass::Nerve if name.starts_with("nerve_root_") => Some(Domain::Intraneural),
        MaterialClass::Nerve if name == "cauda_equina" => Some(Domain::Intrathecal),
        MaterialClass::Muscle | MaterialClass::Fat | MaterialClass::SoftTissue => {
            Some(Domain::Pooling)
        }
        _ => None,
    }
}

/// A crop grid of cubic `cell_mm` cells whose cell faces span `[min_mm, max_mm]` (rounded up to
/// whole cells).
pub fn crop_grid(min_mm: [f64; 3], max_mm: [f64; 3], cell_mm: f64) -> VolumeGrid {
    VolumeGrid {
        dims: std::array::from_fn(|a| ((max_mm[a] - min_mm[a]) / cell_mm).ceil().max(1.0) as usize),
        spacing_mm: [cell_mm; 3],
        origin_mm: std::array::from_fn(|a| min_mm[a] + 0.5 * cell_mm),
    }
}

/// The transport grid of the phantom on `grid` (see the module docs for the mapping).
pub fn phantom_grid(params: &PhantomParams, grid: VolumeGrid) -> ContrastGrid {
    let anatomy = phantom::anatomy(params);
    let workers = worker_count(8);
    let solids: Vec<&Sdf> = anatomy.parts.iter().map(|p| &p.sdf).collect();
    let ids = paint_labels(&grid, &solids, workers, false);
    let mut domain: Vec<Option<Domain>> = ids
        .data
        .iter()
        .map(|&l| {
            (l > 0)
                .then(|| &anatomy.parts[usize::from(l) - 1])
                .and_then(|p| domain_of(&p.name, p.material))
        })
        .collect();
    let vessels = added_vessels(&anatomy);
    let vrefs: Vec<&Sdf> = vessels.iter().collect();
    let vids = paint_labels(&grid, &vrefs, workers, false);
    for (d, &v) in domain.iter_mut().zip(&vids.data) {
        if v > 0 && matches!(d, Some(Domain::Epidural | Domain::Pooling)) {
            *d = Some(Domain::Vascular);
        }
    }
    // The cauda and the crop faces do not make a wall; anything else does.
    with_subdural_layer(grid, domain, |n| {
        ids.data[n] != 0 && anatomy.parts[usize::from(ids.data[n]) - 1].name != "conus_medullaris"
    })
}

/// The grid of `domain`, with the sac's outer cell layer made [`Domain::Subdural`]: the
/// intrathecal cells with a face neighbour that is not intrathecal and is a wall (`is_wall`,
/// by cell index; the crop faces are never walls).
pub fn with_subdural_layer(
    grid: VolumeGrid,
    mut domain: Vec<Option<Domain>>,
    is_wall: impl Fn(usize) -> bool,
) -> ContrastGrid {
    let sac = |d: Option<Domain>| d == Some(Domain::Intrathecal);
    let [nx, ny, nz] = grid.dims;
    let mut subdural = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let c = grid.index(i, j, k);
                if !sac(domain[c]) {
                    continue;
                }
                let ijk = [i as i64, j as i64, k as i64];
                let outside = (0..6).any(|f| {
                    let mut q = ijk;
                    q[f / 2] += if f % 2 == 0 { 1 } else { -1 };
                    if (0..3).any(|a| q[a] < 0 || q[a] >= grid.dims[a] as i64) {
                        return false;
                    }
                    let n = grid.index(q[0] as usize, q[1] as usize, q[2] as usize);
                    !sac(domain[n]) && is_wall(n)
                });
                if outside {
                    subdural.push(c);
                }
            }
        }
    }
    for c in subdural {
        domain[c] = Some(Domain::Subdural);
    }
    ContrastGrid::from_domains(grid, domain)
}
