//! Painting implicit solids into a label grid, and the CT underlay made from it.
//!
//! The grid is split into slabs of z-slices (one block of planes each) that the worker threads
//! (`std::thread::scope`) take in turn; each worker paints every structure into the slab it
//! holds, so the result does not depend on the number of threads. Inside a slab, voxels are visited in 8 x 8 x 8 blocks: one evaluation at the block
//! centre settles the whole block when it is farther from the surface than the block's
//! half-diagonal (the solids are 1-Lipschitz, see [`super::sdf`]), so only blocks that straddle a
//! surface are evaluated voxel by voxel.

use glam::DVec3;

use super::sdf::Sdf;
use crate::par::par_map_on;
use crate::rng::{splitmix64, unit_f64, unit_f64_nonzero};
use crate::volume::{Volume, VolumeGrid};

/// Edge of the culling blocks, in voxels.
const BLOCK: usize = 8;

/// Worker threads to use: the machine's parallelism, at most `cap`.
pub fn worker_count(cap: usize) -> usize {
    std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .clamp(1, cap.max(1))
}

/// Splits `0..nz` into `workers` contiguous ranges of near-equal size.
fn slabs(nz: usize, workers: usize) -> Vec<(usize, usize)> {
    let workers = workers.clamp(1, nz.max(1));
    (0..workers)
        .map(|w| (nz * w / workers, nz * (w + 1) / workers))
        .filter(|(a, b)| b > a)
        .collect()
}

/// Index range of voxels whose centres may lie inside `[lo, hi]` along one axis.
fn axis_range(lo: f64, hi: f64, origin: f64, spacing: f64, n: usize) -> (usize, usize) {
    let a = ((lo - origin) / spacing).floor().max(0.0);
    let b = ((hi - origin) / spacing).ceil() + 1.0;
    let b = if b.is_finite() {
        b.min(n as f64)
    } else {
        n as f64
    };
    let a = if a.is_finite() { a.min(n as f64) } else { 0.0 };
    (a as usize, (b as usize).max(a as usize))
}

/// Paints `solids` (in order; later overwrites earlier) into a label grid: voxel value `i + 1`
/// where solid `i` is the last one containing the voxel centre, 0 where none does.
///
/// `exhaustive` disables the block culling (every voxel of each solid's bounding box is
/// evaluated); it exists so tests can check the culling against the plain evaluation.
pub fn paint_labels(
    grid: &VolumeGrid,
    solids: &[&Sdf],
    workers: usize,
    exhaustive: bool,
) -> Volume<u8> {
    assert!(solids.len() < 255, "labels are u8");
    let [nx, ny, nz] = grid.dims;
    let plane = nx * ny;
    let bounds: Vec<_> = solids.iter().map(|s| s.bounds()).collect();
    // Slabs of one block of planes, taken in turn by the workers: the solids crowd some slabs
    // (the pelvis, the lumbar spine) and leave others nearly empty.
    let slabs = par_map_on(
        workers,
        nz.div_ceil(BLOCK),
        &|s| {
            let (z0, z1) = (s * BLOCK, ((s + 1) * BLOCK).min(nz));
            let mut chunk = vec![0u8; (z1 - z0) * plane];
            paint_slab(grid, solids, &bounds, z0, z1, &mut chunk, exhaustive);
            chunk
        },
        &mut |_| {},
    );
    let data = slabs.concat();
    Volume { grid: *grid, data }
}

/// Paints every solid into the slab of planes `z0..z1` (`chunk`, its voxels).
fn paint_slab(
    grid: &VolumeGrid,
    solids: &[&Sdf],
    bounds: &[super::sdf::Aabb],
    z0: usize,
    z1: usize,
    chunk: &mut [u8],
    exhaustive: bool,
) {
    let [nx, ny, nz] = grid.dims;
    for (si, solid) in solids.iter().enumerate() {
        let label = si as u8 + 1;
        let b = bounds[si];
        let (i0, i1) = axis_range(b.min.x, b.max.x, grid.origin_mm[0], grid.spacing_mm[0], nx);
        let (j0, j1) = axis_range(b.min.y, b.max.y, grid.origin_mm[1], grid.spacing_mm[1], ny);
        let (k0, k1) = axis_range(b.min.z, b.max.z, grid.origin_mm[2], grid.spacing_mm[2], nz);
        let (k0, k1) = (k0.max(z0), k1.min(z1));
        if i0 >= i1 || j0 >= j1 || k0 >= k1 {
            continue;
        }
        paint_one(
            grid,
            solid,
            label,
            [i0, i1],
            [j0, j1],
            [k0, k1],
            z0,
            chunk,
            exhaustive,
        );
    }
}

#[expect(
    clippy::too_many_arguments,
    reason = "a private kernel; the ranges are clearer apart"
)]
fn paint_one(
    grid: &VolumeGrid,
    solid: &Sdf,
    label: u8,
    ri: [usize; 2],
    rj: [usize; 2],
    rk: [usize; 2],
    z0: usize,
    chunk: &mut [u8],
    exhaustive: bool,
) {
    let [nx, ny, _] = grid.dims;
    let sp = grid.spacing_mm;
    let centre = |i: usize, j: usize, k: usize| DVec3::from(grid.voxel_center_mm(i, j, k));
    let mut bk = rk[0];
    while bk < rk[1] {
        let ek = (bk + BLOCK).min(rk[1]);
        let mut bj = rj[0];
        while bj < rj[1] {
            let ej = (bj + BLOCK).min(rj[1]);
            let mut bi = ri[0];
            while bi < ri[1] {
                let ei = (bi + BLOCK).min(ri[1]);
                // Block centre and the distance from it to the farthest voxel centre in the block.
                let lo = centre(bi, bj, bk);
                let hi = centre(ei - 1, ej - 1, ek - 1);
                let c = 0.5 * (lo + hi);
                let half_diag = 0.5 * (hi - lo).length();
                let _ = sp;
                let f = if exhaustive { 0.0 } else { solid.eval(c) };
                if !exhaustive && f > half_diag {
                    // Entirely outside.
                } else if !exhaustive && f + half_diag <= 0.0 {
                    for k in bk..ek {
                        for j in bj..ej {
                            let row = (k - z0) * nx * ny + j * nx;
                            chunk[row + bi..row + ei].fill(label);
                        }
                    }
                } else {
                    for k in bk..ek {
                        for j in bj..ej {
                            let row = (k - z0) * nx * ny + j * nx;
                            for i in bi..ei {
                                if solid.eval(centre(i, j, k)) <= 0.0 {
                                    chunk[row + i] = label;
                                }
                            }
                        }
                    }
                }
                bi = ei;
            }
            bj = ej;
        }
        bk = ek;
    }
}

/// Fractional occupancy of one structure in one voxel near a surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fraction {
    /// Linear voxel index.
    pub voxel: u32,
    /// Structure label (index + 1), as in [`paint_labels`].
    pub label: u8,
    /// Occupancy in `(0, 1]`.
    pub occupancy: f32,
}

/// Partial volumes at the boundaries of the painted labels.
///
/// Under the painting order, structure `i` owns the region where its *exclusive* distance bound
/// `g_i = max(f_i, max_{j > i} -f_j)` is negative (inside `i`, outside everything painted later).
/// `g_i` is 1-Lipschitz like the `f`s, and `clamp(0.5 - g_i / h, 0, 1)` (h = voxel size) is the
/// occupancy of a voxel cut by a plane at signed distance `g_i` along a grid axis. Two structures
/// that meet get occupancies summing to one, whose 0.5 level is their common surface, so their
/// meshes share it; and occupancy >= 0.5 holds exactly where the painted label is that structure.
///
/// Only voxels with a differently labelled 26-neighbour are evaluated (a surface within half a
/// voxel of a centre puts a neighbour's centre on the other side); everywhere else the binary label
/// is exact. Returned sorted by voxel index, one entry per structure with non-zero occupancy.
pub fn partial_volumes(
    grid: &VolumeGrid,
    solids: &[&Sdf],
    labels: &Volume<u8>,
    workers: usize,
) -> Vec<Fraction> {
    let [nx, ny, nz] = grid.dims;
    let h = grid.min_spacing_mm();
    let bounds: Vec<_> = solids.iter().map(|s| s.bounds().expand(h)).collect();
    let lab = &labels.data;
    let differs = |i: usize, j: usize, k: usize| -> bool {
        let l = lab[grid.index(i, j, k)];
        for dk in k.saturating_sub(1)..=(k + 1).min(nz - 1) {
            for dj in j.saturating_sub(1)..=(j + 1).min(ny - 1) {
                let row = grid.index(0, dj, dk);
                for di in i.saturating_sub(1)..=(i + 1).min(nx - 1) {
                    if lab[row + di] != l {
                        return true;
                    }
                }
            }
        }
        false
    };
    // One row of blocks per job, the rows taken in turn by the workers (see `paint_labels`).
    let parts: Vec<Vec<Fraction>> = par_map_on(
        workers,
        nz.div_ceil(BLOCK),
        &|row| {
            let mut out = Vec::new();
            let mut band = Vec::new();
            let mut cand: Vec<usize> = Vec::new();
            let mut f = Vec::new();
            let bk = row * BLOCK;
            let ek = (bk + BLOCK).min(nz);
            for bj in (0..ny).step_by(BLOCK) {
                let ej = (bj + BLOCK).min(ny);
                for bi in (0..nx).step_by(BLOCK) {
                    let ei = (bi + BLOCK).min(nx);
                    band.clear();
                    for k in bk..ek {
                        for j in bj..ej {
                            for i in bi..ei {
                                if differs(i, j, k) {
                                    band.push([i, j, k]);
                                }
                            }
                        }
                    }
                    if band.is_empty() {
                        continue;
                    }
                    let lo = DVec3::from(grid.voxel_center_mm(bi, bj, bk));
                    let hi = DVec3::from(grid.voxel_center_mm(ei - 1, ej - 1, ek - 1));
                    let c = 0.5 * (lo + hi);
                    let reach = 0.5 * (hi - lo).length() + h;
                    // Candidates: the last solid containing the whole block (its f is
                    // below -h throughout, so it zeroes everything painted before it)
                    // and the later solids whose surface may come near the block.
                    cand.clear();
                    let mut floor = None;
                    for (si, solid) in solids.iter().enumerate() {
                        let b = bounds[si];
                        if b.min.cmpgt(hi).any() || b.max.cmplt(lo).any() {
                            continue;
                        }
                        let fc = solid.eval(c);
                        if fc > reach {
                            continue;
                        }
                        if fc < -reach {
                            floor = Some(si);
                            cand.retain(|&x| x > si);
                            continue;
                        }
                        cand.push(si);
                    }
                    for &[i, j, k] in &band {
                        let p = DVec3::from(grid.voxel_center_mm(i, j, k));
                        f.clear();
                        f.extend(cand.iter().map(|&si| solids[si].eval(p)));
                        let voxel = grid.index(i, j, k) as u32;
                        // Walk from the last painted down, carrying max(-f) of later ones.
                        let mut later = f64::NEG_INFINITY;
                        let start = out.len();
                        // Solid `si`'s share of the voxel from its exclusive bound `g`.
                        let mut share = |si: usize, g: f64| {
                            let occ = (0.5 - g / h).clamp(0.0, 1.0);
                            if occ > 0.0 {
                                out.push(Fraction {
                                    voxel,
                                    label: si as u8 + 1,
                                    occupancy: occ as f32,
                                });
                            }
                        };
                        for (n, &si) in cand.iter().enumerate().rev() {
                            share(si, f[n].max(later));
                            later = later.max(-f[n]);
                        }
                        if let Some(si) = floor {
                            share(si, later);
                        }
                        out[start..].reverse();
                    }
                }
            }

            out
        },
        &mut |_| {},
    );
    let mut all: Vec<Fraction> = parts.into_iter().flatten().collect();
    // Blocks are visited in block order, not voxel order: sort (stable, so per-voxel order stays
    // ascending by label).
    all.sort_by_key(|f| f.voxel);
    all
}

/// A reproducible standard-normal deviate for voxel `index` under `seed` (SplitMix64 hashing and
/// the Box-Muller transform): the same on every platform and independent of threading.
pub fn voxel_gaussian(seed: u64, index: u64) -> f64 {
    let a = splitmix64(seed ^ splitmix64(index.wrapping_mul(2)));
    let b = splitmix64(seed ^ splitmix64(index.wrapping_mul(2).wrapping_add(1)));
    // Uniform in (0, 1]: never zero, so the logarithm is finite.
    let u1 = unit_f64_nonzero(a);
    let u2 = unit_f64(b);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Separable Gaussian blur of a volume along each axis (kernel truncated at 3 sigma, edges
/// clamped), `sigma_mm` per axis converted with the grid spacing. Runs over z-slabs in parallel.
pub fn gaussian_blur(vol: &Volume<f32>, sigma_mm: f64, workers: usize) -> Volume<f32> {
    if sigma_mm <= 0.0 {
        return vol.clone();
    }
    let mut cur = vol.data.clone();
    let mut next = vec![0f32; cur.len()];
    let [nx, ny, nz] = vol.grid.dims;
    let strides = [1, nx, nx * ny];
    for axis in 0..3 {
        let sigma_vox = sigma_mm / vol.grid.spacing_mm[axis];
        let radius = (3.0 * sigma_vox).ceil() as isize;
        if radius == 0 {
            continue;
        }
        let w: Vec<f64> = (-radius..=radius)
            .map(|t| (-0.5 * (t as f64 / sigma_vox).powi(2)).exp())
            .collect();
        let norm: f64 = w.iter().sum();
        let w: Vec<f32> = w.iter().map(|x| (x / norm) as f32).collect();
        let n_axis = vol.grid.dims[axis] as isize;
        let stride = strides[axis];
        let src = &cur;
        std::thread::scope(|scope| {
            let mut rest: &mut [f32] = &mut next;
            for (z0, z1) in slabs(nz, workers) {
                let (chunk, tail) = rest.split_at_mut((z1 - z0) * nx * ny);
                rest = tail;
                let w = &w;
                scope.spawn(move || {
                    for (local, out) in chunk.iter_mut().enumerate() {
                        let idx = z0 * nx * ny + local;
                        let pos = [idx % nx, (idx / nx) % ny, idx / (nx * ny)][axis] as isize;
                        let mut acc = 0f32;
                        for (t, wt) in (-radius..=radius).zip(w) {
                            let q = (pos + t).clamp(0, n_axis - 1);
                            let src_idx = (idx as isize + (q - pos) * stride as isize) as usize;
                            acc += wt * src[src_idx];
                        }
                        *out = acc;
                    }
                });
            }
        });
        std::mem::swap(&mut cur, &mut next);
    }
    Volume {
        grid: vol.grid,
        data: cur,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::anatomy::phantom::sdf::Rigid;

    fn grid(n: usize, spacing: f64) -> VolumeGrid {
        let o = -0.5 * (n as f64 - 1.0) * spacing;
        VolumeGrid {
            dims: [n, n, n],
            spacing_mm: [spacing; 3],
            origin_mm: [o, o, o],
        }
    }

    #[test]
    fn sphere_and_box_voxel_volumes_match_analytic() {
        let g = grid(64, 1.0);
        let r = 20.0;
        let sphere = Sdf::Sphere { radius: r }.at(DVec3::new(0.3, -0.2, 0.1));
        let bx = Sdf::RoundBox {
            half: DVec3::new(10.0, 6.0, 4.0),
            round: 0.0,
        }
        .at(DVec3::new(0.25, 0.25, 0.25));
        let labels = paint_labels(&g, &[&sphere], 2, false);
        let n = labels.data.iter().filter(|&&l| l == 1).count() as f64;
        let exact = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
        // Counting voxel centres inside a smooth solid errs by a surface-sampling noise of order
        // sqrt(surface voxels); 0.5 % is about 3 such standard deviations for r = 20 voxels.
        assert!((n - exact).abs() / exact < 5e-3, "sphere {n} vs {exact}");
        // A box offset by a quarter voxel from the grid's centres holds exactly 20 x 12 x 8 centres.
        let labels = paint_labels(&g, &[&bx], 2, false);
        let n = labels.data.iter().filter(|&&l| l == 1).count();
        assert_eq!(n, 20 * 12 * 8);
    }

    #[test]
    fn culling_equals_exhaustive_evaluation_and_threads_do_not_matter() {
        let g = VolumeGrid {
            dims: [50, 41, 37],
            spacing_mm: [1.3, 1.1, 1.7],
            origin_mm: [-30.0, -20.0, -31.0],
        };
        let a = Sdf::Ellipsoid {
            radii: DVec3::new(25.0, 12.0, 20.0),
        };
        let b = Sdf::SmoothUnion(
            vec![
                Sdf::capsule(
                    DVec3::new(-20.0, 0.0, -10.0),
                    DVec3::new(15.0, 5.0, 20.0),
                    5.0,
                ),
                Sdf::RoundBox {
                    half: DVec3::new(4.0, 9.0, 6.0),
                    round: 1.5,
                }
                .placed(Rigid::from_axes(
                    DVec3::new(5.0, -3.0, 0.0),
                    DVec3::new(1.0, 2.0, 0.5),
                    DVec3::Z,
                )),
            ],
            4.0,
        )
        .smooth_minus(
            Sdf::Sphere { radius: 6.0 }.at(DVec3::new(0.0, 0.0, 5.0)),
            2.0,
        );
        let c = Sdf::Scaled(
            Box::new(Sdf::Sphere { radius: 8.0 }),
            DVec3::new(2.0, 0.7, 1.0),
        )
        .at(DVec3::new(0.0, 10.0, -15.0));
        let solids = [&a, &b, &c];
        let fast = paint_labels(&g, &solids, 1, false);
        let slow = paint_labels(&g, &solids, 1, true);
        assert_eq!(fast.data, slow.data);
        let threaded = paint_labels(&g, &solids, 3, false);
        assert_eq!(fast.data, threaded.data);
        for l in 1..=3u8 {
            assert!(fast.data.contains(&l), "label {l} painted");
        }
    }

    #[test]
    fn partial_volumes_recover_analytic_volumes_and_agree_with_labels() {
        let g = grid(48, 1.0);
        let r_out = 15.0;
        let r_in = 9.0;
        let centre = DVec3::new(0.31, -0.17, 0.23);
        let outer = Sdf::Sphere { radius: r_out }.at(centre);
        let inner = Sdf::Sphere { radius: r_in }.at(centre);
        let solids = [&outer, &inner];
        let labels = paint_labels(&g, &solids, 2, false);
        let fr = partial_volumes(&g, &solids, &labels, 2);
        // Occupancy per label: binary labels away from the band, fractions in it.
        let mut occ = [vec![0f64; g.len()], vec![0f64; g.len()]];
        for (v, &l) in labels.data.iter().enumerate() {
            if l > 0 {
                occ[usize::from(l) - 1][v] = 1.0;
            }
        }
        let mut band = vec![false; g.len()];
        for f in &fr {
            band[f.voxel as usize] = true;
        }
        for (v, b) in band.iter().enumerate() {
            if *b {
                occ[0][v] = 0.0;
                occ[1][v] = 0.0;
            }
        }
        for f in &fr {
            occ[usize::from(f.label) - 1][f.voxel as usize] = f64::from(f.occupancy);
            // The painted label is the structure with occupancy >= 0.5.
            assert_eq!(
                f.occupancy >= 0.5,
                labels.data[f.voxel as usize] == f.label,
                "voxel {}",
                f.voxel
            );
        }
        let shell: f64 = occ[0].iter().sum();
        let core: f64 = occ[1].iter().sum();
        let v = |r: f64| 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
        // The linear ramp is exact for planes along an axis; for a sphere of radius >= 9 voxels the
        // curvature and obliquity error is below 0.5 % (it is ~3 % for voxel counting at r = 9).
        assert!(
            (core - v(r_in)).abs() / v(r_in) < 5e-3,
            "core {core} vs {}",
            v(r_in)
        );
        assert!(
            (shell - (v(r_out) - v(r_in))).abs() / (v(r_out) - v(r_in)) < 5e-3,
            "shell {shell}"
        );
        // Where the two meet, their occupancies add up to one.
        for (v, (&shell_occ, &core_occ)) in occ[0].iter().zip(&occ[1]).enumerate() {
            if core_occ > 0.0 && core_occ < 1.0 {
                assert!((shell_occ + core_occ - 1.0).abs() < 1e-6, "voxel {v}");
            }
        }
    }

    #[test]
    fn noise_is_standard_normal() {
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|i| voxel_gaussian(7, i)).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        // Standard errors for n = 2e5: mean 0.0022, variance 0.0032; 5 sigma bounds.
        assert!(mean.abs() < 0.011, "mean {mean}");
        assert!((var - 1.0).abs() < 0.016, "variance {var}");
        assert_ne!(voxel_gaussian(7, 3), voxel_gaussian(8, 3));
    }

    #[test]
    fn blur_preserves_sum_and_spreads_a_point() {
        let g = grid(21, 1.0);
        let mut v = Volume::filled(g, 0f32);
        v.set(10, 10, 10, 1000.0);
        let b = gaussian_blur(&v, 1.0, 2);
        let sum: f64 = b.data.iter().map(|&x| f64::from(x)).sum();
        assert!((sum - 1000.0).abs() < 1e-2, "sum {sum}");
        // Peak of a unit-sigma 3-D Gaussian sampled on unit voxels: (1/sqrt(2 pi))^3 ~ 0.0635
        // (discrete normalisation changes it by < 1 %).
        let peak = f64::from(b.get(10, 10, 10)) / 1000.0;
        assert!((peak - 0.0635).abs() < 0.002, "peak {peak}");
        assert_eq!(b.get(9, 10, 10), b.get(11, 10, 10));
    }
}
