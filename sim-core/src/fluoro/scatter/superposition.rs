//! The scatter of a frame by kernel superposition on a coarse grid.
//!
//! The primary image is averaged over square cells of at most [`MAX_CELLS`] across. Each cell
//! is a source of scatter: its exposed fraction of the open field's signal enters, and its mean
//! primary transmission is read as a water-equivalent thickness at the frame's voltage (an
//! energy-integrating water curve from the same tables). Its scatter reaches every other cell
//! through the pencil kernel of that thickness (interpolated between the tabulated
//! thicknesses, voltages and air gaps of [`super::kernel`]), evaluated at the distance between
//! the cells' centres: kernel superposition with thickness-dependent kernels, as in the
//! adaptive scheme of Sun and Star-Lack 2010 ("Improved scatter correction using adaptive scatter
//! kernel superposition", Phys Med Biol 55:6695), with kernels from this crate's Monte Carlo
//! instead of fitted forms. The cell values are then interpolated bilinearly to the pixels.
//!
//! Scatter is low in spatial frequency (the kernels are centimetres wide at the smallest air
//! gap), so the coarse grid costs little of its accuracy: the test against the Monte Carlo's
//! broad fields states how much.

use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

use super::AntiScatterGrid;
use super::kernel::{GAPS_MM, KVPS, KernelTable, RADII, STEP_MM, WATER_MM};
use super::tables::ScatterTables;
use crate::fluoro::spectrum::Spectrum;

/// Most cells across the coarse grid (a 512 or 1024 pixel frame over the 300 mm detector: 16
/// cells of 18.75 mm). Scatter kernels are centimetres wide even at the smallest air gap; 32
/// cells cost 16 times the pairs (4 ms at 512^2 on two cores) for a centre value that moved by
/// under 1 % in the broad-field test.
pub const MAX_CELLS: usize = 16;

/// Smallest pixel pitch the scatter and receptor models accept, mm.
pub const MIN_PITCH_MM: f64 = 1e-3;

/// Most primary samples per cell side when averaging a cell (every pixel up to this, a regular
/// subsample beyond: the mean of a 64 x 64 pixel cell from 16 x 16 of them).
const SAMPLES_PER_CELL_SIDE: usize = 16;

/// How a frame's scatter is computed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScatterSettings {
    /// Tube voltage, kVp.
    pub kvp: u32,
    /// Whether the anti-scatter grid ([`AntiScatterGrid::FLUOROSCOPY`]) is in.
    pub grid: bool,
    /// Patient's exit surface to detector along the central ray, mm.
    pub air_gap_mm: f64,
    /// Pixel pitch in the detector plane, mm.
    pub pixel_pitch_mm: f64,
}

impl ScatterSettings {
    /// The factor on the primary signal: the grid's primary transmission, or 1.
    pub fn primary_factor(&self) -> f64 {
        if self.grid {
            AntiScatterGrid::FLUOROSCOPY.primary_transmission()
        } else {
            1.0
        }
    }
}

/// A frame's scatter on the coarse grid: signal relative to the open field at each cell centre.
#[derive(Debug, Clone, PartialEq)]
pub struct ScatterField {
    /// Pixels per cell side.
    pub cell_px: usize,
    /// Cells across and down.
    pub cells: [usize; 2],
    /// Scatter per cell, row-major.
    pub values: Vec<f64>,
    /// Image size, pixels.
    pub size: [usize; 2],
}

impl ScatterField {
    /// The scatter at pixel `(i, j)`: bilinear between the cell centres, constant beyond the
    /// outer centres.
    pub fn at(&self, i: usize, j: usize) -> f64 {
        let c = self.cell_px as f64;
        let (nx, ny) = (self.cells[0], self.cells[1]);
        let fx = ((i as f64 + 0.5) / c - 0.5).clamp(0.0, (nx - 1) as f64);
        let fy = ((j as f64 + 0.5) / c - 0.5).clamp(0.0, (ny - 1) as f64);
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(nx - 1), (y0 + 1).min(ny - 1));
        let (ax, ay) = (fx - x0 as f64, fy - y0 as f64);
        let v = |x: usize, y: usize| self.values[y * nx + x];
        (v(x0, y0) * (1.0 - ax) + v(x1, y0) * ax) * (1.0 - ay)
            + (v(x0, y1) * (1.0 - ax) + v(x1, y1) * ax) * ay
    }

    /// The columns' interpolation: for each pixel column, its left cell and the weight of the
    /// right one (what [`ScatterField::at`] computes per pixel).
    pub fn columns(&self) -> Vec<(usize, f64)> {
        let c = self.cell_px as f64;
        let nx = self.cells[0];
        (0..self.size[0])
            .map(|i| {
                let fx = ((i as f64 + 0.5) / c - 0.5).clamp(0.0, (nx - 1) as f64);
                let x0 = fx as usize;
                (
                    x0.min(nx.saturating_sub(2)),
                    fx - x0.min(nx.saturating_sub(2)) as f64,
                )
            })
            .collect()
    }

    /// Row `j`'s cell values interpolated down the column direction (`cells[0]` values, plus
    /// a repeated last one so a column's right neighbour always exists).
    pub fn row_cells(&self, j: usize, out: &mut Vec<f64>) {
        let c = self.cell_px as f64;
        let (nx, ny) = (self.cells[0], self.cells[1]);
        let fy = ((j as f64 + 0.5) / c - 0.5).clamp(0.0, (ny - 1) as f64);
        let y0 = fy as usize;
        let y1 = (y0 + 1).min(ny - 1);
        let ay = fy - y0 as f64;
        out.clear();
        out.extend((0..nx).map(|x| {
            let (a, b) = (self.values[y0 * nx + x], self.values[y1 * nx + x]);
            a * (1.0 - ay) + b * ay
        }));
        out.push(out[nx - 1]);
    }
}

/// The kernels of a frame: for each tabulated thickness, the scatter a fully exposed source cell
/// puts at each cell offset `(dx, dy)` (`dx, dy >= 0`), relative to the open field.
struct FrameKernels {
    /// `[water][dy * nx + dx]`.
    by_water: Vec<Vec<f64>>,
    nx: usize,
}

/// Interpolation weights of `x` in the sorted `knots`: `(lower index, fraction)`, clamped.
fn bracket(knots: &[f64], x: f64) -> (usize, f64) {
    // NaN falls to the first knot.
    if x.is_nan() || x <= knots[0] {
        return (0, 0.0);
    }
    let last = knots.len() - 1;
    if x >= knots[last] {
        return (last - 1, 1.0);
    }
    let i = knots.partition_point(|&k| k <= x) - 1;
    (i, (x - knots[i]) / (knots[i + 1] - knots[i]))
}

/// The cumulative scatter within each table radius at the frame's voltage and gap, for
/// thickness index `w` (bilinear in voltage and gap).
fn cumulative_at(kvp: f64, gap_mm: f64, w: usize, grid: bool) -> [f64; RADII] {
    let table = KernelTable::get();
    let kv: Vec<f64> = KVPS.iter().map(|&k| k as f64).collect();
    let (k0, fk) = bracket(&kv, kvp);
    let (g0, fg) = bracket(&GAPS_MM, gap_mm);
    let mut out = [0.0; RADII];
    for (k, wk) in [(k0, 1.0 - fk), (k0 + 1, fk)] {
        for (g, wg) in [(g0, 1.0 - fg), (g0 + 1, fg)] {
            let w8 = wk * wg;
            if w8 == 0.0 {
                continue;
            }
            let kernel = table.at(k, w, g);
            let c = if grid {
                &kernel.cumulative_grid
            } else {
                &kernel.cumulative
            };
            for (o, v) in out.iter_mut().zip(c) {
                *o += w8 * v;
            }
        }
    }
    out
}

/// Mean scatter density (per mm^2, relative to a unit pencil) on each ring of the table.
fn ring_densities(c: &[f64; RADII]) -> [f64; RADII] {
    std::array::from_fn(|k| {
        let (r0, r1) = (k as f64 * STEP_MM, (k + 1) as f64 * STEP_MM);
        let inner = if k == 0 { 0.0 } else { c[k - 1] };
        (c[k] - inner).max(0.0) / (std::f64::consts::PI * (r1 * r1 - r0 * r0))
    })
}

/// Density at radius `r` mm: linear between ring mid-radii, the first ring's below its middle,
/// zero beyond the table.
fn density_at(rho: &[f64; RADII], r: f64) -> f64 {
    let u = r / STEP_MM - 0.5;
    if u <= 0.0 {
        return rho[0];
    }
    let i = u as usize;
    if i + 1 >= RADII {
        return if i < RADII {
            rho[i] * (1.0 - (u - i as f64))
        } else {
            0.0
        };
    }
    let f = u - i as f64;
    rho[i] * (1.0 - f) + rho[i + 1] * f
}

impl FrameKernels {
    fn new(s: &ScatterSettings, cells: [usize; 2], cell_mm: f64) -> FrameKernels {
        let area = cell_mm * cell_mm;
        let (nx, ny) = (cells[0], cells[1]);
        let by_water = (0..WATER_MM.len())
            .map(|w| {
                let rho = ring_densities(&cumulative_at(s.kvp as f64, s.air_gap_mm, w, s.grid));
                let mut k = vec![0.0; nx * ny];
                for dy in 0..ny {
                    for dx in 0..nx {
                        let r = (dx as f64).hypot(dy as f64) * cell_mm;
                        k[dy * nx + dx] = area * density_at(&rho, r);
                    }
                }
                k
            })
            .collect();
        FrameKernels { by_water, nx }
    }
}

/// Energy-integrating transmission of water at `kvp` on a 1 mm grid from 0 to 600 mm.
fn water_curve(kvp: u32) -> Option<&'static [f64]> {
    static CURVES: OnceLock<Vec<(u32, Vec<f64>)>> = OnceLock::new();
    let curves = CURVES.get_or_init(|| {
        let tables = ScatterTables::get();
        Spectrum::available_kvp()
            .into_iter()
            .filter_map(|kv| {
                let s = Spectrum::tungsten(kv).ok()?;
                let w = s.detector_weights();
                let mu: Vec<f64> = s
                    .energies_kev
                    .iter()
                    .map(|&e| tables.water(e).total_per_mm())
                    .collect();
                let curve = (0..=600)
                    .map(|mm| {
                        w.iter()
                            .zip(&mu)
                            .map(|(w, m)| w * (-m * mm as f64).exp())
                            .sum::<f64>()
                    })
                    .collect();
                Some((kv, curve))
            })
            .collect()
    });
    curves
        .iter()
        .find(|(k, _)| *k == kvp)
        .map(|(_, c)| c.as_slice())
}

/// Energy-integrating transmission of `mm` (0 to 600) of water at `kvp` (log-linear between
/// the curve's millimetres; `None` for a voltage without a spectrum).
pub fn water_transmission(kvp: u32, mm: f64) -> Option<f64> {
    let curve = water_curve(kvp)?;
    let x = mm.clamp(0.0, (curve.len() - 1) as f64);
    let i = (x as usize).min(curve.len() - 2);
    let a = x - i as f64;
    Some((curve[i].ln() * (1.0 - a) + curve[i + 1].ln() * a).exp())
}

/// The water thickness (mm, 0 to 600) whose energy-integrating transmission at `kvp` is `t`
/// (`None` for a voltage without a spectrum).
pub fn water_equivalent_mm(kvp: u32, t: f64) -> Option<f64> {
    let curve = water_curve(kvp)?;
    if t.is_nan() || t >= 1.0 {
        return Some(0.0);
    }
    if t <= curve[curve.len() - 1] {
        return Some((curve.len() - 1) as f64);
    }
    // The curve falls: the first index below t.
    let i = curve.partition_point(|&c| c > t);
    if i == 0 {
        return Some(0.0);
    }
    let (a, b) = (curve[i - 1], curve[i]);
    Some((i - 1) as f64 + (a - t) / (a - b))
}

/// How much of cell `(x, y)`'s whole area lies inside the image (1 but for the last row and
/// column of a grid that does not divide the image), so its samples scale to a whole cell.
fn cell_full_fraction(x: usize, y: usize, cell_px: usize, width: usize, height: usize) -> f64 {
    let w = (width - x * cell_px).min(cell_px) as f64;
    let h = (height - y * cell_px).min(cell_px) as f64;
    let c = cell_px as f64;
    c * c / (w * h)
}

/// The scatter of a frame whose primary transmission (relative to the open field, energy
/// integrating) is `t`, row-major `width x height`, with its exposure mask. `None` for a voltage
/// without a spectrum or an empty image.
pub fn scatter_field<T: Copy + Into<f64>>(
    t: &[T],
    exposed: &[bool],
    width: usize,
    height: usize,
    s: &ScatterSettings,
) -> Option<ScatterField> {
    if width == 0 || height == 0 || t.len() != width * height || exposed.len() != t.len() {
        return None;
    }
    // A pitch under a micrometre (or not a number) is no detector's.
    if s.pixel_pitch_mm.is_nan()
        || s.pixel_pitch_mm < MIN_PITCH_MM
        || s.pixel_pitch_mm.is_infinite()
    {
        return None;
    }
    water_curve(s.kvp)?;
    let cell_px = width.max(height).div_ceil(MAX_CELLS).max(1);
    let cells = [width.div_ceil(cell_px), height.div_ceil(cell_px)];
    let (nx, ny) = (cells[0], cells[1]);
    let cell_mm = cell_px as f64 * s.pixel_pitch_mm;
    // Each cell: exposed fraction of the cell's area, mean primary transmission of the exposed.
    let mut sum_t = vec![0.0f64; nx * ny];
    let mut count = vec![0usize; nx * ny];
    let mut samples = vec![0usize; nx * ny];
    let stride = cell_px.div_ceil(SAMPLES_PER_CELL_SIDE).max(1);
    for j in (stride / 2..height).step_by(stride) {
        let row = (j / cell_px) * nx;
        for i in (stride / 2..width).step_by(stride) {
            let p = j * width + i;
            let c = row + i / cell_px;
            samples[c] += 1;
            if exposed[p] {
                sum_t[c] += t[p].into();
                count[c] += 1;
            }
        }
    }
    // Sources: (cell x, cell y, weight on the lower thickness index, index, fraction).
    let mut sources = Vec::with_capacity(nx * ny);
    for c in 0..nx * ny {
        if count[c] == 0 {
            continue;
        }
        // The cell's exposed share of a whole cell's area (an edge cell is part outside the
        // image: its missing samples count as unexposed).
        let full =
            samples[c].max(1) as f64 * cell_full_fraction(c % nx, c / nx, cell_px, width, height);
        let mean_t = sum_t[c] / count[c] as f64;
        // A non-finite or negative mean (a broken image) is read as opaque.
        let mean_t = if mean_t.is_finite() {
            mean_t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let tau = water_equivalent_mm(s.kvp, mean_t)?;
        let exposed_fraction = count[c] as f64 / full;
        // Below the thinnest tabulated slab, scatter grows in proportion to the thickness.
        let (w, f, scale) = if tau < WATER_MM[0] {
            (0, 0.0, tau / WATER_MM[0])
        } else {
            let (w, f) = bracket(&WATER_MM, tau);
            (w, f, 1.0)
        };
        sources.push((c % nx, c / nx, w, f, exposed_fraction * scale));
    }
    let kernels = FrameKernels::new(s, cells, cell_mm);
    let mut values = vec![0.0; nx * ny];
    for (c, v) in values.iter_mut().enumerate() {
        let (x, y) = (c % nx, c / nx);
        let mut acc = 0.0;
        for &(sx, sy, w, f, weight) in &sources {
            let off = y.abs_diff(sy) * kernels.nx + x.abs_diff(sx);
            let k0 = kernels.by_water[w][off];
            let k = if f > 0.0 {
                k0 + f * (kernels.by_water[w + 1][off] - k0)
            } else {
                k0
            };
            acc += weight * k;
        }
        *v = acc;
    }
    Some(ScatterField {
        cell_px,
        cells,
        values,
        size: [width, height],
    })
}

/// Scatter-to-primary ratio at the centre of a rectangular field of half-sides `half_x_mm` and
/// `half_y_mm` (at the detector) on a uniform water slab of `water_mm`, by the same superposition
/// (the automatic brightness control's estimate of the scatter it meters). `None` for a voltage
/// without a spectrum.
pub fn centre_spr(
    kvp: u32,
    water_mm: f64,
    half_x_mm: f64,
    half_y_mm: f64,
    air_gap_mm: f64,
    grid: bool,
) -> Option<f64> {
    let curve = water_curve(kvp)?;
    let tau = if water_mm.is_nan() {
        0.0
    } else {
        water_mm.clamp(0.0, (curve.len() - 1) as f64)
    };
    let (w, f, scale) = if tau < WATER_MM[0] {
        (0, 0.0, tau / WATER_MM[0])
    } else {
        let (w, f) = bracket(&WATER_MM, tau);
        (w, f, 1.0)
    };
    // Beyond the table's 500 mm reach the kernels are zero: a larger field adds nothing.
    let reach = RADII as f64 * STEP_MM;
    let (half_x_mm, half_y_mm) = (
        half_x_mm.clamp(0.0, reach).max(0.0),
        half_y_mm.clamp(0.0, reach).max(0.0),
    );
    let rho = |w: usize| ring_densities(&cumulative_at(kvp as f64, air_gap_mm, w, grid));
    let (r0, r1) = (rho(w), rho((w + 1).min(WATER_MM.len() - 1)));
    // Integrate over the rectangle on a 5 mm grid (a quarter, by symmetry; the kernels are
    // tabulated on 10 mm rings).
    let step = 5.0;
    let (mx, my) = (
        (half_x_mm / step).ceil().max(1.0) as usize,
        (half_y_mm / step).ceil().max(1.0) as usize,
    );
    let (dx, dy) = (half_x_mm / mx as f64, half_y_mm / my as f64);
    let mut sum = 0.0;
    for j in 0..my {
        for i in 0..mx {
            let r = ((i as f64 + 0.5) * dx).hypot((j as f64 + 0.5) * dy);
            sum += (1.0 - f) * density_at(&r0, r) + f * density_at(&r1, r);
        }
    }
    let scatter = 4.0 * sum * dx * dy * scale;
    let primary_factor = if grid {
        AntiScatterGrid::FLUOROSCOPY.primary_transmission()
    } else {
        1.0
    };
    let primary = water_transmission(kvp, tau)? * primary_factor;
    Some(scatter / primary)
}
