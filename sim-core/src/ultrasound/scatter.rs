//! Coherent speckle: a signed I/Q scatterer field fixed to the TISSUE, seen through the PSF.
//!
//! Scatterers sit on a regular lattice of side `h` in the region frame (cell `(i, j, k)` at
//! `(i h, j h, k h)`), each with a signed complex amplitude drawn from a SplitMix64 hash of the
//! seed and the cell's indices. Nothing depends on the probe: moving the probe moves the image
//! over speckle that stays with the anatomy. The amplitudes are triangular (sum of two uniforms)
//! rather than Gaussian; the PSF sums many of them, so the field it sees is Gaussian and the
//! envelope Rayleigh (tested), and a regular lattice finer than the PSF keeps the local scatter
//! energy constant (random positions would make it fluctuate and spoil the statistics).
//!
//! Each scatterer is weighted by the elevation profile at its distance from the slice, turned
//! by its carrier phase `2 k z` and deposited bilinearly on a (line, sample) grid. A Gaussian
//! across lines per depth row (its width converted from mm with the line spacing AT THAT DEPTH,
//! so diverging sector lines get the right blur) and a Gaussian along each line finish the
//! convolution; the deposit's own spread (variance 1/6 grid step^2) is subtracted from the
//! Gaussian's variance. Beam widths change with depth but the beam's energy does not: the
//! lateral and elevation profiles are scaled by `sqrt(w_focus / w(z))` so that uniform tissue
//! gives the same mean speckle at every depth (losses apart) and a point target is brightest
//! at the focus.

use glam::DVec3;

use super::beam::{Beam, FWHM_PER_SIGMA};
use super::probe::{ProbeFrame, ScanGeometry};
use super::tissue::{AcousticMedium, Texture};
use crate::rng::splitmix64;

/// A complex (I/Q) field on padded (line, sample) nodes, line-major.
#[derive(Debug, Clone)]
pub(crate) struct IqGrid {
    pub lines: usize,
    pub samples: usize,
    /// Padding lines on each side of line 0 / the last line.
    pub pad_l: usize,
    /// Padding samples before sample 0 and after the last one.
    pub pad_s: usize,
    pub re: Vec<f32>,
    pub im: Vec<f32>,
}

impl IqGrid {
    pub fn new(lines: usize, samples: usize, pad_l: usize, pad_s: usize) -> IqGrid {
        let n = (lines + 2 * pad_l) * (samples + 2 * pad_s);
        IqGrid {
            lines,
            samples,
            pad_l,
            pad_s,
            re: zeroed_buffer(n),
            im: zeroed_buffer(n),
        }
    }

    pub fn stride(&self) -> usize {
        self.samples + 2 * self.pad_s
    }

    pub fn total_lines(&self) -> usize {
        self.lines + 2 * self.pad_l
    }

    /// Adds `(a, b)` at fractional unpadded coordinates (bilinear; nodes off the grid are dropped).
    #[inline]
    pub fn deposit(&mut self, u: f64, s: f64, a: f64, b: f64) {
        let up = u + self.pad_l as f64;
        let sp = s + self.pad_s as f64;
        if up.is_nan() || sp.is_nan() || up < 0.0 || sp < 0.0 {
            return;
        }
        // Both are non-negative here, so truncation is floor (and no libm call).
        let (u0, s0) = (up as usize, sp as usize);
        let (fu, fs) = (up - u0 as f64, sp - s0 as f64);
        if u0 + 1 >= self.total_lines() || s0 + 1 >= self.stride() {
            return;
        }
        let st = self.stride();
        for (du, wu) in [(0, 1.0 - fu), (1, fu)] {
            for (ds, ws) in [(0, 1.0 - fs), (1, fs)] {
                let i = (u0 + du) * st + s0 + ds;
                let w = wu * ws;
                self.re[i] += (a * w) as f32;
                self.im[i] += (b * w) as f32;
            }
        }
    }

    /// The top-left node and bilinear weights of a deposit at `(u, s)`, as [`IqGrid::deposit`]
    /// takes them (`None` where it drops the deposit).
    #[inline]
    fn cell(&self, u: f64, s: f64) -> Option<(usize, [f64; 4])> {
        let up = u + self.pad_l as f64;
        let sp = s + self.pad_s as f64;
        if up.is_nan() || sp.is_nan() || up < 0.0 || sp < 0.0 {
            return None;
        }
        let (u0, s0) = (up as usize, sp as usize);
        let (fu, fs) = (up - u0 as f64, sp - s0 as f64);
        if u0 + 1 >= self.total_lines() || s0 + 1 >= self.stride() {
            return None;
        }
        let w = [
            (1.0 - fu) * (1.0 - fs),
            (1.0 - fu) * fs,
            fu * (1.0 - fs),
            fu * fs,
        ];
        Some((u0 * self.stride() + s0, w))
    }

    pub fn add(&mut self, other: &IqGrid) {
        for (x, y) in self.re.iter_mut().zip(&other.re) {
            *x += y;
        }
        for (x, y) in self.im.iter_mut().zip(&other.im) {
            *x += y;
        }
    }
}

/// Deposits into one grid cell (its four nodes), summed in `f64` while consecutive deposits hit
/// the same cell and added to the grid when they move on: the same terms as [`IqGrid::deposit`]
/// one by one, rounded to `f32` once per run instead of once per term.
pub(crate) struct CellSum {
    /// Index of the cell's top-left node (`usize::MAX`: none yet).
    node: usize,
    /// `(re, im)` per node: top-left, below it (next sample), right (next line), diagonal.
    sum: [f64; 8],
}

impl CellSum {
    pub fn new() -> CellSum {
        CellSum {
            node: usize::MAX,
            sum: [0.0; 8],
        }
    }

    /// Adds `(a, b)` at fractional unpadded `(u, s)` as [`IqGrid::deposit`] would.
    #[inline]
    pub fn deposit(&mut self, grid: &mut IqGrid, u: f64, s: f64, a: f64, b: f64) {
        let Some((node, w)) = grid.cell(u, s) else {
            return;
        };
        if node != self.node {
            self.flush(grid);
            self.node = node;
        }
        for (c, wc) in w.iter().enumerate() {
            self.sum[2 * c] += a * wc;
            self.sum[2 * c + 1] += b * wc;
        }
    }

    /// Adds the sums to the grid and starts afresh.
    pub fn flush(&mut self, grid: &mut IqGrid) {
        if self.node != usize::MAX {
            let st = grid.stride();
            for (c, offset) in [0, 1, st, st + 1].into_iter().enumerate() {
                grid.re[self.node + offset] += self.sum[2 * c] as f32;
                grid.im[self.node + offset] += self.sum[2 * c + 1] as f32;
            }
        }
        *self = CellSum::new();
    }
}

/// Buffers of dropped grids, kept for the next frame (a fresh megabyte-sized allocation costs
/// a page fault per 4 KiB page, every frame).
static SPARE_BUFFERS: std::sync::Mutex<Vec<Vec<f32>>> = std::sync::Mutex::new(Vec::new());
/// Most buffers kept (our choice: the two deposit grids of a frame, re and im).
const SPARE_BUFFERS_MAX: usize = 4;

/// `n` zeros, in a spare buffer when there is one.
fn zeroed_buffer(n: usize) -> Vec<f32> {
    let spare = SPARE_BUFFERS.lock().ok().and_then(|mut v| v.pop());
    match spare {
        Some(mut b) => {
            b.clear();
            b.resize(n, 0.0);
            b
        }
        None => vec![0.0; n],
    }
}

impl Drop for IqGrid {
    fn drop(&mut self) {
        if let Ok(mut spare) = SPARE_BUFFERS.lock() {
            for b in [&mut self.re, &mut self.im] {
                if spare.len() < SPARE_BUFFERS_MAX {
                    spare.push(std::mem::take(b));
                }
            }
        }
    }
}

/// Per-sample beam tables of one frame.
#[derive(Debug, Clone)]
pub(crate) struct BeamTables {
    /// Sample spacing along each line, mm.
    pub dz: f64,
    /// `1 / (2 sigma_e^2)` of the elevation profile at each sample.
    pub elev_inv2s2: Vec<f64>,
    /// `sqrt(sigma_e(focus) / sigma_e(z))` at each sample.
    pub elev_energy: Vec<f64>,
    /// Lateral sigma at each sample, mm.
    pub lat_sigma_mm: Vec<f64>,
    /// `sqrt(sigma_l(focus) / sigma_l(z))` at each sample.
    pub lat_energy: Vec<f64>,
    /// Axial sigma, mm.
    pub axial_sigma_mm: f64,
    /// Largest elevation FWHM over the depth, mm.
    pub max_elev_fwhm_mm: f64,
    /// Largest lateral FWHM over the depth, mm.
    pub max_lat_fwhm_mm: f64,
}

impl BeamTables {
    pub fn new(beam: &Beam, depth_mm: f64, samples: usize) -> BeamTables {
        let dz = depth_mm / (samples - 1) as f64;
        let sl_ref = beam.lateral_fwhm_mm(beam.focus_mm);
        let se_ref = beam.elevation_fwhm_mm(beam.elevation_focus_mm);
        let mut t = BeamTables {
            dz,
            elev_inv2s2: Vec::with_capacity(samples),
            elev_energy: Vec::with_capacity(samples),
            lat_sigma_mm: Vec::with_capacity(samples),
            lat_energy: Vec::with_capacity(samples),
            axial_sigma_mm: beam.axial_fwhm_mm() / FWHM_PER_SIGMA,
            max_elev_fwhm_mm: 0.0,
            max_lat_fwhm_mm: 0.0,
        };
        for s in 0..samples {
            let z = s as f64 * dz;
            let we = beam.elevation_fwhm_mm(z);
            let wl = beam.lateral_fwhm_mm(z);
            let se = we / FWHM_PER_SIGMA;
            t.elev_inv2s2.push(1.0 / (2.0 * se * se));
            t.elev_energy.push((se_ref / we).sqrt());
            t.lat_sigma_mm.push(wl / FWHM_PER_SIGMA);
            t.lat_energy.push((sl_ref / wl).sqrt());
            t.max_elev_fwhm_mm = t.max_elev_fwhm_mm.max(we);
            t.max_lat_fwhm_mm = t.max_lat_fwhm_mm.max(wl);
        }
        t
    }

    /// Nearest sample index of depth `z` (clamped).
    #[inline]
    pub fn sample_of(&self, z: f64) -> usize {
        self.sample_at(z / self.dz)
    }

    /// Nearest sample index of fractional sample `s = z / dz` (clamped).
    #[inline]
    pub fn sample_at(&self, s: f64) -> usize {
        // Round half up by truncation of a non-negative value (no libm call).
        ((s + 0.5).max(0.0) as usize).min(self.elev_inv2s2.len() - 1)
    }

    /// Peak-normalised elevation weight of offset `e` at depth `z`, times the energy factor.
    #[inline]
    pub fn elevation_weight(&self, e: f64, z: f64) -> f64 {
        let s = self.sample_of(z);
        exp_neg(e * e * self.elev_inv2s2[s]) * self.elev_energy[s]
    }
}

/// Elevation reach of the scatter sum, in FWHM of the slice at each depth.
const ELEV_REACH_FWHM: f64 = 1.0;

/// The tissue's scatterer lattice: cell side and seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ScatterField {
    pub cell_mm: f64,
    pub seed: u64,
}

/// Entries per turn of the [`cis`] table.
const CIS_N: usize = 4096;
/// Entries per unit argument of the [`exp_neg`] table, and its range.
const EXP_PER_UNIT: f64 = 128.0;
const EXP_MAX: f64 = 16.0;

fn cis_table() -> &'static [(f64, f64)] {
    static T: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        (0..CIS_N)
            .map(|n| {
                let (s, c) = (std::f64::consts::TAU * n as f64 / CIS_N as f64).sin_cos();
                (c, s)
            })
            .collect()
    })
}

/// Entries of the [`exp_neg`] table: `EXP_MAX * EXP_PER_UNIT + 2`.
const EXP_LEN: usize = 16 * 128 + 2;
const _: () = assert!(EXP_LEN == (EXP_MAX * EXP_PER_UNIT) as usize + 2);

fn exp_table() -> &'static [f64; EXP_LEN] {
    static T: std::sync::OnceLock<[f64; EXP_LEN]> = std::sync::OnceLock::new();
    T.get_or_init(|| std::array::from_fn(|i| (-(i as f64) / EXP_PER_UNIT).exp()))
}

/// `(cos phi, sin phi)` from a 4096-entry table with a first-order correction: error below
/// `(pi / 4096)^2 / 2 = 3e-7`, several times faster than `sin_cos` in the scatter loop.
pub(crate) fn cis(phi: f64) -> (f64, f64) {
    let x = phi * (CIS_N as f64 / std::f64::consts::TAU);
    let n = floor_fast(x + 0.5);
    let d = (x - n) * (std::f64::consts::TAU / CIS_N as f64);
    let (c, s) = cis_table()[(n as i64).rem_euclid(CIS_N as i64) as usize];
    (c - s * d, s + c * d)
}

/// `floor` without a libm call (the baseline x86-64 target has no rounding instruction).
pub(crate) fn floor_fast(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// `exp(-x)` for `x >= 0`, linearly interpolated in a table of step 1/128 (relative error below
/// `(1/128)^2 / 8 = 8e-6`); zero beyond 16.
pub(crate) fn exp_neg(x: f64) -> f64 {
    exp_neg_in(exp_table(), x)
}

/// [`exp_neg`] with the table at hand (the scatter loop fetches it once).
#[inline]
fn exp_neg_in(tab: &[f64; EXP_LEN], x: f64) -> f64 {
    if x.is_nan() || x >= EXP_MAX {
        return 0.0;
    }
    let t = x.max(0.0) * EXP_PER_UNIT;
    // 0 <= t < 2048 here: through i64, the same index with a plain conversion; the `min` changes
    // nothing but lets the compiler drop the bounds checks.
    let i = (t as i64 as usize).min(EXP_LEN - 2);
    let f = t - i as f64;
    tab[i] + (tab[i + 1] - tab[i]) * f
}

/// Hash of a lattice cell (three indices and the seed).
fn cell_hash(seed: u64, i: i64, j: i64, k: i64) -> u64 {
    splitmix64(splitmix64(splitmix64(seed ^ i as u64) ^ j as u64) ^ k as u64)
}

/// The lattice cells a frame can reach, and how its columns run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LatticeBounds {
    /// Lowest cell index per region axis.
    pub lo_cell: [i64; 3],
    /// Highest cell index per region axis.
    pub hi_cell: [i64; 3],
    /// The region axis closest to the elevation direction: lattice columns run along it.
    pub column_axis: usize,
    /// The two other region axes, in increasing order.
    pub across: (usize, usize),
}

/// The lattice cells (side `cell_mm`) of the box around image extent `(x0, x1, y0, y1)` (mm,
/// already widened by the in-plane PSF reach) and `+-reach_elev_mm` across the slice, in the
/// region frame; shared by the CPU deposit and the GPU path so both visit the same cells.
pub fn lattice_bounds(
    f: &ProbeFrame,
    (x0, x1, y0, y1): (f64, f64, f64, f64),
    reach_elev_mm: f64,
    cell_mm: f64,
) -> LatticeBounds {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = DVec3::splat(f64::NEG_INFINITY);
    for x in [x0, x1] {
        for y in [y0, y1] {
            for e in [-reach_elev_mm, reach_elev_mm] {
                let p = f.to_region(DVec3::new(x, y, e));
                lo = lo.min(p);
                hi = hi.max(p);
            }
        }
    }
    let ev = f.elevation.to_array();
    let column_axis = (0..3)
        .max_by(|&a, &b| ev[a].abs().total_cmp(&ev[b].abs()))
        .unwrap_or(2);
    let across = match column_axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    LatticeBounds {
        lo_cell: std::array::from_fn(|a| (lo[a] / cell_mm).floor() as i64),
        hi_cell: std::array::from_fn(|a| (hi[a] / cell_mm).ceil() as i64),
        column_axis,
        across,
    }
}

/// Deposits every lattice scatterer within reach of the frame into `grid` (not yet convolved).
pub(crate) fn deposit_scatterers(
    grid: &mut IqGrid,
    geo: &ScanGeometry,
    beam: &Beam,
    tables: &BeamTables,
    medium: &dyn AcousticMedium,
    field: ScatterField,
    part: u64,
) {
    let ScatterField { cell_mm, seed } = field;
    let f = &geo.frame;
    let h = cell_mm;
    // Reach: in elevation 1 FWHM at the column's depth (the Gaussian's energy beyond it is
    // erfc(2.355) = 0.1 %), in plane the lateral/axial PSF tails.
    let t_e = ELEV_REACH_FWHM * tables.max_elev_fwhm_mm;
    let m = 1.5 * tables.max_lat_fwhm_mm + 4.0 * tables.axial_sigma_mm;
    let (x0, x1, y0, y1) = geo.image_extent_mm();
    let (x0, x1, y0, y1) = (x0 - m, x1 + m, y0 - m, y1 + m);
    let LatticeBounds {
        lo_cell,
        hi_cell,
        column_axis: am,
        across: (aa, ab),
    } = lattice_bounds(f, (x0, x1, y0, y1), t_e, h);
    let idx_lo = |a: usize| lo_cell[a];
    let idx_hi = |a: usize| hi_cell[a];
    let mut unit = [DVec3::ZERO; 3];
    for (a, u) in unit.iter_mut().enumerate() {
        *u = f.to_probe(f.origin + DVec3::AXES[a]);
    }
    let step_m = unit[am] * h;
    let em = unit[am].z;
    // A lattice column (along axis `am`) drifts this far in plane per mm of elevation, and the
    // slice thickness changes at most `lip` mm per mm of depth (the elevation cone).
    let drift = unit[am].x.hypot(unit[am].y) / em.abs();
    let lip = beam.elevation_aperture_mm / beam.elevation_focus_mm / std::f64::consts::SQRT_2;
    let mut echo = EchoCache {
        db: f64::NAN,
        amp: 0.0,
    };
    let k0 = 2.0 * std::f64::consts::PI / beam.wavelength_mm();
    let norm = amplitude_norm(beam, tables, h);
    let lines_max = (geo.lines - 1) as f64;
    let reach_u = grid.pad_l as f64;
    let reach_s = grid.pad_s as f64 * tables.dz;
    let depth = geo.depth_mm;
    let mut p = [0i64; 3];
    let mut row_hash: Vec<u64> = Vec::new();
    let mut cells = CellSum::new();
    // The scatterers of a lattice column share their in-plane point whenever the column is
    // along the slice normal (a probe square to the lattice); everything that depends only on
    // that point is computed once and the column's sum is deposited once.
    let mut at = PlanePoint::none();
    // The sum over the scatterers seen at `at` so far of their weighted I and Q before the
    // carrier turn (which they share); locals, so that they stay in registers.
    let (mut sum_i, mut sum_q) = (0.0, 0.0);
    let reach = Reach {
        u: (-reach_u, lines_max + reach_u),
        z: (-reach_s, depth + reach_s),
    };
    let exp_tab = exp_table();
    let cx = ScatterContext {
        geo,
        tables,
        medium,
        exp_tab,
        reach,
        k0,
        h,
        norm,
        seed,
    };
    // Square to the lattice, a column keeps its in-plane point exactly (steps of zero).
    let square = step_m.x == 0.0 && step_m.y == 0.0;
    for ia in idx_lo(aa)..=idx_hi(aa) {
        // Two interleaved halves of the lattice (a fixed split, so the sum is deterministic).
        if ia.rem_euclid(2) as u64 != part {
            continue;
        }
        // With the column along axis 0 or 1, `ib` is the last index the hash takes: its first
        // two levels depend on `ia` and `k` only, so they are computed once for the whole row.
        row_hash.clear();
        if am < 2 {
            row_hash.extend((idx_lo(am)..=idx_hi(am)).map(|k| {
                let (first, second) = if am == 0 { (k, ia) } else { (ia, k) };
                splitmix64(splitmix64(seed ^ first as u64) ^ second as u64)
            }));
        }
        for ib in idx_lo(ab)..=idx_hi(ab) {
            let mut base = DVec3::ZERO;
            base[aa] = ia as f64 * h;
            base[ab] = ib as f64 * h;
            let q0 = f.to_probe(base);
            // Elevation is q0.z + x_m * em; keep |e| <= the reach at this column's depth.
            let qc = q0 - unit[am] * (q0.z / em);
            let (uc, zc) = geo.plane_to_line(qc.x, qc.y);
            let wander = t_e * drift;
            let t_col = (ELEV_REACH_FWHM
                * (beam.elevation_fwhm_mm(zc.clamp(0.0, depth)) + lip * wander))
                .min(t_e);
            let (mut a, mut b) = ((-t_col - q0.z) / em, (t_col - q0.z) / em);
            if a > b {
                std::mem::swap(&mut a, &mut b);
            }
            let k_lo = ((a / h).ceil() as i64).max(idx_lo(am));
            let k_hi = ((b / h).floor() as i64).min(idx_hi(am));
            if k_lo > k_hi {
                continue;
            }
            let q = q0 + unit[am] * (k_lo as f64 * h);
            p[aa] = ia;
            p[ab] = ib;
            let pos = base;
            // Along axis 2, the hash's two leading levels stay fixed along the column.
            let prefix = if am == 2 {
                splitmix64(splitmix64(seed ^ p[0] as u64) ^ p[1] as u64)
            } else {
                0
            };
            if square && !at.is(q.x, q.y) {
                at.deposit(grid, &mut cells, sum_i, sum_q);
                (sum_i, sum_q) = (0.0, 0.0);
                // Square, qc is q bit for bit (the column's steps are zero in plane).
                let line = if qc.x.to_bits() == q.x.to_bits() && qc.y.to_bits() == q.y.to_bits() {
                    (uc, zc)
                } else {
                    geo.plane_to_line(q.x, q.y)
                };
                at = PlanePoint::new(q.x, q.y, line, tables, k0, &cx.reach);
            }
            if square && !at.inside {
                continue;
            }
            let col = Column {
                k: k_lo..k_hi + 1,
                q,
                step: step_m,
                p,
                prefix,
                row_hash: &row_hash,
                k_first: idx_lo(am),
                pos,
            };
            let state = (&mut at, &mut *grid, &mut cells, &mut echo);
            let sums = (sum_i, sum_q);
            (sum_i, sum_q) = if square {
                column_on_axis::<true>(am, &cx, &col, state, sums)
            } else {
                column_on_axis::<false>(am, &cx, &col, state, sums)
            };
        }
    }
    at.deposit(grid, &mut cells, sum_i, sum_q);
    cells.flush(grid);
}

/// What every column of one deposit shares.
struct ScatterContext<'a> {
    geo: &'a ScanGeometry,
    tables: &'a BeamTables,
    medium: &'a dyn AcousticMedium,
    exp_tab: &'a [f64; EXP_LEN],
    reach: Reach,
    /// Wavenumber, rad/mm.
    k0: f64,
    /// Lattice cell, mm.
    h: f64,
    /// Amplitude scale (see [`amplitude_norm`]).
    norm: f64,
    seed: u64,
}

/// One lattice column: its cells `k` along axis `AM`, the probe-frame point of the first
/// and the step between cells, the other two indices (in `p`), the hash levels that do not
/// depend on `k` (axis 2) or on the column (axes 0 and 1, per row), and the region point with
/// the fixed coordinates set.
struct Column<'a> {
    k: std::ops::Range<i64>,
    q: DVec3,
    step: DVec3,
    p: [i64; 3],
    /// For `AM` 2: the hash's first two levels.
    prefix: u64,
    /// For `AM` 0 or 1: the hash's first two levels for every `k` of the row, from `k_first`.
    row_hash: &'a [u64],
    k_first: i64,
    pos: DVec3,
}

/// The last echogenicity seen (dB) and its amplitude (the `powf` is done on change only).
struct EchoCache {
    db: f64,
    amp: f64,
}

/// [`column_sum`] for column axis `am` (each compiled on its own).
#[inline(always)]
fn column_on_axis<const SQUARE: bool>(
    am: usize,
    cx: &ScatterContext<'_>,
    col: &Column<'_>,
    (at, grid, cells, echo): (&mut PlanePoint, &mut IqGrid, &mut CellSum, &mut EchoCache),
    sums: (f64, f64),
) -> (f64, f64) {
    match am {
        0 => column_sum::<0, SQUARE>(cx, col, at, grid, cells, echo, sums),
        1 => column_sum::<1, SQUARE>(cx, col, at, grid, cells, echo, sums),
        _ => column_sum::<2, SQUARE>(cx, col, at, grid, cells, echo, sums),
    }
}

/// Adds the column's scatterers to the running sum `(sum_i, sum_q)` at `at`, depositing it and
/// moving `at` whenever the in-plane point changes (`SQUARE`: it never does within a column,
/// and `at` is already the column's point). Generic over the column axis `AM` and `SQUARE`, so
/// that each of the six loops is compiled with its indices and checks fixed.
#[inline(always)]
fn column_sum<const AM: usize, const SQUARE: bool>(
    cx: &ScatterContext<'_>,
    col: &Column<'_>,
    at: &mut PlanePoint,
    grid: &mut IqGrid,
    cells: &mut CellSum,
    echo: &mut EchoCache,
    (mut sum_i, mut sum_q): (f64, f64),
) -> (f64, f64) {
    let geo = cx.geo;
    let f = &geo.frame;
    let lines_max = (geo.lines - 1) as f64;
    let mut q = col.q;
    let mut pos = col.pos;
    let p2 = col.p[2] as u64;
    for k in col.k.clone() {
        let here = q;
        q += col.step;
        if !SQUARE && !at.is(here.x, here.y) {
            at.deposit(grid, cells, sum_i, sum_q);
            (sum_i, sum_q) = (0.0, 0.0);
            let line = geo.plane_to_line(here.x, here.y);
            *at = PlanePoint::new(here.x, here.y, line, cx.tables, cx.k0, &cx.reach);
        }
        if !SQUARE && !at.inside {
            continue;
        }
        let ku = k as u64;
        let hsh = match AM {
            0 | 1 => splitmix64(col.row_hash[(k - col.k_first) as usize] ^ p2),
            _ => splitmix64(col.prefix ^ ku),
        };
        pos[AM] = k as f64 * cx.h;
        let tissue = cx.medium.props(pos);
        if tissue.scatter_density < 1.0 {
            let keep = crate::rng::unit_f64(splitmix64(hsh));
            if keep >= tissue.scatter_density {
                continue;
            }
        }
        if tissue.echogenicity_db != echo.db {
            echo.db = tissue.echogenicity_db;
            echo.amp = cx.norm * 10f64.powf(echo.db / 20.0);
        }
        let mut w =
            echo.amp * (exp_neg_in(cx.exp_tab, here.z * here.z * at.elev_inv2s2) * at.elev_energy);
        if tissue.texture == Texture::Fascicular {
            let ([_, _], [dx, dy]) = geo.line_in_plane(at.u.clamp(0.0, lines_max));
            let dir = f.lateral * dx + f.beam * dy;
            w *= fascicle_factor(pos, cx.medium.fibre_axis(pos), dir, cx.seed);
        }
        let (ci, cq) = iq_of_hash(hsh);
        sum_i += ci * w;
        sum_q += cq * w;
    }
    (sum_i, sum_q)
}

/// The in-plane reach of the scatter sum: line index and depth (mm) ranges.
struct Reach {
    u: (f64, f64),
    z: (f64, f64),
}

/// Everything a scatterer's deposit needs that depends only on its in-plane point (the
/// scatterers seen there are summed and deposited together: their bilinear weights are equal).
struct PlanePoint {
    x: u64,
    y: u64,
    u: f64,
    /// Fractional sample index `z / dz`.
    s: f64,
    elev_inv2s2: f64,
    elev_energy: f64,
    carrier: (f64, f64),
    /// Whether the point is within the reach (scatterers outside it are skipped).
    inside: bool,
}

impl PlanePoint {
    /// A point no scatterer has (NaN coordinates).
    fn none() -> PlanePoint {
        PlanePoint {
            x: f64::NAN.to_bits(),
            y: f64::NAN.to_bits(),
            u: f64::NAN,
            s: f64::NAN,
            elev_inv2s2: 0.0,
            elev_energy: 0.0,
            carrier: (0.0, 0.0),
            inside: false,
        }
    }

    /// The point `(x, y)` whose line index and depth are `(u, z)`.
    fn new(
        x: f64,
        y: f64,
        (u, z): (f64, f64),
        tables: &BeamTables,
        k0: f64,
        reach: &Reach,
    ) -> PlanePoint {
        if !(u >= reach.u.0 && u <= reach.u.1 && z >= reach.z.0 && z <= reach.z.1) {
            // Out of reach: its scatterers are skipped, nothing else is needed.
            return PlanePoint {
                x: x.to_bits(),
                y: y.to_bits(),
                ..PlanePoint::none()
            };
        }
        let s = z / tables.dz;
        let i = tables.sample_at(s);
        PlanePoint {
            x: x.to_bits(),
            y: y.to_bits(),
            u,
            s,
            elev_inv2s2: tables.elev_inv2s2[i],
            elev_energy: tables.elev_energy[i],
            carrier: cis(2.0 * k0 * z),
            inside: true,
        }
    }

    /// Whether `(x, y)` is this point, bit for bit.
    #[inline]
    fn is(&self, x: f64, y: f64) -> bool {
        self.x == x.to_bits() && self.y == y.to_bits()
    }

    /// Turns the sum `(i, q)` of the scatterers seen here by the carrier and deposits it.
    fn deposit(&self, grid: &mut IqGrid, cells: &mut CellSum, i: f64, q: f64) {
        if i != 0.0 || q != 0.0 {
            let (cs, sn) = self.carrier;
            cells.deposit(grid, self.u, self.s, i * cs - q * sn, i * sn + q * cs);
        }
    }
}

/// Spacing of the fascicle honeycomb, mm (our choice: lumbar roots and plexus nerves show
/// fascicles of a few tenths of a millimetre).
pub const FASCICLE_CELL_MM: f64 = 0.8;
/// Radius of a fascicle, mm (our choice).
pub const FASCICLE_RADIUS_MM: f64 = 0.3;
/// Scatter amplitude inside a fascicle and in the perineurium between them (our choice: the
/// honeycomb contrast of a nerve in short axis, about 14 dB).
pub const FASCICLE_INSIDE: f64 = 0.35;
/// See [`FASCICLE_INSIDE`].
pub const FASCICLE_OUTSIDE: f64 = 1.75;
/// Nerve echo with the beam along the fibres, relative to perpendicular (our choice: about
/// -12 dB, the anisotropy that makes nerves fade when the probe is tilted).
pub const NERVE_ANISOTROPY_FLOOR: f64 = 0.25;

/// Texture and anisotropy factor of a nerve scatterer at `p` seen along beam direction `dir`.
/// Fascicles are tubes along `axis` centred on a jittered square lattice (cell
/// [`FASCICLE_CELL_MM`]) in the plane across it, all fixed to the tissue by the seed; without
/// an axis they are blobs on a 3D lattice and there is no anisotropy.
pub(crate) fn fascicle_factor(p: DVec3, axis: Option<DVec3>, dir: DVec3, seed: u64) -> f64 {
    let c = FASCICLE_CELL_MM;
    let (coords, dims, aniso) = match axis.and_then(DVec3::try_normalize) {
        Some(a) => {
            let r = if a.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
            let b1 = (r - a * r.dot(a)).normalize();
            let b2 = a.cross(b1);
            let along = dir.dot(a);
            let aniso =
                NERVE_ANISOTROPY_FLOOR + (1.0 - NERVE_ANISOTROPY_FLOOR) * (1.0 - along * along);
            (DVec3::new(p.dot(b1), p.dot(b2), 0.0), 2, aniso)
        }
        None => (p, 3, 1.0),
    };
    let cell = (coords / c).floor();
    let mut best = f64::INFINITY;
    let range = |d: usize| if d < dims { -1..=1 } else { 0..=0 };
    for i in range(0) {
        for j in range(1) {
            for k in range(2) {
                let n = cell + DVec3::new(f64::from(i), f64::from(j), f64::from(k));
                let h = cell_hash(seed ^ 0xF45C_1C1E, n.x as i64, n.y as i64, n.z as i64);
                let (jx, jy) = iq_of_hash(h);
                let jz = if dims == 3 {
                    crate::rng::unit_f64(splitmix64(h)) - 0.5
                } else {
                    0.0
                };
                let centre = (n + DVec3::new(0.5 + 0.4 * jx, 0.5 + 0.4 * jy, 0.5 + jz * 0.8)) * c;
                let mut d = coords - centre;
                if dims == 2 {
                    d.z = 0.0;
                }
                best = best.min(d.length());
            }
        }
    }
    let inside = if best < FASCICLE_RADIUS_MM {
        FASCICLE_INSIDE
    } else {
        FASCICLE_OUTSIDE
    };
    inside * aniso
}

/// Signed I and Q of a scatterer: each the sum of two 16-bit uniforms minus 1 (mean 0,
/// variance 1/6).
fn iq_of_hash(x: u64) -> (f64, f64) {
    // u(a) + u(b) with u(sh) = ((x >> sh) & 0xFFFF) / 65536: the sum of the two 16-bit integers
    // scaled once is the same f64 (every step is exact), with one conversion instead of two.
    let pair = |a: u32, b: u32| {
        let n = ((x >> a) & 0xFFFF) as u32 + ((x >> b) & 0xFFFF) as u32;
        f64::from(n) / 65536.0 - 1.0
    };
    (pair(0, 16), pair(32, 48))
}

/// Scale making uniform tissue's mean squared speckle amplitude `10^(echogenicity/10)`:
/// `E|s|^2 = (1/h^3) (1/3) pi^(3/2) sigma_a sigma_l,focus sigma_e,focus` for unit amplitude.
fn amplitude_norm(beam: &Beam, tables: &BeamTables, h: f64) -> f64 {
    let sl = beam.lateral_fwhm_mm(beam.focus_mm) / FWHM_PER_SIGMA;
    let se = beam.elevation_fwhm_mm(beam.elevation_focus_mm) / FWHM_PER_SIGMA;
    let integral = std::f64::consts::PI.powf(1.5) * tables.axial_sigma_mm * sl * se;
    (3.0 * h * h * h / integral).sqrt()
}

/// Gaussian taps `exp(-t^2 / 2 s^2)` for `t = -k ..= k`.
fn gaussian_taps(sigma: f64, k: usize) -> Vec<f32> {
    (0..=2 * k)
        .map(|i| {
            let t = i as f64 - k as f64;
            (-(t * t) / (2.0 * sigma * sigma)).exp() as f32
        })
        .collect()
}

/// The deposit's bilinear spread has variance 1/6 step^2; the Gaussian supplies the rest.
pub(crate) fn conv_sigma(sigma_steps: f64) -> f64 {
    (sigma_steps * sigma_steps - 1.0 / 6.0).max(0.01).sqrt()
}

/// The lateral convolution of every depth row (width from the line spacing at that depth),
/// times the lateral energy factor, as per-sample tap weights.
pub(crate) struct LateralKernel {
    st: usize,
    /// `weights[t * st + s]` for tap `t` (source line `j + t - pad_l`) at padded sample `s`.
    weights: Vec<f32>,
    /// The taps with a nonzero weight at some sample (the others underflow f32 everywhere).
    taps: std::ops::Range<usize>,
}

impl LateralKernel {
    /// The kernel of `grid`'s shape; `spacing_mm(z)` is the line spacing at depth `z`.
    pub fn new(
        grid: &IqGrid,
        tables: &BeamTables,
        spacing_mm: &dyn Fn(f64) -> f64,
    ) -> LateralKernel {
        let st = grid.stride();
        let k = grid.pad_l;
        let ntap = 2 * k + 1;
        let mut weights = vec![0f32; ntap * st];
        for sp in 0..st {
            let s = sp as isize - grid.pad_s as isize;
            let z = s as f64 * tables.dz;
            let si = (s.max(0) as usize).min(grid.samples - 1);
            let sig = conv_sigma(tables.lat_sigma_mm[si] / spacing_mm(z.max(0.0)));
            let taps = gaussian_taps(sig, k);
            let en = tables.lat_energy[si] as f32;
            for t in 0..ntap {
                weights[t * st + sp] = taps[t] * en;
            }
        }
        let live = |t: &usize| weights[t * st..(t + 1) * st].iter().any(|&w| w != 0.0);
        let first = (0..ntap).find(live).unwrap_or(0);
        let last = (0..ntap).rev().find(live).map_or(0, |t| t + 1);
        LateralKernel {
            st,
            weights,
            taps: first..last.max(first),
        }
    }

    /// Unpadded line `j` of the laterally convolved grid, all `stride` padded samples, into
    /// `re`/`im`. (Skipped taps are zero at every sample: adding their products changes nothing.)
    pub fn row(&self, grid: &IqGrid, j: usize, re: &mut [f32], im: &mut [f32]) {
        let st = self.st;
        let (ore, oim) = (&mut re[..st], &mut im[..st]);
        ore.fill(0.0);
        oim.fill(0.0);
        for t in self.taps.clone() {
            // Source line (padded index) j + t - k + pad_l = j + t.
            let src = (j + t) * st;
            let w = &self.weights[t * st..(t + 1) * st];
            let (sre, sim) = (&grid.re[src..src + st], &grid.im[src..src + st]);
            for s in 0..st {
                ore[s] += w[s] * sre[s];
                oim[s] += w[s] * sim[s];
            }
        }
    }
}

/// Taps of the axial convolution with the pulse envelope (`2 pad_s + 1` of them).
pub(crate) fn axial_taps(grid: &IqGrid, tables: &BeamTables) -> Vec<f32> {
    gaussian_taps(conv_sigma(tables.axial_sigma_mm / tables.dz), grid.pad_s)
}

/// Axial convolution of one padded row (`samples + 2 pad_s` long) into its `samples` unpadded
/// samples.
pub(crate) fn convolve_axial_row(
    taps: &[f32],
    row_re: &[f32],
    row_im: &[f32],
    re: &mut [f32],
    im: &mut [f32],
) {
    for (s, (a_out, b_out)) in re.iter_mut().zip(im.iter_mut()).enumerate() {
        let (mut a, mut b) = (0f32, 0f32);
        // Output sample s is padded index s + k; sources s + k + t - k = s + t.
        for (t, w) in taps.iter().enumerate() {
            a += w * row_re[s + t];
            b += w * row_im[s + t];
        }
        *a_out = a;
        *b_out = b;
    }
}
