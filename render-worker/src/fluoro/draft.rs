//! The draft of a fluoroscopy frame (progressive frames; the session side, which decides when
//! a draft is shown and keeps the draft scenes, is `session::modalities::fluoro::draft`): the
//! same frame rendered by a renderer of the region's draft scene (`sim_core::fluoro::draft`) at
//! half the detector resolution with one sample per pixel, then doubled to the full size.
//! Noise keeps its dose: a draft pixel covers four detector pixels and collects four times the
//! quanta. Deterministic like every frame of the renderer, so a replay reproduces a draft bit
//! for bit.

use sim_core::fluoro::receptor::ReceptorSettings;
use sim_core::fluoro::scatter::superposition::ScatterSettings;
use sim_core::fluoro::{Image, IodineField, Projection, QuantumNoise, RenderSettings};

use super::{FluoroGpuError, GpuFluoroRenderer};

/// Smallest detector (pixels a side) that is drafted: the draft has half as many.
const DRAFT_MIN_DETECTOR_PIXELS: u32 = 64;

/// Whether frames of `projection` can be drafted (an even detector of at least 64 pixels a
/// side).
pub fn draftable(projection: &Projection) -> bool {
    let [w, h] = projection.detector_pixels;
    w.is_multiple_of(2) && h.is_multiple_of(2) && w.min(h) >= DRAFT_MIN_DETECTOR_PIXELS
}

/// The draft of the frame `projection`, `settings` and `iodine` give, rendered by `draft` (a
/// renderer of the draft scene), at the full frame's size. `projection` must be
/// [`draftable`].
pub fn render_draft_frame(
    draft: &mut GpuFluoroRenderer,
    projection: &Projection,
    settings: &RenderSettings,
    iodine: Option<&IodineField>,
) -> Result<Image, FluoroGpuError> {
    let [w, h] = projection.detector_pixels;
    let half = Projection {
        detector_pixels: [w / 2, h / 2],
        pixel_pitch_mm: projection.pixel_pitch_mm.map(|p| 2.0 * p),
        ..*projection
    };
    // Scatter and the receptor work in millimetres: the draft's pixels are twice as wide.
    let settings = RenderSettings {
        supersample: 1,
        noise: settings.noise.map(|n| QuantumNoise {
            photons_per_pixel: 4.0 * n.photons_per_pixel,
            ..n
        }),
        scatter: settings.scatter.map(|s| ScatterSettings {
            pixel_pitch_mm: 2.0 * s.pixel_pitch_mm,
            ..s
        }),
        receptor: settings.receptor.map(|r| ReceptorSettings {
            pixel_pitch_mm: 2.0 * r.pixel_pitch_mm,
            ..r
        }),
        ..*settings
    };
    let small = draft.render_frame(&half, &settings, iodine)?;
    Ok(upscale2(&small))
}

/// `image` at twice its width and height, bilinear with pixel centres aligned (each output
/// pixel weighs its nearest source pixel 3/4 and the next one 1/4 along each axis, edges
/// clamped), rounded to nearest in exact integer arithmetic.
pub fn upscale2(image: &Image) -> Image {
    let (w, h) = (image.width as usize, image.height as usize);
    if w == 0 || h == 0 {
        return Image {
            width: 0,
            height: 0,
            pixels: Vec::new(),
        };
    }
    // Source index and its neighbour towards output pixel `o` (0-based) along an axis of `n`.
    let taps = |o: usize, n: usize| -> (usize, usize) {
        let i = o / 2;
        let j = if o.is_multiple_of(2) {
            i.saturating_sub(1)
        } else {
            (i + 1).min(n - 1)
        };
        (i, j)
    };
    let (ow, oh) = (2 * w, 2 * h);
    let mut pixels = vec![0u8; ow * oh];
    for y in 0..oh {
        let (y0, y1) = taps(y, h);
        let (r0, r1) = (&image.pixels[y0 * w..][..w], &image.pixels[y1 * w..][..w]);
        for x in 0..ow {
            let (x0, x1) = taps(x, w);
            let sum = 9 * u32::from(r0[x0])
                + 3 * u32::from(r0[x1])
                + 3 * u32::from(r1[x0])
                + u32::from(r1[x1]);
            pixels[y * ow + x] = ((sum + 8) / 16) as u8;
        }
    }
    Image {
        width: ow as u32,
        height: oh as u32,
        pixels,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upscaling_keeps_flat_images_and_interpolates_ramps() {
        let flat = Image {
            width: 3,
            height: 2,
            pixels: vec![77; 6],
        };
        let up = upscale2(&flat);
        assert_eq!((up.width, up.height), (6, 4));
        assert!(up.pixels.iter().all(|&p| p == 77));
        // A ramp 0, 16, 32 along x: outputs at a quarter and three quarters between samples.
        let ramp = Image {
            width: 3,
            height: 1,
            pixels: vec![0, 16, 32],
        };
        let up = upscale2(&ramp);
        assert_eq!(up.pixels[..6], [0, 4, 12, 20, 28, 32]);
        assert_eq!(up.pixels[..6], up.pixels[6..]);
    }
}
