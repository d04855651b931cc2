//! Step 5 of the family meshing (see [`super`]), for structures given as level sets: splitting
//! the edges whose midpoints lie off the surface and putting the new vertices on it.
//!
//! Extraction puts every vertex on the zero set, but a triangle between three surface points cuts
//! inside a convex surface: a tube 3 mm across on a 1.5 mm lattice loses 4-7 % of its volume
//! between its vertices (measured on the phantom's nerve roots), and decimation adds up to its
//! error bound. Here every edge inside a patch is tested at its midpoint: the midpoint is
//! projected onto the zero set of the patch's first owner (steps along the bound's gradient);
//! where it moved more than the tolerance (and more than [`MIN_SAGITTA_FRACTION`] of the edge)
//! the edge is split there, and the patch's triangles with split edges are subdivided (into two,
//! three or four). A split halves the chord, so its sagitta falls four-fold; rounds repeat on the
//! new edges.
//!
//! Only edges inside one patch are split (both their triangles in that patch and no other patch
//! using them): a shared patch is refined once for all its owners, and patch borders (junction
//! curves) keep their vertices, so touching structures still share their interface exactly.
//! Edges of triangles with a corner on a junction are split like the others: that is where a
//! thin layer's rim is, and leaving them cost the ligamentum flavum 1.2 % of its volume on the
//! default phantom; a split there that folds over a neighbour's triangle at that corner is
//! found by the corner test of the crossing checks and undone (see `mesh_family`). (Splitting
//! the junction edges themselves was tried: it changed no structure's volume by 0.1 %, and
//! where three surfaces meet it folded triangles that share the new vertex.)

use glam::DVec3;
use rustc_hash::FxHashMap;

use super::weld::Family;
use crate::anatomy::level_set_mesh::LevelSetFn;
use crate::par::par_map;

/// Step of the forward differences of the gradient, mm (well below any feature, well above the
/// rounding of the bounds' evaluation).
const GRADIENT_STEP_MM: f64 = 1e-4;

/// Largest steps per midpoint.
const PROJECTION_STEPS: usize = 6;

/// A projection is accepted when the bound is within this fraction of the tolerance of zero.
const ON_SURFACE_FRACTION: f64 = 0.05;

/// Smallest move of a midpoint, as a fraction of its edge, that splits the edge: the sagitta of
/// a chord of length `L` on a radius `R` is about `L^2 / 8R`, so this splits where `L > R / 3`
/// (thin tubes, sharp rims) and leaves long chords on gently curved surfaces, whose volume they
/// hardly change (simulator choice: on the default phantom 3.7 M triangles against 3.5 M at
/// 0.08, whose nerve roots lose 3-4 % instead of 2-3 %).
const MIN_SAGITTA_FRACTION: f64 = 0.04;

/// Largest move of a midpoint, as a fraction of its edge: a projection that goes farther has
/// jumped to another part of the surface (across a crease or a thin gap) and is not used.
const MAX_MOVE_FRACTION: f64 = 0.3;

/// The projection of `p` (where `f` is `g0`) onto the zero set of `f`: steps along the gradient
/// at `p` (forward differences, once; a chord method, which converges where the surface is
/// smooth on the scale of the step), accepted when within `on_surface` of the zero set and at
/// most `max_move` from `p`.
fn project(
    f: LevelSetFn<'_>,
    p: [f64; 3],
    g0: f64,
    on_surface: f64,
    max_move: f64,
) -> Option<[f64; 3]> {
    let grad: [f64; 3] = std::array::from_fn(|a| {
        let mut q = p;
        q[a] += GRADIENT_STEP_MM;
        (f(q) - g0) / GRADIENT_STEP_MM
    });
    let n2: f64 = grad.iter().map(|x| x * x).sum();
    if n2.is_nan() || n2 <= 1e-12 || !n2.is_finite() {
        return None;
    }
    let mut q = p;
    let mut g = g0;
    for _ in 0..PROJECTION_STEPS {
        q = std::array::from_fn(|a| q[a] - g * grad[a] / n2);
        g = f(q);
        if g.abs() <= on_surface {
            return (dist(p, q) <= max_move).then_some(q);
        }
    }
    None
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

/// Edges per parallel job.
const CHUNK: usize = 4096;

/// Least cosine between a split's move and the edge's normal (outward where the midpoint is
/// inside, inward where it is outside): a projection that leaves sideways or backwards has found
/// another sheet of the surface (the other face of a layer thinner than the move) and is not
/// used (simulator choice: 60 degrees; a chord's sagitta points along the normal).
const MIN_MOVE_COSINE: f64 = 0.5;

/// Where to split the edge `pa -> pb` on the zero set of `f`, if its midpoint lies farther than
/// `tolerance_mm` (and than [`MIN_SAGITTA_FRACTION`] of the edge) from it, moving along the edge's
/// outward normal `normal` (any length) where the midpoint is inside and against it where outside.
fn split_point(
    f: LevelSetFn<'_>,
    pa: [f64; 3],
    pb: [f64; 3],
    normal: DVec3,
    tolerance_mm: f64,
) -> Option<[f64; 3]> {
    let mid: [f64; 3] = std::array::from_fn(|k| 0.5 * (pa[k] + pb[k]));
    // The bound is at most the distance: a midpoint where it is within the tolerance is taken
    // as close enough without projecting it (for a bound that underestimates the distance this
    // accepts a little more).
    let g = f(mid);
    if g.abs() <= tolerance_mm {
        return None;
    }
    let len = dist(pa, pb);
    let on_surface = ON_SURFACE_FRACTION * tolerance_mm;
    project(f, mid, g, on_surface, MAX_MOVE_FRACTION * len).filter(|&q| {
        let d = dist(q, mid);
        let along = -g.signum() * (DVec3::from(q) - DVec3::from(mid)).dot(normal);
        d > tolerance_mm
            && d > MIN_SAGITTA_FRACTION * len
            && along >= MIN_MOVE_COSINE * d * normal.length()
    })
}

/// What one call of [`refine_family`] did.
pub(super) struct Refined {
    /// Positions: the family's, then the new vertices.
    pub(super) positions: Vec<[f64; 3]>,
    /// Triangles per patch.
    pub(super) triangles: Vec<Vec<[u32; 3]>>,
    /// Edges split.
    pub(super) splits: usize,
    /// Per new vertex (in order, from the family's vertex count on), the ends of the edge it
    /// split.
    pub(super) parents: Vec<(u32, u32)>,
}

/// Refines the patches `source` (triangles per patch, on `fam.positions`) whose first owner has a
/// level set, in up to `rounds` rounds, splitting edges whose midpoint is more than
/// `tolerance_mm` off the surface.
pub(super) fn refine_family(
    fam: &Family,
    source: &[Vec<[u32; 3]>],
    level_sets: &[Option<LevelSetFn<'_>>],
    tolerance_mm: f64,
    rounds: usize,
) -> Refined {
    let level_set_of = |p: usize| {
        fam.patches[p]
            .owners
            .first()
            .and_then(|&(m, _)| level_sets.get(m as usize).copied().flatten())
    };
    refine_patches(
        &fam.positions,
        source,
        &level_set_of,
        tolerance_mm,
        rounds,
        false,
    )
}

/// [`refine_family`] on `positions` with the level set of each patch from `level_set_of`; with
/// `every_edge_each_round`, each round looks at every triangle again (the reference the rounds'
/// shortcut is tested against).
fn refine_patches<'a>(
    positions: &[[f64; 3]],
    source: &[Vec<[u32; 3]>],
    level_set_of: &(dyn Fn(usize) -> Option<LevelSetFn<'a>> + Sync),
    tolerance_mm: f64,
    rounds: usize,
    every_edge_each_round: bool,
) -> Refined {
    let mut positions = positions.to_vec();
    let mut triangles: Vec<Vec<[u32; 3]>> = source.to_vec();
    let mut splits = 0;
    let mut parents = Vec::new();
    // Edges tested and found close enough; they stay so until split, which they never are.
    // The edges of pillows are never split either (see [`pillow_edges`]).
    let mut settled: rustc_hash::FxHashSet<(u32, u32)> =
        triangles.iter().flat_map(|t| pillow_edges(t)).collect();
    // The first vertex made by the last round (every vertex before the first round). A round
    // can only split an edge with a vertex the last one made: an edge between older vertices
    // has the users it had in the last round (a subdivision keeps each unsplit edge in one
    // child), so it was tested then and settled, or split and gone, or is not used twice by one
    // patch (a junction, a non-manifold edge) and still is not. The triangles of a new vertex are
    // all new ones, so later rounds look at the last round's triangles alone.
    let mut made_from: u32 = 0;
    for _ in 0..rounds {
        let made = |t: &[u32; 3]| t.iter().any(|&v| v >= made_from);
        // Every edge inside one patch (used twice by it and by no other patch), with that
        // patch and the sum of its triangles' normals, in a deterministic order.
        let mut users: FxHashMap<(u32, u32), (usize, u32, DVec3)> = FxHashMap::default();
        for (p, tris) in triangles.iter().enumerate() {
            for t in tris.iter().filter(|t| made(t)) {
                // Twice the area vector: outward as the patch's first owner holds the triangle.
                let [x, y, z] = t.map(|v| DVec3::from(positions[v as usize]));
                let n = (y - x).cross(z - x);
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    if a.max(b) < made_from {
                        continue;
                    }
                    let e = users
                        .entry((a.min(b), a.max(b)))
                        .or_insert((p, 0, DVec3::ZERO));
                    e.1 = if e.0 == p && e.1 != u32::MAX {
                        e.1 + 1
                    } else {
                        u32::MAX
                    };
                    e.2 += n;
                }
            }
        }
        let mut edges: Vec<((u32, u32), usize, DVec3)> = users
            .into_iter()
            .filter(|(e, (_, n, _))| *n == 2 && !settled.contains(e))
            .map(|(e, (p, _, n))| (e, p, n))
            .collect();
        edges.sort_unstable_by_key(|&(e, p, _)| (e, p));
        let pos = &positions;
        let chunks = edges.len().div_ceil(CHUNK).max(1);
        let found: Vec<Vec<Option<[f64; 3]>>> = par_map(
            chunks,
            &|c| {
                edges[(c * CHUNK).min(edges.len())..((c + 1) * CHUNK).min(edges.len())]
                    .iter()
                    .map(|&((a, b), p, n)| {
                        let f = level_set_of(p)?;
                        split_point(f, pos[a as usize], pos[b as usize], n, tolerance_mm)
                    })
                    .collect()
            },
            &mut |_| {},
        );
        let mut mid_of: FxHashMap<(u32, u32), u32> = FxHashMap::default();
        let next_from = positions.len() as u32;
        for (&(e, _, _), q) in edges.iter().zip(found.into_iter().flatten()) {
            match q {
                Some(q) => {
                    positions.push(q);
                    parents.push(e);
                    mid_of.insert(e, (positions.len() - 1) as u32);
                    splits += 1;
                }
                None => {
                    settled.insert(e);
                }
            }
        }
        if mid_of.is_empty() {
            break;
        }
        for tris in &mut triangles {
            let old = std::mem::take(tris);
            for t in old {
                if made(&t) {
                    subdivide(t, &mid_of, &positions, tris);
                } else {
                    tris.push(t);
                }
            }
        }
        if !every_edge_each_round {
            made_from = next_from;
        }
    }
    Refined {
        positions,
        triangles,
        splits,
        parents,
    }
}

/// The edges of the pillows among `triangles`: two triangles on the same three corners with
/// opposite windings, a closed sheet of no volume that extraction or decimation can leave where a
/// surface pinches (seen on the 3 mm phantom's L5 cortex and cancellous bone). Splitting an edge
/// of a pillow joins the new vertex to the same apex from both sides, so the edge from it to the
/// apex would be used by four triangles.
fn pillow_edges(triangles: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut seen: FxHashMap<[u32; 3], usize> = FxHashMap::default();
    for t in triangles {
        let mut key = *t;
        key.sort_unstable();
        *seen.entry(key).or_insert(0) += 1;
    }
    let mut edges: Vec<(u32, u32)> = seen
        .into_iter()
        .filter(|&(_, n)| n >= 2)
        .flat_map(|([a, b, c], _)| [(a, b), (b, c), (a, c)])
        .collect();
    edges.sort_unstable();
    edges
}

/// Appends the subdivision of triangle `t` by the new vertices on its split edges.
fn subdivide(
    t: [u32; 3],
    mid_of: &FxHashMap<(u32, u32), u32>,
    positions: &[[f64; 3]],
    out: &mut Vec<[u32; 3]>,
) {
    let mid = |k: usize| {
        let (a, b) = (t[k], t[(k + 1) % 3]);
        mid_of.get(&(a.min(b), a.max(b))).copied()
    };
    let m = [mid(0), mid(1), mid(2)];
    match m.iter().filter(|x| x.is_some()).count() {
        0 => out.push(t),
        1 => {
            // Edge k (t[k] -> t[k+1]) split at x: two triangles through the opposite corner.
            let k = m.iter().position(Option::is_some).unwrap_or(0);
            let x = m[k].unwrap_or(t[k]);
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            out.push([a, x, c]);
            out.push([x, b, c]);
        }
        2 => {
            // The unsplit edge k: t[k] -> t[k+1]; the corner c = t[k+2] is cut off by the two
            // new vertices, and the quad left is split along its shorter diagonal.
            let k = m.iter().position(Option::is_none).unwrap_or(0);
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            let (Some(xb), Some(xc)) = (m[(k + 1) % 3], m[(k + 2) % 3]) else {
                out.push(t);
                return;
            };
            // xb on b -> c, xc on c -> a.
            out.push([xc, xb, c]);
            let d1 = dist(positions[a as usize], positions[xb as usize]);
            let d2 = dist(positions[b as usize], positions[xc as usize]);
            if d1 <= d2 {
                out.push([a, b, xb]);
                out.push([a, xb, xc]);
            } else {
                out.push([a, b, xc]);
                out.push([b, xb, xc]);
            }
        }
        _ => {
            let (x0, x1, x2) = (
                m[0].unwrap_or(t[0]),
                m[1].unwrap_or(t[1]),
                m[2].unwrap_or(t[2]),
            );
            out.push([t[0], x0, x2]);
            out.push([x0, t[1], x1]);
            out.push([x2, x1, t[2]]);
            out.push([x0, x1, x2]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An icosahedron on the sphere of radius `r` about the origin: vertices and outward faces.
    fn icosahedron(r: f64) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let phi = 0.5 * (1.0 + 5f64.sqrt());
        let mut v = Vec::new();
        for (a, b) in [(1.0, phi), (-1.0, phi), (1.0, -phi), (-1.0, -phi)] {
            v.extend([[0.0, a, b], [a, b, 0.0], [b, 0.0, a]]);
        }
        let v: Vec<DVec3> = v
            .into_iter()
            .map(|p| DVec3::from(p).normalize() * r)
            .collect();
        let edge = (v[0] - v[1]).length().min((v[0] - v[2]).length());
        let near = |i: usize, j: usize| (v[i] - v[j]).length() < 1.01 * edge;
        let mut faces = Vec::new();
        for i in 0..12 {
            for j in i + 1..12 {
                for k in j + 1..12 {
                    if near(i, j) && near(j, k) && near(i, k) {
                        let n = (v[j] - v[i]).cross(v[k] - v[i]);
                        let t = [i as u32, j as u32, k as u32];
                        faces.push(if n.dot(v[i]) > 0.0 {
                            t
                        } else {
                            [t[0], t[2], t[1]]
                        });
                    }
                }
            }
        }
        (v.iter().map(DVec3::to_array).collect(), faces)
    }

    /// The shortcut of later rounds (only the last round's triangles, only edges with a new
    /// vertex) refines exactly as looking at every triangle each round would, on a family with
    /// junctions: an icosahedron on a sphere of 10 mm in two patches, and its mirror image that
    /// touches it along one edge, a third patch without a level set (never refined). That edge
    /// is used by two triangles of each body; once the first body's two are subdivided at their
    /// other edges, the last round's triangles alone use it twice.
    #[test]
    fn later_rounds_refine_as_a_full_rescan_would() {
        let r = 10.0;
        let (mut positions, a_faces) = icosahedron(r);
        // The shared edge: the highest one; the second body is the first mirrored in the plane
        // that touches the first along it.
        let mid = |t: [u32; 3], k: usize| {
            (DVec3::from(positions[t[k] as usize])
                + DVec3::from(positions[t[(k + 1) % 3] as usize]))
                * 0.5
        };
        let (t, k) = a_faces
            .iter()
            .flat_map(|&t| (0..3).map(move |k| (t, k)))
            .max_by(|x, y| mid(x.0, x.1).z.total_cmp(&mid(y.0, y.1).z))
            .expect("faces");
        let (ea, eb) = (t[k], t[(k + 1) % 3]);
        let m = mid(t, k);
        let n = m.normalize();
        let mirror = |p: DVec3| p - 2.0 * (p - m).dot(n) * n;
        let base = positions.len() as u32;
        let map: Vec<u32> = (0..12u32)
            .map(|i| if i == ea || i == eb { i } else { base + i })
            .collect();
        for i in 0..12 {
            positions.push(mirror(DVec3::from(positions[i])).to_array());
        }
        // Mirroring turns the winding over.
        let b_faces: Vec<[u32; 3]> = a_faces
            .iter()
            .map(|t| [map[t[0] as usize], map[t[2] as usize], map[t[1] as usize]])
            .collect();
        let centroid_z = |t: &[u32; 3]| t.iter().map(|&v| positions[v as usize][2]).sum::<f64>();
        let (upper, lower): (Vec<[u32; 3]>, Vec<[u32; 3]>) =
            a_faces.iter().partition(|t| centroid_z(t) > 0.0);
        let source = vec![upper, lower, b_faces];
        let sphere = move |p: [f64; 3]| DVec3::from(p).length() - r;
        let level_set_of = |p: usize| -> Option<LevelSetFn<'_>> { (p < 2).then_some(&sphere) };
        let fast = refine_patches(&positions, &source, &level_set_of, 0.06, 5, false);
        let full = refine_patches(&positions, &source, &level_set_of, 0.06, 5, true);
        let shared = |tris: &[Vec<[u32; 3]>]| {
            tris.iter()
                .flatten()
                .filter(|t| t.contains(&ea) && t.contains(&eb))
                .count()
        };
        assert_eq!(shared(&source), 4);
        assert_eq!(shared(&full.triangles), 4, "a junction edge is never split");
        // More splits than the first round can make (the first body's patches have 30 edges
        // less their junction).
        assert!(full.splits > 30, "{} splits", full.splits);
        assert_eq!(fast.splits, full.splits);
        assert_eq!(fast.parents, full.parents);
        assert_eq!(fast.triangles, full.triangles);
        let bits = |p: &[[f64; 3]]| p.iter().map(|q| q.map(f64::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(&fast.positions), bits(&full.positions));
    }

    #[test]
    fn a_pillow_keeps_its_edges_and_other_triangles_do_not() {
        // A tetrahedron (no pillow) beside a pillow on corners 4, 5, 6.
        let tets = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]];
        assert!(pillow_edges(&tets).is_empty());
        let mut tris = tets.to_vec();
        tris.extend([[4, 5, 6], [5, 4, 6]]);
        assert_eq!(pillow_edges(&tris), vec![(4, 5), (4, 6), (5, 6)]);
        // Why: splitting edge 4-5 of the pillow at 7 uses edge 7-6 four times.
        let mid_of: FxHashMap<(u32, u32), u32> = [((4, 5), 7)].into_iter().collect();
        let positions = vec![[0.0; 3]; 8];
        let mut out = Vec::new();
        for t in [[4, 5, 6], [5, 4, 6]] {
            subdivide(t, &mid_of, &positions, &mut out);
        }
        let uses = out
            .iter()
            .filter(|t| t.contains(&7) && t.contains(&6))
            .count();
        assert_eq!(uses, 4);
    }
}
