//! Steps 1 and 2 of the family meshing (see [`super`]): welding the vertices that touching
//! structures share and partitioning the triangles into patches by their owners.

use rustc_hash::FxHashMap;

use super::surface::{ExtractedSurface, WELD_EDGE_FRACTION};
use crate::mesh::TriMesh;

/// A set of triangles (welded vertex ids) with the same owners.
#[derive(Debug, Clone)]
pub(super) struct Patch {
    /// Owning meshes and whether each holds the triangles reversed (the first owner never does).
    pub(super) owners: Vec<(u32, bool)>,
    /// Triangles in the first owner's orientation.
    pub(super) triangles: Vec<[u32; 3]>,
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
pub(super) struct Family {
    pub(super) positions: Vec<[f64; 3]>,
    /// Per welded vertex, its fallback position (see [`ExtractedSurface::interpolated_mm`]).
    pub(super) fallback: Vec<[f64; 3]>,
    pub(super) patches: Vec<Patch>,
    /// Per mesh: its patches and whether it holds each reversed.
    pub(super) mesh_patches: Vec<Vec<(usize, bool)>>,
    /// Per welded vertex: on triangles of two or more patches.
    pub(super) junction: Vec<bool>,
}

pub(super) fn weld_and_partition(items: &[ExtractedSurface]) -> Family {
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
    let mut fallback = Vec::with_capacity(recs.len());
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
                    let it = &items[m as usize];
                    positions.push(it.mesh.vertices_mm[v as usize]);
                    fallback.push(
                        it.interpolated_mm
                            .get(v as usize)
                            .copied()
                            .unwrap_or(it.mesh.vertices_mm[v as usize]),
                    );
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
    // The owners of each triangle made of shared vertices: its records (corners, mesh, winding)
    // sorted by corners, stably, so each triangle's owners keep mesh order (sorting millions of
    // records costs less than a map of lists).
    let mut shared: Vec<([u32; 3], u32, u32, bool)> = Vec::new();
    for (m, ts) in tris.iter().enumerate() {
        for (i, &t) in ts.iter().enumerate() {
            if t.iter().all(|&g| multi[g as usize]) {
                let (key, even) = canonical(t);
                shared.push((key, m as u32, i as u32, even));
            }
        }
    }
    shared.sort_by_key(|r| r.0);
    // Per mesh and triangle, its owners as a range of `owners` when it has several (empty
    // otherwise).
    let mut owner_range: Vec<Vec<(u32, u32)>> =
        tris.iter().map(|ts| vec![(0, 0); ts.len()]).collect();
    let mut owners: Vec<(u32, bool)> = Vec::new();
    let mut start = 0;
    while start < shared.len() {
        let mut end = start + 1;
        while end < shared.len() && shared[end].0 == shared[start].0 {
            end += 1;
        }
        if end - start > 1 {
            let range = (owners.len() as u32, (owners.len() + end - start) as u32);
            for &(_, m, i, even) in &shared[start..end] {
                owners.push((m, even));
                owner_range[m as usize][i as usize] = range;
            }
        }
        start = end;
    }
    drop(shared);
    let mut patch_index: FxHashMap<Vec<(u32, bool)>, usize> = FxHashMap::default();
    let mut patches: Vec<Patch> = Vec::new();
    let mut key: Vec<(u32, bool)> = Vec::new();
    for (m, ts) in tris.iter().enumerate() {
        let mut single: Option<usize> = None;
        for (i, &t) in ts.iter().enumerate() {
            let (a, b) = owner_range[m][i];
            let p = if a < b {
                let list = &owners[a as usize..b as usize];
                if list[0].0 != m as u32 {
                    // Added with the first owner's triangles.
                    continue;
                }
                let first = list[0].1;
                key.clear();
                key.extend(list.iter().map(|&(o, e)| (o, e != first)));
                match patch_index.get(key.as_slice()) {
                    Some(&p) => p,
                    None => {
                        patches.push(Patch {
                            owners: key.clone(),
                            triangles: Vec::new(),
                        });
                        patch_index.insert(key.clone(), patches.len() - 1);
                        patches.len() - 1
                    }
                }
            } else {
                *single.get_or_insert_with(|| {
                    patches.push(Patch {
                        owners: vec![(m as u32, false)],
                        triangles: Vec::new(),
                    });
                    patches.len() - 1
                })
            };
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
        fallback,
        patches,
        mesh_patches,
        junction,
    }
}

impl Family {
    /// The triangles of mesh `m` (welded ids) from per-patch triangle lists.
    pub(super) fn mesh_triangles(&self, m: usize, source: &[Vec<[u32; 3]>]) -> Vec<[u32; 3]> {
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
    pub(super) fn assemble(
        &self,
        m: usize,
        source: &[Vec<[u32; 3]>],
        positions: &[[f64; 3]],
    ) -> TriMesh {
        let mut map: FxHashMap<u32, u32> = FxHashMap::default();
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
    pub(super) fn neighbours(&self) -> Vec<Vec<u32>> {
        crate::anatomy::smooth::neighbours_of(
            self.positions.len(),
            self.patches.iter().flat_map(|p| &p.triangles),
        )
    }

    /// Per junction vertex, its neighbours along junction curves (edges whose triangles lie in
    /// two or more patches).
    pub(super) fn curve_neighbours(&self) -> Vec<Vec<u32>> {
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
    pub(super) fn mesh_volumes(
        &self,
        source: &[Vec<[u32; 3]>],
        positions: &[[f64; 3]],
    ) -> Vec<f64> {
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
