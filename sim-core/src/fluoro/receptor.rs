//! Image receptor profiles: what the detector does to the signal between the X-rays that reach
//! it and the picture, for a flat panel and an image intensifier.
//!
//! Applied to the mean signal (primary plus scatter) before quantum noise, in this order:
//! 1. veiling glare: a fraction of the signal spread over centimetres (light scattered in the
//!    scintillator or the intensifier's output window and optics), on the coarse grid of the
//!    scatter model;
//! 2. the point-spread function's core: a Gaussian of `psf_sigma_mm` (the scintillator's light
//!    spread; for the intensifier also its electron optics and camera), separable, per pixel;
//! 3. pincushion distortion (intensifier only): the curved input phosphor maps a point at
//!    normalised radius `rho` (distance from the image centre over half the image side) to
//!    `rho (1 + k rho^2)`, so the periphery is magnified; the picture is resampled
//!    (bilinearly) and the collimator mask with it.
//!
//! Then, after noise and tone mapping, vignetting (intensifier only): the output's brightness
//! falls as `1 - a rho^2` (light lost in the optics after the quantum sink, so it dims the
//! periphery without adding noise), applied as the grey offset that factor is on the log tone
//! curve.
//!
//! Quantum noise stays white per pixel: its correlation by the point-spread function is not
//! modelled (simulator choice; the noise variance then follows the detector kerma exactly).
//!
//! Everything a rubric measures stays in patient space: [`Distortion::undistort_px`] turns a
//! pixel of a distorted image back into the pixel of the ideal projection, whose ray
//! [`crate::fluoro::Projection::pixel_ray`] gives.

use serde::{Deserialize, Serialize};

use super::scatter::superposition::{MIN_PITCH_MM, ScatterField};

/// The kind of image receptor a station's C-arm has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReceptorKind {
    /// A CsI flat-panel detector.
    FlatPanel,
    /// An image intensifier with a camera.
    ImageIntensifier,
}

/// The stated parameters of a receptor (simulator choices; see each kind's values in
/// [`ReceptorKind::params`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReceptorParams {
    /// Standard deviation of the Gaussian point-spread core, mm in the detector plane.
    pub psf_sigma_mm: f64,
    /// Fraction of the signal spread as veiling glare.
    pub glare_fraction: f64,
    /// Standard deviation of the glare's Gaussian spread, mm.
    pub glare_sigma_mm: f64,
    /// Fractional brightness loss at the middle of an image edge (`rho = 1`): `a`.
    pub vignetting: f64,
    /// Pincushion coefficient `k` (0: none).
    pub pincushion: f64,
}

impl ReceptorKind {
    /// Both kinds.
    pub const ALL: [ReceptorKind; 2] = [ReceptorKind::FlatPanel, ReceptorKind::ImageIntensifier];

    /// The name commands and station files use.
    pub fn name(self) -> &'static str {
        match self {
            ReceptorKind::FlatPanel => "flat_panel",
            ReceptorKind::ImageIntensifier => "image_intensifier",
        }
    }

    /// The kind named `name`.
    pub fn parse(name: &str) -> Option<ReceptorKind> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }

    /// The receptor's parameters. Simulator choices, set from the contrasts the literature
    /// draws between the two (J. A. Seibert, "Flat-panel detectors: how much better are
    /// they?", Pediatr. Radiol. 36 Suppl. 2 (2006) 173-181: flat panels free of the
    /// intensifier's distortion, vignetting and veiling glare, at higher resolution):
    /// - flat panel: PSF core 0.15 mm (MTF 0.64 at 1 cycle/mm), 2 % long-tail glare over
    ///   10 mm, no vignetting or distortion;
    /// - image intensifier: core 0.25 mm (MTF 0.29 at 1 cycle/mm), 10 % veiling glare over
    ///   40 mm, 20 % vignetting at the edge's middle (36 % at the corners), pincushion
    ///   `k = 0.05` (a point at the edge's middle appears 5 % farther out).
    pub fn params(self) -> ReceptorParams {
        match self {
            ReceptorKind::FlatPanel => ReceptorParams {
                psf_sigma_mm: 0.15,
                glare_fraction: 0.02,
                glare_sigma_mm: 10.0,
                vignetting: 0.0,
                pincushion: 0.0,
            },
            ReceptorKind::ImageIntensifier => ReceptorParams {
                psf_sigma_mm: 0.25,
                glare_fraction: 0.10,
                glare_sigma_mm: 40.0,
                vignetting: 0.20,
                pincushion: 0.05,
            },
        }
    }
}

/// How a frame's receptor is applied.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ReceptorSettings {
    /// The receptor.
    pub kind: ReceptorKind,
    /// Pixel pitch in the detector plane, mm.
    pub pixel_pitch_mm: f64,
}

/// The pincushion mapping of an image `width x height` pixels with coefficient `k`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distortion {
    /// Image centre, continuous pixel coordinates.
    pub centre: [f64; 2],
    /// Half the image side (the larger), pixels: `rho = 1` there.
    pub half_side_px: f64,
    /// Coefficient `k`.
    pub k: f64,
}

impl Distortion {
    /// The mapping of `kind` on a `width x height` image, or `None` for a kind without
    /// distortion.
    pub fn of(kind: ReceptorKind, width: u32, height: u32) -> Option<Distortion> {
        let k = kind.params().pincushion;
        (k != 0.0).then(|| Distortion {
            centre: [0.5 * f64::from(width), 0.5 * f64::from(height)],
            half_side_px: 0.5 * f64::from(width.max(height)),
            k,
        })
    }

    /// Where the ideal projection's pixel `px` appears in the distorted image.
    pub fn distort_px(&self, px: [f64; 2]) -> [f64; 2] {
        let (dx, dy) = (px[0] - self.centre[0], px[1] - self.centre[1]);
        let rho2 = (dx * dx + dy * dy) / (self.half_side_px * self.half_side_px);
        let s = 1.0 + self.k * rho2;
        [self.centre[0] + dx * s, self.centre[1] + dy * s]
    }

    /// The ideal projection's pixel that appears at `px` of the distorted image (the inverse
    /// of [`Distortion::distort_px`], by Newton's method on `rho_u (1 + k rho_u^2) = rho_d`).
    pub fn undistort_px(&self, px: [f64; 2]) -> [f64; 2] {
        let (dx, dy) = (px[0] - self.centre[0], px[1] - self.centre[1]);
        let rho_d = (dx * dx + dy * dy).sqrt() / self.half_side_px;
        let s = self.source_scale(rho_d);
        [self.centre[0] + dx * s, self.centre[1] + dy * s]
    }

    /// `rho_u / rho_d` tabulated against `rho_d^2` over the image (corners included), for
    /// resampling a whole frame.
    fn scale_table(&self) -> RadialTable {
        RadialTable::new(|q| self.source_scale(q.sqrt()))
    }

    /// `rho_u / rho_d` for a distorted radius `rho_d`.
    fn source_scale(&self, rho_d: f64) -> f64 {
        if rho_d <= 0.0 || !rho_d.is_finite() {
            return 1.0;
        }
        let mut u = rho_d;
        for _ in 0..20 {
            let f = u * (1.0 + self.k * u * u) - rho_d;
            let df = 1.0 + 3.0 * self.k * u * u;
            let step = f / df;
            u -= step;
            if step.abs() < 1e-15 {
                break;
            }
        }
        u / rho_d
    }
}

/// A function of `rho^2` on `[0, 2]` (the square image's corners are at 2) tabulated at 4,097
/// points, linear in between (error below 1e-8 for the pincushion's scale and below 1e-6 of a
/// grey level for the vignetting offset: the step squared times the second derivative over 8).
struct RadialTable {
    values: Vec<f64>,
}

impl RadialTable {
    const STEPS: usize = 4096;
    const MAX_RHO2: f64 = 2.0;

    fn new(f: impl Fn(f64) -> f64) -> RadialTable {
        RadialTable {
            values: (0..=Self::STEPS)
                .map(|k| f(k as f64 * Self::MAX_RHO2 / Self::STEPS as f64))
                .collect(),
        }
    }

    fn at(&self, rho2: f64) -> f64 {
        let u = (rho2 / Self::MAX_RHO2 * Self::STEPS as f64).clamp(0.0, Self::STEPS as f64);
        let i = (u as usize).min(Self::STEPS - 1);
        let f = u - i as f64;
        self.values[i] + f * (self.values[i + 1] - self.values[i])
    }
}

/// Applies glare, the point-spread core and the distortion of `s` to the signal image `signal`
/// (`width x height`, row-major) and its exposure mask, on `threads` workers. Returns the mask
/// of the result (the distorted mask, or a copy).
pub fn apply(
    signal: &mut [f32],
    exposed: &[bool],
    width: usize,
    height: usize,
    s: &ReceptorSettings,
    threads: usize,
) -> Vec<bool> {
    let p = s.kind.params();
    if !valid(signal, exposed, width, height, s) {
        return exposed.to_vec();
    }
    glare(
        signal,
        exposed,
        width,
        height,
        &p,
        s.pixel_pitch_mm,
        threads,
    );
    apply_after_glare(signal, exposed, width, height, s, threads)
}

/// Below this core width, pixels (the side taps would carry under 0.4 % of the weight), the
/// blur is skipped: a flat panel's 0.15 mm core on the 0.59 mm pixels of a 512^2 frame.
pub const MIN_BLUR_SIGMA_PX: f64 = 0.3;

/// [`apply`] without the glare (for a caller that folded the glare into its own pass, as the
/// frame's finish does with the scatter): the point-spread core and the distortion.
pub fn apply_after_glare(
    signal: &mut [f32],
    exposed: &[bool],
    width: usize,
    height: usize,
    s: &ReceptorSettings,
    threads: usize,
) -> Vec<bool> {
    let p = s.kind.params();
    if !valid(signal, exposed, width, height, s) {
        return exposed.to_vec();
    }
    let sigma_px = p.psf_sigma_mm / s.pixel_pitch_mm;
    if sigma_px.is_finite() && sigma_px >= MIN_BLUR_SIGMA_PX {
        blur(signal, width, height, sigma_px, threads);
    }
    match Distortion::of(s.kind, width as u32, height as u32) {
        // The resampling map packs two flags above the pixel index: images of 2^30 pixels and
        // more (32768^2, no detector's) are not distorted.
        Some(d) if width * height < 1 << 30 => distort(signal, exposed, width, height, &d, threads),
        _ => exposed.to_vec(),
    }
}

/// Whether an image and its settings can be processed: sizes that agree, and a pitch of at
/// least [`MIN_PITCH_MM`] (anything else is left as it is).
fn valid(
    signal: &[f32],
    exposed: &[bool],
    width: usize,
    height: usize,
    s: &ReceptorSettings,
) -> bool {
    width > 0
        && height > 0
        && signal.len() == width * height
        && exposed.len() == signal.len()
        && s.pixel_pitch_mm.is_finite()
        && s.pixel_pitch_mm >= MIN_PITCH_MM
}

/// Cell means of an image on a coarse grid of `cell_px` pixels and `cells` cells, from a
/// regular subsample (at most 16 x 16 per cell): the mean over the whole cell (unexposed pixels,
/// and the part of an edge cell outside the image, counting 0) and the exposed share of the
/// whole cell.
pub fn cell_means<T: Copy + Into<f64>>(
    t: &[T],
    exposed: &[bool],
    width: usize,
    height: usize,
    cell_px: usize,
    cells: [usize; 2],
) -> (Vec<f64>, Vec<f64>) {
    let nx = cells[0];
    let n = cells[0] * cells[1];
    let stride = cell_px.div_ceil(16).max(1);
    let (mut sum, mut hits) = (vec![0.0f64; n], vec![0usize; n]);
    for j in (stride / 2..height).step_by(stride) {
        for i in (stride / 2..width).step_by(stride) {
            let c = (j / cell_px) * nx + i / cell_px;
            if exposed[j * width + i] {
                let v: f64 = t[j * width + i].into();
                sum[c] += if v.is_finite() { v } else { 0.0 };
                hits[c] += 1;
            }
        }
    }
    // Per whole cell: a cell cut by the image's edge counts its missing part as empty, so it
    // weighs as much as the part of it that is in the image.
    // Sample positions `stride / 2 + k stride` in `[lo, hi)` (cells need not hold a whole
    // number of strides).
    let positions = |lo: usize, hi: usize| -> usize {
        let off = stride / 2;
        let first = if lo <= off {
            off
        } else {
            off + (lo - off).div_ceil(stride) * stride
        };
        if first >= hi {
            0
        } else {
            (hi - 1 - first) / stride + 1
        }
    };
    let whole = |c: usize| {
        let (x, y) = (c % nx, c / nx);
        let count =
            positions(x * cell_px, (x + 1) * cell_px) * positions(y * cell_px, (y + 1) * cell_px);
        count.max(1) as f64
    };
    let means = (0..n).map(|c| sum[c] / whole(c)).collect();
    let share = (0..n).map(|c| hits[c] as f64 / whole(c)).collect();
    (means, share)
}

/// The glare of cell means `means` (`cells` across and down, `cell_mm` wide): each cell's mean
/// spread by the receptor's glare Gaussian, sampled at the cells' centres and normalised over
/// the whole (infinite) lattice so that a uniform field keeps its value whatever the cell size.
pub fn glare_cells(means: &[f64], cells: [usize; 2], cell_mm: f64, p: &ReceptorParams) -> Vec<f64> {
    let (nx, ny) = (cells[0], cells[1]);
    let sigma = (p.glare_sigma_mm / cell_mm).max(1e-3);
    let reach = ((6.0 * sigma).ceil() as i64 + 1).min(nx.max(ny) as i64 + 1);
    let lattice: f64 = (-reach..=reach)
        .map(|k| (-((k * k) as f64) / (2.0 * sigma * sigma)).exp())
        .sum();
    let norm = 1.0 / (lattice * lattice);
    let weights: Vec<f64> = (0..nx * ny)
        .map(|o| {
            let (dx, dy) = ((o % nx) as f64, (o / nx) as f64);
            (-(dx * dx + dy * dy) / (2.0 * sigma * sigma)).exp() * norm
        })
        .collect();
    (0..nx * ny)
        .map(|c| {
            let (x, y) = (c % nx, c / nx);
            means
                .iter()
                .enumerate()
                .map(|(s, m)| m * weights[y.abs_diff(s / nx) * nx + x.abs_diff(s % nx)])
                .sum()
        })
        .collect()
}

/// Veiling glare: `(1 - g) s + g (G * s)`, the convolution on the coarse grid (cell means of
/// the whole image, shutters included), interpolated back to the exposed pixels.
fn glare(
    signal: &mut [f32],
    exposed: &[bool],
    width: usize,
    height: usize,
    p: &ReceptorParams,
    pitch_mm: f64,
    threads: usize,
) {
    let g = p.glare_fraction;
    if g <= 0.0 {
        return;
    }
    let cell_px = width
        .max(height)
        .div_ceil(super::scatter::superposition::MAX_CELLS)
        .max(1);
    let (nx, ny) = (width.div_ceil(cell_px), height.div_ceil(cell_px));
    let all = vec![true; exposed.len()];
    let (means, _) = cell_means(signal, &all, width, height, cell_px, [nx, ny]);
    let values = glare_cells(&means, [nx, ny], cell_px as f64 * pitch_mm, p);
    let field = ScatterField {
        cell_px,
        cells: [nx, ny],
        values,
        size: [width, height],
    };
    let columns = field.columns();
    super::rows::par_rows(
        signal,
        width,
        super::rows::thread_count(threads),
        |j, row| {
            let mut cells = Vec::with_capacity(nx + 1);
            field.row_cells(j, &mut cells);
            for (i, out) in row.iter_mut().enumerate() {
                if exposed[j * width + i] {
                    let (x0, ax) = columns[i];
                    let spread = cells[x0] + ax * (cells[x0 + 1] - cells[x0]);
                    *out = ((1.0 - g) * f64::from(*out) + g * spread) as f32;
                }
            }
        },
    );
}

/// Separable Gaussian blur of standard deviation `sigma_px`, normalised, the image's edge
/// repeated; taps to 3 sigma, less those under 0.1 % of the centre tap (a core of 0.51 px, a
/// flat panel at 1024^2, keeps 3 taps instead of 5: the MTF moves by under 0.1 %).
fn blur(signal: &mut [f32], width: usize, height: usize, sigma_px: f64, threads: usize) {
    let by_weight = (sigma_px * (2.0 * 1000f64.ln()).sqrt()).floor();
    let radius = ((3.0 * sigma_px).ceil().min(by_weight).max(1.0) as usize).min(width.max(height));
    let mut taps: Vec<f32> = (0..=2 * radius)
        .map(|k| {
            let d = k as f64 - radius as f64;
            (-(d * d) / (2.0 * sigma_px * sigma_px)).exp() as f32
        })
        .collect();
    let sum: f32 = taps.iter().sum();
    for t in &mut taps {
        *t /= sum;
    }
    let threads = super::rows::thread_count(threads);
    // One pass: each output row is the column sum of the `2 radius + 1` source rows around it,
    // then convolved along the row (separable, so the order is free), from one copy of the
    // image.
    let src = signal.to_vec();
    super::rows::par_rows(signal, width, threads, |j, row| {
        let mut column = vec![0.0f32; width];
        for (k, t) in taps.iter().enumerate() {
            let y = (j as isize + k as isize - radius as isize).clamp(0, height as isize - 1);
            let line = &src[y as usize * width..(y as usize + 1) * width];
            for (o, v) in column.iter_mut().zip(line) {
                *o += t * v;
            }
        }
        convolve_line(&column, row, &taps, radius);
    });
}

/// One line convolved with `taps` (centred, `2 radius + 1` long), the line's ends repeated:
/// tap by tap over the interior (so the inner loop runs over contiguous pixels), pixel by pixel
/// at the ends.
fn convolve_line(line: &[f32], out: &mut [f32], taps: &[f32], radius: usize) {
    let n = line.len();
    let at = |x: isize| line[x.clamp(0, n as isize - 1) as usize];
    let edge = |i: usize| -> f32 {
        taps.iter()
            .enumerate()
            .map(|(k, t)| t * at(i as isize + k as isize - radius as isize))
            .sum()
    };
    if n <= 2 * radius {
        for (i, o) in out.iter_mut().enumerate() {
            *o = edge(i);
        }
        return;
    }
    let inner = &mut out[radius..n - radius];
    inner.fill(0.0);
    for (k, t) in taps.iter().enumerate() {
        for (o, v) in inner.iter_mut().zip(&line[k..k + n - 2 * radius]) {
            *o += t * v;
        }
    }
    for i in (0..radius).chain(n - radius..n) {
        out[i] = edge(i);
    }
}

/// The resampling of a distortion over a whole image: per output pixel, the top-left source
/// pixel of its bilinear sample with [`RIGHT_BIT`] and [`DOWN_BIT`] (`u32::MAX`: outside the
/// ideal image) and the sample's weights.
/// Depends only on the image's size and the coefficient, so it is made once per process for
/// each (the last few kept) and shared by every frame and session.
struct ResampleMap {
    top_left: Vec<u32>,
    weights: Vec<[f32; 2]>,
}

/// Flags of a [`ResampleMap`] entry: the pixel right of the top-left one exists.
const RIGHT_BIT: u32 = 1 << 31;
/// The pixel below the top-left one exists.
const DOWN_BIT: u32 = 1 << 30;

fn resample_map(d: &Distortion, width: usize, height: usize) -> std::sync::Arc<ResampleMap> {
    type Key = (usize, usize, u64);
    static MAPS: std::sync::Mutex<Vec<(Key, std::sync::Arc<ResampleMap>)>> =
        std::sync::Mutex::new(Vec::new());
    let key = (width, height, d.k.to_bits());
    let mut maps = MAPS.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, m)) = maps.iter().find(|(k, _)| *k == key) {
        return m.clone();
    }
    let lut = d.scale_table();
    let (w, h) = (width as f64, height as f64);
    let mut top_left = Vec::with_capacity(width * height);
    let mut weights = Vec::with_capacity(width * height);
    for j in 0..height {
        for i in 0..width {
            let (dx, dy) = (i as f64 + 0.5 - d.centre[0], j as f64 + 0.5 - d.centre[1]);
            let scale = lut.at((dx * dx + dy * dy) / (d.half_side_px * d.half_side_px));
            let (x, y) = (d.centre[0] + dx * scale, d.centre[1] + dy * scale);
            if !(0.0..w).contains(&x) || !(0.0..h).contains(&y) {
                top_left.push(u32::MAX);
                weights.push([0.0; 2]);
                continue;
            }
            // Pixel centres at half-integers; the last row and column repeat themselves.
            let (fx, fy) = ((x - 0.5).clamp(0.0, w - 1.0), (y - 0.5).clamp(0.0, h - 1.0));
            let (x0, y0) = (fx as usize, fy as usize);
            // The neighbours' existence in the top two bits (an image is far below 2^30
            // pixels), so the pass needs no division to find them.
            let right = if x0 + 1 < width { RIGHT_BIT } else { 0 };
            let down = if y0 + 1 < height { DOWN_BIT } else { 0 };
            top_left.push((y0 * width + x0) as u32 | right | down);
            weights.push([(fx - x0 as f64) as f32, (fy - y0 as f64) as f32]);
        }
    }
    let map = std::sync::Arc::new(ResampleMap { top_left, weights });
    if maps.len() >= 4 {
        maps.remove(0);
    }
    maps.push((key, map.clone()));
    map
}

/// Resamples the signal through the distortion: each output pixel takes the ideal image's
/// value (bilinear) and mask (nearest sample) at its undistorted position; outside the ideal
/// image, nothing (shutter).
fn distort(
    signal: &mut [f32],
    exposed: &[bool],
    width: usize,
    height: usize,
    d: &Distortion,
    threads: usize,
) -> Vec<bool> {
    let map = resample_map(d, width, height);
    let src = signal.to_vec();
    let mut mask = vec![false; exposed.len()];
    let threads = super::rows::thread_count(threads);
    super::rows::par_rows_pair(signal, &mut mask, width, threads, |j, row, mrow| {
        let base = j * width;
        for (i, (out, m)) in row.iter_mut().zip(mrow.iter_mut()).enumerate() {
            let p = map.top_left[base + i];
            if p == u32::MAX {
                *out = 0.0;
                *m = false;
                continue;
            }
            let right = usize::from(p & RIGHT_BIT != 0);
            let down = if p & DOWN_BIT != 0 { width } else { 0 };
            let p = (p & !(RIGHT_BIT | DOWN_BIT)) as usize;
            let [ax, ay] = map.weights[base + i];
            let (a, b) = (src[p], src[p + right]);
            let (c, e) = (src[p + down], src[p + down + right]);
            let top = a + ax * (b - a);
            let bottom = c + ax * (e - c);
            *out = top + ay * (bottom - top);
            let near = p + if ax >= 0.5 { right } else { 0 } + if ay >= 0.5 { down } else { 0 };
            *m = exposed[near];
        }
    });
    mask
}

/// Vignetting's grey offset per pixel of a `width x height` frame (`slope ln v`, rounded), made
/// once per size, kind and slope (the last few kept) and shared by every frame.
pub(crate) fn vignetting_offsets(
    kind: ReceptorKind,
    width: usize,
    height: usize,
    slope: f64,
) -> std::sync::Arc<Vec<i16>> {
    type Key = (usize, usize, ReceptorKind, u64);
    static TABLES: std::sync::Mutex<Vec<(Key, std::sync::Arc<Vec<i16>>)>> =
        std::sync::Mutex::new(Vec::new());
    let key = (width, height, kind, slope.to_bits());
    let mut tables = TABLES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, t)) = tables.iter().find(|(k, _)| *k == key) {
        return t.clone();
    }
    let table: Vec<i16> = (0..width * height)
        .map(|p| {
            let v = vignetting(kind, width, height, p % width, p / width);
            (slope * v.ln()).round().clamp(-255.0, 255.0) as i16
        })
        .collect();
    let table = std::sync::Arc::new(table);
    if tables.len() >= 4 {
        tables.remove(0);
    }
    tables.push((key, table.clone()));
    table
}

/// The vignetting factor `1 - a rho^2` at pixel `(i, j)` of a `width x height` image (at least
/// 0.05), and 1 for a receptor without vignetting.
pub fn vignetting(kind: ReceptorKind, width: usize, height: usize, i: usize, j: usize) -> f64 {
    let a = kind.params().vignetting;
    if a == 0.0 {
        return 1.0;
    }
    let half = 0.5 * width.max(height) as f64;
    let (dx, dy) = (
        i as f64 + 0.5 - 0.5 * width as f64,
        j as f64 + 0.5 - 0.5 * height as f64,
    );
    (1.0 - a * (dx * dx + dy * dy) / (half * half)).max(0.05)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distortion_inverts_itself_and_pushes_the_periphery_out() {
        let d = Distortion::of(ReceptorKind::ImageIntensifier, 512, 512).expect("pincushion");
        assert!(Distortion::of(ReceptorKind::FlatPanel, 512, 512).is_none());
        for j in (0..=512).step_by(32) {
            for i in (0..=512).step_by(32) {
                let p = [i as f64, j as f64];
                let back = d.distort_px(d.undistort_px(p));
                assert!(
                    (back[0] - p[0]).abs() < 1e-9 && (back[1] - p[1]).abs() < 1e-9,
                    "{p:?}"
                );
            }
        }
        // The middle of the right edge of the ideal image appears 5 % farther out; the centre
        // stays.
        let edge = d.distort_px([512.0, 256.0]);
        assert!((edge[0] - (256.0 + 256.0 * 1.05)).abs() < 1e-9, "{edge:?}");
        assert_eq!(d.distort_px([256.0, 256.0]), [256.0, 256.0]);
    }

    #[test]
    fn receptor_leaves_images_it_cannot_process_as_they_are() {
        for (w, h) in [(0usize, 0usize), (0, 5), (5, 0)] {
            let mut s: Vec<f32> = vec![0.5; w * h];
            let mask = apply(&mut s, &vec![true; w * h], w, h, &settings(1.0), 2);
            assert_eq!(mask.len(), w * h);
        }
        for pitch in [0.0, -1.0, 1e-9, f64::NAN] {
            let mut s = vec![0.5f32; 64];
            let mask = apply(&mut s, &[true; 64], 8, 8, &settings(pitch), 2);
            assert_eq!((s, mask), (vec![0.5f32; 64], vec![true; 64]), "pitch {pitch}");
        }
        // A 1 x 1 image and one far wider than tall go through.
        for (w, h) in [(1usize, 1usize), (300, 2)] {
            let mut s = vec![0.5f32; w * h];
            apply(&mut s, &vec![true; w * h], w, h, &settings(0.5), 2);
            assert!(s.iter().all(|v| v.is_finite() && *v >= 0.0));
        }
    }

    fn settings(pitch_mm: f64) -> ReceptorSettings {
        ReceptorSettings {
            kind: ReceptorKind::ImageIntensifier,
            pixel_pitch_mm: pitch_mm,
        }
    }

    #[test]
    fn receptor_blur_has_the_stated_mtf_and_glare_keeps_a_uniform_field() {
        // A sinusoid of 1 cycle/mm along the rows on 0.1 mm pixels: after the core blur, its
        // amplitude is exp(-2 pi^2 sigma^2 f^2) of the input (0.64 flat panel, 0.29 image
        // intensifier) within 2 % (sampling of the Gaussian's taps).
        let (n, pitch) = (200usize, 0.1);
        for kind in ReceptorKind::ALL {
            let sigma = kind.params().psf_sigma_mm;
            let mut s: Vec<f32> = (0..n * n)
                .map(|p| {
                    let x = ((p % n) as f64 + 0.5) * pitch;
                    (1.0 + 0.5 * (std::f64::consts::TAU * x).sin()) as f32
                })
                .collect();
            blur(&mut s, n, n, sigma / pitch, 2);
            let row = &s[(n / 2) * n + 20..(n / 2) * n + n - 20];
            let (lo, hi) = row
                .iter()
                .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            let mtf = f64::from(hi - lo) / 2.0 / 0.5;
            let want = (-2.0 * std::f64::consts::PI.powi(2) * sigma * sigma).exp();
            assert!(
                (mtf - want).abs() < 0.02,
                "{}: MTF {mtf} vs {want}",
                kind.name()
            );
        }
        // Glare redistributes: a uniform field keeps its value away from the image's edges.
        let n = 256;
        let mut s = vec![0.3f32; n * n];
        let p = ReceptorKind::ImageIntensifier.params();
        glare(&mut s, &vec![true; n * n], n, n, &p, 1.0, 2);
        let centre = s[(n / 2) * n + n / 2];
        assert!((centre / 0.3 - 1.0).abs() < 0.01, "{centre}");
        assert!(s.iter().all(|v| v.is_finite() && *v >= 0.0));
    }
}
