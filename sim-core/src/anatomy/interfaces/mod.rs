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
//! 5. *Refinement* (for structures given as level sets, with a surface tolerance): edges whose
//!    midpoints lie off the surface are split onto it, once for every triangle using them, so
//!    shared patches stay shared ([`refine`]).
//!
//! The result is deterministic (every step is ordered by structure, vertex or patch index; the
//! parallel parts write by index) and independent of the thread count.

mod crossing;
mod decimation;
mod refine;
mod smoothing;
mod surface;
mod weld;

pub use super::mesher::EdgeCrossing;
pub use decimation::CHUNK_EDGES;
pub use surface::{ExtractedSurface, WELD_EDGE_FRACTION, lattice_edge_key};

use super::decimate::DecimationParams;
use super::error::AnatomyError;
use super::level_set_mesh::LevelSetFn;
use super::smooth::TaubinParams;
use crate::mesh::TriMesh;
use crate::par::{joined, par_map_heaviest_first};
use crossing::{LiveCrossings, crossing_pairs, mean_edge_mm};
use decimation::decimate_family;
use smoothing::smooth_family;
use weld::{Family, weld_and_partition};

/// Rounds of level-set refinement (step 5): each halves the chords it splits, so five take a
/// sagitta down a thousand-fold where needed (simulator choice: on the neck phantom's 1 mm grid
/// five rounds give its flavum -4.96 % against -5.01 % with three, for 3 % more triangles).
const REFINE_ROUNDS: usize = 5;

/// A step of [`mesh_family`], as its progress names and weighs it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FamilyStep {
    Weld,
    LevelSets,
    Smoothing,
    Decimation,
    Refinement,
    UndoingCrossingSplits,
}

impl FamilyStep {
    /// The name progress reports.
    pub fn name(self) -> &'static str {
        match self {
            FamilyStep::Weld => "weld",
            FamilyStep::LevelSets => "level sets",
            FamilyStep::Smoothing => "smoothing",
            FamilyStep::Decimation => "decimation",
            FamilyStep::Refinement => "refinement",
            FamilyStep::UndoingCrossingSplits => "undoing crossing splits",
        }
    }

    /// The step's share of the family's time, in tenths of a second of the default lumbar
    /// phantom's cold build on 2 cores (dev profile, measured 2026-12-01: weld 2.0 s, level
    /// sets 4.5 s, decimation 10.4 s, refinement 4.9 s, undoing crossing splits 3.7 s).
    /// Smoothing runs only for mask meshes, which no shipped phantom uses: it is given the
    /// weld's share (a pass over the same vertices), untimed. Only shapes reported progress.
    pub fn cost(self) -> usize {
        match self {
            FamilyStep::Weld | FamilyStep::Smoothing => 20,
            FamilyStep::LevelSets => 45,
            FamilyStep::Decimation => 104,
            FamilyStep::Refinement => 49,
            FamilyStep::UndoingCrossingSplits => 37,
        }
    }
}

/// Smooths and decimates a family of extracted surfaces so that touching structures share their
/// interfaces exactly (see the module doc), then refines the patches of structures that come
/// with a level set (`level_sets`, one per item or empty) until their edges' midpoints are within
/// `surface_tolerance_mm` of the surface. Returns each mesh with its notes, in input order; every
/// mesh is checked (closed, consistently wound, positive volume) after each stage, and
/// `progress` is told each stage done as `(stage, done, total)`: the work done so far and in
/// all, in units of [`FamilyStep::cost`], so that `done / total` follows the time.
pub fn mesh_family(
    items: &[ExtractedSurface],
    smoothing: Option<&TaubinParams>,
    decimation: Option<&DecimationParams>,
    level_sets: &[Option<LevelSetFn<'_>>],
    surface_tolerance_mm: Option<f64>,
    progress: &mut dyn FnMut(&'static str, usize, usize),
) -> Result<FamilyMeshes, AnatomyError> {
    let level_set_family = level_sets.iter().any(Option::is_some);
    let refining = surface_tolerance_mm.is_some() && level_set_family;
    let steps = [
        (FamilyStep::Weld, true),
        (FamilyStep::LevelSets, level_set_family),
        (FamilyStep::Smoothing, smoothing.is_some()),
        (FamilyStep::Decimation, decimation.is_some()),
        (FamilyStep::Refinement, refining),
        (FamilyStep::UndoingCrossingSplits, refining),
    ];
    let total: usize = steps
        .iter()
        .filter(|(_, runs)| *runs)
        .map(|(s, _)| s.cost())
        .sum();
    let mut done = 0;
    let mut step = |stage: FamilyStep| {
        done += stage.cost();
        progress(stage.name(), done, total);
    };
    let mut fam = weld_and_partition(items);
    let names: Vec<String> = items.iter().map(|it| it.name.clone()).collect();
    let mut notes: Vec<Vec<String>> = vec![Vec::new(); items.len()];
    let mut region_notes = Vec::new();
    let input: Vec<Vec<[u32; 3]>> = fam.patches.iter().map(|p| p.triangles.clone()).collect();
    // Neighbour lists of the welded patches (`Family::neighbours`), once a step has made them.
    let mut family_neighbours: Option<Vec<Vec<u32>>> = None;
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
        // Each mesh is checked on the thread that assembled it, the largest first; the first
        // failure in input order is the one reported, whatever the thread count.
        let weights: Vec<usize> = (0..names.len())
            .map(|m| {
                fam.mesh_patches[m]
                    .iter()
                    .map(|&(p, _)| source[p].len())
                    .sum()
            })
            .collect();
        par_map_heaviest_first(&weights, &|m| {
            let mesh = fam.assemble(m, source, &fam.positions);
            super::solid::check_solid(&names[m], &mesh, after).map(|()| mesh)
        })
        .into_iter()
        .collect()
    }
    let mut meshes = check_all(&fam, &names, &input, "welding shared interfaces")?;
    step(FamilyStep::Weld);
    if level_set_family {
        // Every vertex starts on its level set. Where exact positions make two surfaces cross
        // (two structures passing within a lattice cell of each other), the vertices of the
        // crossing triangles and a ring around them take their interpolated positions,
        // whose surfaces meet as the masks' do. All before decimation, whose own crossing
        // checks then see the final positions.
        let fallback = fam.fallback.clone();
        let (restored, passes, neighbours) =
            fall_back_where_crossing(&mut fam.positions, &input, &fallback, &[]);
        // The welded patches' connectivity, which decimation needs again (1.2 s on one core
        // for the default phantom's family): the patches keep their triangles until then.
        family_neighbours = Some(neighbours);
        region_notes.push(format!(
            "level sets: {restored} of {} vertices interpolated where exact positions made surfaces cross ({passes} passes)",
            fam.positions.len()
        ));
        meshes = check_all(&fam, &names, &input, "placing vertices on the level sets")?;
        step(FamilyStep::LevelSets);
    }
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
        let neighbours = family_neighbours.get_or_insert_with(|| fam.neighbours());
        let mut restored = 0usize;
        let mut passes = 0usize;
        loop {
            let cross = crossing_pairs(&input, &fam.positions, &all, cell_mm, false);
            if cross.is_empty() {
                break;
            }
            passes += 1;
            let crossing = crossing_corners(&cross, &input);
            for v in crate::anatomy::smooth::grow_rings(crossing, neighbours, 2) {
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
        step(FamilyStep::Smoothing);
    }
    let mut current = input;
    if let Some(dp) = decimation {
        let (result, dnotes, summary) = decimate_family(&fam, &names, dp, family_neighbours.take());
        for (m, n) in dnotes.into_iter().enumerate() {
            notes[m].push(n);
        }
        if items.len() > 1 {
            region_notes.push(summary);
        }
        meshes = check_all(&fam, &names, &result, "decimation")?;
        current = result;
        step(FamilyStep::Decimation);
    }
    if let Some(tol) = surface_tolerance_mm
        && refining
    {
        let before: Vec<usize> = meshes.iter().map(TriMesh::triangle_count).collect();
        let refined = refine::refine_family(&fam, &current, level_sets, tol, REFINE_ROUNDS);
        fam.positions = refined.positions;
        let parents = refined.parents;
        current = refined.triangles;
        meshes = check_all(&fam, &names, &current, "refinement on the level set")?;
        for (m, n) in notes.iter_mut().enumerate() {
            if meshes[m].triangle_count() != before[m] {
                n.push(format!(
                    "{}: refined on its level set to {tol} mm, {} -> {} triangles",
                    names[m],
                    before[m],
                    meshes[m].triangle_count()
                ));
            }
        }
        region_notes.push(format!(
            "level-set refinement: {} edges split (tolerance {tol} mm)",
            refined.splits
        ));
        step(FamilyStep::Refinement);
        if !parents.is_empty() {
            // A split that bulges a surface into another is undone (its vertex back to the
            // middle of the edge it split; see `fall_back_where_crossing`).
            let base = fam.positions.len() - parents.len();
            let fallback: Vec<[f64; 3]> = fam.positions[..base].to_vec();
            let (restored, passes, _) =
                fall_back_where_crossing(&mut fam.positions, &current, &fallback, &parents);
            region_notes.push(format!(
                "level-set refinement: {restored} splits undone where surfaces crossed ({passes} passes)"
            ));
            meshes = check_all(
                &fam,
                &names,
                &current,
                "undoing splits where surfaces crossed",
            )?;
        }
        step(FamilyStep::UndoingCrossingSplits);
    }
    Ok(FamilyMeshes {
        meshes: meshes.into_iter().zip(notes).collect(),
        notes: region_notes,
    })
}

/// A triangle of a family: (patch, index in the patch).
type TriangleRef = (u32, u32);

/// The corners of the crossing triangle pairs `cross` (as [`crossing_pairs`] gives them) of
/// the patches `source`.
fn crossing_corners(cross: &[(TriangleRef, TriangleRef)], source: &[Vec<[u32; 3]>]) -> Vec<u32> {
    cross
        .iter()
        .flat_map(|&((pa, ta), (pb, tb))| {
            source[pa as usize][ta as usize]
                .into_iter()
                .chain(source[pb as usize][tb as usize])
        })
        .collect()
}

/// The fall-back loop of [`mesh_family`] for level-set families: where triangles of two patches
/// cross (and did not where every vertex is at its fallback), the vertices of both (and a ring
/// around them, for exact vertices) move to their fallbacks, repeated until nothing new
/// crosses. Vertices below `fallback.len()` fall back to `fallback`; those after are split
/// vertices, one per `parents` entry in order, and fall back to the middle of the edge they
/// split.
///
/// With exact vertices falling back to interpolated ones (no `parents`), one ring keeps the
/// fewest vertices off the surface (the loop repeats where that is not enough), and a pair
/// that crosses where every vertex is back counts only where one of its corners is elsewhere.
/// For splits (`parents`), only the crossing triangles' corners go back (with a ring, 206 k of
/// the default phantom's 259 k splits went back in three rounds, against 105 k, and the
/// ligamentum flavum lost 0.5 % more of its volume), triangles sharing a corner are compared
/// too (a split beside a junction can fold over a neighbour's triangle at that corner), and a
/// pair that crossed before the splits (the flat triangles) is not new and does not count.
/// Returns the vertices moved, the passes, and the neighbour lists of `source`'s triangles.
fn fall_back_where_crossing(
    positions: &mut [[f64; 3]],
    source: &[Vec<[u32; 3]>],
    fallback: &[[f64; 3]],
    parents: &[(u32, u32)],
) -> (usize, usize, Vec<Vec<u32>>) {
    let splits = !parents.is_empty();
    let rings = if splits { 0 } else { 1 };
    let all = vec![true; source.len()];
    let base = fallback.len();
    let back_of = |v: usize, pos: &[[f64; 3]]| -> [f64; 3] {
        if v < base {
            fallback[v]
        } else {
            let (a, b) = parents[v - base];
            let (pa, pb) = (pos[a as usize], pos[b as usize]);
            std::array::from_fn(|k| 0.5 * (pa[k] + pb[k]))
        }
    };
    let cell_mm = 4.0 * mean_edge_mm(source, positions);
    // Where every vertex is at its fallback.
    let mut all_back = positions.to_vec();
    for v in 0..all_back.len() {
        all_back[v] = back_of(v, &all_back);
    }
    // Three independent set-ups side by side: the neighbour lists (one core), the crossings
    // where all is back, and the crossing pairs now, which are found once and then re-tested
    // only around the vertices that move (both searches spread over the cores themselves). On
    // the default phantom's family, 3.3 s one after the other, and a core idle for 1.3 s of it.
    let now: &[[f64; 3]] = positions;
    let (neighbours, before, mut live) = std::thread::scope(|s| {
        let neighbours =
            s.spawn(|| crate::anatomy::smooth::neighbours_of(now.len(), source.iter().flatten()));
        let before = s.spawn(|| {
            crossing_pairs(source, &all_back, &all, cell_mm, splits)
                .into_iter()
                .collect::<rustc_hash::FxHashSet<_>>()
        });
        let live = LiveCrossings::new(source, now, cell_mm, splits);
        (joined(neighbours.join()), joined(before.join()), live)
    });
    let mut moved = vec![false; positions.len()];
    let (mut restored, mut passes) = (0usize, 0usize);
    loop {
        // A pair that crosses where all is back is not new (see above).
        let at_back = |(p, t): (u32, u32), pos: &[[f64; 3]]| {
            source[p as usize][t as usize]
                .iter()
                .all(|&v| pos[v as usize] == all_back[v as usize])
        };
        let cross: Vec<_> = live
            .pairs()
            .into_iter()
            .filter(|&(a, b)| {
                !(before.contains(&(a, b))
                    && (splits || (at_back(a, positions) && at_back(b, positions))))
            })
            .collect();
        if cross.is_empty() {
            break;
        }
        passes += 1;
        let crossing = crossing_corners(&cross, source);
        let mut fresh = 0;
        for v in crate::anatomy::smooth::grow_rings(crossing, &neighbours, rings) {
            let v = v as usize;
            if !moved[v] {
                moved[v] = true;
                fresh += 1;
            }
        }
        // Split vertices follow their parents (they come after them).
        let mut changed = Vec::new();
        for v in 0..positions.len() {
            if moved[v] {
                let back = back_of(v, positions);
                if back.map(f64::to_bits) != positions[v].map(f64::to_bits) {
                    changed.push(v as u32);
                }
                positions[v] = back;
            }
        }
        live.moved(positions, &changed);
        restored += fresh;
        if fresh == 0 {
            break;
        }
    }
    (restored, passes, neighbours)
}

/// What [`mesh_family`] gives: every mesh with its notes (input order), and notes on the family.
#[derive(Debug, Clone)]
pub struct FamilyMeshes {
    /// Meshes and per-structure notes, in input order.
    pub meshes: Vec<(TriMesh, Vec<String>)>,
    /// Notes on the whole family (decimation rounds, crossings backed off).
    pub notes: Vec<String>,
}
