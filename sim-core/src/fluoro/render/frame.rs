//! The whole CPU reference frame, and the finish (metering, noise, tone mapping) that the CPU
//! reference and the GPU renderer share.

use super::display::{exposure_centre, grey, ln_t_floor, to_display_centred};
use super::noise::noisy_count;
use super::rows::{par_rows, thread_count};
use super::settings::{Image, RenderSettings, SHUTTER_GREY, TransmissionImage};
use super::transmission::render_transmission;
use crate::fluoro::contrast::IodineField;
use crate::fluoro::geometry::Projection;
use crate::fluoro::scene::Scene;
use crate::fluoro::spectrum::UnknownKvp;

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
/// With noise the result equals [`apply_noise`](super::noise::apply_noise) then
/// [`to_display_centred`] bit for bit, but faster: the grey of a count `k` is taken from a table
/// over `k` built per frame (the same arithmetic on the same `k / photons`), and the rows are
/// split over `settings.threads` workers (each pixel's noise has its own seed, so the split does
/// not change the frame).
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
