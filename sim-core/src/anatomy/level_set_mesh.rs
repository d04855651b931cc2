//! Extraction from a signed distance bound instead of an occupancy mask: the lattice is sampled
//! from the bound itself and every vertex is moved onto its zero set along its lattice edge.
//!
//! A mask's 0.5 level, interpolated linearly between voxel centres, is only where the surface is
//! when the occupancy is linear along the edge; a layer thinner than a few voxels (a ligament,
//! a nerve root, a cortical shell) has a tent-shaped distance across it, whose linear
//! interpolation puts both faces inside the layer and loses a third or more of its volume on a
//! 3 mm grid. Here the sign at every lattice point comes from the bound, and each crossing is
//! found by bracketed root finding (Illinois regula falsi) on the bound along the edge, so
//! every vertex lies on the surface to 1e-6 of an edge. What a lattice cannot show (a layer that
//! passes between two lattice points without containing either) stays unseen: a finer mesh
//! lattice (`PipelineParams::upsample`) is the remedy, and it costs what the finer grid costs
//! only near surfaces (whole 8^3 blocks the bound shows to be inside or outside are filled
//! without evaluating it, and the 4^3 and 2^3 sub-blocks of the others whose every point it
//! shows to be beyond the clamp band).
//!
//! The lattice is the one the mask path up-samples to (fine sample `i'` of a box of coarse voxels
//! at coarse index `(i' + 0.5) / u - 0.5`), so a structure meshed from its bound and one meshed
//! from its mask key their crossings on the same lattice edges.

use crate::mesh::TriMesh;
use crate::volume::VolumeGrid;

use super::mesher::{EdgeCrossing, ScalarField, extract_isosurface_keyed};

/// A structure's signed distance bound in the region's model frame, mm: negative inside, zero on
/// its surface, and 1-Lipschitz (`|f(p) - f(q)| <= |p - q|`), so that a whole block of the
/// lattice can be settled from one value at its centre.
pub type LevelSetFn<'a> = &'a (dyn Fn([f64; 3]) -> f64 + Sync);

/// Edge of the blocks the sampling settles whole, in lattice points.
const BLOCK: usize = 8;

/// Largest number of root-finding steps per vertex (Illinois converges super-linearly; a
/// bisection alone would reach 1e-6 of an edge in 20).
const MAX_STEPS: usize = 60;

/// Relative width of the bracket, as a fraction of the edge, at which a root is accepted.
const ROOT_TOLERANCE: f64 = 1e-7;

/// The field value of a lattice point at signed distance `g`: an occupancy-like
/// `clamp(1/2 - g / h, 0, 1)` whose 0.5 level is the bound's zero set (strictly above 0.5 inside,
/// at most 0.5 outside, whatever the rounding to `f32`).
fn field_value(g: f64, h: f64) -> f32 {
    let v = (0.5 - g / h).clamp(0.0, 1.0) as f32;
    if g < 0.0 {
        v.max(f32::from_bits(0.5f32.to_bits() + 1))
    } else {
        v.min(0.5)
    }
}

/// Samples `f` on `grid` (lattice points at voxel centres) into field values, settling whole
/// blocks by the Lipschitz bound. Returns the values and the number of evaluations.
pub fn sample_level_set(f: LevelSetFn<'_>, grid: &VolumeGrid) -> (Vec<f32>, usize) {
    let (values, _, evals) = sample_bound(f, grid);
    (values, evals)
}

/// Margin beyond which a sub-block's points are certain to be outside the clamp band, mm: far
/// above the rounding of the bound and of the distances in the box (about 1e-13 mm for
/// coordinates within a metre), far below any feature.
const SETTLE_MARGIN_MM: f64 = 1e-9;

/// [`sample_level_set`], also returning the bound itself at every point it evaluated (NaN at
/// the points of settled blocks), so that extraction need not evaluate the ends of its edges
/// again.
///
/// A block of [`BLOCK`]^3 points is settled (every value 0 or 1) when its centre's bound exceeds
/// the block's half-diagonal. A block that is not is sampled in sub-blocks of half the edge, down
/// to 2^3, each settled only where every point of it lies beyond the clamp band (bound at least
/// half a spacing from zero), so that its values are exactly those that evaluating each point
/// gives ([`Sampled::sample_blocks`]).
fn sample_bound(f: LevelSetFn<'_>, grid: &VolumeGrid) -> (Vec<f32>, Vec<f64>, usize) {
    let mut out = Sampled {
        values: vec![0f32; grid.len()],
        bound: vec![f64::NAN; grid.len()],
        evals: 0,
        h: grid.min_spacing_mm(),
    };
    out.sample_blocks(f, grid, [0; 3], grid.dims, BLOCK, true);
    (out.values, out.bound, out.evals)
}

/// The sampling's output: field values, the bound where evaluated, evaluations made; and the
/// lattice's smallest spacing `h`, mm (the clamp band of [`field_value`]).
struct Sampled {
    values: Vec<f32>,
    bound: Vec<f64>,
    evals: usize,
    h: f64,
}

impl Sampled {
    /// The bound at the centre of the box of points `lo..hi` (exclusive) and the box's
    /// half-diagonal, mm.
    fn centre(
        &mut self,
        f: LevelSetFn<'_>,
        grid: &VolumeGrid,
        lo: [usize; 3],
        hi: [usize; 3],
    ) -> (f64, f64) {
        let a = grid.voxel_center_mm(lo[0], lo[1], lo[2]);
        let b = grid.voxel_center_mm(hi[0] - 1, hi[1] - 1, hi[2] - 1);
        let c: [f64; 3] = std::array::from_fn(|k| 0.5 * (a[k] + b[k]));
        let reach = 0.5 * (0..3).map(|k| (b[k] - a[k]).powi(2)).sum::<f64>().sqrt();
        self.evals += 1;
        (f(c), reach)
    }

    /// Sets the value of every point of `lo..hi` to `v`.
    fn fill(&mut self, grid: &VolumeGrid, lo: [usize; 3], hi: [usize; 3], v: f32) {
        for k in lo[2]..hi[2] {
            for j in lo[1]..hi[1] {
                for i in lo[0]..hi[0] {
                    self.values[grid.index(i, j, k)] = v;
                }
            }
        }
    }

    /// Samples the points `lo..hi` in blocks of `size` points a side. A block is filled with 0
    /// or 1 where its centre's bound exceeds its half-diagonal: by nothing more for the
    /// `outermost` blocks, and by half a spacing (and [`SETTLE_MARGIN_MM`]) for the sub-blocks,
    /// whose every point is then beyond the clamp band of [`field_value`]. A block that is not
    /// filled is sampled in sub-blocks of half the size, and below 2 (or a single point of a
    /// sub-block) point by point.
    fn sample_blocks(
        &mut self,
        f: LevelSetFn<'_>,
        grid: &VolumeGrid,
        lo: [usize; 3],
        hi: [usize; 3],
        size: usize,
        outermost: bool,
    ) {
        let margin = if outermost {
            0.0
        } else {
            0.5 * self.h + SETTLE_MARGIN_MM
        };
        for k in (lo[2]..hi[2]).step_by(size) {
            for j in (lo[1]..hi[1]).step_by(size) {
                for i in (lo[0]..hi[0]).step_by(size) {
                    let s = [i, j, k];
                    let e: [usize; 3] = std::array::from_fn(|a| (s[a] + size).min(hi[a]));
                    let points: usize = (0..3).map(|a| e[a] - s[a]).product();
                    if outermost || (size >= 2 && points > 1) {
                        let (g, reach) = self.centre(f, grid, s, e);
                        if g > reach + margin {
                            self.fill(grid, s, e, 0.0);
                            continue;
                        }
                        if g < -(reach + margin) {
                            self.fill(grid, s, e, 1.0);
                            continue;
                        }
                        if size > 2 {
                            self.sample_blocks(f, grid, s, e, size / 2, false);
                            continue;
                        }
                    }
                    for kk in s[2]..e[2] {
                        for jj in s[1]..e[1] {
                            for ii in s[0]..e[0] {
                                let idx = grid.index(ii, jj, kk);
                                self.evals += 1;
                                let g = f(grid.voxel_center_mm(ii, jj, kk));
                                self.bound[idx] = g;
                                self.values[idx] = field_value(g, self.h);
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The zero of `f` on the segment `a -> b` where `fa = f(a)` and `fb = f(b)` have opposite signs,
/// as the fraction `t` of the segment from `a` (Illinois regula falsi: the false-position step,
/// halving the weight of an end kept twice in a row).
pub fn root_on_segment(f: LevelSetFn<'_>, a: [f64; 3], b: [f64; 3], fa: f64, fb: f64) -> f64 {
    let (mut t0, mut t1, mut f0, mut f1) = (0.0f64, 1.0f64, fa, fb);
    let mut side = 0i8;
    for _ in 0..MAX_STEPS {
        if t1 - t0 <= ROOT_TOLERANCE {
            break;
        }
        let mut t = (t0 * f1 - t1 * f0) / (f1 - f0);
        if !t.is_finite() || t <= t0 || t >= t1 {
            t = 0.5 * (t0 + t1);
        }
        let p: [f64; 3] = std::array::from_fn(|k| a[k] + t * (b[k] - a[k]));
        let ft = f(p);
        if ft == 0.0 {
            return t;
        }
        if (ft < 0.0) == (f0 < 0.0) {
            t0 = t;
            f0 = ft;
            if side == -1 {
                f1 *= 0.5;
            }
            side = -1;
        } else {
            t1 = t;
            f1 = ft;
            if side == 1 {
                f0 *= 0.5;
            }
            side = 1;
        }
    }
    if f0.abs() < f1.abs() { t0 } else { t1 }
}

/// What [`extract_level_set`] gives.
#[derive(Debug, Clone)]
pub struct LevelSetSurface {
    /// The mesh, every vertex on the zero set.
    pub mesh: TriMesh,
    /// Per vertex, its lattice edge ([`extract_isosurface_keyed`]'s crossings, `s` the root).
    pub crossings: Vec<EdgeCrossing>,
    /// Per vertex, where the linear interpolation of the sampled field values puts it: the
    /// positions whose surfaces cannot cross another structure's (two disjoint structures'
    /// values sum to at most one, as two occupancies do), to fall back on where the exact ones
    /// would (see `interfaces`).
    pub interpolated_mm: Vec<[f64; 3]>,
    /// Bound evaluations made to sample the lattice and to bracket the roots (not counting the
    /// root steps).
    pub evaluations: usize,
}

/// Extracts the zero set of `f` on `grid` (a box of the region's fine lattice, whose outermost
/// points must be outside) and places every vertex on it. `None` when a point on the box's faces
/// is inside.
pub fn extract_level_set(f: LevelSetFn<'_>, grid: &VolumeGrid) -> Option<LevelSetSurface> {
    let (values, bound, mut evals) = sample_bound(f, grid);
    let (mut mesh, mut crossings) = extract_isosurface_keyed(
        &ScalarField {
            grid: *grid,
            values: &values,
        },
        0.5,
        1,
    )?;
    let interpolated_mm = mesh.vertices_mm.clone();
    for (v, c) in mesh.vertices_mm.iter_mut().zip(crossings.iter_mut()) {
        let upper = [
            c.lower[0] + usize::from(c.axes & 1),
            c.lower[1] + usize::from((c.axes >> 1) & 1),
            c.lower[2] + usize::from((c.axes >> 2) & 1),
        ];
        let a = grid.voxel_center_mm(c.lower[0], c.lower[1], c.lower[2]);
        let b = grid.voxel_center_mm(upper[0], upper[1], upper[2]);
        // The samples' signs are the bound's; the field values hold it only within the clamp
        // band, so the ends take the bound kept by the sampling, or are evaluated again where a
        // settled block kept none.
        let mut end = |p: [f64; 3], i: [usize; 3]| {
            let g = bound[grid.index(i[0], i[1], i[2])];
            if g.is_nan() {
                evals += 1;
                f(p)
            } else {
                g
            }
        };
        let (fa, fb) = (end(a, c.lower), end(b, upper));
        if (fa < 0.0) == (fb < 0.0) {
            continue;
        }
        let t = root_on_segment(f, a, b, fa, fb).clamp(1e-3, 1.0 - 1e-3);
        *v = std::array::from_fn(|k| a[k] + t * (b[k] - a[k]));
        c.s = t;
    }
    Some(LevelSetSurface {
        mesh,
        crossings,
        interpolated_mm,
        evaluations: evals,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_vertex_lies_on_the_zero_set() {
        let sphere = |p: [f64; 3]| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 7.3;
        let LevelSetSurface {
            mesh, crossings, ..
        } = extract_level_set(&sphere, &VolumeGrid::centred_cube(14, 1.5)).unwrap();
        assert!(mesh.topology_report().is_closed_and_consistent());
        assert_eq!(mesh.vertices_mm.len(), crossings.len());
        for v in &mesh.vertices_mm {
            assert!(sphere(*v).abs() < 1e-5, "{v:?}: {}", sphere(*v));
        }
    }

    #[test]
    fn a_sheet_thinner_than_the_lattice_keeps_its_thickness() {
        // A 2.2 mm slab (a tent-shaped distance across it) on a 1.5 mm lattice: its faces are
        // meshed where they are, so the enclosed volume is the slab's within the rounded rim.
        let slab = |p: [f64; 3]| {
            let q = [p[0].abs() - 1.1, p[1].abs() - 8.0, p[2].abs() - 8.0];
            let out = q.iter().map(|x| x.max(0.0).powi(2)).sum::<f64>().sqrt();
            out + q[0].max(q[1]).max(q[2]).min(0.0)
        };
        let mesh = extract_level_set(&slab, &VolumeGrid::centred_cube(20, 1.5))
            .unwrap()
            .mesh;
        let v = mesh.signed_volume_mm3();
        let exact = 2.2 * 16.0 * 16.0;
        // The box's edges and corners are chamfered by the lattice (16 mm edges, 1.5 mm
        // spacing); the faces themselves are exact: within 6 %.
        assert!((v - exact).abs() < 0.06 * exact, "{v} vs {exact}");
        for p in &mesh.vertices_mm {
            assert!(slab(*p).abs() < 1e-5);
        }
    }

    /// The sub-blocks settle only points whose own value is 0 or 1: the values are those of
    /// evaluating every point of each block that is not settled whole, on shapes with thin parts
    /// (a slab thinner than the lattice, a thin tube) and off-centre lattices, with fewer
    /// evaluations.
    #[test]
    fn sub_blocks_settle_only_what_evaluating_each_point_would() {
        fn every_point(f: LevelSetFn<'_>, grid: &VolumeGrid) -> (Vec<f32>, usize) {
            let [nx, ny, nz] = grid.dims;
            let h = grid.min_spacing_mm();
            let mut values = vec![0f32; grid.len()];
            let mut evals = 0;
            for bk in (0..nz).step_by(BLOCK) {
                for bj in (0..ny).step_by(BLOCK) {
                    for bi in (0..nx).step_by(BLOCK) {
                        let e = [
                            (bi + BLOCK).min(nx),
                            (bj + BLOCK).min(ny),
                            (bk + BLOCK).min(nz),
                        ];
                        let lo = grid.voxel_center_mm(bi, bj, bk);
                        let hi = grid.voxel_center_mm(e[0] - 1, e[1] - 1, e[2] - 1);
                        let c: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
                        let reach =
                            0.5 * (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
                        let gc = f(c);
                        evals += 1;
                        for k in bk..e[2] {
                            for j in bj..e[1] {
                                for i in bi..e[0] {
                                    values[grid.index(i, j, k)] = if gc > reach {
                                        0.0
                                    } else if gc < -reach {
                                        1.0
                                    } else {
                                        evals += 1;
                                        field_value(f(grid.voxel_center_mm(i, j, k)), h)
                                    };
                                }
                            }
                        }
                    }
                }
            }
            (values, evals)
        }
        let slab = |p: [f64; 3]| {
            let q = [p[0].abs() - 0.7, p[1].abs() - 11.0, p[2].abs() - 9.0];
            let out = q.iter().map(|x| x.max(0.0).powi(2)).sum::<f64>().sqrt();
            out + q[0].max(q[1]).max(q[2]).min(0.0)
        };
        let tube = |p: [f64; 3]| (p[0] * p[0] + (p[1] - 0.4) * (p[1] - 0.4)).sqrt() - 1.3;
        let ball = |p: [f64; 3]| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 13.7;
        let shapes: [LevelSetFn<'_>; 3] = [&slab, &tube, &ball];
        for (n, spacing) in [(37usize, 0.75), (30, 1.5), (19, 1.1)] {
            let mut grid = VolumeGrid::centred_cube(n, spacing);
            grid.origin_mm = grid.origin_mm.map(|o| o + 0.31 * spacing);
            for f in shapes {
                let (values, evals) = sample_level_set(f, &grid);
                let (reference, reference_evals) = every_point(f, &grid);
                let differ: Vec<usize> = (0..values.len())
                    .filter(|&i| values[i].to_bits() != reference[i].to_bits())
                    .collect();
                assert!(
                    differ.is_empty(),
                    "{n} x {spacing} mm: {} points differ, first {:?}",
                    differ.len(),
                    differ
                        .first()
                        .map(|&i| (grid.ijk(i), values[i], reference[i]))
                );
                assert!(evals < reference_evals, "{evals} vs {reference_evals}");
            }
        }
    }

    #[test]
    fn the_sampling_settles_blocks_only_where_the_bound_allows() {
        let sphere = |p: [f64; 3]| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 20.0;
        let g = VolumeGrid::centred_cube(40, 1.5);
        let (values, evals) = sample_level_set(&sphere, &g);
        assert!(evals < g.len() / 2, "{evals} of {}", g.len());
        for (idx, &v) in values.iter().enumerate() {
            let [i, j, k] = g.ijk(idx);
            let inside = sphere(g.voxel_center_mm(i, j, k)) < 0.0;
            assert_eq!(v > 0.5, inside, "{i} {j} {k}");
        }
    }
}
