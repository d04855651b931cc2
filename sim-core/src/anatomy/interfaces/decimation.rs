//! Step 4 of the family meshing (see [`super`]): decimating each patch once, chunk by chunk, with
//! junction and chunk-border vertices locked, and backing off where a mesh fails its checks.

use rustc_hash::FxHashMap;

use super::crossing::{crossing_pairs, lock_around_crossing, mean_edge_mm};
use super::weld::Family;
use crate::anatomy::decimate::{Closure, DecimationParams, acceptable, defective_vertices};
use crate::par::{joined, par_map, par_map_heaviest_first};

/// Edge of the cubes that split patches into chunks for decimation, in mean input edge
/// lengths (about 25 mm on a 1.5 mm grid). Smaller chunks lock more vertices along their
/// borders; larger ones make each back-off redo more. Simulator choice.
pub const CHUNK_EDGES: f64 = 32.0;

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
    let mut local_of: FxHashMap<u32, u32> = FxHashMap::default();
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

/// Decimates the family (see the module doc); returns the per-patch triangles, one note per mesh
/// and a note on the family.
///
/// The unit of decimation is a *chunk*: the triangles of one patch whose centroids fall in one
/// cube of [`CHUNK_EDGES`] mean edge lengths. Chunk borders are locked like patch borders, so a
/// back-off redoes only the chunks around a defect, and large patches (the skin) spread over
/// all cores.
pub(super) fn decimate_family(
    fam: &Family,
    names: &[String],
    params: &DecimationParams,
    neighbours: Option<Vec<Vec<u32>>>,
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
    // Each patch's triangles by the cell of their centroids, cells in key order, triangles in
    // patch order within a cell; the patches in parallel.
    let per_patch: Vec<Vec<Vec<[u32; 3]>>> = par_map(
        input.len(),
        &|p| {
            let mut keyed: Vec<([i64; 3], u32)> = input[p]
                .iter()
                .enumerate()
                .map(|(i, t)| {
                    let v = t.map(|g| fam.positions[g as usize]);
                    let cell: [i64; 3] = std::array::from_fn(|a| {
                        ((v[0][a] + v[1][a] + v[2][a]) / 3.0 / chunk_mm).floor() as i64
                    });
                    (cell, i as u32)
                })
                .collect();
            keyed.sort_unstable();
            keyed
                .chunk_by(|a, b| a.0 == b.0)
                .map(|run| run.iter().map(|&(_, i)| input[p][i as usize]).collect())
                .collect::<Vec<Vec<[u32; 3]>>>()
        },
        &mut |_| {},
    );
    let mut chunk_patch: Vec<usize> = Vec::new();
    let mut chunks: Vec<Vec<[u32; 3]>> = Vec::new();
    for (p, cs) in per_patch.into_iter().enumerate() {
        for c in cs {
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
    // Structures whose input surfaces already cross (a nested whole-solid mesh such as the
    // phantom's deep soft tissue, which later structures leave) are not laminar to begin with;
    // decimation is only kept from making new crossings. The neighbour lists (given, or made
    // on one core meanwhile) serve the back-offs' locks.
    let (neighbours, crossing_before) = std::thread::scope(|s| {
        let made = neighbours.is_none().then(|| s.spawn(|| fam.neighbours()));
        let pairs = crossing_pairs(&chunks, &fam.positions, &vec![true; n_chunk], cell_mm, true);
        let made = made.map(|h| joined(h.join()));
        (neighbours.or(made).expect("given or made"), pairs)
    });
    let mut exempt: Vec<(u32, u32)> = Vec::new();
    for ((ca, _), (cb, _)) in crossing_before {
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
                acceptable(
                    before[m],
                    &mesh,
                    params.max_volume_change,
                    Closure::Manifold,
                )
                .map_err(|why| (why, defective_vertices(&tris, Closure::Manifold)))
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
        // around each crossing and redo the chunks that hold them. Triangles sharing one corner
        // are compared too: a collapse beside a junction vertex can fold a triangle through its
        // neighbour's at that corner (on the 5 mm phantom with a 28 mm L5, the right ilium's
        // cortex through its cancellous bone, 0.09 mm deep), which no edge-free test sees.
        let mut crossings = crossing_pairs(&result, &fam.positions, &fresh, cell_mm, true);
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
        // The meshes that changed are checked (the heaviest first, over the cores) while one
        // more thread looks for crossings at the reverted chunks: on the default phantom's
        // family the checks took 0.8 s on one core.
        let (mut next, crossing_now) = std::thread::scope(|s| {
            let crossing = s.spawn(|| crossing_pairs(&result, &fam.positions, &now, cell_mm, true));
            let changed: Vec<bool> = (0..n_mesh)
                .map(|m| {
                    let mut cs = fam.mesh_patches[m]
                        .iter()
                        .flat_map(|&(p, _)| &chunks_of_patch[p]);
                    cs.clone().any(|&c| now[c]) && !cs.all(|&c| reverted[c])
                })
                .collect();
            let weights: Vec<usize> = (0..n_mesh)
                .map(|m| {
                    if changed[m] {
                        fam.mesh_patches[m]
                            .iter()
                            .map(|&(p, _)| per_patch[p].len())
                            .sum()
                    } else {
                        0
                    }
                })
                .collect();
            let fails = par_map_heaviest_first(&weights, &|m| {
                changed[m]
                    && acceptable(
                        before[m],
                        &fam.assemble(m, &per_patch, &fam.positions),
                        params.max_volume_change,
                        Closure::Manifold,
                    )
                    .is_err()
            });
            let next: Vec<usize> = (0..n_mesh).filter(|&m| fails[m]).collect();
            (next, joined(crossing.join()))
        });
        for ((ca, _), (cb, _)) in crossing_now {
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
    let notes = par_map(
        n_mesh,
        &|m| {
            let ps = &fam.mesh_patches[m];
            let cs: Vec<usize> = ps
                .iter()
                .flat_map(|&(p, _)| chunks_of_patch[p].iter().copied())
                .collect();
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
            let mut verts: Vec<u32> = cs
                .iter()
                .flat_map(|&c| chunks[c].iter().flatten().copied())
                .collect();
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
        },
        &mut |_| {},
    );
    let summary = format!(
        "decimation of {} patches in {n_chunk} chunks: new crossings between surfaces per round {crossing_counts:?} (each backed off by local locks); {} pairs of structures crossed before decimation and are not checked",
        fam.patches.len(),
        exempt.len()
    );
    (per_patch, notes, summary)
}
