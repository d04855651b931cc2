//! Finding surfaces that cross each other after smoothing or decimation, and the locks that back
//! off around a crossing.

use rustc_hash::FxHashMap;

use glam::DVec3;

use super::par::par_map;
use super::weld::Family;

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
) -> Vec<((u32, u32), (u32, u32))> {
    let mut tris: Vec<(u32, u32)> = Vec::new();
    let mut boxes: Vec<([f64; 3], [f64; 3])> = Vec::new();
    let mut cells: FxHashMap<[i64; 3], Vec<u32>> = FxHashMap::default();
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
                        let shared = a.iter().filter(|v| b.contains(v)).count();
                        let crosses = match shared {
                            0 => triangles_cross(
                                a.map(|g| positions[g as usize]),
                                b.map(|g| positions[g as usize]),
                            ),
                            1 if corners => {
                                let s = a.iter().position(|v| b.contains(v)).unwrap_or(0);
                                let r = b.iter().position(|&v| v == a[s]).unwrap_or(0);
                                corner_sharing_triangles_cross(
                                    [a[s], a[(s + 1) % 3], a[(s + 2) % 3]]
                                        .map(|g| positions[g as usize]),
                                    [b[r], b[(r + 1) % 3], b[(r + 2) % 3]]
                                        .map(|g| positions[g as usize]),
                                )
                            }
                            _ => false,
                        };
                        if crosses {
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
}
