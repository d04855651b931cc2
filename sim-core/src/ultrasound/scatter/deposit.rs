//! The deposit: every lattice scatterer within reach of the frame, weighted by the elevation
//! profile at its distance from the slice, turned by its carrier phase and deposited bilinearly
//! on the (line, sample) grid, before any convolution.

use std::f64::consts::PI;

use glam::DVec3;

use super::super::beam::{Beam, FWHM_PER_SIGMA};
use super::super::probe::{ProbeFrame, ScanGeometry};
use super::super::tissue::{AcousticMedium, ScatterProps, Texture};
use super::amplitude::iq_of_hash;
use super::column::{Column, EchoCache, Reach, ScatterContext};
use super::fascicle::fascicle_factor;
use super::grid::{CellSum, IqGrid};
use super::lookup::{cis, exp_neg_in, exp_table};
use super::oblique::{ConvexReach, column_oblique};
use super::tables::BeamTables;
use crate::rng::splitmix64;

/// Elevation reach of the scatter sum, in FWHM of the slice at each depth.
const ELEV_REACH_FWHM: f64 = 1.0;

/// The tissue's scatterer lattice: cell side and seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ScatterField {
    pub cell_mm: f64,
    pub seed: u64,
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

/// Deposits every lattice scatterer within reach of the frame into `grid` (not yet convolved),
/// asking `stop` before each row of lattice columns: once it says so, the rest is left out
/// (the caller discards the grid).
#[expect(
    clippy::too_many_arguments,
    reason = "one frame's deposit, called from `scan`"
)]
pub(crate) fn deposit_scatterers(
    grid: &mut IqGrid,
    geo: &ScanGeometry,
    beam: &Beam,
    tables: &BeamTables,
    medium: &dyn AcousticMedium,
    field: ScatterField,
    part: u64,
    stop: &(dyn Fn() -> bool + Sync),
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
    // The tissue of the current column's cells (one call to the medium per column).
    let mut tissues: Vec<ScatterProps> = Vec::new();
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
        by_column: medium.lookups_by_column(),
    };
    // Square to the lattice, a column keeps its in-plane point exactly (steps of zero).
    let square = step_m.x == 0.0 && step_m.y == 0.0;
    // Rows of columns cross the frame's bounding box in region axes; a tilted or rotated frame
    // fills little of it. Each row visits only the columns whose in-plane trace can meet the
    // reach (every other column's scatterers are all out of reach, so the sum is unchanged).
    let columns = ColumnSpan::new(geo, &cx.reach, &unit, (am, ab), h, t_e * drift);
    let region = ConvexReach::new(geo, &cx.reach);
    for ia in idx_lo(aa)..=idx_hi(aa) {
        // Two interleaved halves of the lattice (a fixed split, so the sum is deterministic).
        if ia.rem_euclid(2) as u64 != part {
            continue;
        }
        if stop() {
            return;
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
        let mut row = DVec3::ZERO;
        row[aa] = ia as f64 * h;
        let (ib_lo, ib_hi) = columns.of_row(f.to_probe(row), (idx_lo(ab), idx_hi(ab)));
        for ib in ib_lo..=ib_hi {
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
            let state = (&mut echo, &mut tissues);
            if square {
                (sum_i, sum_q) = column_on_axis(am, &cx, &col, (&at, state), (sum_i, sum_q));
            } else {
                match am {
                    0 => column_oblique::<0>(&cx, &col, &region, grid, &mut cells, state),
                    1 => column_oblique::<1>(&cx, &col, &region, grid, &mut cells, state),
                    _ => column_oblique::<2>(&cx, &col, &region, grid, &mut cells, state),
                }
            }
        }
    }
    at.deposit(grid, &mut cells, sum_i, sum_q);
    cells.flush(grid);
}

/// The in-plane box that holds every point within the deposit's reach, and how a row's columns
/// cross the plane: the column `ib` of a row whose region origin maps to `q_row` (probe frame)
/// meets the slice at `q_row + ib (h unit_ab - h unit_am unit_ab.z / em) - unit_am q_row.z / em`,
/// and its scatterers stray at most `wander` mm in plane from there.
struct ColumnSpan {
    /// `(x_min, x_max, y_min, y_max)`, mm, widened by the wander and a cell.
    area: (f64, f64, f64, f64),
    /// In-plane step per column, mm.
    per_column: (f64, f64),
    unit_am: DVec3,
}

impl ColumnSpan {
    fn new(
        geo: &ScanGeometry,
        reach: &Reach,
        unit: &[DVec3; 3],
        (am, ab): (usize, usize),
        h: f64,
        wander: f64,
    ) -> ColumnSpan {
        let (x0, x1, y0, y1) = reach_area(geo, reach);
        let pad = wander + h;
        let em = unit[am].z;
        let step = unit[ab] * h - unit[am] * (unit[ab].z * h / em);
        ColumnSpan {
            area: (x0 - pad, x1 + pad, y0 - pad, y1 + pad),
            per_column: (step.x, step.y),
            unit_am: unit[am],
        }
    }

    /// The columns `lo..=hi` (within `bounds`) of the row whose region origin maps to `q_row`.
    fn of_row(&self, q_row: DVec3, (lo, hi): (i64, i64)) -> (i64, i64) {
        let c = q_row - self.unit_am * (q_row.z / self.unit_am.z);
        let (x0, x1, y0, y1) = self.area;
        let (mut a, mut b) = (lo as f64, hi as f64);
        for (start, d, min, max) in [
            (c.x, self.per_column.0, x0, x1),
            (c.y, self.per_column.1, y0, y1),
        ] {
            if d.abs() < 1e-12 {
                if start < min || start > max {
                    return (1, 0);
                }
                continue;
            }
            let (mut t0, mut t1) = ((min - start) / d, (max - start) / d);
            if t0 > t1 {
                std::mem::swap(&mut t0, &mut t1);
            }
            a = a.max(t0);
            b = b.min(t1);
        }
        // Empty, or NaN from a degenerate frame (then nothing of the row is in reach either).
        if a.partial_cmp(&b)
            .is_none_or(|o| o == std::cmp::Ordering::Greater)
        {
            return (1, 0);
        }
        // A cell of slack on each side against rounding.
        (
            (a.floor() as i64 - 1).max(lo),
            (b.ceil() as i64 + 1).min(hi),
        )
    }
}

/// The in-plane box (image coordinates, mm) of every point whose line index and depth are
/// within `reach`: the padded lines' footprint (linear) or annular sector (curvilinear).
fn reach_area(geo: &ScanGeometry, reach: &Reach) -> (f64, f64, f64, f64) {
    use super::super::probe::ProbeKind;
    let at = |u: f64| geo.line_coordinate(u);
    match geo.spec.kind {
        ProbeKind::Linear => (at(reach.u.0), at(reach.u.1), reach.z.0, reach.z.1),
        ProbeKind::Curvilinear => {
            let r0 = geo.spec.radius_mm;
            let theta = |u: f64| at(u).clamp(-PI, PI);
            let (t0, t1) = (theta(reach.u.0), theta(reach.u.1));
            let (r_lo, r_hi) = ((r0 + reach.z.0).max(0.0), (r0 + reach.z.1).max(0.0));
            // The box of an annular sector: its corners, and where it crosses an axis.
            let mut angles = vec![t0, t1];
            angles.extend(
                [-PI / 2.0, 0.0, PI / 2.0]
                    .into_iter()
                    .filter(|a| (t0..=t1).contains(a)),
            );
            let (mut x_lo, mut x_hi, mut y_lo, mut y_hi) = (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            );
            for r in [r_lo, r_hi] {
                for &t in &angles {
                    let (sn, cs) = t.sin_cos();
                    x_lo = x_lo.min(r * sn);
                    x_hi = x_hi.max(r * sn);
                    y_lo = y_lo.min(r * cs - r0);
                    y_hi = y_hi.max(r * cs - r0);
                }
            }
            (x_lo, x_hi, y_lo, y_hi)
        }
    }
}

/// [`column_sum`] for column axis `am` (each compiled on its own).
#[inline(always)]
fn column_on_axis(
    am: usize,
    cx: &ScatterContext<'_>,
    col: &Column<'_>,
    (at, state): (&PlanePoint, (&mut EchoCache, &mut Vec<ScatterProps>)),
    sums: (f64, f64),
) -> (f64, f64) {
    match am {
        0 => column_sum::<0>(cx, col, at, state, sums),
        1 => column_sum::<1>(cx, col, at, state, sums),
        _ => column_sum::<2>(cx, col, at, state, sums),
    }
}

/// Adds the scatterers of a column square to the slice (all at the in-plane point `at`) to the
/// running sum `(sum_i, sum_q)` at `at`. Generic over the column axis `AM`, so that each of the
/// three loops is compiled with its indices fixed.
#[inline(always)]
fn column_sum<const AM: usize>(
    cx: &ScatterContext<'_>,
    col: &Column<'_>,
    at: &PlanePoint,
    (echo, tissues): (&mut EchoCache, &mut Vec<ScatterProps>),
    (mut sum_i, mut sum_q): (f64, f64),
) -> (f64, f64) {
    let geo = cx.geo;
    let f = &geo.frame;
    let lines_max = (geo.lines - 1) as f64;
    let mut q = col.q;
    let mut pos = col.pos;
    col.tissue::<AM>(cx, col.k.clone(), tissues);
    for (i, k) in col.k.clone().enumerate() {
        let tissue = &col.tissue_at::<AM>(cx, (i, k), tissues);
        let here = q;
        q += col.step;
        let Some(hsh) = col.scatterer::<AM>(cx, k, tissue, &mut pos, echo) else {
            continue;
        };
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
        if !reach.contains(u, z) {
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

/// Scale making uniform tissue's mean squared speckle amplitude `10^(echogenicity/10)`:
/// `E|s|^2 = (1/h^3) (1/3) pi^(3/2) sigma_a sigma_l,focus sigma_e,focus` for unit amplitude.
fn amplitude_norm(beam: &Beam, tables: &BeamTables, h: f64) -> f64 {
    let sl = beam.lateral_fwhm_mm(beam.focus_mm) / FWHM_PER_SIGMA;
    let se = beam.elevation_fwhm_mm(beam.elevation_focus_mm) / FWHM_PER_SIGMA;
    let integral = std::f64::consts::PI.powf(1.5) * tables.axial_sigma_mm * sl * se;
    (3.0 * h * h * h / integral).sqrt()
}

#[cfg(test)]
mod tests {
    use super::super::column::test_frames;
    use super::*;
    use crate::ultrasound::probe::{ProbeKind, ProbePose};

    /// Every column that a row leaves out has its whole in-plane trace (the slab's elevations)
    /// out of reach, for both probes and poses square, tilted and rotated: skipping it cannot
    /// change the deposit.
    #[test]
    fn the_columns_a_row_skips_are_all_out_of_reach() {
        let mut rand = test_frames::uniform(0x2545_f491_4f6c_dd1d);
        let h = 0.2;
        let t_e = 3.0;
        for kind in [ProbeKind::Linear, ProbeKind::Curvilinear] {
            for trial in 0..12 {
                let beam = if trial == 0 {
                    DVec3::Z
                } else {
                    DVec3::new(rand() - 0.5, rand() - 0.5, 1.0)
                };
                let pose = ProbePose::from_rotation(
                    DVec3::new(10.0 * rand(), -5.0 * rand(), 2.0),
                    beam,
                    if trial == 0 {
                        0.0
                    } else {
                        180.0 * rand() - 90.0
                    },
                );
                let (geo, reach) = test_frames::scan_at(kind, pose);
                let f = &geo.frame;
                let unit: [DVec3; 3] =
                    std::array::from_fn(|a| f.to_probe(f.origin + DVec3::AXES[a]));
                let bounds = lattice_bounds(f, (-60.0, 60.0, -20.0, 80.0), t_e, h);
                let (am, (aa, ab)) = (bounds.column_axis, bounds.across);
                let em = unit[am].z;
                let drift = unit[am].x.hypot(unit[am].y) / em.abs();
                let span = ColumnSpan::new(&geo, &reach, &unit, (am, ab), h, t_e * drift);
                let (lo, hi) = (bounds.lo_cell[ab], bounds.hi_cell[ab]);
                let mut skipped = 0;
                for ia in (bounds.lo_cell[aa]..=bounds.hi_cell[aa]).step_by(7) {
                    let mut row = DVec3::ZERO;
                    row[aa] = ia as f64 * h;
                    let q_row = f.to_probe(row);
                    let (a, b) = span.of_row(q_row, (lo, hi));
                    for ib in (lo..=hi).filter(|ib| *ib < a || *ib > b) {
                        skipped += 1;
                        let q0 = q_row + unit[ab] * (ib as f64 * h);
                        let qc = q0 - unit[am] * (q0.z / em);
                        for i in 0..=8 {
                            let e = t_e * (i as f64 / 4.0 - 1.0);
                            let q = qc + unit[am] * (e / em);
                            assert!(
                                !test_frames::in_reach(&geo, &reach, q.x, q.y),
                                "{kind:?} trial {trial}: row {ia} column {ib} skipped but in reach at e {e}"
                            );
                        }
                    }
                }
                if trial > 0 {
                    assert!(
                        skipped > 0,
                        "{kind:?} trial {trial}: a rotated frame skips columns"
                    );
                }
            }
        }
    }
}
