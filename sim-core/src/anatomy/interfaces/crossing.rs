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

/// Pairs of triangles from different patches that cross each other (see [`triangles_cross`]),
/// as `(patch, triangle index)` pairs, sorted. Only pairs with at least one triangle from a
/// patch in `fresh` are tested; triangles sharing a vertex are not compared (they meet at it).
pub(super) fn crossing_pairs(
    source: &[Vec<[u32; 3]>],
    positions: &[[f64; 3]],
    fresh: &[bool],
    cell_mm: f64,
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
