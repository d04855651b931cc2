//! Automatic brightness and the logarithmic tone curve: transmission to 8-bit grey, with the
//! collimator shutters.

use super::settings::{Exposure, Image, QuantumNoise, SHUTTER_GREY, TransmissionImage};

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
pub(super) fn ln_t_floor(noise: Option<&QuantumNoise>) -> f64 {
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
pub(super) fn grey(exposure: &Exposure, invert: bool, centre: f64, ln_t: f64) -> u8 {
    let g = (exposure.target_grey + (ln_t - centre) / exposure.log_range).clamp(0.0, 1.0);
    let g = if invert { 1.0 - g } else { g };
    (g * 255.0).round() as u8
}

fn roi(n: usize, fraction: f64) -> (usize, usize) {
    let m = ((n as f64 * fraction.clamp(0.0, 1.0)).round() as usize).clamp(1, n.max(1));
    let start = (n - m.min(n)) / 2;
    (start, start + m.min(n))
}
