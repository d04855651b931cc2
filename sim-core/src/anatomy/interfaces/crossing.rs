//! Finding surfaces that cross each other after smoothing or decimation, and the locks that back
//! off around a crossing.

use rustc_hash::FxHashMap;

use glam::DVec3;

use super::weld::Family;
use crate::mesh::Buckets;
use crate::par::par_map;

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

/// Whether two triangles that share the corner `a` (and no other) cross: their intersection
/// reaches beyond `a`. `p = [a, b, c]`, `q = [a, d, e]`, the shared corner first. Each triangle
/// meets the other's plane in a segment from `a` (where its other two corners lie on opposite
/// sides of that plane); the triangles overlap beyond `a` when both segments exist and leave `a`
/// the same way along the planes' common line. Corners in the other's plane (a meeting along an
/// edge) do not count, as in [`triangles_cross`].
fn corner_sharing_triangles_cross(p: [[f64; 3]; 3], q: [[f64; 3]; 3]) -> bool {
    let (p, q) = (p.map(DVec3::from), q.map(DVec3::from));
    let a = p[0];
    // Where the edge between the other two corners of `t` crosses the plane through `a` with
    // normal `n`, relative to `a`; `None` when both lie on one side (or either on the plane).
    let reach = |t: [DVec3; 3], n: DVec3| -> Option<DVec3> {
        let (db, dc) = (n.dot(t[1] - a), n.dot(t[2] - a));
        if !((db > 0.0 && dc < 0.0) || (db < 0.0 && dc > 0.0)) {
            return None;
        }
        Some(t[1] + (t[2] - t[1]) * (db / (db - dc)) - a)
    };
    let np = (p[1] - a).cross(p[2] - a);
    let nq = (q[1] - a).cross(q[2] - a);
    let (Some(up), Some(uq)) = (reach(p, nq), reach(q, np)) else {
        return false;
    };
    // Both lie on the common line through `a`; they overlap beyond `a` when they point the same
    // way. The shorter one is the overlap; under a nanometre it is rounding at the corner. Two
    // triangles all but coplanar (neighbours on a smooth surface) have a common line that
    // rounding sets anywhere: points that are not on one line within a millionth of a radian
    // are not a crossing (a fold that flat encloses no volume worth a check).
    let (lp, lq) = (up.length(), uq.length());
    up.dot(uq) > 0.0 && lp.min(lq) > 1e-6 * 1e-3 && up.cross(uq).length() <= 1e-6 * lp * lq
}

/// A triangle's axis-aligned box, mm.
type TriBox = ([f64; 3], [f64; 3]);

/// A triangle pair as `(patch, triangle index)` pairs.
type Pair = ((u32, u32), (u32, u32));

/// The box of triangle `t`.
fn triangle_box(t: [u32; 3], positions: &[[f64; 3]]) -> TriBox {
    let v = t.map(|g| positions[g as usize]);
    let lo: [f64; 3] = std::array::from_fn(|a| v[0][a].min(v[1][a]).min(v[2][a]));
    let hi: [f64; 3] = std::array::from_fn(|a| v[0][a].max(v[1][a]).max(v[2][a]));
    (lo, hi)
}

/// The cells of a uniform grid of edge `cell_mm` that `b` meets, visited in order.
fn for_cells(b: &TriBox, cell_mm: f64, mut f: impl FnMut([i64; 3])) {
    let c0 = b.0.map(|x| (x / cell_mm).floor() as i64);
    let c1 = b.1.map(|x| (x / cell_mm).floor() as i64);
    for z in c0[2]..=c1[2] {
        for y in c0[1]..=c1[1] {
            for x in c0[0]..=c1[0] {
                f([x, y, z]);
            }
        }
    }
}

fn boxes_overlap(a: &TriBox, b: &TriBox) -> bool {
    !(0..3).any(|d| a.0[d] > b.1[d] || b.0[d] > a.1[d])
}

/// Whether triangles `a` and `b` (of different patches) cross: [`triangles_cross`] when they share
/// no corner, [`corner_sharing_triangles_cross`] when they share one and `corners` is set; never
/// when they share an edge (they meet along it).
fn pair_crosses(a: [u32; 3], b: [u32; 3], positions: &[[f64; 3]], corners: bool) -> bool {
    let shared = a.iter().filter(|v| b.contains(v)).count();
    match shared {
        0 => triangles_cross(
            a.map(|g| positions[g as usize]),
            b.map(|g| positions[g as usize]),
        ),
        1 if corners => {
            let s = a.iter().position(|v| b.contains(v)).unwrap_or(0);
            let r = b.iter().position(|&v| v == a[s]).unwrap_or(0);
            corner_sharing_triangles_cross(
                [a[s], a[(s + 1) % 3], a[(s + 2) % 3]].map(|g| positions[g as usize]),
                [b[r], b[(r + 1) % 3], b[(r + 2) % 3]].map(|g| positions[g as usize]),
            )
        }
        _ => false,
    }
}

/// Every triangle of a family with its `(patch, index)` and box, and the triangles of each grid
/// cell its box meets. Two triangles whose boxes overlap share a cell.
struct TriangleGrid {
    tris: Vec<(u32, u32)>,
    boxes: Vec<TriBox>,
    cells: FxHashMap<[i64; 3], Vec<u32>>,
    cell_mm: f64,
}

impl TriangleGrid {
    fn new(source: &[Vec<[u32; 3]>], positions: &[[f64; 3]], cell_mm: f64) -> TriangleGrid {
        TriangleGrid::around(source, positions, cell_mm, None)
    }

    /// The grid of every triangle, or with `fresh`, of the cells that hold a triangle of a fresh
    /// patch only (a pair to test has a fresh triangle, and shares one of its cells): triangles
    /// of the other patches are listed only in those cells.
    fn around(
        source: &[Vec<[u32; 3]>],
        positions: &[[f64; 3]],
        cell_mm: f64,
        fresh: Option<&[bool]>,
    ) -> TriangleGrid {
        let mut tris: Vec<(u32, u32)> = Vec::new();
        let mut boxes: Vec<TriBox> = Vec::new();
        let mut cells: FxHashMap<[i64; 3], Vec<u32>> = FxHashMap::default();
        for (p, ts) in source.iter().enumerate() {
            for (i, t) in ts.iter().enumerate() {
                tris.push((p as u32, i as u32));
                boxes.push(triangle_box(*t, positions));
            }
        }
        let fresh_patch = |id: usize| fresh.is_none_or(|f| f[tris[id].0 as usize]);
        for (id, b) in boxes.iter().enumerate() {
            if fresh_patch(id) {
                for_cells(b, cell_mm, |c| cells.entry(c).or_default().push(id as u32));
            }
        }
        if let Some(fresh) = fresh {
            // The other patches' triangles go into the fresh cells only: a patch none of whose
            // box's cells is one is passed over whole (after a few rounds of the decimation,
            // most of them).
            let mut first = 0;
            for (p, ts) in source.iter().enumerate() {
                let ids = first..first + ts.len();
                first = ids.end;
                if fresh[p] || ts.is_empty() {
                    continue;
                }
                let patch_box = boxes[ids.clone()].iter().fold(boxes[ids.start], |a, b| {
                    (
                        std::array::from_fn(|k| a.0[k].min(b.0[k])),
                        std::array::from_fn(|k| a.1[k].max(b.1[k])),
                    )
                });
                let mut near = false;
                for_cells(&patch_box, cell_mm, |c| near |= cells.contains_key(&c));
                if !near {
                    continue;
                }
                for id in ids {
                    for_cells(&boxes[id], cell_mm, |c| {
                        if let Some(list) = cells.get_mut(&c) {
                            list.push(id as u32);
                        }
                    });
                }
            }
        }
        TriangleGrid {
            tris,
            boxes,
            cells,
            cell_mm,
        }
    }

    /// The triangle `id`'s corners.
    fn corners(&self, source: &[Vec<[u32; 3]>], id: u32) -> [u32; 3] {
        let (p, t) = self.tris[id as usize];
        source[p as usize][t as usize]
    }

    /// The pair of triangles `i` and `j`, the lower id first.
    fn pair(&self, i: u32, j: u32) -> Pair {
        let (a, b) = (self.tris[i as usize], self.tris[j as usize]);
        if i < j { (a, b) } else { (b, a) }
    }

    /// Every crossing pair with a triangle of a patch in `fresh`, as triangle ids, the lower
    /// first (sorted, each once; ids follow `(patch, index)` order), tested cell by cell in
    /// parallel.
    ///
    /// Each pair is tested once, in its *reference cell*: the cell of the lowest corner of the
    /// two boxes' overlap, which both boxes meet. Within a cell the triangles of each two
    /// patches are swept in order of their boxes' lowest x ([`sweep`]), so that a triangle meets
    /// only the other patch's triangles whose boxes reach it along x, not every triangle in the
    /// cell.
    fn crossing_ids(
        &self,
        source: &[Vec<[u32; 3]>],
        positions: &[[f64; 3]],
        fresh: &[bool],
        corners: bool,
    ) -> Vec<(u32, u32)> {
        let tris = &self.tris;
        let cells: Vec<(&[i64; 3], &Vec<u32>)> = self
            .cells
            .iter()
            .filter(|(_, c)| {
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
                // Per cell: (lowest x, highest x, patch, id), sorted by patch and then lowest x.
                let mut order: Vec<(f64, f64, u32, u32)> = Vec::new();
                let mut groups: Vec<std::ops::Range<usize>> = Vec::new();
                for &(key, cell) in &cells[ci * chunk..((ci + 1) * chunk).min(cells.len())] {
                    order.clear();
                    order.extend(cell.iter().map(|&i| {
                        let b = &self.boxes[i as usize];
                        (b.0[0], b.1[0], tris[i as usize].0, i)
                    }));
                    order.sort_unstable_by(|a, b| a.2.cmp(&b.2).then(a.0.total_cmp(&b.0)));
                    groups.clear();
                    let mut from = 0;
                    for k in 1..=order.len() {
                        if k == order.len() || order[k].2 != order[from].2 {
                            groups.push(from..k);
                            from = k;
                        }
                    }
                    let mut test = |i: u32, j: u32| {
                        let (abox, bbox) = (&self.boxes[i as usize], &self.boxes[j as usize]);
                        if boxes_overlap(abox, bbox)
                            && self.is_reference(key, abox, bbox)
                            && pair_crosses(
                                self.corners(source, i),
                                self.corners(source, j),
                                positions,
                                corners,
                            )
                        {
                            out.push((i.min(j), i.max(j)));
                        }
                    };
                    for (g, ga) in groups.iter().enumerate() {
                        for gb in &groups[g + 1..] {
                            let (a, b) = (&order[ga.clone()], &order[gb.clone()]);
                            if !(fresh[a[0].2 as usize] || fresh[b[0].2 as usize]) {
                                continue;
                            }
                            sweep(a, b, false, &mut test);
                            sweep(b, a, true, &mut test);
                        }
                    }
                }
                out
            },
            &mut |_| {},
        );
        let mut pairs: Vec<_> = found.into_iter().flatten().collect();
        pairs.sort_unstable();
        pairs
    }

    /// Whether `cell` is the reference cell of two overlapping boxes: the one holding the lowest
    /// corner of their overlap (computed as [`for_cells`] computes a box's first cell, so both
    /// boxes list it).
    fn is_reference(&self, cell: &[i64; 3], a: &TriBox, b: &TriBox) -> bool {
        (0..3).all(|d| (a.0[d].max(b.0[d]) / self.cell_mm).floor() as i64 == cell[d])
    }
}

/// Calls `test(i, j)` for every `i` of `a` and `j` of `b` (each `(lowest x, highest x, _, id)`,
/// sorted by lowest x) whose x ranges overlap and where `j` starts at or after `i` along x
/// (`strictly`: after it), so that `sweep(a, b, false)` and `sweep(b, a, true)` together meet
/// every overlapping pair once.
fn sweep(
    a: &[(f64, f64, u32, u32)],
    b: &[(f64, f64, u32, u32)],
    strictly: bool,
    test: &mut impl FnMut(u32, u32),
) {
    let mut first = 0;
    for &(lo, hi, _, i) in a {
        while first < b.len() && (b[first].0 < lo || (strictly && b[first].0 == lo)) {
            first += 1;
        }
        for &(blo, _, _, j) in &b[first..] {
            if blo > hi {
                break;
            }
            test(i, j);
        }
    }
}

/// Pairs of triangles from different patches that cross each other (see [`triangles_cross`]),
/// as `(patch, triangle index)` pairs, sorted. Only pairs with at least one triangle from a
/// patch in `fresh` are tested. Triangles sharing an edge are not compared (they meet along
/// it); those sharing one corner are compared only when `corners` is set (see
/// [`corner_sharing_triangles_cross`]), otherwise taken to meet at it.
pub(super) fn crossing_pairs(
    source: &[Vec<[u32; 3]>],
    positions: &[[f64; 3]],
    fresh: &[bool],
    cell_mm: f64,
    corners: bool,
) -> Vec<Pair> {
    let partly = fresh.iter().any(|f| !f);
    let grid = TriangleGrid::around(source, positions, cell_mm, partly.then_some(fresh));
    grid.crossing_ids(source, positions, fresh, corners)
        .into_iter()
        .map(|(i, j)| grid.pair(i, j))
        .collect()
}

/// The crossing pairs of a family whose vertices move a few at a time (the loops that put
/// vertices back where surfaces cross): after the first full search, [`LiveCrossings::moved`]
/// re-tests only the triangles around the vertices that moved, against the triangles their new
/// boxes meet. The pairs are always those [`crossing_pairs`] would find at the current positions
/// with every patch fresh (tested against it in `tests`).
pub(super) struct LiveCrossings<'a> {
    source: &'a [Vec<[u32; 3]>],
    corners: bool,
    grid: TriangleGrid,
    /// Triangle ids of each vertex.
    by_vertex: Buckets,
    /// Crossing pairs as triangle ids, the lower first.
    pairs: rustc_hash::FxHashSet<(u32, u32)>,
    /// Scratch: triangles moved in the current update.
    marked: Vec<bool>,
}

impl<'a> LiveCrossings<'a> {
    pub(super) fn new(
        source: &'a [Vec<[u32; 3]>],
        positions: &[[f64; 3]],
        cell_mm: f64,
        corners: bool,
    ) -> LiveCrossings<'a> {
        let grid = TriangleGrid::new(source, positions, cell_mm);
        let all = vec![true; source.len()];
        let pairs = grid
            .crossing_ids(source, positions, &all, corners)
            .into_iter()
            .collect();
        let corners_of = || {
            source
                .iter()
                .flatten()
                .enumerate()
                .flat_map(|(id, t)| t.map(|v| (v, id as u32)))
        };
        let by_vertex = Buckets::new(positions.len(), corners_of);
        let marked = vec![false; grid.tris.len()];
        LiveCrossings {
            source,
            corners,
            grid,
            by_vertex,
            pairs,
            marked,
        }
    }

    /// The crossing pairs now, as `(patch, triangle index)` pairs, sorted.
    pub(super) fn pairs(&self) -> Vec<Pair> {
        let mut out: Vec<Pair> = self
            .pairs
            .iter()
            .map(|&(i, j)| self.grid.pair(i, j))
            .collect();
        out.sort_unstable();
        out
    }

    /// Takes the vertices in `moved` to their new `positions` (every other vertex must be where
    /// it was at the last call) and re-tests the triangles around them.
    pub(super) fn moved(&mut self, positions: &[[f64; 3]], moved: &[u32]) {
        let mut tris: Vec<u32> = Vec::new();
        for &v in moved {
            for &t in self.by_vertex.bucket(v as usize) {
                if !self.marked[t as usize] {
                    self.marked[t as usize] = true;
                    tris.push(t);
                }
            }
        }
        let marked = &self.marked;
        self.pairs
            .retain(|&(i, j)| !marked[i as usize] && !marked[j as usize]);
        let grid = &mut self.grid;
        for &t in &tris {
            let old = grid.boxes[t as usize];
            for_cells(&old, grid.cell_mm, |c| {
                if let Some(list) = grid.cells.get_mut(&c) {
                    list.retain(|&x| x != t);
                }
            });
            let b = triangle_box(grid.corners(self.source, t), positions);
            for_cells(&b, grid.cell_mm, |c| {
                grid.cells.entry(c).or_default().push(t)
            });
            grid.boxes[t as usize] = b;
        }
        for &i in &tris {
            let pi = self.grid.tris[i as usize].0;
            let a = self.grid.corners(self.source, i);
            let abox = self.grid.boxes[i as usize];
            for_cells(&abox, self.grid.cell_mm, |c| {
                let Some(list) = self.grid.cells.get(&c) else {
                    return;
                };
                for &j in list {
                    // Two moved triangles are tested once, from the lower id.
                    if j == i || (self.marked[j as usize] && j < i) {
                        continue;
                    }
                    if self.grid.tris[j as usize].0 == pi
                        || !boxes_overlap(&abox, &self.grid.boxes[j as usize])
                    {
                        continue;
                    }
                    let b = self.grid.corners(self.source, j);
                    if pair_crosses(a, b, positions, self.corners) {
                        self.pairs.insert((i.min(j), i.max(j)));
                    }
                }
            });
        }
        for &t in &tris {
            self.marked[t as usize] = false;
        }
    }
}

/// Locks, in the two patches of a crossing, every input vertex inside the box of the two
/// crossing triangles (grown by half its size) and one ring around them: the decimated triangles
/// span input vertices that were collapsed into their corners, so locking the corners alone
/// would not keep the next attempt from cutting the same corner.
pub(super) fn lock_around_crossing(
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
pub(super) fn mean_edge_mm(source: &[Vec<[u32; 3]>], positions: &[[f64; 3]]) -> f64 {
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

#[cfg(test)]
mod tests {
    use super::*;

    const A: [f64; 3] = [0.0, 0.0, 0.0];

    /// A fan triangle at `a`: corners at unit distance in the directions `deg0` and `deg1`
    /// (degrees in the x-y plane), lifted by `z0` and `z1`.
    fn fan(deg0: f64, deg1: f64, z0: f64, z1: f64) -> [[f64; 3]; 3] {
        let at = |d: f64, z: f64| {
            let r = d.to_radians();
            [r.cos(), r.sin(), z]
        };
        [A, at(deg0, z0), at(deg1, z1)]
    }

    #[test]
    fn a_triangle_folded_over_its_neighbour_at_a_shared_corner_crosses_it() {
        // The second triangle covers the first's sector, tilted through its plane.
        let p = fan(0.0, 60.0, 0.0, 0.0);
        let q = fan(10.0, 50.0, -0.3, 0.3);
        assert!(corner_sharing_triangles_cross(p, q));
        assert!(corner_sharing_triangles_cross(q, p));
        // Lifted clear of it: they meet at the corner only.
        let q = fan(10.0, 50.0, 0.1, 0.3);
        assert!(!corner_sharing_triangles_cross(p, q));
    }

    #[test]
    fn neighbours_around_a_corner_of_a_smooth_surface_do_not_cross() {
        // Disjoint sectors of one plane, exactly and with rounding-sized lifts (whose common
        // line with the plane rounding sets anywhere), and of a gently bent surface.
        for (z0, z1) in [(0.0, 0.0), (1e-17, -1e-17), (-3e-16, 2e-16)] {
            let p = fan(0.0, 60.0, 0.0, 0.0);
            let q = fan(90.0, 150.0, z0, z1);
            assert!(!corner_sharing_triangles_cross(p, q), "{z0} {z1}");
        }
        let p = fan(0.0, 60.0, 0.02, 0.03);
        let q = fan(70.0, 130.0, 0.03, 0.01);
        assert!(!corner_sharing_triangles_cross(p, q));
    }

    #[test]
    fn crossing_pairs_compare_corner_sharing_triangles_only_when_asked() {
        let positions = vec![
            A,
            [1.0, 0.0, 0.0],
            [0.5, 0.866, 0.0],
            [0.98, 0.17, -0.3],
            [0.64, 0.77, 0.3],
        ];
        let source = vec![vec![[0, 1, 2]], vec![[0, 3, 4]]];
        let fresh = [true, true];
        assert!(crossing_pairs(&source, &positions, &fresh, 2.0, false).is_empty());
        assert_eq!(
            crossing_pairs(&source, &positions, &fresh, 2.0, true),
            vec![((0, 0), (1, 0))]
        );
        // Sharing an edge is a meeting, whatever `corners` says.
        let source = vec![vec![[0, 1, 2]], vec![[0, 1, 4]]];
        assert!(crossing_pairs(&source, &positions, &fresh, 2.0, true).is_empty());
    }

    /// Every pair is tested in exactly one cell (its reference cell), whatever the cells' size
    /// against the triangles': random triangles of four patches, some sharing corners, give the
    /// pairs a test of every pair would, with cells from a tenth of a triangle to many.
    #[test]
    fn crossing_pairs_are_those_of_testing_every_pair() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut rnd = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut positions: Vec<[f64; 3]> = (0..300)
            .map(|_| [8.0 * rnd(), 8.0 * rnd(), 8.0 * rnd()])
            .collect();
        // Negative coordinates too (cells below zero).
        for p in positions.iter_mut().step_by(3) {
            p[1] -= 8.0;
        }
        let mut source: Vec<Vec<[u32; 3]>> = vec![Vec::new(); 4];
        for i in 0..240 {
            // Corners near each other (small triangles), from a shared pool of vertices.
            let a = (rnd() * 300.0) as u32 % 300;
            let mut t = [a, a, a];
            for c in &mut t[1..] {
                *c = (a + 1 + (rnd() * 20.0) as u32) % 300;
            }
            if t[1] != t[2] {
                source[i % 4].push(t);
            }
        }
        for corners in [false, true] {
            let mut every = Vec::new();
            for (pa, ta) in source.iter().enumerate() {
                for (pb, tb) in source.iter().enumerate().skip(pa + 1) {
                    for (i, &a) in ta.iter().enumerate() {
                        for (j, &b) in tb.iter().enumerate() {
                            if pair_crosses(a, b, &positions, corners) {
                                every.push(((pa as u32, i as u32), (pb as u32, j as u32)));
                            }
                        }
                    }
                }
            }
            every.sort_unstable();
            assert!(every.len() > 20, "{} crossing pairs", every.len());
            for cell_mm in [0.4, 1.3, 3.0, 20.0] {
                let all = vec![true; source.len()];
                assert_eq!(
                    crossing_pairs(&source, &positions, &all, cell_mm, corners),
                    every
                );
                // With one patch fresh: the pairs that have a triangle of it.
                let fresh = [false, true, false, false];
                let some: Vec<Pair> = every
                    .iter()
                    .copied()
                    .filter(|&((pa, _), (pb, _))| pa == 1 || pb == 1)
                    .collect();
                assert_eq!(
                    crossing_pairs(&source, &positions, &fresh, cell_mm, corners),
                    some
                );
            }
        }
    }

    /// Two bumpy sheets (two patches each) that cross in places, their vertices moved a few at a
    /// time: the live pairs are the full search's after every move, with and without the
    /// corner test.
    #[test]
    fn live_crossings_follow_moves_as_a_full_search_would() {
        let n = 14usize;
        let mut state = 0x2545_f491_4f6c_dd1d_u64;
        let mut rnd = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut positions = Vec::new();
        let mut source = vec![Vec::new(); 4];
        for sheet in 0..2 {
            let base = positions.len() as u32;
            for j in 0..n {
                for i in 0..n {
                    positions.push([i as f64, j as f64, 0.15 * sheet as f64 + 0.3 * rnd()]);
                }
            }
            let at = |i: usize, j: usize| base + (j * n + i) as u32;
            for j in 0..n - 1 {
                for i in 0..n - 1 {
                    let patch = 2 * sheet + usize::from(i >= n / 2);
                    source[patch].push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
                    source[patch].push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
                }
            }
        }
        let all = vec![true; source.len()];
        for corners in [false, true] {
            let mut pos = positions.clone();
            let mut live = LiveCrossings::new(&source, &pos, 2.5, corners);
            let first = crossing_pairs(&source, &pos, &all, 2.5, corners);
            assert!(!first.is_empty(), "the sheets cross");
            assert_eq!(live.pairs(), first);
            for _ in 0..40 {
                let moved: Vec<u32> = (0..5)
                    .map(|_| ((rnd() + 0.5) * pos.len() as f64) as u32 % pos.len() as u32)
                    .collect();
                for &v in &moved {
                    // Now and then far enough to change cells.
                    let reach = if rnd() > 0.3 { 3.0 } else { 0.4 };
                    for x in &mut pos[v as usize] {
                        *x += reach * rnd();
                    }
                }
                live.moved(&pos, &moved);
                assert_eq!(
                    live.pairs(),
                    crossing_pairs(&source, &pos, &all, 2.5, corners)
                );
            }
        }
    }
}
