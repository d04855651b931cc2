//! The whole CPU reference frame, and the finish (metering, noise, tone mapping) that the CPU
//! reference and the GPU renderer share.

use super::display::{Samples, grey, ln_t_floor};
use super::noise::noisy_count;
use super::settings::{Image, RenderSettings, SHUTTER_GREY, TransmissionImage};
use super::transmission::render_transmission;
use crate::fluoro::contrast::IodineField;
use crate::fluoro::geometry::Projection;
use crate::fluoro::receptor;
use crate::fluoro::rows::{par_rows, thread_count};
use crate::fluoro::scatter::superposition::{ScatterField, ScatterSettings, scatter_field};
use crate::fluoro::scene::SceneRef;
use crate::fluoro::spectrum::UnknownKvp;

/// The full CPU reference frame: transmission, noise, automatic brightness, tone mapping and
/// shutters. The GPU renderer is compared against this. `scene` is a
/// [`Scene`](crate::fluoro::Scene) or a [`SceneRef`] (a scene with an overlay, such as a
/// session's needle on a shared anatomy).
pub fn render_frame<'a>(
    scene: impl Into<SceneRef<'a>>,
    iodine: Option<&IodineField>,
    projection: &Projection,
    settings: &RenderSettings,
) -> Result<Image, UnknownKvp> {
    let t = render_transmission(scene, iodine, projection, settings)?;
    Ok(finish_frame(&t, settings))
}

/// Turns a transmission image into the displayed frame: scatter (when set) added to the
/// primary, automatic brightness metered on the noise-free image, then seeded quantum noise (when enabled), tone mapping and shutters. The
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
/// Without noise the result equals [`to_display`](super::display::to_display) bit for bit, its
/// rows split over `settings.threads` workers. With noise it equals
/// [`apply_noise`](super::noise::apply_noise) then
/// [`to_display_centred`](super::display::to_display_centred) bit for bit, but faster: the grey of a count `k` is taken from a table
/// over `k` built per frame (the same arithmetic on the same `k / photons`), and the rows are
/// split over `settings.threads` workers (each pixel's noise has its own seed, so the split does
/// not change the frame).
pub fn finish_frame(t: &TransmissionImage, settings: &RenderSettings) -> Image {
    finish(Samples::of(t), settings)
}

/// [`finish_frame`] of a transmission held in `f32` (what the GPU renderer reads back), row-major
/// `width x height`, with its exposure mask: each value is widened to `f64` where it is read,
/// exactly as an `f64` copy would hold it, so the frame equals `finish_frame` of that copy bit
/// for bit without making it (8 MB at 1024 x 1024).
pub fn finish_frame_f32(
    width: u32,
    height: u32,
    transmission: &[f32],
    exposed: &[bool],
    settings: &RenderSettings,
) -> Image {
    finish(samples_f32(width, height, transmission, exposed), settings)
}

/// The samples of an `f32` transmission; panics when the slices do not hold `width x height`
/// pixels.
fn samples_f32<'a>(
    width: u32,
    height: u32,
    transmission: &'a [f32],
    exposed: &'a [bool],
) -> Samples<'a, f32> {
    let (w, h) = (width as usize, height as usize);
    assert!(
        transmission.len() == w * h && exposed.len() == w * h,
        "a {width} x {height} image has {} pixels (transmission {}, mask {})",
        w * h,
        transmission.len(),
        exposed.len()
    );
    Samples {
        width: w,
        height: h,
        transmission,
        exposed,
    }
}

fn finish<T: Copy + Into<f64> + Sync>(t: Samples<'_, T>, settings: &RenderSettings) -> Image {
    if settings.scatter.is_none() && settings.receptor.is_none() {
        return finish_total(t, settings);
    }
    DetectorSignal::from_samples(t, settings).finish(settings)
}

/// What a frame's detector holds before the quantum noise: the transmission with the scatter
/// and the receptor's veiling glare added and its blur and distortion applied, and the mask of
/// the pixels that get a signal. It depends on the transmission, `settings.scatter` and
/// `settings.receptor` only, not on the noise, the technique's quanta or the display, so a
/// renderer that keeps it finishes a new shot of an unchanged view from it
/// ([`DetectorSignal::finish`]) without that work, bit for bit as [`finish_frame_f32`] (the
/// finish makes its frames the same way). With neither scatter nor a receptor profile it is the
/// transmission itself.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectorSignal {
    width: usize,
    height: usize,
    signal: Vec<f32>,
    exposed: Vec<bool>,
    scatter: Option<ScatterSettings>,
    receptor: Option<receptor::ReceptorSettings>,
}

impl DetectorSignal {
    /// The signal of an `f32` transmission (row-major `width x height`, what the GPU renderer
    /// reads back) with its exposure mask, under `settings`' scatter and receptor.
    pub fn of_f32(
        width: u32,
        height: u32,
        transmission: &[f32],
        exposed: &[bool],
        settings: &RenderSettings,
    ) -> DetectorSignal {
        DetectorSignal::from_samples(samples_f32(width, height, transmission, exposed), settings)
    }

    /// Whether this signal is the one `settings` would make of the same transmission: the same
    /// scatter and receptor, bit for bit (so settings holding a NaN serve their own signal).
    pub fn serves(&self, settings: &RenderSettings) -> bool {
        let scatter = |s: &Option<ScatterSettings>| {
            s.map(|s| {
                (
                    s.kvp,
                    s.grid,
                    s.air_gap_mm.to_bits(),
                    s.pixel_pitch_mm.to_bits(),
                )
            })
        };
        let receptor = |r: &Option<receptor::ReceptorSettings>| {
            r.map(|r| (r.kind, r.pixel_pitch_mm.to_bits()))
        };
        scatter(&self.scatter) == scatter(&settings.scatter)
            && receptor(&self.receptor) == receptor(&settings.receptor)
    }

    /// The displayed frame: noise, automatic brightness, tone mapping, shutters and the
    /// receptor's vignetting, as [`finish_frame_f32`] finishes the transmission this signal was
    /// made of. `settings` must be served by this signal ([`DetectorSignal::serves`]).
    pub fn finish(&self, settings: &RenderSettings) -> Image {
        debug_assert!(
            self.serves(settings),
            "a signal finished under other settings"
        );
        let mut image = finish_total(
            Samples {
                width: self.width,
                height: self.height,
                transmission: &self.signal,
                exposed: &self.exposed,
            },
            settings,
        );
        if let Some(r) = &self.receptor {
            vignette(&mut image, &self.exposed, r.kind, settings);
        }
        image
    }

    fn from_samples<T: Copy + Into<f64> + Sync>(
        t: Samples<'_, T>,
        settings: &RenderSettings,
    ) -> DetectorSignal {
        let threads = settings.threads;
        let copy = || -> Vec<f32> { t.transmission.iter().map(|&v| v.into() as f32).collect() };
        let (signal, exposed) = match settings.receptor.as_ref() {
            None => {
                let signal = settings
                    .scatter
                    .as_ref()
                    .and_then(|s| with_scatter(t, s, threads))
                    .unwrap_or_else(copy);
                (signal, t.exposed.to_vec())
            }
            Some(r) => match settings
                .scatter
                .as_ref()
                .and_then(|s| scatter_and_glare(t, s, r, threads))
            {
                // Scatter and glare in one pass: the point-spread core and distortion remain.
                Some(mut glared) => {
                    let mask = receptor::apply_after_glare(
                        &mut glared,
                        t.exposed,
                        t.width,
                        t.height,
                        r,
                        threads,
                    );
                    (glared, mask)
                }
                None => {
                    let mut signal = copy();
                    let mask =
                        receptor::apply(&mut signal, t.exposed, t.width, t.height, r, threads);
                    (signal, mask)
                }
            },
        };
        DetectorSignal {
            width: t.width,
            height: t.height,
            signal,
            exposed,
            scatter: settings.scatter,
            receptor: settings.receptor,
        }
    }
}

/// Scatter and the receptor's veiling glare folded into one pass over the pixels: with the
/// primary `T`, the grid's primary factor `f`, the scatter field `S` and the glare fraction `g`,
/// the signal `(1 - g)(f T + S) + g G` where `G` is the glare of `f T + S`, computed on the
/// scatter's coarse grid from the cell means (`f` times the primary's cell mean plus the
/// cell's scatter times its exposed share). `None` when the scatter cannot be computed.
fn scatter_and_glare<T: Copy + Into<f64> + Sync>(
    t: Samples<'_, T>,
    s: &ScatterSettings,
    r: &receptor::ReceptorSettings,
    threads: usize,
) -> Option<Vec<f32>> {
    let mut field = scatter_field(t.transmission, t.exposed, t.width, t.height, s)?;
    let p = r.kind.params();
    let g = p.glare_fraction;
    let f = s.primary_factor();
    let (means, share) = receptor::cell_means(
        t.transmission,
        t.exposed,
        t.width,
        t.height,
        field.cell_px,
        field.cells,
    );
    let total: Vec<f64> = (0..means.len())
        .map(|c| f * means[c] + field.values[c] * share[c])
        .collect();
    let glare = receptor::glare_cells(
        &total,
        field.cells,
        field.cell_px as f64 * r.pixel_pitch_mm,
        &p,
    );
    for (v, gl) in field.values.iter_mut().zip(&glare) {
        *v = (1.0 - g) * *v + g * gl;
    }
    Some(add_field(t, &field, (1.0 - g) * f, threads))
}

/// The receptor's vignetting on a finished frame: each exposed pixel's grey moves by what the
/// factor `v` is on the log tone curve (`255 ln v / log_range`, the other way in radiograph
/// polarity); the shutters stay.
pub(super) fn vignette(
    image: &mut Image,
    exposed: &[bool],
    kind: receptor::ReceptorKind,
    settings: &RenderSettings,
) {
    if kind.params().vignetting == 0.0 {
        return;
    }
    let (w, h) = (image.width as usize, image.height as usize);
    let slope = 255.0 / settings.exposure.log_range * if settings.invert { -1.0 } else { 1.0 };
    let offsets = receptor::vignetting_offsets(kind, w, h, slope);
    par_rows(
        &mut image.pixels,
        w,
        thread_count(settings.threads),
        |j, row| {
            let (offs, mask) = (&offsets[j * w..(j + 1) * w], &exposed[j * w..(j + 1) * w]);
            for ((g, &o), &e) in row.iter_mut().zip(offs).zip(mask) {
                if e {
                    *g = (i16::from(*g) + o).clamp(0, 255) as u8;
                }
            }
        },
    );
}

/// The detector's signal with scatter: the primary times the grid's primary transmission plus
/// the superposed scatter, on exposed pixels (0 behind the shutters, as the primary). `None`
/// when the scatter cannot be computed (a voltage without a spectrum): the primary alone.
fn with_scatter<T: Copy + Into<f64> + Sync>(
    t: Samples<'_, T>,
    s: &ScatterSettings,
    threads: usize,
) -> Option<Vec<f32>> {
    let field = scatter_field(t.transmission, t.exposed, t.width, t.height, s)?;
    Some(add_field(t, &field, s.primary_factor(), threads))
}

/// `factor` times the primary plus the coarse `field` interpolated, on exposed pixels (0
/// behind the shutters).
fn add_field<T: Copy + Into<f64> + Sync>(
    t: Samples<'_, T>,
    field: &ScatterField,
    factor: f64,
    threads: usize,
) -> Vec<f32> {
    let columns = field.columns();
    let w = t.width;
    let mut total = vec![0.0f32; t.transmission.len()];
    par_rows(&mut total, w, thread_count(threads), |j, row| {
        let mut cells = Vec::with_capacity(field.cells[0] + 1);
        field.row_cells(j, &mut cells);
        for (i, out) in row.iter_mut().enumerate() {
            let p = j * w + i;
            if t.exposed[p] {
                let (x0, ax) = columns[i];
                let scatter = cells[x0] + ax * (cells[x0 + 1] - cells[x0]);
                *out = (factor * t.at(p) + scatter) as f32;
            }
        }
    });
    total
}

fn finish_total<T: Copy + Into<f64> + Sync>(t: Samples<'_, T>, settings: &RenderSettings) -> Image {
    let noise = settings.noise.as_ref();
    let centre = t.exposure_centre(&settings.exposure, noise);
    let Some(noise) = noise else {
        return t.display_centred(
            &settings.exposure,
            settings.invert,
            None,
            centre,
            settings.threads,
        );
    };
    let (e, invert) = (&settings.exposure, settings.invert);
    let floor = ln_t_floor(Some(noise));
    let n = noise.photons_per_pixel;
    let grey_of_count = |k: f64| grey(e, invert, centre, (k / n).max(floor).ln());
    // Counts up to the open-field mean plus 8 standard deviations (T <= 1), at most 2^16
    // entries; rarer or larger counts are mapped directly.
    let table_len = (n + 8.0 * n.sqrt() + 16.0).clamp(16.0, 65_536.0) as usize;
    let table: Vec<u8> = (0..table_len).map(|k| grey_of_count(k as f64)).collect();
    let w = t.width;
    let mut pixels = vec![SHUTTER_GREY; t.transmission.len()];
    par_rows(&mut pixels, w, thread_count(settings.threads), |j, row| {
        for (i, out) in row.iter_mut().enumerate() {
            let p = j * w + i;
            if t.exposed[p] {
                let k = noisy_count(noise, p, t.at(p));
                *out = table
                    .get(k as usize)
                    .copied()
                    .unwrap_or_else(|| grey_of_count(k));
            }
        }
    });
    Image {
        width: t.width as u32,
        height: t.height as u32,
        pixels,
    }
}
