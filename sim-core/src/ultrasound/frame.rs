//! Envelope, log compression and scan conversion to an image in millimetre-scaled pixels.

use serde::{Deserialize, Serialize};

use super::needle::NeedleView;
use super::probe::ScanGeometry;
use super::settings::Settings;

/// The detected envelope `sqrt(I^2 + Q^2)` on the scan lines, after the two-way losses and
/// before gain and TGC (0 dB = a perfect plane reflector at the skin).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// Scan lines (line 0 on the marker side).
    pub lines: usize,
    /// Samples per line; sample `s` is at depth `s * sample_mm`.
    pub samples: usize,
    /// Sample spacing along a line, mm.
    pub sample_mm: f64,
    /// Amplitude, line-major (`data[line * samples + sample]`).
    pub data: Vec<f32>,
}

impl Envelope {
    /// Amplitude at (line, sample).
    pub fn at(&self, line: usize, sample: usize) -> f32 {
        self.data[line * self.samples + sample]
    }
}

/// One B-mode frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BModeFrame {
    /// Image width in pixels (columns run from the marker side, left, to the far side).
    pub width: usize,
    /// Image height in pixels (rows run from the probe face down).
    pub height: usize,
    /// Side of a square pixel, mm.
    pub pixel_mm: f64,
    /// Image coordinates (mm, see [`super::probe`]) of the centre of pixel (0, 0).
    pub origin_mm: [f64; 2],
    /// Grey levels, row-major; 0 outside the scanned sector.
    pub pixels: Vec<u8>,
    /// Whether each pixel lies inside the scanned region.
    pub inside: Vec<bool>,
    /// The envelope the image was made from.
    pub envelope: Envelope,
    /// What the image shows of the needle, when there is one.
    pub needle: Option<NeedleView>,
    /// The settings the frame was made with (depth, focus marker, ...).
    pub settings: Settings,
}

impl BModeFrame {
    /// Grey level at column `x`, row `y`.
    pub fn pixel(&self, x: usize, y: usize) -> u8 {
        self.pixels[y * self.width + x]
    }

    /// Image coordinates (mm) of the centre of pixel (x, y).
    pub fn pixel_center_mm(&self, x: usize, y: usize) -> [f64; 2] {
        [
            self.origin_mm[0] + x as f64 * self.pixel_mm,
            self.origin_mm[1] + y as f64 * self.pixel_mm,
        ]
    }
}

/// Bilinear interpolation of the envelope at fractional (line, sample), or `None` outside.
pub(crate) fn sample_envelope(env: &Envelope, u: f64, s: f64) -> Option<f64> {
    let (lmax, smax) = ((env.lines - 1) as f64, (env.samples - 1) as f64);
    if !(u >= 0.0 && u <= lmax && s >= 0.0 && s <= smax) {
        return None;
    }
    let (u0, s0) = (
        (u as usize).min(env.lines - 2),
        (s as usize).min(env.samples - 2),
    );
    let (fu, fs) = (u - u0 as f64, s - s0 as f64);
    let v = |a: usize, b: usize| f64::from(env.at(a, b));
    Some(
        (v(u0, s0) * (1.0 - fs) + v(u0, s0 + 1) * fs) * (1.0 - fu)
            + (v(u0 + 1, s0) * (1.0 - fs) + v(u0 + 1, s0 + 1) * fs) * fu,
    )
}

/// Scan conversion and display mapping: `grey = 255 (dB + gain + TGC + DR) / DR`, clamped.
pub(crate) fn scan_convert(
    geo: &ScanGeometry,
    settings: &Settings,
    pixel_mm: f64,
    envelope: Envelope,
    needle: Option<NeedleView>,
) -> BModeFrame {
    let (x0, x1, y0, y1) = geo.image_extent_mm();
    let width = ((x1 - x0) / pixel_mm).floor() as usize + 1;
    let height = ((y1 - y0) / pixel_mm).floor() as usize + 1;
    // Grey level + 1 per pixel, 0 outside the scanned region; rows split over two threads.
    let mut grey = vec![0u16; width * height];
    let dr = settings.dynamic_range_db;
    let map = (width * height <= super::pixel_map::MAP_PIXELS_MAX)
        .then(|| super::pixel_map::pixel_map(geo, [x0, y0], pixel_mm, (width, height)));
    super::parallel::in_two(&mut grey, width, |rows, y_first| {
        for (i, row) in rows.chunks_mut(width).enumerate() {
            let y = y_first + i;
            let ym = y0 + y as f64 * pixel_mm;
            for (x, out) in row.iter_mut().enumerate() {
                let (u, z) = match &map {
                    Some(m) => m.line_depth[y * width + x],
                    None => geo.plane_to_line(x0 + x as f64 * pixel_mm, ym),
                };
                let Some(a) = sample_envelope(&envelope, u, z / envelope.sample_mm) else {
                    continue;
                };
                let db = super::decibel::amplitude_db(a.max(1e-12))
                    + settings.gain_db
                    + settings.tgc_at_db(z);
                let g = ((db + dr) / dr).clamp(0.0, 1.0) * 255.0;
                *out = u16::from((g + 0.5) as u8) + 1;
            }
        }
    });
    let pixels = grey.iter().map(|&g| g.saturating_sub(1) as u8).collect();
    let inside = grey.iter().map(|&g| g > 0).collect();
    BModeFrame {
        width,
        height,
        pixel_mm,
        origin_mm: [x0, y0],
        pixels,
        inside,
        envelope,
        needle,
        settings: *settings,
    }
}
