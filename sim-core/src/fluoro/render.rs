//! The CPU reference frame: transmission per pixel (with supersampling), quantum noise,
//! automatic brightness, log mapping to 8 bit and collimator shutters.
//!
//! Everything is deterministic: the same inputs (and noise seed) give bit-identical images, for
//! any thread count, because each pixel's noise comes from its own seeded generator.

use serde::{Deserialize, Serialize};

use super::FluoroMaterial;
use super::attenuation::{EnergyModel, MaterialChords, SpectralModel, basis_depths};
use super::contrast::IodineField;
use super::geometry::{DetectorFrame, Projection, ray_through};
use super::scene::{ChordScratch, RayChords, Scene};
use super::spectrum::UnknownKvp;
use crate::rng::SplitMix64;

/// Automatic brightness: how transmission becomes grey.
///
/// Like a C-arm's automatic brightness control, the median log-transmission of a central region
/// of interest is mapped to `target_grey`, so the picture's brightness does not depend on patient
/// thickness or tube output. Grey is linear in `ln T` (a logarithmic tone curve), spanning
/// `log_range` natural-log units from black to white.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Exposure {
    /// Side of the central region of interest as a fraction of the image (0.5: the middle half).
    pub roi_fraction: f64,
    /// Grey level (0..1) of the region's median.
    pub target_grey: f64,
    /// `ln T` span from black to white (3.5: a factor of 33 in transmission; simulator choice
    /// giving bone, soft tissue and a needle distinct grey levels).
    pub log_range: f64,
}

impl Default for Exposure {
    fn default() -> Self {
        Exposure {
            roi_fraction: 0.5,
            target_grey: 0.5,
            log_range: 3.5,
        }
    }
}

/// Quantum (photon counting) noise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct QuantumNoise {
    /// Mean detected quanta per pixel without attenuation (sets the noise level; a low-dose
    /// fluoroscopy pulse gives a few thousand per pixel, simulator choice).
    pub photons_per_pixel: f64,
    /// Seed; the same seed gives the same noise.
    pub seed: u64,
}

/// Everything that decides a frame besides the scene and the projection.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RenderSettings {
    /// Single-energy or polychromatic transmission.
    pub energy: EnergyModel,
    /// `n` for `n x n` stratified samples in a supersampled pixel (1: pixel centre only).
    pub supersample: u32,
    /// Supersample only pixels at a silhouette (a neighbour's centre ray crosses other meshes) or
    /// within a pixel of a projected steel edge; `false` supersamples every pixel.
    pub adaptive: bool,
    /// Automatic brightness and tone mapping.
    pub exposure: Exposure,
    /// Quantum noise, or `None` for the noiseless expectation.
    pub noise: Option<QuantumNoise>,
    /// `false`: fluoroscopy polarity (more transmission is brighter: bone and steel dark);
    /// `true`: radiograph polarity.
    pub invert: bool,
    /// Worker threads (0: all available cores).
    pub threads: usize,
}

impl Default for RenderSettings {
    /// 80 kVp (the methods page's assumed starting beam), 4 x 4 adaptive supersampling (a 0.72 mm
    /// needle at 2x magnification is 2.5 pixels of 0.59 mm wide; 4 x 4 samples resolve its edges
    /// to 1/4 pixel), no noise.
    fn default() -> Self {
        RenderSettings {
            energy: EnergyModel::Spectral { kvp: 80 },
            supersample: 4,
            adaptive: true,
            exposure: Exposure::default(),
            noise: None,
            invert: false,
            threads: 0,
        }
    }
}

/// Per-pixel transmission before display.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TransmissionImage {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Mean transmission over the pixel's samples (0 outside the collimator), row-major.
    pub transmission: Vec<f64>,
    /// Whether the pixel is inside the collimator opening.
    pub exposed: Vec<bool>,
    /// Number of supersampled pixels.
    pub supersampled_pixels: usize,
}

/// An 8-bit grey image, row-major, top row first.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Image {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Grey levels.
    pub pixels: Vec<u8>,
}

/// Grey level of pixels behind the collimator shutters.
pub const SHUTTER_GREY: u8 = 0;

struct Ctx<'a> {
    scene: &'a Scene,
    iodine: Option<&'a IodineField>,
    projection: &'a Projection,
    frame: DetectorFrame,
    model: SpectralModel,
}

impl Ctx<'_> {
    fn sample(&self, px: [f64; 2], scratch: &mut ChordScratch) -> (f64, u64) {
        let ray = ray_through(&self.frame, self.projection, px);
        let r = self
            .scene
            .ray_chords(ray.origin_mm, ray.dir, ray.detector_t_mm, scratch);
        let iodine = self.iodine.map_or(0.0, |f| {
            f.column_stock_mm(ray.origin_mm, ray.dir, 0.0, ray.detector_t_mm)
        });
        (
            self.model.transmission(&basis_depths(&r.chords_mm, iodine)),
            r.signature,
        )
    }

    fn supersampled(&self, i: usize, j: usize, n: u32, scratch: &mut ChordScratch) -> f64 {
        let mut acc = 0.0;
        for b in 0..n {
            for a in 0..n {
                let px = [
                    i as f64 + (a as f64 + 0.5) / n as f64,
                    j as f64 + (b as f64 + 0.5) / n as f64,
                ];
                acc += self.sample(px, scratch).0;
            }
        }
        acc / f64::from(n * n)
    }
}

/// Runs `f(row, row_slice)` over all rows on `threads` workers (contiguous blocks of rows).
fn par_rows<T: Send>(
    out: &mut [T],
    width: usize,
    threads: usize,
    f: impl Fn(usize, &mut [T]) + Sync,
) {
    let height = out.len() / width.max(1);
    let threads = threads.clamp(1, height.max(1));
    let rows_per = height.div_ceil(threads);
    std::thread::scope(|s| {
        for (block, chunk) in out.chunks_mut(rows_per * width).enumerate() {
            let f = &f;
            s.spawn(move || {
                for (k, row) in chunk.chunks_mut(width).enumerate() {
                    f(block * rows_per + k, row);
                }
            });
        }
    });
}

fn thread_count(requested: usize) -> usize {
    if requested > 0 {
        requested
    } else {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }
}

/// Exact per-material chords at every pixel centre (no supersampling): what the GPU's path-length
/// pass must reproduce. Pixels outside the collimator get chords too (geometry only).
pub fn render_chords(scene: &Scene, projection: &Projection, threads: usize) -> Vec<RayChords> {
    let frame = projection.frame();
    let [w, h] = projection.detector_pixels.map(|x| x as usize);
    let empty = RayChords {
        chords_mm: [0.0; FluoroMaterial::COUNT],
        signature: 0,
    };
    let mut out = vec![empty; w * h];
    par_rows(&mut out, w, thread_count(threads), |j, row| {
        let mut scratch = ChordScratch::default();
        for (i, o) in row.iter_mut().enumerate() {
            let ray = ray_through(&frame, projection, [i as f64 + 0.5, j as f64 + 0.5]);
            *o = scene.ray_chords(ray.origin_mm, ray.dir, ray.detector_t_mm, &mut scratch);
        }
    });
    out
}

/// Transmission per pixel: centre samples, then `n x n` supersampling where needed.
pub fn render_transmission(
    scene: &Scene,
    iodine: Option<&IodineField>,
    projection: &Projection,
    settings: &RenderSettings,
) -> Result<TransmissionImage, UnknownKvp> {
    let ctx = Ctx {
        scene,
        iodine,
        projection,
        frame: projection.frame(),
        model: SpectralModel::new(settings.energy)?,
    };
    let [w, h] = projection.detector_pixels.map(|x| x as usize);
    let threads = thread_count(settings.threads);
    let exposed: Vec<bool> = (0..w * h)
        .map(|p| projection.is_exposed([(p % w) as f64 + 0.5, (p / w) as f64 + 0.5]))
        .collect();
    // Pass 1: pixel centres.
    let mut centre = vec![(0.0f64, 0u64); w * h];
    par_rows(&mut centre, w, threads, |j, row| {
        let mut scratch = ChordScratch::default();
        for (i, o) in row.iter_mut().enumerate() {
            if exposed[j * w + i] {
                *o = ctx.sample([i as f64 + 0.5, j as f64 + 0.5], &mut scratch);
            }
        }
    });
    // Pass 2: which pixels need supersampling.
    let n = settings.supersample.max(1);
    let mut flag = vec![false; w * h];
    if n > 1 {
        if settings.adaptive {
            for j in 0..h {
                for i in 0..w {
                    let s = centre[j * w + i].1;
                    let differs = (j.saturating_sub(1)..(j + 2).min(h)).any(|jj| {
                        (i.saturating_sub(1)..(i + 2).min(w)).any(|ii| centre[jj * w + ii].1 != s)
                    });
                    flag[j * w + i] = differs;
                }
            }
            mark_steel_edges(scene, projection, &mut flag, w, h);
        } else {
            flag.fill(true);
        }
    }
    // Pass 3: supersample flagged pixels.
    let mut transmission: Vec<f64> = centre.iter().map(|c| c.0).collect();
    par_rows(&mut transmission, w, threads, |j, row| {
        let mut scratch = ChordScratch::default();
        for (i, t) in row.iter_mut().enumerate() {
            let p = j * w + i;
            if flag[p] && exposed[p] {
                *t = ctx.supersampled(i, j, n, &mut scratch);
            }
        }
    });
    let supersampled_pixels = flag
        .iter()
        .zip(&exposed)
        .filter(|(f, e)| **f && **e)
        .count();
    Ok(TransmissionImage {
        width: w as u32,
        height: h as u32,
        transmission,
        exposed,
        supersampled_pixels,
    })
}

/// Flags every pixel within 1.5 pixels of a projected edge of a steel mesh, so an instrument
/// thinner than a pixel (which centre rays can miss entirely) is still supersampled.
fn mark_steel_edges(scene: &Scene, projection: &Projection, flag: &mut [bool], w: usize, h: usize) {
    for entry in scene
        .entries()
        .iter()
        .filter(|e| e.material == FluoroMaterial::Steel)
    {
        mark_projected_edges(
            projection,
            entry.bvh.triangles_mm().iter().copied(),
            flag,
            w,
            h,
        );
    }
}

/// The steel-edge rule shared by the CPU reference and the GPU renderer: every pixel within
/// `1.5` pixels of a projected triangle edge is flagged, walking each edge in 0.5-pixel steps
/// with the f64 projection. `flag` is row-major, `w x h`.
pub fn mark_projected_edges(
    projection: &Projection,
    triangles_mm: impl IntoIterator<Item = [[f64; 3]; 3]>,
    flag: &mut [bool],
    w: usize,
    h: usize,
) {
    // 1.5 px covers the 3x3 neighbourhood of any pixel a sub-pixel needle edge passes through;
    // 0.5 px steps cannot skip a pixel (simulator choice, tested through needle supersampling).
    const RADIUS_PX: f64 = 1.5;
    let edges = triangles_mm
        .into_iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]);
    for (a, b) in edges {
        let (Some(pa), Some(pb)) = (projection.project_point(a), projection.project_point(b))
        else {
            continue;
        };
        let len = ((pb[0] - pa[0]).powi(2) + (pb[1] - pa[1]).powi(2)).sqrt();
        let steps = (len / 0.5).ceil().max(1.0) as usize;
        for k in 0..=steps {
            let f = k as f64 / steps as f64;
            let (x, y) = (pa[0] + f * (pb[0] - pa[0]), pa[1] + f * (pb[1] - pa[1]));
            let (x0, x1) = (
                (x - RADIUS_PX).floor().max(0.0),
                (x + RADIUS_PX).floor().min(w as f64 - 1.0),
            );
            let (y0, y1) = (
                (y - RADIUS_PX).floor().max(0.0),
                (y + RADIUS_PX).floor().min(h as f64 - 1.0),
            );
            if x1 < x0 || y1 < y0 {
                continue;
            }
            for jj in y0 as usize..=y1 as usize {
                for ii in x0 as usize..=x1 as usize {
                    flag[jj * w + ii] = true;
                }
            }
        }
    }
}

/// Poisson sample drawn from `rng` (a SplitMix64 seeded per pixel), exact: Knuth's product method
/// below a mean of [`PTRS_MIN_MEAN`], above it Hörmann's transformed rejection with squeeze
/// (PTRS; W. Hörmann, "The transformed rejection method for generating Poisson random
/// variables", Insurance: Mathematics and Economics 12, 1993, 39-45; constants from its Table 1):
/// two uniforms and two divisions per candidate, plus two logarithms when the squeeze does not
/// decide (about 65 % of candidates at a mean of 10, 25 % at 1000). (It replaced the normal
/// approximation above a mean of 30 and Knuth's method up to 30, which drew up to 30 uniforms per
/// pixel and was most of a frame's CPU time.)
fn poisson(rng: &mut SplitMix64, mean: f64) -> f64 {
    if mean <= 0.0 {
        return 0.0;
    }
    if mean < PTRS_MIN_MEAN {
        let limit = (-mean).exp();
        let (mut k, mut p) = (0.0, rng.next_f64_nonzero());
        while p > limit {
            k += 1.0;
            p *= rng.next_f64_nonzero();
        }
        return k;
    }
    let sqrt_mean = mean.sqrt();
    let b = 0.931 + 2.53 * sqrt_mean;
    let a = -0.059 + 0.02483 * b;
    let v_r = 0.9277 - 3.6224 / (b - 2.0);
    // Needed only when the squeeze does not decide (about two thirds of candidates at a
    // mean of 10, a quarter at 1000): computed then, once per sample.
    let mut slow: Option<(f64, f64)> = None;
    loop {
        let u = rng.next_f64_nonzero() - 0.5;
        let v = rng.next_f64_nonzero();
        let us = 0.5 - u.abs();
        let x = (2.0 * a / us + b) * u + mean + 0.43;
        if x < 0.0 {
            // k < 0: rejected (the squeeze region has x > 0).
            continue;
        }
        // floor(x) for x >= 0 by truncation (a conversion instruction, not a libm call).
        let k = x as u64 as f64;
        if us >= 0.07 && v <= v_r {
            return k;
        }
        if us < 0.013 && v > us {
            continue;
        }
        let (inv_alpha, ln_mean) =
            *slow.get_or_insert_with(|| (1.1239 + 1.1328 / (b - 3.4), mean.ln()));
        // ln v + ln alpha^-1 - ln(a / us^2 + b), as one logarithm.
        let lhs = (v * inv_alpha / (a / (us * us) + b)).ln();
        if lhs <= -mean + k * ln_mean - ln_factorial(k) {
            return k;
        }
    }
}

/// Smallest mean drawn with PTRS (its validity bound in Hörmann 1993).
const PTRS_MIN_MEAN: f64 = 10.0;

/// `ln k!` for `k = 0..=16` (Python's `math.lgamma(k + 1)`, correctly rounded to f64 within
/// an ulp; the test below checks them against sums of logarithms).
const LN_FACTORIAL_SMALL: [f64; 17] = [
    0.0,
    0.0,
    std::f64::consts::LN_2,
    1.7917594692280554,
    3.178053830347945,
    4.787491742782047,
    6.579251212010102,
    8.525161361065415,
    10.604602902745249,
    12.801827480081467,
    15.104412573075514,
    17.502307845873887,
    19.987214495661885,
    22.55216385312342,
    25.191221182738683,
    27.89927138384089,
    30.671860106080672,
];

/// `ln k!` for a whole `k >= 0`: a table up to 16, then Stirling's series to the `x^-5` term
/// (truncation error below `1 / (1680 x^7)` at `x = k + 1 >= 17`: 1.4e-12).
fn ln_factorial(k: f64) -> f64 {
    if k < 17.0 {
        return LN_FACTORIAL_SMALL[k as usize];
    }
    let x = k + 1.0;
    let x2 = x * x;
    (x - 0.5) * x.ln() - x
        + 0.5 * (std::f64::consts::TAU).ln()
        + (1.0 / 12.0 - (1.0 / 360.0 - 1.0 / (1260.0 * x2)) / x2) / x
}

/// The noisy count of pixel `p` (mean `photons_per_pixel x t`), from its own seeded generator.
fn noisy_count(noise: &QuantumNoise, p: usize, t: f64) -> f64 {
    let mut rng = SplitMix64::new(noise.seed ^ (p as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    poisson(&mut rng, noise.photons_per_pixel * t)
}

/// Applies quantum noise (if any) to a transmission image, in place.
pub fn apply_noise(t: &mut TransmissionImage, noise: &QuantumNoise) {
    for (p, v) in t.transmission.iter_mut().enumerate() {
        if t.exposed[p] {
            *v = noisy_count(noise, p, *v) / noise.photons_per_pixel;
        }
    }
}

/// Automatic brightness, log tone mapping and shutters: transmission to 8-bit grey, metered on
/// `t` itself (see [`exposure_centre`]).
pub fn to_display(
    t: &TransmissionImage,
    exposure: &Exposure,
    invert: bool,
    noise: Option<&QuantumNoise>,
) -> Image {
    let centre = exposure_centre(t, exposure, noise);
    to_display_centred(t, exposure, invert, noise, centre)
}

/// Floor for `ln T`: half a quantum when noisy (a zero count), else 1e-12.
fn ln_t_floor(noise: Option<&QuantumNoise>) -> f64 {
    noise.map_or(1e-12, |n| 0.5 / n.photons_per_pixel)
}

/// The automatic-brightness set point: the median `ln T` of the exposed pixels in the central
/// region of interest (all exposed pixels if it has none).
pub fn exposure_centre(
    t: &TransmissionImage,
    exposure: &Exposure,
    noise: Option<&QuantumNoise>,
) -> f64 {
    let (w, h) = (t.width as usize, t.height as usize);
    let floor = ln_t_floor(noise);
    // The median of ln max(T, floor) is ln of the median of max(T, floor) (ln is increasing):
    // one logarithm instead of one per pixel.
    let clamped = |p: usize| t.transmission[p].max(floor);
    let (rx0, rx1) = roi(w, exposure.roi_fraction);
    let (ry0, ry1) = roi(h, exposure.roi_fraction);
    let mut vals: Vec<f64> = (ry0..ry1)
        .flat_map(|j| (rx0..rx1).map(move |i| j * w + i))
        .filter(|&p| t.exposed[p])
        .map(clamped)
        .collect();
    if vals.is_empty() {
        vals = (0..w * h).filter(|&p| t.exposed[p]).map(clamped).collect();
    }
    if vals.is_empty() {
        0.0
    } else {
        let mid = vals.len() / 2;
        vals.select_nth_unstable_by(mid, f64::total_cmp).1.ln()
    }
}

/// Log tone mapping around a given set point `centre` (`ln T` shown at the target grey) and
/// shutters.
pub fn to_display_centred(
    t: &TransmissionImage,
    exposure: &Exposure,
    invert: bool,
    noise: Option<&QuantumNoise>,
    centre: f64,
) -> Image {
    let (w, h) = (t.width as usize, t.height as usize);
    let floor = ln_t_floor(noise);
    let ln_t = |p: usize| t.transmission[p].max(floor).ln();
    let pixels = (0..w * h)
        .map(|p| {
            if !t.exposed[p] {
                return SHUTTER_GREY;
            }
            grey(exposure, invert, centre, ln_t(p))
        })
        .collect();
    Image {
        width: t.width,
        height: t.height,
        pixels,
    }
}

/// The grey level of `ln T` around the set point `centre`.
fn grey(exposure: &Exposure, invert: bool, centre: f64, ln_t: f64) -> u8 {
    let g = (exposure.target_grey + (ln_t - centre) / exposure.log_range).clamp(0.0, 1.0);
    let g = if invert { 1.0 - g } else { g };
    (g * 255.0).round() as u8
}

fn roi(n: usize, fraction: f64) -> (usize, usize) {
    let m = ((n as f64 * fraction.clamp(0.0, 1.0)).round() as usize).clamp(1, n.max(1));
    let start = (n - m.min(n)) / 2;
    (start, start + m.min(n))
}

/// The full CPU reference frame: transmission, noise, automatic brightness, tone mapping and
/// shutters. The GPU renderer is compared against this.
pub fn render_frame(
    scene: &Scene,
    iodine: Option<&IodineField>,
    projection: &Projection,
    settings: &RenderSettings,
) -> Result<Image, UnknownKvp> {
    let t = render_transmission(scene, iodine, projection, settings)?;
    Ok(finish_frame(&t, settings))
}

/// Turns a transmission image into the displayed frame: automatic brightness metered on the
/// noise-free image, then seeded quantum noise (when enabled), tone mapping and shutters. The
/// CPU reference and the GPU renderer both end with this, so their frames differ only where
/// their transmissions do.
///
/// Why meter before the noise: a C-arm's brightness control integrates its sensor over many
/// pulses, so it follows the mean signal, not one frame's grain. Metering the noisy frame made
/// the set point a median of integer photon counts (about 12 per pixel behind the lumbar spine
/// at 2.5 mA), which jumps by a whole count (0.087 in `ln T`, 6 grey levels) when a few
/// silhouette pixels change slightly: a 2 mm needle move could flip the brightness of the whole
/// image, and the GPU frame (same transmission within 0.005 in the median) differed from the
/// CPU's everywhere (render-worker's `gpu_session_oblique_view_with_needle_matches_the_cpu`).
///
/// With noise the result equals [`apply_noise`] then [`to_display_centred`] bit for bit, but
/// faster: the grey of a count `k` is taken from a table over `k` built per frame (the same
/// arithmetic on the same `k / photons`), and the rows are split over `settings.threads`
/// workers (each pixel's noise has its own seed, so the split does not change the frame).
pub fn finish_frame(t: &TransmissionImage, settings: &RenderSettings) -> Image {
    let noise = settings.noise.as_ref();
    let centre = exposure_centre(t, &settings.exposure, noise);
    let Some(noise) = noise else {
        return to_display_centred(t, &settings.exposure, settings.invert, None, centre);
    };
    let (e, invert) = (&settings.exposure, settings.invert);
    let floor = ln_t_floor(Some(noise));
    let n = noise.photons_per_pixel;
    let grey_of_count = |k: f64| grey(e, invert, centre, (k / n).max(floor).ln());
    // Counts up to the open-field mean plus 8 standard deviations (T <= 1), at most 2^16
    // entries; rarer or larger counts are mapped directly.
    let table_len = (n + 8.0 * n.sqrt() + 16.0).clamp(16.0, 65_536.0) as usize;
    let table: Vec<u8> = (0..table_len).map(|k| grey_of_count(k as f64)).collect();
    let w = t.width as usize;
    let mut pixels = vec![SHUTTER_GREY; t.transmission.len()];
    par_rows(&mut pixels, w, thread_count(settings.threads), |j, row| {
        for (i, out) in row.iter_mut().enumerate() {
            let p = j * w + i;
            if t.exposed[p] {
                let k = noisy_count(noise, p, t.transmission[p]);
                *out = table
                    .get(k as usize)
                    .copied()
                    .unwrap_or_else(|| grey_of_count(k));
            }
        }
    });
    Image {
        width: t.width,
        height: t.height,
        pixels,
    }
}

/// Chord channels of one pixel-centre ray (a convenience for tests and picking overlays).
pub fn pixel_chords(scene: &Scene, projection: &Projection, px: [f64; 2]) -> MaterialChords {
    let ray = projection.pixel_ray(px);
    scene
        .ray_chords(
            ray.origin_mm,
            ray.dir,
            ray.detector_t_mm,
            &mut ChordScratch::default(),
        )
        .chords_mm
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::{capped_cylinder, equal_area_vertex_radius};
    use crate::material::MaterialClass;
    use crate::mesh::TriMesh;

    fn small_projection(n: u32) -> Projection {
        Projection {
            detector_pixels: [n, n],
            pixel_pitch_mm: [120.0 / n as f64; 2],
            ..Projection::default()
        }
    }

    fn body_with_needle(needle_x_mm: f64) -> Scene {
        let mut s = Scene::new();
        s.add(
            "body",
            FluoroMaterial::Tissue(MaterialClass::SoftTissue),
            &TriMesh::icosphere([0.0; 3], 40.0, 3),
        );
        let r = equal_area_vertex_radius(0.36, 16);
        s.add(
            "needle",
            FluoroMaterial::Steel,
            &capped_cylinder([needle_x_mm, 0.0, -25.0], [needle_x_mm, 0.0, 25.0], r, 16),
        );
        s
    }

    #[test]
    fn frames_are_deterministic_and_thread_count_independent() {
        let scene = body_with_needle(3.3);
        let p = small_projection(48);
        let noise = QuantumNoise {
            photons_per_pixel: 2000.0,
            seed: 42,
        };
        let s1 = RenderSettings {
            noise: Some(noise),
            threads: 1,
            ..RenderSettings::default()
        };
        let s2 = RenderSettings { threads: 2, ..s1 };
        let a = render_frame(&scene, None, &p, &s1).unwrap();
        let b = render_frame(&scene, None, &p, &s2).unwrap();
        assert_eq!(a, b);
        let c = render_frame(
            &scene,
            None,
            &p,
            &RenderSettings {
                noise: Some(QuantumNoise { seed: 43, ..noise }),
                ..s1
            },
        )
        .unwrap();
        assert_ne!(a, c, "another seed gives other grain");
    }

    #[test]
    fn brightness_is_metered_on_the_noise_free_image() {
        // Uniform T with 11.5 expected quanta per pixel: the noisy counts are integers, so a
        // meter on the noisy frame would put the median count (11 or 12) at the target grey.
        // Metered on the noise-free image, count k shows at 0.5 + ln(k / 11.5) / 3.5 exactly.
        let (n, photons) = (64usize, 1000.0);
        let lambda = 11.5;
        let t = TransmissionImage {
            width: n as u32,
            height: n as u32,
            transmission: vec![lambda / photons; n * n],
            exposed: vec![true; n * n],
            supersampled_pixels: 0,
        };
        for seed in [1, 2, 3] {
            let noise = QuantumNoise {
                photons_per_pixel: photons,
                seed,
            };
            let settings = RenderSettings {
                noise: Some(noise),
                ..RenderSettings::default()
            };
            let mut noisy = t.clone();
            apply_noise(&mut noisy, &noise);
            let img = finish_frame(&t, &settings);
            let e = settings.exposure;
            for (p, &g) in img.pixels.iter().enumerate() {
                let ln_t = noisy.transmission[p].max(0.5 / photons).ln();
                let want = (e.target_grey + (ln_t - (lambda / photons).ln()) / e.log_range)
                    .clamp(0.0, 1.0);
                assert_eq!(g, (want * 255.0).round() as u8, "seed {seed} pixel {p}");
            }
        }
    }

    #[test]
    fn quantum_noise_has_poisson_variance() {
        // Uniform transmission 0.25 at 4000 quanta: mean 1000 counts, so the relative standard
        // deviation of T is 1/sqrt(1000) = 3.16 %. 10,000 pixels estimate it to about 1 %.
        let n = 100usize;
        let mut t = TransmissionImage {
            width: n as u32,
            height: n as u32,
            transmission: vec![0.25; n * n],
            exposed: vec![true; n * n],
            supersampled_pixels: 0,
        };
        apply_noise(
            &mut t,
            &QuantumNoise {
                photons_per_pixel: 4000.0,
                seed: 7,
            },
        );
        let mean = t.transmission.iter().sum::<f64>() / (n * n) as f64;
        let var = t
            .transmission
            .iter()
            .map(|v| (v - mean).powi(2))
            .sum::<f64>()
            / (n * n - 1) as f64;
        let rel_sd = var.sqrt() / mean;
        assert!((mean - 0.25).abs() < 0.25 * 0.002, "{mean}");
        assert!(
            (rel_sd - 1.0 / 1000f64.sqrt()).abs() < 0.05 / 1000f64.sqrt(),
            "{rel_sd}"
        );
    }

    #[test]
    fn noisy_counts_follow_the_poisson_distribution() {
        // Pearson's chi-square of 20,000 draws against the exact Poisson pmf (bins with an
        // expected count of at least 5, tails pooled), at means on both sides of the switch
        // from Knuth's method to PTRS and far above it. The 99.9 % quantile of chi-square with
        // d degrees of freedom is below d + 3.1 sqrt(2 d) + 10 for the 13 to 263 here
        // (Wilson-Hilferty), so a correct sampler fails this with probability about 1e-3 per
        // mean; the seeds are fixed, so the test is deterministic.
        let draws = 20_000usize;
        for (case, mean) in [3.7, 9.99, 10.0, 12.5, 29.5, 31.0, 150.0, 2500.0]
            .into_iter()
            .enumerate()
        {
            let noise = QuantumNoise {
                photons_per_pixel: mean,
                seed: 1000 + case as u64,
            };
            let mut hist = std::collections::BTreeMap::<u64, usize>::new();
            let (mut sum, mut sum2) = (0.0, 0.0);
            for p in 0..draws {
                let k = noisy_count(&noise, p, 1.0);
                assert!(k >= 0.0 && k.fract() == 0.0, "{k}");
                *hist.entry(k as u64).or_default() += 1;
                sum += k;
                sum2 += k * k;
            }
            let m = sum / draws as f64;
            let var = sum2 / draws as f64 - m * m;
            // Standard errors of the mean and the variance: sqrt(mean / n), mean sqrt(2 / n).
            assert!(
                (m - mean).abs() < 5.0 * (mean / draws as f64).sqrt(),
                "{mean}: {m}"
            );
            assert!(
                (var - mean).abs() < 5.0 * mean * (2.0 / draws as f64).sqrt(),
                "{mean}: {var}"
            );
            // Bins [lo, hi] around the mean with expected counts >= 5; outside pooled.
            let pmf = |k: u64| (-mean + k as f64 * mean.ln() - ln_factorial(k as f64)).exp();
            let expected = |k: u64| pmf(k) * draws as f64;
            let mode = mean.floor() as u64;
            let lo = (0..=mode).find(|&k| expected(k) >= 5.0).unwrap_or(0);
            let hi = (mode..)
                .take_while(|&k| expected(k) >= 5.0)
                .last()
                .unwrap_or(mode);
            let mut chi2 = 0.0;
            let mut inside_expected = 0.0;
            let mut inside_observed = 0usize;
            for k in lo..=hi {
                let (o, e) = (*hist.get(&k).unwrap_or(&0) as f64, expected(k));
                chi2 += (o - e).powi(2) / e;
                inside_expected += e;
                inside_observed += o as usize;
            }
            let (o, e) = (
                (draws - inside_observed) as f64,
                draws as f64 - inside_expected,
            );
            if e >= 5.0 {
                chi2 += (o - e).powi(2) / e;
            }
            let dof = (hi - lo) as f64 + 1.0;
            let bound = dof + 3.1 * (2.0 * dof).sqrt() + 10.0;
            eprintln!("poisson mean {mean}: chi2 {chi2:.1} over {dof} bins (bound {bound:.1})");
            assert!(chi2 < bound, "mean {mean}: chi2 {chi2} >= {bound}");
        }
    }

    #[test]
    fn ln_factorial_matches_the_exact_sum() {
        let mut exact = 0.0f64;
        for k in 0..400u32 {
            if k > 1 {
                exact += f64::from(k).ln();
            }
            let got = ln_factorial(f64::from(k));
            // Summing 400 logarithms in f64 accumulates a few ulps of ln 400! (about 2000).
            assert!(
                (got - exact).abs() <= 1e-12 * exact.max(1.0),
                "{k}: {got} vs {exact}"
            );
        }
    }

    #[test]
    fn the_fast_finish_equals_noise_then_tone_mapping() {
        // finish_frame's table over counts and row split must give exactly apply_noise then
        // to_display_centred: a ramp of transmissions (Knuth and PTRS means, zero, and T = 5,
        // whose counts run past the table), shutters, both polarities, several thread counts.
        let (w, h) = (37usize, 23usize);
        let t = TransmissionImage {
            width: w as u32,
            height: h as u32,
            transmission: (0..w * h)
                .map(|p| {
                    if p % 97 == 0 {
                        5.0
                    } else {
                        (p % 41) as f64 / 40.0
                    }
                })
                .collect(),
            exposed: (0..w * h).map(|p| p % 13 != 0).collect(),
            supersampled_pixels: 0,
        };
        for (photons, invert, threads) in [(40.0, false, 1), (40.0, true, 3), (3000.0, false, 0)] {
            let noise = QuantumNoise {
                photons_per_pixel: photons,
                seed: 5,
            };
            let settings = RenderSettings {
                noise: Some(noise),
                invert,
                threads,
                ..RenderSettings::default()
            };
            let centre = exposure_centre(&t, &settings.exposure, Some(&noise));
            let mut noisy = t.clone();
            apply_noise(&mut noisy, &noise);
            let want = to_display_centred(&noisy, &settings.exposure, invert, Some(&noise), centre);
            assert_eq!(
                finish_frame(&t, &settings),
                want,
                "{photons} {invert} {threads}"
            );
        }
    }

    #[test]
    fn supersampling_keeps_a_subpixel_needle_shift_smooth() {
        // A needle parallel to the image columns, moved by 1/8 pixel at a time. Its signal (the
        // intensity it removes, summed over the image) should not depend on where it falls within
        // a pixel. With 4 x 4 n-rooks samples each needle edge is resolved to 1/16 pixel; the
        // needle is 0.72 mm x 2.03 / 0.586 mm = 2.5 pixels wide, so the bound is 2 x (1/16) / 2.5
        // = 5 %. Centre sampling jumps by whole pixels (up to 1 / 2.5 = 40 %).
        let p = Projection {
            detector_pixels: [96, 96],
            pixel_pitch_mm: [300.0 / 512.0; 2],
            ..Projection::default()
        };
        let pitch_at_iso = p.pixel_pitch_mm[0] / p.isocentre_magnification();
        let body = {
            let mut s = Scene::new();
            s.add(
                "body",
                FluoroMaterial::Tissue(MaterialClass::SoftTissue),
                &TriMesh::icosphere([0.0; 3], 40.0, 3),
            );
            s
        };
        let settings = RenderSettings {
            energy: EnergyModel::Mono60,
            ..RenderSettings::default()
        };
        let single = RenderSettings {
            supersample: 1,
            ..settings
        };
        let removed = |s: &RenderSettings, x: f64| {
            let base = render_transmission(&body, None, &p, s).unwrap();
            let t = render_transmission(&body_with_needle(x), None, &p, s).unwrap();
            t.transmission
                .iter()
                .zip(&base.transmission)
                .map(|(a, b)| b - a)
                .sum::<f64>()
        };
        let (mut ss, mut one) = (Vec::new(), Vec::new());
        for k in 0..8 {
            let x = 2.0 + k as f64 * pitch_at_iso / 8.0;
            ss.push(removed(&settings, x));
            one.push(removed(&single, x));
        }
        let spread = |v: &[f64]| {
            let (lo, hi) = v
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                    (l.min(x), h.max(x))
                });
            (hi - lo) / hi
        };
        assert!(
            spread(&ss) < 0.05,
            "supersampled spread {}: {ss:?}",
            spread(&ss)
        );
        assert!(
            spread(&one) > 0.15,
            "centre sampling aliases: spread {}: {one:?}",
            spread(&one)
        );
    }

    #[test]
    fn shutters_and_brightness() {
        let scene = body_with_needle(0.0);
        let mut p = small_projection(40);
        p.collimation.x_max_mm = 30.0;
        let img = render_frame(&scene, None, &p, &RenderSettings::default()).unwrap();
        // Right of the blade (x > 30 mm, i.e. columns above 20 + 30/3 = 30): shutter grey.
        assert!(
            img.pixels[5 * 40 + 35..5 * 40 + 40]
                .iter()
                .all(|&g| g == SHUTTER_GREY)
        );
        // Fluoroscopy polarity: the needle (column 20) is darker than the tissue beside it.
        let row = 20 * 40;
        assert!(
            img.pixels[row + 20] < img.pixels[row + 14],
            "{:?}",
            &img.pixels[row..row + 40]
        );
        // Automatic brightness: a thicker patient (lower T everywhere) gives the same centre grey.
        let thick = {
            let mut s = Scene::new();
            s.add(
                "body",
                FluoroMaterial::Tissue(MaterialClass::SoftTissue),
                &TriMesh::icosphere([0.0; 3], 45.0, 3),
            );
            s
        };
        let thin = {
            let mut s = Scene::new();
            s.add(
                "body",
                FluoroMaterial::Tissue(MaterialClass::SoftTissue),
                &TriMesh::icosphere([0.0; 3], 40.0, 3),
            );
            s
        };
        let st = RenderSettings {
            energy: EnergyModel::Mono60,
            ..RenderSettings::default()
        };
        let a = render_frame(&thick, None, &small_projection(40), &st).unwrap();
        let b = render_frame(&thin, None, &small_projection(40), &st).unwrap();
        let c = 20 * 40 + 20;
        assert!(
            (i32::from(a.pixels[c]) - i32::from(b.pixels[c])).abs() <= 1,
            "{} {}",
            a.pixels[c],
            b.pixels[c]
        );
    }

    #[test]
    fn iodine_column_darkens_the_frame_where_the_contrast_is() {
        // A synthetic contrast pool: a 21^3 grid of 1 mm voxels at 50 % stock in its middle
        // 11^3 voxels, centred 10 mm left of the isocentre (so it images right of centre).
        use crate::volume::{Volume, VolumeGrid};
        let grid = VolumeGrid {
            dims: [21, 21, 21],
            spacing_mm: [1.0; 3],
            origin_mm: [-20.0, -10.0, -10.0],
        };
        let mut v = Volume::filled(grid, 0.0f32);
        for k in 5..16 {
            for j in 5..16 {
                for i in 5..16 {
                    v.set(i, j, k, 0.5);
                }
            }
        }
        let field = IodineField::new(v);
        let mut scene = Scene::new();
        scene.add(
            "body",
            FluoroMaterial::Tissue(MaterialClass::SoftTissue),
            &TriMesh::icosphere([0.0; 3], 40.0, 3),
        );
        let p = small_projection(40);
        let settings = RenderSettings::default();
        let with = render_transmission(&scene, Some(&field), &p, &settings).unwrap();
        let without = render_transmission(&scene, None, &p, &settings).unwrap();
        // Pool centre at x = -10 mm: column 20 + 10 x 2.03 / 3 = 26.8; row 20.
        let at = |t: &TransmissionImage, i: usize, j: usize| t.transmission[j * 40 + i];
        // Through the pool: 11 mm at 50 % (plus the trilinear ramps) = about 5.5 mm of stock;
        // at 80 kVp behind 8 cm of tissue that removes well over a third of the signal.
        assert!(at(&with, 26, 20) < 0.7 * at(&without, 26, 20));
        // Away from the pool nothing changes.
        assert_eq!(at(&with, 10, 20), at(&without, 10, 20));
    }
}
