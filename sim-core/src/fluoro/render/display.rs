//! Automatic brightness and the logarithmic tone curve: transmission to 8-bit grey, with the
//! collimator shutters.

use crate::fluoro::rows::{par_rows, thread_count};
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
    Samples::of(t).exposure_centre(exposure, noise)
}

/// A transmission image's values (in `f64`, or in `f32` as the GPU renderer reads them back,
/// widened exactly where they are read) and its exposure mask, row-major.
#[derive(Debug, Clone, Copy)]
pub(super) struct Samples<'a, T> {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) transmission: &'a [T],
    pub(super) exposed: &'a [bool],
}

impl<'a> Samples<'a, f64> {
    pub(super) fn of(t: &'a TransmissionImage) -> Samples<'a, f64> {
        Samples {
            width: t.width as usize,
            height: t.height as usize,
            transmission: &t.transmission,
            exposed: &t.exposed,
        }
    }
}

impl<T: Copy + Into<f64>> Samples<'_, T> {
    /// Transmission of pixel `p`.
    pub(super) fn at(self, p: usize) -> f64 {
        self.transmission[p].into()
    }

    /// See [`exposure_centre`].
    pub(super) fn exposure_centre(self, exposure: &Exposure, noise: Option<&QuantumNoise>) -> f64 {
        let (w, h) = (self.width, self.height);
        let floor = ln_t_floor(noise);
        // The median of ln max(T, floor) is ln of the median of max(T, floor) (ln is
        // increasing): one logarithm instead of one per pixel.
        let clamped = |p: usize| self.at(p).max(floor);
        let (rx0, rx1) = roi(w, exposure.roi_fraction);
        let (ry0, ry1) = roi(h, exposure.roi_fraction);
        let mut vals: Vec<f64> = (ry0..ry1)
            .flat_map(|j| (rx0..rx1).map(move |i| j * w + i))
            .filter(|&p| self.exposed[p])
            .map(clamped)
            .collect();
        if vals.is_empty() {
            vals = (0..w * h)
                .filter(|&p| self.exposed[p])
                .map(clamped)
                .collect();
        }
        if vals.is_empty() {
            0.0
        } else {
            let mid = vals.len() / 2;
            vals.select_nth_unstable_by(mid, f64::total_cmp).1.ln()
        }
    }

    /// See [`to_display_centred`]; the rows are split over `threads` workers (0: every core),
    /// which does not change the image.
    pub(super) fn display_centred(
        self,
        exposure: &Exposure,
        invert: bool,
        noise: Option<&QuantumNoise>,
        centre: f64,
        threads: usize,
    ) -> Image
    where
        T: Sync,
    {
        let floor = ln_t_floor(noise);
        let w = self.width;
        let mut pixels = vec![SHUTTER_GREY; w * self.height];
        par_rows(&mut pixels, w, thread_count(threads), |j, row| {
            for (i, out) in row.iter_mut().enumerate() {
                let p = j * w + i;
                if self.exposed[p] {
                    *out = grey(exposure, invert, centre, self.at(p).max(floor).ln());
                }
            }
        });
        Image {
            width: self.width as u32,
            height: self.height as u32,
            pixels,
        }
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
    Samples::of(t).display_centred(exposure, invert, noise, centre, 1)
}

/// The grey level of `ln T` around the set point `centre`.
pub(super) fn grey(exposure: &Exposure, invert: bool, centre: f64, ln_t: f64) -> u8 {
    let g = (exposure.target_grey + (ln_t - centre) / exposure.log_range).clamp(0.0, 1.0);
    let g = if invert { 1.0 - g } else { g };
    round_grey(g * 255.0)
}

/// `x.round() as u8` for `x` in `[0, 255]` (halves away from zero), without the `round` call
/// that the baseline x86-64 target makes of `f64::round`: the truncation is exact there and so
/// is `x - whole` (both below 2^52), so the result is the same bit for bit.
#[inline]
pub(super) fn round_grey(x: f64) -> u8 {
    let whole = x as u8;
    // Without a branch: the fraction is random across a frame's pixels.
    whole + u8::from(x - f64::from(whole) >= 0.5)
}

fn roi(n: usize, fraction: f64) -> (usize, usize) {
    let m = ((n as f64 * fraction.clamp(0.0, 1.0)).round() as usize).clamp(1, n.max(1));
    let start = (n - m.min(n)) / 2;
    (start, start + m.min(n))
}
