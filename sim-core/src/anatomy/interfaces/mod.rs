//! Shared interfaces: meshing a family of structures so that structures that touch share their
//! common surface exactly, after smoothing and decimation as well as after extraction.
//!
//! Why: two disjoint occupancy masks that meet (cortex and marrow, disc and endplate, muscle and
//! fat) sum to one along their common boundary, so marching tetrahedra puts both 0.5 surfaces
//! through the same points there (linear interpolation in each tetrahedron: two disjoint
//! occupancies cannot both exceed 0.5). Smoothing or decimating each mesh on its own then gives
//! the two sides different triangulations that cross each other: thin slivers where tissue is
//! counted twice or not at all. A renderer that only sums per-mesh chords (an L-buffer) is exact
//! only for a *laminar* family, where every two meshes are disjoint (touching allowed) or nested.
//!
//! How, for the meshes of one region:
//! 1. *Weld*: every extracted vertex lies on an edge of the common sample lattice
//!    ([`EdgeCrossing`]). Vertices of different structures on the same lattice edge within
//!    [`WELD_EDGE_FRACTION`] of an edge of each other become one vertex (the two extractions
//!    compute the same crossing from fields that agree only to `f32` rounding).
//! 2. *Patches*: a triangle present in several meshes (same three welded vertices) is shared;
//!    each triangle is labelled with the meshes that hold it and the orientation in each
//!    (opposite for touching structures, the same for a structure touching the inside of the one
//!    it is nested in). Triangles with the same label form a patch; a vertex on triangles of two
//!    or more patches is a *junction* vertex (patch borders, and points or curves where meshes
//!    touch without sharing triangles).
//! 3. *Smoothing* (optional): Taubin's lambda/mu steps on the welded vertices, once for all
//!    meshes: a vertex inside a patch moves with its neighbours, a junction vertex only along its
//!    junction curve (when it has exactly two junction neighbours; corners stay), with the
//!    displacement cap of [`TaubinParams`] and the volume guard per structure (a structure whose
//!    volume error would pass its limit stops there: its vertices keep their last positions).
//! 4. *Decimation* (optional): each patch once, with meshoptimizer and its junction vertices
//!    locked, so a shared patch stays identical in both meshes and patch borders stay closed.
//!    Each mesh is then reassembled from its patches and checked (closed, consistently wound, no
//!    degenerate triangles, volume change limit); a mesh that fails gets two rings of locks
//!    around its defects, or half the error where it has none, and its patches are redone (up to
//!    eight rounds); after that, its patches are left undecimated.
//!
//! The result is deterministic (every step is ordered by structure, vertex or patch index; the
//! parallel parts write by index) and independent of the thread count.

mod crossing;
mod decimation;
mod par;
mod smoothing;
mod surface;
mod weld;

pub use super::mesher::EdgeCrossing;
pub use decimation::CHUNK_EDGES;
pub(crate) use par::{par_map, par_map_heaviest_first};
pub use surface::{ExtractedSurface, WELD_EDGE_FRACTION, lattice_edge_key};

use super::decimate::DecimationParams;
use super::error::AnatomyError;
use super::smooth::TaubinParams;
use crate::mesh::TriMesh;
use crossing::{crossing_pairs, mean_edge_mm};
use decimation::decimate_family;
use smoothing::smooth_family;
use weld::{Family, weld_and_partition};

/// Smooths and decimates a family of extracted surfaces so that touching structures share their
/// interfaces exactly (see the module doc). Returns each mesh with its notes, in input order;
/// every mesh is checked (closed, consistently wound, positive volume) after each stage.
pub fn mesh_family(
    items: &[ExtractedSurface],
    smoothing: Option<&TaubinParams>,
    decimation: Option<&DecimationParams>,
) -> Result<FamilyMeshes, AnatomyError> {
    let mut fam = weld_and_partition(items);
    let names: Vec<String> = items.iter().map(|it| it.name.clone()).collect();
    let mut notes: Vec<Vec<String>> = vec![Vec::new(); items.len()];
    let mut region_notes = Vec::new();
    let input: Vec<Vec<[u32; 3]>> = fam.patches.iter().map(|p| p.triangles.clone()).collect();
    let shared: Vec<usize> = (0..items.len())
        .map(|m| {
            fam.mesh_patches[m]
                .iter()
                .filter(|&&(p, _)| fam.patches[p].owners.len() > 1)
                .map(|&(p, _)| fam.patches[p].triangles.len())
                .sum()
        })
        .collect();
    if items.len() > 1 {
        for (m, n) in notes.iter_mut().enumerate() {
            if shared[m] > 0 {
                n.push(format!(
                    "{}: {} of {} triangles shared with touching structures",
                    names[m],
                    shared[m],
                    items[m].mesh.triangles.len()
                ));
            }
        }
    }
    fn check_all(
        fam: &Family,
        names: &[String],
        source: &[Vec<[u32; 3]>],
        after: &str,
    ) -> Result<Vec<TriMesh>, AnatomyError> {
        let meshes = par_map(
            names.len(),
            &|m| fam.assemble(m, source, &fam.positions),
            &mut |_| {},
        );
        for (m, mesh) in meshes.iter().enumerate() {
            super::solid::check_solid(&names[m], mesh, after)?;
        }
        Ok(meshes)
    }
    let mut meshes = check_all(&fam, &names, &input, "welding shared interfaces")?;
    if let Some(sp) = smoothing {
        let extracted_positions = fam.positions.clone();
        for (m, n) in smooth_family(&mut fam, items, sp).into_iter().enumerate() {
            notes[m].push(n);
        }
        // Smoothing can fold surfaces through each other where they meet at a small angle
        // (typically around the small free patches where three structures meet). Where two
        // surfaces cross, the vertices of the crossing triangles and two rings around them go
        // back to their extracted positions, which do not cross; repeated until none is left
        // (at worst every vertex is back where extraction put it).
        let all = vec![true; fam.patches.len()];
        let cell_mm = 4.0 * mean_edge_mm(&input, &extracted_positions);
        let neighbours = fam.neighbours();
        let mut restored = 0usize;
        let mut passes = 0usize;
        loop {
            let cross = crossing_pairs(&input, &fam.positions, &all, cell_mm);
            if cross.is_empty() {
                break;
            }
            passes += 1;
            let crossing: Vec<u32> = cross
                .iter()
                .flat_map(|&((pa, ta), (pb, tb))| {
                    input[pa as usize][ta as usize]
                        .into_iter()
                        .chain(input[pb as usize][tb as usize])
                })
                .collect();
            for v in crate::anatomy::smooth::grow_rings(crossing, &neighbours, 2) {
                let v = v as usize;
                if fam.positions[v] != extracted_positions[v] {
                    fam.positions[v] = extracted_positions[v];
                    restored += 1;
                }
            }
        }
        region_notes.push(format!(
            "smoothing: {restored} vertices restored to their extracted positions in {passes} passes where surfaces crossed"
        ));
        meshes = check_all(&fam, &names, &input, "smoothing")?;
    }
    if let Some(dp) = decimation {
        let (result, dnotes, summary) = decimate_family(&fam, &names, dp);
        for (m, n) in dnotes.into_iter().enumerate() {
            notes[m].push(n);
        }
        if items.len() > 1 {
            region_notes.push(summary);
        }
        meshes = check_all(&fam, &names, &result, "decimation")?;
    }
    Ok(FamilyMeshes {
        meshes: meshes.into_iter().zip(notes).collect(),
        notes: region_notes,
    })
}

/// What [`mesh_family`] gives: every mesh with its notes (input order), and notes on the family.
#[derive(Debug, Clone)]
pub struct FamilyMeshes {
    /// Meshes and per-structure notes, in input order.
    pub meshes: Vec<(TriMesh, Vec<String>)>,
    /// Notes on the whole family (decimation rounds, crossings backed off).
    pub notes: Vec<String>,
}
