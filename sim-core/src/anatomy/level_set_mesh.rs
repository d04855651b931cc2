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
//! without evaluating it).
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

/// [`sample_level_set`], also returning the bound itself at every point it evaluated (NaN at
/// the points of settled blocks), so that extraction need not evaluate the ends of its edges
/// again.
fn sample_bound(f: LevelSetFn<'_>, grid: &VolumeGrid) -> (Vec<f32>, Vec<f64>, usize) {
    let [nx, ny, nz] = grid.dims;
    let h = grid.min_spacing_mm();
    let mut values = vec![0f32; grid.len()];
    let mut bound = vec![f64::NAN; grid.len()];
    let mut evals = 0;
    for bk in (0..nz).step_by(BLOCK) {
        let ek = (bk + BLOCK).min(nz);
        for bj in (0..ny).step_by(BLOCK) {
            let ej = (bj + BLOCK).min(ny);
            for bi in (0..nx).step_by(BLOCK) {
                let ei = (bi + BLOCK).min(nx);
                let lo = grid.voxel_center_mm(bi, bj, bk);
                let hi = grid.voxel_center_mm(ei - 1, ej - 1, ek - 1);
                let c: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
                let reach = 0.5 * (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
                let gc = f(c);
                evals += 1;
                let settled = if gc > reach {
                    Some(0.0)
                } else if gc < -reach {
                    Some(1.0)
                } else {
                    None
                };
                for k in bk..ek {
                    for j in bj..ej {
                        for i in bi..ei {
                            let idx = grid.index(i, j, k);
                            values[idx] = match settled {
                                Some(v) => v,
                                None => {
                                    evals += 1;
                                    let g = f(grid.voxel_center_mm(i, j, k));
                                    bound[idx] = g;
                                    field_value(g, h)
                                }
                            };
                        }
                    }
                }
            }
        }
    }
    (values, bound, evals)
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
