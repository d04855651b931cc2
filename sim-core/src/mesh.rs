//! Closed triangle meshes in millimetres: the shared surface type of anatomy, fluoroscopy and
//! needle contact.
//!
//! Convention: triangles are wound counter-clockwise seen from outside, so the right-hand normal
//! `(b - a) x (c - a)` points out of the solid and a closed mesh has positive signed volume.

use rustc_hash::FxHashMap;

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// An indexed triangle mesh with vertex positions in millimetres.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TriMesh {
    /// Vertex positions, millimetres, in the region's model frame.
    pub vertices_mm: Vec<[f64; 3]>,
    /// Triangles as vertex indices, counter-clockwise seen from outside.
    pub triangles: Vec<[u32; 3]>,
}

/// Edge topology of a mesh: what makes it usable as the boundary of a solid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TopologyReport {
    /// Edges used by exactly one triangle (holes).
    pub boundary_edges: usize,
    /// Edges used by more than two triangles.
    pub non_manifold_edges: usize,
    /// Interior edges whose two triangles traverse them in the same direction (flipped winding).
    pub inconsistent_edges: usize,
    /// Triangles with a repeated vertex index.
    pub degenerate_triangles: usize,
}

impl TopologyReport {
    /// True when every edge is shared by exactly two oppositely oriented triangles.
    pub fn is_closed_and_consistent(&self) -> bool {
        *self == TopologyReport::default()
    }
}

impl TriMesh {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// The three corner positions of triangle `i`.
    pub fn triangle(&self, i: usize) -> [[f64; 3]; 3] {
        let [a, b, c] = self.triangles[i];
        [
            self.vertices_mm[a as usize],
            self.vertices_mm[b as usize],
            self.vertices_mm[c as usize],
        ]
    }

    /// Signed enclosed volume in mm^3 (divergence theorem); positive for outward winding.
    pub fn signed_volume_mm3(&self) -> f64 {
        // Sum of signed tetrahedra against the centroid of the vertices, which keeps the
        // cancellation error small for meshes far from the origin.
        let c = DVec3::from(self.centroid_of_vertices());
        let mut six_v = 0.0;
        for i in 0..self.triangles.len() {
            let [a, b, d] = self.triangle(i).map(|p| DVec3::from(p) - c);
            six_v += a.dot(b.cross(d));
        }
        six_v / 6.0
    }

    /// Total surface area in mm^2.
    pub fn area_mm2(&self) -> f64 {
        (0..self.triangles.len())
            .map(|i| {
                let [a, b, c] = self.triangle(i).map(DVec3::from);
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    /// Axis-aligned bounding box `(min, max)` in mm, or `None` for an empty mesh.
    pub fn bounding_box_mm(&self) -> Option<([f64; 3], [f64; 3])> {
        let first = *self.vertices_mm.first()?;
        Some(self.vertices_mm.iter().fold((first, first), |(lo, hi), v| {
            (
                [lo[0].min(v[0]), lo[1].min(v[1]), lo[2].min(v[2])],
                [hi[0].max(v[0]), hi[1].max(v[1]), hi[2].max(v[2])],
            )
        }))
    }

    fn centroid_of_vertices(&self) -> [f64; 3] {
        let n = self.vertices_mm.len().max(1) as f64;
        let s = self
            .vertices_mm
            .iter()
            .fold([0.0; 3], |s, v| [s[0] + v[0], s[1] + v[1], s[2] + v[2]]);
        [s[0] / n, s[1] / n, s[2] / n]
    }

    /// Counts boundary, non-manifold and inconsistently wound edges (by vertex index).
    pub fn topology_report(&self) -> TopologyReport {
        let mut report = TopologyReport {
            degenerate_triangles: self.triangles.iter().filter(|t| is_degenerate(t)).count(),
            ..TopologyReport::default()
        };
        for &(_, (fwd, back)) in &directed_edge_uses(&self.triangles) {
            match fwd + back {
                1 => report.boundary_edges += 1,
                2 if fwd != 1 => report.inconsistent_edges += 1,
                2 => {}
                _ => report.non_manifold_edges += 1,
            }
        }
        report
    }

    /// Applies `f` to every vertex position.
    pub fn map_vertices(&mut self, mut f: impl FnMut([f64; 3]) -> [f64; 3]) {
        for v in &mut self.vertices_mm {
            *v = f(*v);
        }
    }

    /// Appends another mesh (its indices are offset); the result holds both solids.
    pub fn append(&mut self, other: &TriMesh) {
        let offset = self.vertices_mm.len() as u32;
        self.vertices_mm.extend_from_slice(&other.vertices_mm);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + offset, t[1] + offset, t[2] + offset]),
        );
    }

    /// Reverses the winding of every triangle (turns the mesh inside out).
    pub fn flip_winding(&mut self) {
        for t in &mut self.triangles {
            t.swap(1, 2);
        }
    }

    /// A closed, outward-wound axis-aligned box (12 triangles).
    pub fn axis_aligned_box(min_mm: [f64; 3], max_mm: [f64; 3]) -> TriMesh {
        let (l, h) = (min_mm, max_mm);
        let vertices_mm = vec![
            [l[0], l[1], l[2]],
            [h[0], l[1], l[2]],
            [h[0], h[1], l[2]],
            [l[0], h[1], l[2]],
            [l[0], l[1], h[2]],
            [h[0], l[1], h[2]],
            [h[0], h[1], h[2]],
            [l[0], h[1], h[2]],
        ];
        let triangles = vec![
            [0, 2, 1],
            [0, 3, 2], // z = min, normal -z
            [4, 5, 6],
            [4, 6, 7], // z = max, normal +z
            [0, 1, 5],
            [0, 5, 4], // y = min, normal -y
            [3, 7, 6],
            [3, 6, 2], // y = max, normal +y
            [0, 4, 7],
            [0, 7, 3], // x = min, normal -x
            [1, 2, 6],
            [1, 6, 5], // x = max, normal +x
        ];
        TriMesh {
            vertices_mm,
            triangles,
        }
    }

    /// A geodesic sphere: an icosahedron subdivided `subdivisions` times, vertices on the sphere.
    ///
    /// It has `20 * 4^subdivisions` triangles (7 subdivisions give 327,680). Being inscribed, its
    /// chords are slightly shorter than the analytic sphere's; the gap falls as `4^-subdivisions`.
    pub fn icosphere(center_mm: [f64; 3], radius_mm: f64, subdivisions: u32) -> TriMesh {
        let phi = (1.0 + 5f64.sqrt()) / 2.0;
        let mut verts: Vec<[f64; 3]> = vec![
            [-1.0, phi, 0.0],
            [1.0, phi, 0.0],
            [-1.0, -phi, 0.0],
            [1.0, -phi, 0.0],
            [0.0, -1.0, phi],
            [0.0, 1.0, phi],
            [0.0, -1.0, -phi],
            [0.0, 1.0, -phi],
            [phi, 0.0, -1.0],
            [phi, 0.0, 1.0],
            [-phi, 0.0, -1.0],
            [-phi, 0.0, 1.0],
        ];
        for v in &mut verts {
            *v = unit_by_division(DVec3::from(*v));
        }
        let mut tris: Vec<[u32; 3]> = vec![
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ];
        for _ in 0..subdivisions {
            let mut midpoint: FxHashMap<(u32, u32), u32> =
                FxHashMap::with_capacity_and_hasher(tris.len() * 3 / 2, Default::default());
            let mut next = Vec::with_capacity(tris.len() * 4);
            let mut mid = |a: u32, b: u32, verts: &mut Vec<[f64; 3]>| -> u32 {
                *midpoint.entry((a.min(b), a.max(b))).or_insert_with(|| {
                    let (p, q) = (verts[a as usize], verts[b as usize]);
                    verts.push(unit_by_division(DVec3::from(p) + DVec3::from(q)));
                    (verts.len() - 1) as u32
                })
            };
            for &[a, b, c] in &tris {
                let ab = mid(a, b, &mut verts);
                let bc = mid(b, c, &mut verts);
                let ca = mid(c, a, &mut verts);
                next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
            }
            tris = next;
        }
        let vertices_mm = verts
            .into_iter()
            .map(|v| {
                [
                    center_mm[0] + radius_mm * v[0],
                    center_mm[1] + radius_mm * v[1],
                    center_mm[2] + radius_mm * v[2],
                ]
            })
            .collect();
        TriMesh {
            vertices_mm,
            triangles: tris,
        }
    }
}

/// Values grouped by a small integer key, laid out in one array (a counting sort: one pass to
/// count each key's values, one to place them): `bucket(k)` holds key `k`'s values in the order
/// they were given. Serves the mesh code's per-vertex lists (edges by lower vertex, neighbours,
/// triangles of each vertex), where millions of small growing vectors cost several times more.
pub(crate) struct Buckets {
    /// `starts[k]..starts[k + 1]` is key `k`'s range of `values`.
    starts: Vec<u32>,
    values: Vec<u32>,
}

impl Buckets {
    /// The `(key, value)` pairs that `pairs()` gives (called twice, the same pairs each time)
    /// under `keys` keys (each key below). Panics if there are `u32::MAX` values or more.
    pub(crate) fn new<I>(keys: usize, pairs: impl Fn() -> I) -> Buckets
    where
        I: Iterator<Item = (u32, u32)>,
    {
        let mut starts = vec![0u32; keys + 1];
        for (k, _) in pairs() {
            starts[k as usize + 1] += 1;
        }
        for k in 0..keys {
            starts[k + 1] = starts[k + 1]
                .checked_add(starts[k])
                .expect("fewer than 2^32 values");
        }
        let mut next = starts.clone();
        let mut values = vec![0u32; starts[keys] as usize];
        for (k, v) in pairs() {
            let slot = &mut next[k as usize];
            values[*slot as usize] = v;
            *slot += 1;
        }
        Buckets { starts, values }
    }

    /// Values of key `k`, in the order given.
    pub(crate) fn bucket(&self, k: usize) -> &[u32] {
        &self.values[self.starts[k] as usize..self.starts[k + 1] as usize]
    }

    /// Values of key `k`, to sort or rewrite in place.
    pub(crate) fn bucket_mut(&mut self, k: usize) -> &mut [u32] {
        &mut self.values[self.starts[k] as usize..self.starts[k + 1] as usize]
    }
}

/// True for a triangle with a repeated vertex index.
pub fn is_degenerate(t: &[u32; 3]) -> bool {
    t[0] == t[1] || t[1] == t[2] || t[0] == t[2]
}

/// For each undirected edge `(lo, hi)` of the non-degenerate triangles: how many triangles
/// traverse it `lo -> hi` and how many `hi -> lo`, sorted by edge. A closed, consistently wound
/// mesh has `(1, 1)` on every edge.
///
/// The half-edges are bucketed by their lower vertex (a counting sort) and each bucket, a
/// vertex's few edges, is sorted on its own: a phantom's closedness checks count millions of
/// edges, and this costs a third of sorting them as keys (which remains for triangles whose
/// vertex ids are sparse: more ids than twice the half-edges).
pub fn directed_edge_uses(triangles: &[[u32; 3]]) -> Vec<((u32, u32), (u32, u32))> {
    let Some(max_id) = triangles.iter().flatten().copied().max() else {
        return Vec::new();
    };
    let ids = max_id as usize + 1;
    if max_id >= 1 << 31 || ids > 6 * triangles.len() + 1024 {
        return directed_edge_uses_sorted(triangles);
    }
    // By lower vertex: the upper vertex times two, plus one for a use from the upper vertex down.
    let half_edges = || {
        triangles
            .iter()
            .filter(|t| !is_degenerate(t))
            .flat_map(|t| (0..3).map(move |k| (t[k], t[(k + 1) % 3])))
            .map(|(a, b)| (a.min(b), (a.max(b) << 1) | u32::from(a > b)))
    };
    let mut entries = Buckets::new(ids, half_edges);
    let mut edges = Vec::with_capacity(entries.values.len() / 2 + 1);
    for lo in 0..ids {
        let bucket = entries.bucket_mut(lo);
        bucket.sort_unstable();
        let mut i = 0;
        while i < bucket.len() {
            let hi = bucket[i] >> 1;
            let (mut fwd, mut back) = (0, 0);
            while i < bucket.len() && bucket[i] >> 1 == hi {
                if bucket[i] & 1 == 0 {
                    fwd += 1;
                } else {
                    back += 1;
                }
                i += 1;
            }
            edges.push(((lo as u32, hi), (fwd, back)));
        }
    }
    edges
}

/// [`directed_edge_uses`] by sorting every half-edge's key.
fn directed_edge_uses_sorted(triangles: &[[u32; 3]]) -> Vec<((u32, u32), (u32, u32))> {
    let mut forward: Vec<u64> = Vec::with_capacity(triangles.len() * 3 / 2);
    let mut backward: Vec<u64> = Vec::with_capacity(triangles.len() * 3 / 2);
    for t in triangles.iter().filter(|t| !is_degenerate(t)) {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            let key = (u64::from(a.min(b)) << 32) | u64::from(a.max(b));
            if a < b {
                forward.push(key);
            } else {
                backward.push(key);
            }
        }
    }
    forward.sort_unstable();
    backward.sort_unstable();
    let mut edges = Vec::with_capacity(forward.len().max(backward.len()));
    let (mut i, mut j) = (0, 0);
    while let Some(key) = match (forward.get(i), backward.get(j)) {
        (Some(&f), Some(&b)) => Some(f.min(b)),
        (Some(&f), None) => Some(f),
        (None, Some(&b)) => Some(b),
        (None, None) => None,
    } {
        let (mut fwd, mut back) = (0, 0);
        while forward.get(i) == Some(&key) {
            fwd += 1;
            i += 1;
        }
        while backward.get(j) == Some(&key) {
            back += 1;
            j += 1;
        }
        edges.push((((key >> 32) as u32, key as u32), (fwd, back)));
    }
    edges
}

/// `v / |v|` as an array. Divides by the length rather than multiplying by its reciprocal, as
/// glam's `normalize` does: the icosphere's vertices (and every mesh and hash built on them) keep
/// the values they had before glam was used here.
fn unit_by_division(v: DVec3) -> [f64; 3] {
    (v / v.length()).to_array()
}

/// `n` triangles whose corners are drawn from `0..vertices` by SplitMix64 from `*state`
/// (repeated edges, both windings, degenerate triangles): a soup for tests of edge counting.
#[cfg(test)]
pub(crate) fn random_soup(state: &mut u64, n: usize, vertices: u32) -> Vec<[u32; 3]> {
    (0..n)
        .map(|_| {
            std::array::from_fn(|_| {
                *state = crate::rng::splitmix64(*state);
                (*state % u64::from(vertices)) as u32
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buckets_hold_each_keys_values_in_the_order_given() {
        // Random pairs over 0, 1 and 50 keys (some keys empty) against growing vectors.
        let mut u = 3_u64;
        for (keys, n) in [(0usize, 0usize), (1, 7), (50, 400), (50, 3)] {
            let pairs: Vec<(u32, u32)> = (0..n)
                .map(|_| {
                    u = crate::rng::splitmix64(u);
                    ((u % keys as u64) as u32, (u >> 32) as u32)
                })
                .collect();
            let mut want = vec![Vec::new(); keys];
            for &(k, v) in &pairs {
                want[k as usize].push(v);
            }
            let mut b = Buckets::new(keys, || pairs.iter().copied());
            for (k, w) in want.iter().enumerate() {
                assert_eq!(b.bucket(k), &w[..], "key {k} of {keys}");
                b.bucket_mut(k).reverse();
                assert_eq!(b.bucket(k).first(), w.last());
            }
        }
    }

    #[test]
    fn directed_edge_uses_counts_each_direction_sorted_by_edge() {
        // Random soups over 12 vertices (repeated edges, both windings, degenerate triangles)
        // against a plain map count.
        let mut u = 7_u64;
        for _ in 0..200 {
            let tris = random_soup(&mut u, 30, 12);
            let mut want: std::collections::BTreeMap<(u32, u32), (u32, u32)> = Default::default();
            for t in tris.iter().filter(|t| !is_degenerate(t)) {
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    let e = want.entry((a.min(b), a.max(b))).or_default();
                    if a < b {
                        e.0 += 1;
                    } else {
                        e.1 += 1;
                    }
                }
            }
            let got = directed_edge_uses(&tris);
            let want: Vec<_> = want.into_iter().collect();
            assert_eq!(got, want);
            // Sparse ids (the keys' sort) give the same counts.
            let spread: Vec<[u32; 3]> = tris.iter().map(|t| t.map(|v| v * 1_000_003)).collect();
            let spread_want: Vec<_> = want
                .iter()
                .map(|&((a, b), n)| ((a * 1_000_003, b * 1_000_003), n))
                .collect();
            assert_eq!(directed_edge_uses(&spread), spread_want);
            assert_eq!(directed_edge_uses_sorted(&tris), want);
        }
        assert!(directed_edge_uses(&[]).is_empty());
        // A closed box: every edge once each way.
        let b = TriMesh::axis_aligned_box([0.0; 3], [1.0; 3]);
        let uses = directed_edge_uses(&b.triangles);
        assert_eq!(uses.len(), 18);
        assert!(uses.iter().all(|&(_, n)| n == (1, 1)));
    }

    #[test]
    fn box_volume_area_and_topology() {
        let b = TriMesh::axis_aligned_box([-1.0, 2.0, 3.0], [1.0, 5.0, 7.0]);
        assert!((b.signed_volume_mm3() - 24.0).abs() < 1e-12);
        assert!((b.area_mm2() - 2.0 * (6.0 + 8.0 + 12.0)).abs() < 1e-12);
        assert!(b.topology_report().is_closed_and_consistent());
        assert_eq!(
            b.bounding_box_mm(),
            Some(([-1.0, 2.0, 3.0], [1.0, 5.0, 7.0]))
        );
    }

    #[test]
    fn icosphere_converges_to_sphere_volume() {
        let r = 10.0;
        let exact = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
        let mut last_err = f64::INFINITY;
        for n in 0..6 {
            let s = TriMesh::icosphere([100.0, -50.0, 7.0], r, n);
            assert_eq!(s.triangle_count(), 20 * 4usize.pow(n));
            assert!(
                s.topology_report().is_closed_and_consistent(),
                "subdivision {n}"
            );
            let v = s.signed_volume_mm3();
            assert!(
                v > 0.0 && v < exact,
                "inscribed polyhedron is smaller than the sphere"
            );
            let err = (exact - v) / exact;
            assert!(err < last_err);
            last_err = err;
        }
        // Inscribed-polyhedron volume deficit after 5 subdivisions (edge about 0.04 r) is ~1e-3.
        assert!(last_err < 2e-3, "relative volume error {last_err}");
    }

    #[test]
    fn defects_are_reported() {
        let mut b = TriMesh::axis_aligned_box([0.0; 3], [1.0; 3]);
        b.triangles.pop();
        let r = b.topology_report();
        assert_eq!(r.boundary_edges, 3);
        let mut f = TriMesh::axis_aligned_box([0.0; 3], [1.0; 3]);
        f.triangles[0].swap(1, 2);
        assert!(f.topology_report().inconsistent_edges > 0);
        let mut inside_out = TriMesh::axis_aligned_box([0.0; 3], [1.0; 3]);
        inside_out.flip_winding();
        assert!(inside_out.signed_volume_mm3() < 0.0);
        assert!(inside_out.topology_report().is_closed_and_consistent());
    }
}
