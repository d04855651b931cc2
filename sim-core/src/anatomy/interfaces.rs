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

use std::collections::{BTreeMap, HashMap};

use glam::DVec3;

use super::decimate::{DecimationParams, acceptable, defective_vertices};
use super::error::AnatomyError;
pub use super::mesher::EdgeCrossing;
use super::smooth::TaubinParams;
use crate::mesh::TriMesh;

/// Edge of the cubes that split patches into chunks for decimation, in mean input edge
/// lengths (about 25 mm on a 1.5 mm grid). Smaller chunks lock more vertices along their
/// borders; larger ones make each back-off redo more. Simulator choice.
pub const CHUNK_EDGES: f64 = 32.0;

/// Largest distance along a lattice edge, as a fraction of the edge, at which the crossings of
/// two structures are taken as the same point. Where two occupancies sum to one, their crossings
/// differ by the `f32` rounding of the mask values divided by the field's change along the edge
/// (about 1e-7 / 0.01 for a surface at 89 degrees to the edge); a genuine gap narrower than a
/// thousandth of an edge (1.5 micrometres on a 1.5 mm grid) is closed by welding, which moves a
/// vertex by at most that much. Simulator choice.
pub const WELD_EDGE_FRACTION: f64 = 1e-3;

/// One extracted structure: its mesh and, per vertex, a key of its lattice edge that is unique in
/// the region (see [`lattice_edge_key`]) and the position along that edge.
#[derive(Debug, Clone)]
pub struct ExtractedSurface {
    /// Structure name (for errors and notes).
    pub name: String,
    /// The closed extracted surface.
    pub mesh: TriMesh,
    /// Per vertex: region-wide lattice edge key and position along the edge (`0..1`).
    pub edges: Vec<(u64, f64)>,
    /// Mask volume, mm^3 (the smoothing guard's reference).
    pub mask_volume_mm3: f64,
}

/// A region-wide key for a lattice edge: `lower` in the region's fine lattice (non-negative),
/// `extent` the number of fine lattice points per axis that keys may use.
pub fn lattice_edge_key(lower: [u64; 3], axes: u8, extent: [u64; 3]) -> u64 {
    ((lower[2] * extent[1] + lower[1]) * extent[0] + lower[0]) * 8 + u64::from(axes)
}

/// Runs `f(0..n)` on up to one thread per core (each thread taking the next index) and returns
/// the results in index order; `done(i)` is called on the calling thread as each one finishes.
pub(crate) fn par_map<T: Send>(
    n: usize,
    f: &(dyn Fn(usize) -> T + Sync),
    done: &mut dyn FnMut(usize),
) -> Vec<T> {
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, n.max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<Option<T>> = (0..n).map(|_| None).collect();
    std::thread::scope(|scope| {
        let (tx, rx) = std::sync::mpsc::channel::<(usize, T)>();
        for _ in 0..threads {
            let (tx, next) = (tx.clone(), &next);
            scope.spawn(move || {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    if i >= n || tx.send((i, f(i))).is_err() {
                        break;
                    }
                }
            });
        }
        drop(tx);
        for (i, r) in rx.iter() {
            done(i);
            out[i] = Some(r);
        }
    });
    out.into_iter()
        .map(|r| r.expect("every index is taken by exactly one worker"))
        .collect()
}

/// A set of triangles (welded vertex ids) with the same owners.
#[derive(Debug, Clone)]
struct Patch {
    /// Owning meshes and whether each holds the triangles reversed (the first owner never does).
    owners: Vec<(u32, bool)>,
    /// Triangles in the first owner's orientation.
    triangles: Vec<[u32; 3]>,
}

/// Sorted vertex ids of a triangle and whether its winding is the even permutation of them.
fn canonical(t: [u32; 3]) -> ([u32; 3], bool) {
    let r = if t[0] < t[1] && t[0] < t[2] {
        t
    } else if t[1] < t[2] {
        [t[1], t[2], t[0]]
    } else {
        [t[2], t[0], t[1]]
    };
    let even = r[1] < r[2];
    let mut s = t;
    s.sort_unstable();
    (s, even)
}

/// Welded, patch-partitioned family of meshes.
struct Family {
    positions: Vec<[f64; 3]>,
    patches: Vec<Patch>,
    /// Per mesh: its patches and whether it holds each reversed.
    mesh_patches: Vec<Vec<(usize, bool)>>,
    /// Per welded vertex: on triangles of two or more patches.
    junction: Vec<bool>,
}

fn weld_and_partition(items: &[ExtractedSurface]) -> Family {
    // Weld: sort (edge key, mesh, vertex) and cluster each edge's crossings.
    let mut recs: Vec<(u64, u32, u32)> = Vec::new();
    for (m, it) in items.iter().enumerate() {
        recs.extend(
            it.edges
                .iter()
                .enumerate()
                .map(|(v, &(key, _))| (key, m as u32, v as u32)),
        );
    }
    recs.sort_unstable();
    let mut gid_of: Vec<Vec<u32>> = items
        .iter()
        .map(|it| vec![u32::MAX; it.mesh.vertices_mm.len()])
        .collect();
    let mut positions = Vec::with_capacity(recs.len());
    let mut start = 0;
    let mut clusters: Vec<(f64, u32)> = Vec::new();
    while start < recs.len() {
        let key = recs[start].0;
        let mut end = start;
        clusters.clear();
        while end < recs.len() && recs[end].0 == key {
            let (_, m, v) = recs[end];
            let s = items[m as usize].edges[v as usize].1;
            let gid = match clusters
                .iter()
                .find(|(s0, _)| (s - s0).abs() <= WELD_EDGE_FRACTION)
            {
                Some(&(_, g)) => g,
                None => {
                    let g = positions.len() as u32;
                    positions.push(items[m as usize].mesh.vertices_mm[v as usize]);
                    clusters.push((s, g));
                    g
                }
            };
            gid_of[m as usize][v as usize] = gid;
            end += 1;
        }
        start = end;
    }
    let tris: Vec<Vec<[u32; 3]>> = items
        .iter()
        .zip(&gid_of)
        .map(|(it, map)| {
            it.mesh
                .triangles
                .iter()
                .map(|t| t.map(|v| map[v as usize]))
                .collect()
        })
        .collect();
    // Vertices used by more than one mesh; only triangles made of them can be shared.
    let mut first_mesh = vec![u32::MAX; positions.len()];
    let mut multi = vec![false; positions.len()];
    for (m, map) in gid_of.iter().enumerate() {
        for &g in map {
            let f = &mut first_mesh[g as usize];
            if *f == u32::MAX {
                *f = m as u32;
            } else if *f != m as u32 {
                multi[g as usize] = true;
            }
        }
    }
    let mut owners_of: HashMap<[u32; 3], Vec<(u32, bool)>> = HashMap::new();
    for (m, ts) in tris.iter().enumerate() {
        for &t in ts {
            if t.iter().all(|&g| multi[g as usize]) {
                let (key, even) = canonical(t);
                owners_of.entry(key).or_default().push((m as u32, even));
            }
        }
    }
    let mut patch_index: BTreeMap<Vec<(u32, bool)>, usize> = BTreeMap::new();
    let mut patches: Vec<Patch> = Vec::new();
    for (m, ts) in tris.iter().enumerate() {
        for &t in ts {
            let owners: Vec<(u32, bool)> = match owners_of.get(&canonical(t).0) {
                Some(list) if list.len() > 1 => {
                    if list[0].0 != m as u32 {
                        // Added with the first owner's triangles.
                        continue;
                    }
                    let first = list[0].1;
                    list.iter().map(|&(o, e)| (o, e != first)).collect()
                }
                _ => vec![(m as u32, false)],
            };
            let p = *patch_index.entry(owners.clone()).or_insert_with(|| {
                patches.push(Patch {
                    owners,
                    triangles: Vec::new(),
                });
                patches.len() - 1
            });
            patches[p].triangles.push(t);
        }
    }
    let mut mesh_patches = vec![Vec::new(); items.len()];
    for (p, patch) in patches.iter().enumerate() {
        for &(m, rev) in &patch.owners {
            mesh_patches[m as usize].push((p, rev));
        }
    }
    let mut first_patch = vec![usize::MAX; positions.len()];
    let mut junction = vec![false; positions.len()];
    for (p, patch) in patches.iter().enumerate() {
        for &g in patch.triangles.iter().flatten() {
            let f = &mut first_patch[g as usize];
            if *f == usize::MAX {
                *f = p;
            } else if *f != p {
                junction[g as usize] = true;
            }
        }
    }
    Family {
        positions,
        patches,
        mesh_patches,
        junction,
    }
}

impl Family {
    /// The triangles of mesh `m` (welded ids) from per-patch triangle lists.
    fn mesh_triangles(&self, m: usize, source: &[Vec<[u32; 3]>]) -> Vec<[u32; 3]> {
        let mut out = Vec::new();
        for &(p, rev) in &self.mesh_patches[m] {
            out.extend(
                source[p]
                    .iter()
                    .map(|t| if rev { [t[0], t[2], t[1]] } else { *t }),
            );
        }
        out
    }

    /// Mesh `m` as a compact [`TriMesh`] (vertices in order of first use).
    fn assemble(&self, m: usize, source: &[Vec<[u32; 3]>], positions: &[[f64; 3]]) -> TriMesh {
        let mut map: HashMap<u32, u32> = HashMap::new();
        let mut out = TriMesh::default();
        for t in self.mesh_triangles(m, source) {
            out.triangles.push(t.map(|g| {
                *map.entry(g).or_insert_with(|| {
                    out.vertices_mm.push(positions[g as usize]);
                    (out.vertices_mm.len() - 1) as u32
                })
            }));
        }
        out
    }

    /// Neighbour lists of the whole complex (each shared triangle counted once).
    fn neighbours(&self) -> Vec<Vec<u32>> {
        let mut nb: Vec<Vec<u32>> = vec![Vec::new(); self.positions.len()];
        for t in self.patches.iter().flat_map(|p| &p.triangles) {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                nb[a as usize].push(b);
                nb[b as usize].push(a);
            }
        }
        for n in &mut nb {
            n.sort_unstable();
            n.dedup();
        }
        nb
    }

    /// Per junction vertex, its neighbours along junction curves (edges whose triangles lie in
    /// two or more patches).
    fn curve_neighbours(&self) -> Vec<Vec<u32>> {
        let mut edges: Vec<(u32, u32, usize)> = Vec::new();
        for (p, patch) in self.patches.iter().enumerate() {
            for t in &patch.triangles {
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    edges.push((a.min(b), a.max(b), p));
                }
            }
        }
        edges.sort_unstable();
        let mut nb: Vec<Vec<u32>> = vec![Vec::new(); self.positions.len()];
        let mut i = 0;
        while i < edges.len() {
            let mut j = i;
            let mut distinct = false;
            while j < edges.len() && (edges[j].0, edges[j].1) == (edges[i].0, edges[i].1) {
                distinct |= edges[j].2 != edges[i].2;
                j += 1;
            }
            if distinct {
                let (a, b) = (edges[i].0, edges[i].1);
                nb[a as usize].push(b);
                nb[b as usize].push(a);
            }
            i = j;
        }
        nb
    }

    /// Signed volume of every mesh from per-patch contributions.
    fn mesh_volumes(&self, source: &[Vec<[u32; 3]>], positions: &[[f64; 3]]) -> Vec<f64> {
        let patch_volume: Vec<f64> = source
            .iter()
            .map(|tris| {
                tris.iter()
                    .map(|t| {
                        let [a, b, c] = t.map(|g| positions[g as usize]);
                        (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                            + a[2] * (b[0] * c[1] - b[1] * c[0]))
                            / 6.0
                    })
                    .sum()
            })
            .collect();
        self.mesh_patches
            .iter()
            .map(|ps| {
                ps.iter()
                    .map(|&(p, rev)| {
                        if rev {
                            -patch_volume[p]
                        } else {
                            patch_volume[p]
                        }
                    })
                    .sum()
            })
            .collect()
    }
}

fn laplacian(pos: &[[f64; 3]], nb: &[Vec<u32>], movable: &[bool], w: f64) -> Vec<[f64; 3]> {
    pos.iter()
        .zip(nb)
        .zip(movable)
        .map(|((p, n), &mv)| {
            if !mv || n.is_empty() {
                return *p;
            }
            let mut avg = [0.0; 3];
            for &q in n {
                let q = pos[q as usize];
                for a in 0..3 {
                    avg[a] += q[a];
                }
            }
            std::array::from_fn(|a| p[a] + w * (avg[a] / n.len() as f64 - p[a]))
        })
        .collect()
}

/// Taubin smoothing of the whole family (see the module doc); returns one note per mesh.
fn smooth_family(
    fam: &mut Family,
    items: &[ExtractedSurface],
    params: &TaubinParams,
) -> Vec<String> {
    let source: Vec<Vec<[u32; 3]>> = fam.patches.iter().map(|p| p.triangles.clone()).collect();
    let all = fam.neighbours();
    let curve = fam.curve_neighbours();
    let nb: Vec<Vec<u32>> = (0..fam.positions.len())
        .map(|g| {
            if !fam.junction[g] {
                all[g].clone()
            } else if curve[g].len() == 2 {
                curve[g].clone()
            } else {
                Vec::new()
            }
        })
        .collect();
    let vertices_of: Vec<Vec<u32>> = (0..items.len())
        .map(|m| {
            let mut v: Vec<u32> = fam
                .mesh_triangles(m, &source)
                .into_iter()
                .flatten()
                .collect();
            v.sort_unstable();
            v.dedup();
            v
        })
        .collect();
    let original = fam.positions.clone();
    let rel_err = |vols: &[f64], m: usize| {
        (vols[m] - items[m].mask_volume_mm3).abs() / items[m].mask_volume_mm3.max(f64::MIN_POSITIVE)
    };
    let vols0 = fam.mesh_volumes(&source, &original);
    let err0: Vec<f64> = (0..items.len()).map(|m| rel_err(&vols0, m)).collect();
    let allowed: Vec<f64> = err0
        .iter()
        .map(|&e| params.max_volume_change.max(e))
        .collect();
    let mut movable = vec![true; original.len()];
    let mut stopped = vec![false; items.len()];
    let mut done = vec![0u32; items.len()];
    let mut capped = vec![0u32; original.len()];
    let mut current = original.clone();
    for _ in 0..params.iterations {
        if stopped.iter().all(|&s| s) {
            break;
        }
        let step = laplacian(&current, &nb, &movable, params.lambda);
        let mut step = laplacian(&step, &nb, &movable, params.mu);
        let mut capped_now = vec![false; original.len()];
        for (g, (p, o)) in step.iter_mut().zip(&original).enumerate() {
            let d = [p[0] - o[0], p[1] - o[1], p[2] - o[2]];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            if len > params.max_displacement_mm {
                let s = params.max_displacement_mm / len;
                *p = std::array::from_fn(|a| o[a] + d[a] * s);
                capped_now[g] = true;
            }
        }
        // A structure whose volume error would pass its limit stops: its vertices go back to
        // their last positions and stay. Restoring them can push a neighbour over its own limit,
        // so repeat until no structure is over (each round stops at least one more).
        loop {
            let vols = fam.mesh_volumes(&source, &step);
            let over: Vec<usize> = (0..items.len())
                .filter(|&m| !stopped[m] && rel_err(&vols, m) > allowed[m])
                .collect();
            if over.is_empty() {
                break;
            }
            for m in over {
                stopped[m] = true;
                for &g in &vertices_of[m] {
                    step[g as usize] = current[g as usize];
                    movable[g as usize] = false;
                    capped_now[g as usize] = false;
                }
            }
        }
        for (c, now) in capped.iter_mut().zip(&capped_now) {
            *c += u32::from(*now);
        }
        for (d, s) in done.iter_mut().zip(&stopped) {
            *d += u32::from(!s);
        }
        current = step;
    }
    let vols = fam.mesh_volumes(&source, &current);
    let notes = (0..items.len())
        .map(|m| {
            let moves: u32 = vertices_of[m].iter().map(|&g| capped[g as usize]).sum();
            format!(
                "{}: Taubin smoothing {}/{} pairs{}, volume error vs mask {:.2}% -> {:.2}%, {moves} vertex moves capped at {} mm",
                items[m].name,
                done[m],
                params.iterations,
                if stopped[m] {
                    " (stopped by the volume guard)"
                } else {
                    ""
                },
                100.0 * err0[m],
                100.0 * rel_err(&vols, m),
                params.max_displacement_mm
            )
        })
        .collect();
    fam.positions = current;
    notes
}

/// Decimates one patch with `locked` vertices fixed; returns its triangles and meshoptimizer's
/// error estimate, mm.
fn decimate_patch(
    tris: &[[u32; 3]],
    positions: &[[f64; 3]],
    locked: &dyn Fn(u32) -> bool,
    fraction: f64,
    max_error_mm: f64,
) -> (Vec<[u32; 3]>, f32) {
    let target = (((tris.len() as f64) * fraction).round() as usize * 3).max(12);
    if target >= tris.len() * 3 {
        return (tris.to_vec(), 0.0);
    }
    let mut local_of: HashMap<u32, u32> = HashMap::new();
    let mut global = Vec::new();
    let indices: Vec<u32> = tris
        .iter()
        .flatten()
        .map(|&g| {
            *local_of.entry(g).or_insert_with(|| {
                global.push(g);
                (global.len() - 1) as u32
            })
        })
        .collect();
    let pos: Vec<[f32; 3]> = global
        .iter()
        .map(|&g| positions[g as usize].map(|x| x as f32))
        .collect();
    let locks: Vec<bool> = global.iter().map(|&g| locked(g)).collect();
    let mut err = 0.0f32;
    let out = meshopt::simplify_with_locks_decoder(
        &indices,
        &pos,
        &locks,
        target,
        max_error_mm as f32,
        meshopt::SimplifyOptions::ErrorAbsolute,
        Some(&mut err),
    );
    let tris = out
        .chunks_exact(3)
        .map(|c| {
            [
                global[c[0] as usize],
                global[c[1] as usize],
                global[c[2] as usize],
            ]
        })
        .collect();
    (tris, err)
}

/// Whether two triangles cross: their intersection is a segment of positive length. Touching
/// (a vertex or an edge lying in the other triangle's plane) and coplanar pairs do not count.
/// Interval-overlap test after T. Moeller, "A fast triangle-triangle intersection test",
/// J. Graphics Tools 2(2), 1997.
fn triangles_cross(p: [[f64; 3]; 3], q: [[f64; 3]; 3]) -> bool {
    let (p, q) = (p.map(DVec3::from), q.map(DVec3::from));
    let side = |d: [f64; 3]| {
        d.iter().all(|&x| x > 0.0) || d.iter().all(|&x| x < 0.0) || d.iter().all(|&x| x == 0.0)
    };
    let nq = (q[1] - q[0]).cross(q[2] - q[0]);
    let dp = p.map(|v| nq.dot(v - q[0]));
    if side(dp) {
        return false;
    }
    let np = (p[1] - p[0]).cross(p[2] - p[0]);
    let dq = q.map(|v| np.dot(v - p[0]));
    if side(dq) {
        return false;
    }
    let line = np.cross(nq);
    let scale = line.length();
    if scale == 0.0 {
        return false;
    }
    // The stretch of the line of the two planes that each triangle covers.
    let interval = |v: [DVec3; 3], d: [f64; 3]| {
        let proj = v.map(|x| line.dot(x));
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for i in 0..3 {
            let j = (i + 1) % 3;
            if d[i] == 0.0 {
                lo = lo.min(proj[i]);
                hi = hi.max(proj[i]);
            }
            if (d[i] > 0.0 && d[j] < 0.0) || (d[i] < 0.0 && d[j] > 0.0) {
                let t = proj[i] + (proj[j] - proj[i]) * d[i] / (d[i] - d[j]);
                lo = lo.min(t);
                hi = hi.max(t);
            }
        }
        (lo, hi)
    };
    let (a0, a1) = interval(p, dp);
    let (b0, b1) = interval(q, dq);
    // `line` is not normalised: lengths along it are scaled by `scale`. A crossing shorter than
    // a nanometre is rounding at a touching point.
    a1.min(b1) - a0.max(b0) > 1e-6 * 1e-3 * scale
}

/// Pairs of triangles from different patches that cross each other (see [`triangles_cross`]),
/// as `(patch, triangle index)` pairs, sorted. Only pairs with at least one triangle from a
/// patch in `fresh` are tested; triangles sharing a vertex are not compared (they meet at it).
fn crossing_pairs(
    source: &[Vec<[u32; 3]>],
    positions: &[[f64; 3]],
    fresh: &[bool],
    cell_mm: f64,
) -> Vec<((u32, u32), (u32, u32))> {
    let mut tris: Vec<(u32, u32)> = Vec::new();
    let mut boxes: Vec<([f64; 3], [f64; 3])> = Vec::new();
    let mut cells: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
    for (p, ts) in source.iter().enumerate() {
        for (i, t) in ts.iter().enumerate() {
            let v = t.map(|g| positions[g as usize]);
            let lo: [f64; 3] = std::array::from_fn(|a| v[0][a].min(v[1][a]).min(v[2][a]));
            let hi: [f64; 3] = std::array::from_fn(|a| v[0][a].max(v[1][a]).max(v[2][a]));
            let id = tris.len() as u32;
            tris.push((p as u32, i as u32));
            boxes.push((lo, hi));
            let c0 = lo.map(|x| (x / cell_mm).floor() as i64);
            let c1 = hi.map(|x| (x / cell_mm).floor() as i64);
            for z in c0[2]..=c1[2] {
                for y in c0[1]..=c1[1] {
                    for x in c0[0]..=c1[0] {
                        cells.entry([x, y, z]).or_default().push(id);
                    }
                }
            }
        }
    }
    let cells: Vec<Vec<u32>> = cells
        .into_values()
        .filter(|c| {
            c.len() > 1
                && c.iter().any(|&i| fresh[tris[i as usize].0 as usize])
                && c.iter()
                    .any(|&i| tris[i as usize].0 != tris[c[0] as usize].0)
        })
        .collect();
    let chunk = 256;
    let found = par_map(
        cells.len().div_ceil(chunk),
        &|ci| {
            let mut out = Vec::new();
            for cell in &cells[ci * chunk..((ci + 1) * chunk).min(cells.len())] {
                for (k, &i) in cell.iter().enumerate() {
                    let (pi, ti) = tris[i as usize];
                    let a = source[pi as usize][ti as usize];
                    let (alo, ahi) = boxes[i as usize];
                    for &j in &cell[k + 1..] {
                        let (pj, tj) = tris[j as usize];
                        if pi == pj || !(fresh[pi as usize] || fresh[pj as usize]) {
                            continue;
                        }
                        let (blo, bhi) = boxes[j as usize];
                        if (0..3).any(|d| alo[d] > bhi[d] || blo[d] > ahi[d]) {
                            continue;
                        }
                        let b = source[pj as usize][tj as usize];
                        if a.iter().any(|v| b.contains(v)) {
                            continue;
                        }
                        let pa = a.map(|g| positions[g as usize]);
                        let pb = b.map(|g| positions[g as usize]);
                        if triangles_cross(pa, pb) {
                            out.push(if i < j {
                                ((pi, ti), (pj, tj))
                            } else {
                                ((pj, tj), (pi, ti))
                            });
                        }
                    }
                }
            }
            out
        },
        &mut |_| {},
    );
    let mut pairs: Vec<_> = found.into_iter().flatten().collect();
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// Locks, in the two patches of a crossing, every input vertex inside the box of the two
/// crossing triangles (grown by half its size) and one ring around them: the decimated triangles
/// span input vertices that were collapsed into their corners, so locking the corners alone
/// would not keep the next attempt from cutting the same corner.
fn lock_around_crossing(
    fam: &Family,
    input: &[Vec<[u32; 3]>],
    neighbours: &[Vec<u32>],
    triangles: [[u32; 3]; 2],
    patches: [usize; 2],
    lock: &mut Vec<u32>,
) {
    let pts: Vec<[f64; 3]> = triangles
        .iter()
        .flatten()
        .map(|&g| fam.positions[g as usize])
        .collect();
    let mut lo = pts[0];
    let mut hi = pts[0];
    for q in &pts {
        for a in 0..3 {
            lo[a] = lo[a].min(q[a]);
            hi[a] = hi[a].max(q[a]);
        }
    }
    let grow: [f64; 3] = std::array::from_fn(|a| 0.5 * (hi[a] - lo[a]));
    let mut ring: Vec<u32> = triangles.iter().flatten().copied().collect();
    for p in patches {
        for &g in input[p].iter().flatten() {
            let q = fam.positions[g as usize];
            if (0..3).all(|a| q[a] >= lo[a] - grow[a] && q[a] <= hi[a] + grow[a]) {
                ring.push(g);
            }
        }
    }
    let mut next = ring.clone();
    for &v in &ring {
        next.extend_from_slice(&neighbours[v as usize]);
    }
    lock.extend(next);
}

/// Mean edge length of the triangles, mm (a small positive number for none).
fn mean_edge_mm(source: &[Vec<[u32; 3]>], positions: &[[f64; 3]]) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for t in source.iter().flatten() {
        for k in 0..3 {
            let d = DVec3::from(positions[t[k] as usize])
                - DVec3::from(positions[t[(k + 1) % 3] as usize]);
            sum += d.length();
            n += 1;
        }
    }
    (sum / n.max(1) as f64).max(1e-6)
}

/// Decimates the family (see the module doc); returns the per-patch triangles, one note per mesh
/// and a note on the family.
///
/// The unit of decimation is a *chunk*: the triangles of one patch whose centroids fall in one
/// cube of [`CHUNK_EDGES`] mean edge lengths. Chunk borders are locked like patch borders, so a
/// back-off redoes only the chunks around a defect, and large patches (the skin) spread over
/// all cores.
fn decimate_family(
    fam: &Family,
    names: &[String],
    params: &DecimationParams,
) -> (Vec<Vec<[u32; 3]>>, Vec<String>, String) {
    let n_mesh = fam.mesh_patches.len();
    let input: Vec<Vec<[u32; 3]>> = fam.patches.iter().map(|p| p.triangles.clone()).collect();
    let fraction = params.target_fraction.clamp(0.0, 1.0);
    if fraction >= 1.0 {
        let notes = names
            .iter()
            .map(|n| format!("{n}: decimation skipped: target fraction 1"))
            .collect();
        return (input, notes, String::new());
    }
    let mean_edge = mean_edge_mm(&input, &fam.positions);
    // Grid cell of the crossing search: a few input edges, so that a decimated triangle spans
    // a handful of cells.
    let cell_mm = 4.0 * mean_edge;
    let chunk_mm = CHUNK_EDGES * mean_edge;
    let mut chunk_patch: Vec<usize> = Vec::new();
    let mut chunks: Vec<Vec<[u32; 3]>> = Vec::new();
    for (p, tris) in input.iter().enumerate() {
        let mut by_cell: BTreeMap<[i64; 3], Vec<[u32; 3]>> = BTreeMap::new();
        for &t in tris {
            let v = t.map(|g| fam.positions[g as usize]);
            let cell: [i64; 3] = std::array::from_fn(|a| {
                ((v[0][a] + v[1][a] + v[2][a]) / 3.0 / chunk_mm).floor() as i64
            });
            by_cell.entry(cell).or_default().push(t);
        }
        for (_, c) in by_cell {
            chunk_patch.push(p);
            chunks.push(c);
        }
    }
    let n_chunk = chunks.len();
    let mut chunks_of_patch: Vec<Vec<usize>> = vec![Vec::new(); fam.patches.len()];
    for (c, &p) in chunk_patch.iter().enumerate() {
        chunks_of_patch[p].push(c);
    }
    // Vertices on two or more chunks (chunk borders, which include patch borders).
    let mut first_chunk = vec![usize::MAX; fam.positions.len()];
    let mut border = vec![false; fam.positions.len()];
    for (c, tris) in chunks.iter().enumerate() {
        for &g in tris.iter().flatten() {
            let f = &mut first_chunk[g as usize];
            if *f == usize::MAX {
                *f = c;
            } else if *f != c {
                border[g as usize] = true;
            }
        }
    }
    let owners_of_chunk = |c: u32| &fam.patches[chunk_patch[c as usize]].owners;
    let before: Vec<f64> = fam.mesh_volumes(&input, &fam.positions);
    let neighbours = fam.neighbours();
    // Structures whose input surfaces already cross (a nested whole-solid mesh such as the
    // phantom's deep soft tissue, which later structures leave) are not laminar to begin with;
    // decimation is only kept from making new crossings.
    let mut exempt: Vec<(u32, u32)> = Vec::new();
    for ((ca, _), (cb, _)) in crossing_pairs(&chunks, &fam.positions, &vec![true; n_chunk], cell_mm)
    {
        for &(m, _) in owners_of_chunk(ca) {
            for &(n, _) in owners_of_chunk(cb) {
                if m != n {
                    exempt.push((m.min(n), m.max(n)));
                }
            }
        }
    }
    exempt.sort_unstable();
    exempt.dedup();
    let relevant = |ca: u32, cb: u32| {
        owners_of_chunk(ca).iter().any(|&(m, _)| {
            owners_of_chunk(cb)
                .iter()
                .any(|&(n, _)| m == n || exempt.binary_search(&(m.min(n), m.max(n))).is_err())
        })
    };
    let mut extra_lock = vec![false; fam.positions.len()];
    let mut max_error = vec![params.max_error_mm; n_chunk];
    let mut result: Vec<Vec<[u32; 3]>> = vec![Vec::new(); n_chunk];
    let mut errors = vec![0f32; n_chunk];
    let mut dirty = vec![true; n_chunk];
    let mut rejections: Vec<Vec<String>> = vec![Vec::new(); n_mesh];
    let mut rounds = vec![0usize; n_mesh];
    let mut failing: Vec<usize> = Vec::new();
    let mut crossing_counts = Vec::new();
    let patch_result = |result: &[Vec<[u32; 3]>]| -> Vec<Vec<[u32; 3]>> {
        chunks_of_patch
            .iter()
            .map(|cs| cs.iter().flat_map(|&c| result[c].iter().copied()).collect())
            .collect()
    };
    for round in 0..8 {
        let todo: Vec<usize> = (0..n_chunk).filter(|&c| dirty[c]).collect();
        let locked =
            |g: u32| border[g as usize] || fam.junction[g as usize] || extra_lock[g as usize];
        let done = par_map(
            todo.len(),
            &|i| {
                let c = todo[i];
                decimate_patch(&chunks[c], &fam.positions, &locked, fraction, max_error[c])
            },
            &mut |_| {},
        );
        let mut fresh = vec![false; n_chunk];
        for (&c, (tris, err)) in todo.iter().zip(done) {
            result[c] = tris;
            errors[c] = err;
            dirty[c] = false;
            fresh[c] = true;
        }
        let per_patch = patch_result(&result);
        let touched: Vec<bool> = (0..n_mesh)
            .map(|m| {
                fam.mesh_patches[m]
                    .iter()
                    .any(|&(p, _)| chunks_of_patch[p].iter().any(|&c| fresh[c]))
            })
            .collect();
        let checks = par_map(
            n_mesh,
            &|m| {
                if !touched[m] {
                    return Ok(());
                }
                let tris = fam.mesh_triangles(m, &per_patch);
                let mesh = fam.assemble(m, &per_patch, &fam.positions);
                acceptable(before[m], &mesh, params.max_volume_change)
                    .map_err(|why| (why, defective_vertices(&tris)))
            },
            &mut |_| {},
        );
        failing.clear();
        let mut new_locks: Vec<u32> = Vec::new();
        for (m, check) in checks.into_iter().enumerate() {
            if touched[m] {
                rounds[m] = round + 1;
            }
            let Err((why, defects)) = check else { continue };
            failing.push(m);
            rejections[m].push(why);
            if defects.is_empty() {
                for &(p, _) in &fam.mesh_patches[m] {
                    for &c in &chunks_of_patch[p] {
                        max_error[c] *= 0.5;
                        dirty[c] = true;
                    }
                }
            } else {
                // Lock the defect's vertices and two rings around them.
                let mut ring = defects;
                for _ in 0..2 {
                    let mut next = ring.clone();
                    for &v in &ring {
                        next.extend_from_slice(&neighbours[v as usize]);
                    }
                    ring = next;
                }
                new_locks.extend(ring);
            }
        }
        // Different structures must not cross (nor a structure itself): lock the input vertices
        // around each crossing and redo the chunks that hold them.
        let mut crossings = crossing_pairs(&result, &fam.positions, &fresh, cell_mm);
        crossings.retain(|&((ca, _), (cb, _))| relevant(ca, cb));
        crossing_counts.push(crossings.len());
        for &((ca, ta), (cb, tb)) in &crossings {
            let before_len = new_locks.len();
            lock_around_crossing(
                fam,
                &chunks,
                &neighbours,
                [(ca, ta), (cb, tb)].map(|(c, t)| result[c as usize][t as usize]),
                [ca as usize, cb as usize],
                &mut new_locks,
            );
            debug_assert!(new_locks.len() > before_len);
            for c in [ca, cb] {
                dirty[c as usize] = true;
                for &(m, _) in owners_of_chunk(c) {
                    let m = m as usize;
                    if !failing.contains(&m) {
                        failing.push(m);
                        rejections[m].push("crosses a neighbouring surface".into());
                    }
                }
            }
        }
        for &v in &new_locks {
            extra_lock[v as usize] = true;
        }
        if !new_locks.is_empty() {
            let mut is_new = vec![false; fam.positions.len()];
            for &v in &new_locks {
                is_new[v as usize] = true;
            }
            for (c, tris) in chunks.iter().enumerate() {
                if !dirty[c] && tris.iter().flatten().any(|&g| is_new[g as usize]) {
                    dirty[c] = true;
                }
            }
        }
        if failing.is_empty() {
            break;
        }
    }
    // Meshes still failing keep their extracted (or smoothed) patches; that changes their
    // neighbours' shared patches too, so check again until every mesh passes (a mesh with all
    // its patches reverted is its input mesh, which passed) and no reverted chunk is crossed.
    let mut reverted = vec![false; n_chunk];
    failing.sort_unstable();
    while !failing.is_empty() {
        let mut now = vec![false; n_chunk];
        for &m in &failing {
            for &(p, _) in &fam.mesh_patches[m] {
                for &c in &chunks_of_patch[p] {
                    if !reverted[c] {
                        reverted[c] = true;
                        now[c] = true;
                        result[c] = chunks[c].clone();
                        errors[c] = 0.0;
                    }
                }
            }
        }
        let per_patch = patch_result(&result);
        let mut next: Vec<usize> = (0..n_mesh)
            .filter(|&m| {
                let cs = fam.mesh_patches[m]
                    .iter()
                    .flat_map(|&(p, _)| &chunks_of_patch[p]);
                let mut cs2 = cs.clone();
                cs.clone().any(|&c| now[c])
                    && !cs2.all(|&c| reverted[c])
                    && acceptable(
                        before[m],
                        &fam.assemble(m, &per_patch, &fam.positions),
                        params.max_volume_change,
                    )
                    .is_err()
            })
            .collect();
        for ((ca, _), (cb, _)) in crossing_pairs(&result, &fam.positions, &now, cell_mm) {
            if !relevant(ca, cb) {
                continue;
            }
            for c in [ca as usize, cb as usize] {
                if !reverted[c] {
                    next.extend(
                        fam.patches[chunk_patch[c]]
                            .owners
                            .iter()
                            .map(|&(m, _)| m as usize),
                    );
                }
            }
        }
        next.sort_unstable();
        next.dedup();
        failing = next;
    }
    let per_patch = patch_result(&result);
    let after = fam.mesh_volumes(&per_patch, &fam.positions);
    let notes = (0..n_mesh)
        .map(|m| {
            let ps = &fam.mesh_patches[m];
            let cs: Vec<usize> = ps.iter().flat_map(|&(p, _)| chunks_of_patch[p].iter().copied()).collect();
            let n_in: usize = ps.iter().map(|&(p, _)| input[p].len()).sum();
            let n_out: usize = ps.iter().map(|&(p, _)| per_patch[p].len()).sum();
            let n_rev = cs.iter().filter(|&&c| reverted[c]).count();
            if n_rev == cs.len() {
                return format!(
                    "{}: decimation backed off, mesh kept at {n_in} triangles ({})",
                    names[m],
                    rejections[m].join("; ")
                );
            }
            let err = cs.iter().map(|&c| errors[c]).fold(0.0f32, f32::max);
            let mut verts: Vec<u32> =
                cs.iter().flat_map(|&c| chunks[c].iter().flatten().copied()).collect();
            verts.sort_unstable();
            verts.dedup();
            let junction = verts.iter().filter(|&&g| fam.junction[g as usize]).count();
            let extra = verts
                .iter()
                .filter(|&&g| extra_lock[g as usize] && !fam.junction[g as usize])
                .count();
            format!(
                "{}: decimated {n_in} -> {n_out} triangles in {} patches, {} chunks (max error {err:.3} mm, volume change {:.3}%, round {}, {junction} interface and {extra} back-off vertices locked{})",
                names[m],
                ps.len(),
                cs.len(),
                100.0 * (after[m] - before[m]) / before[m],
                rounds[m],
                if n_rev > 0 {
                    format!(", {n_rev} chunks kept undecimated after a back-off")
                } else {
                    String::new()
                }
            )
        })
        .collect();
    let summary = format!(
        "decimation of {} patches in {n_chunk} chunks: new crossings between surfaces per round {crossing_counts:?} (each backed off by local locks); {} pairs of structures crossed before decimation and are not checked",
        fam.patches.len(),
        exempt.len()
    );
    (per_patch, notes, summary)
}

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
            let mut ring: Vec<u32> = cross
                .iter()
                .flat_map(|&((pa, ta), (pb, tb))| {
                    input[pa as usize][ta as usize]
                        .into_iter()
                        .chain(input[pb as usize][tb as usize])
                })
                .collect();
            for _ in 0..2 {
                let mut next = ring.clone();
                for &v in &ring {
                    next.extend_from_slice(&neighbours[v as usize]);
                }
                ring = next;
            }
            for v in ring {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn canonical_orders_and_tells_winding() {
        assert_eq!(canonical([5, 1, 3]), ([1, 3, 5], true));
        assert_eq!(canonical([1, 5, 3]), ([1, 3, 5], false));
        assert_eq!(canonical([3, 5, 1]), ([1, 3, 5], true));
        assert_eq!(canonical([3, 1, 5]), ([1, 3, 5], false));
    }
}
