//! The frame caches (sessions: the needle moves far more often than the C-arm) and the
//! pixel-rectangle arithmetic of the partial resolve.
//!
//! With [`GpuFluoroRenderer::caching`] (the default) the renderer keeps, between frames, the
//! geometric L-buffer of the last projection (pass 1 is skipped while the C-arm stays), the last
//! full-image transmission without iodine ([`Resolved`]: only the union of the needle's old and
//! new pixel rectangles is resolved and read back, since outside it every input of the resolve
//! is unchanged), the last displayed transmission ([`FrameKey`]: a shot with nothing changed
//! costs only the CPU's noise and display) and the exposure mask ([`ExposureKey`]). Each cached
//! frame is bit-identical to a frame from scratch, and so is culling (tests in
//! `render-worker/tests/fluoro_cache.rs`).
use sim_core::fluoro::{IodineField, Projection, SpectralModel};

use super::types::*;

impl GpuFluoroRenderer {
    /// Records the full image's passes and resolve into `enc`, from the caches where they
    /// apply; [`GpuFluoroRenderer::end_full`] completes it after the read-back.
    pub(super) fn begin_full(
        &mut self,
        enc: &mut wgpu::CommandEncoder,
        projection: &Projection,
        model: &SpectralModel,
        iodine: Option<&IodineField>,
    ) -> FullFrame {
        let full = PixelRect::full(projection);
        self.ensure_targets(0, full.size);
        let key = (*projection, Layout::Transmission);
        let geometry = !(self.caching && self.geo_key == Some(key));
        self.timings.geometry_reused = !geometry;
        let previous = if !geometry && iodine.is_none() {
            self.resolved
                .take()
                .filter(|r| r.projection == *projection && r.model == model.model)
        } else {
            None
        };
        self.resolved = None;
        let passes = Passes {
            geometry,
            ..Passes::ALL
        };
        // Invalidated until the frame is read back: a failure leaves no stale key behind.
        self.geo_key = None;
        let pending = self.encode_region(
            enc,
            projection,
            model,
            iodine,
            full,
            passes,
            previous.as_ref().map(|p| p.needle_rect),
        );
        FullFrame {
            pending,
            key,
            model: model.model,
            previous,
            width: full.size[0] as usize,
        }
    }

    /// The full-image transmission from its read-back `out`, kept for the next frame.
    pub(super) fn end_full(
        &mut self,
        frame: FullFrame,
        out: PixelRectOut,
        iodine: Option<&IodineField>,
    ) -> Vec<f32> {
        let FullFrame {
            key,
            model,
            previous,
            width: w,
            ..
        } = frame;
        let projection = &key.0;
        self.geo_key = Some(key);
        let transmission = match previous {
            Some(mut p) => {
                let start = out.rows.start as usize * w;
                p.transmission[start..start + out.data.len()].copy_from_slice(&out.data);
                p.transmission
            }
            None => out.data,
        };
        if self.caching && iodine.is_none() {
            self.resolved = Some(Resolved {
                projection: *projection,
                model,
                needle_rect: out.needle_rect,
                transmission: transmission.clone(),
            });
        }
        transmission
    }
}

/// Overlap of two rectangles `[x, y, w, h]` (`None` if they do not overlap).
pub(super) fn intersect_rect(a: [u32; 4], b: [u32; 4]) -> Option<[u32; 4]> {
    let (x0, y0) = (a[0].max(b[0]), a[1].max(b[1]));
    let x1 = (a[0] + a[2]).min(b[0] + b[2]);
    let y1 = (a[1] + a[3]).min(b[1] + b[3]);
    (x1 > x0 && y1 > y0).then(|| [x0, y0, x1 - x0, y1 - y0])
}

/// `a` less `b` (which lies inside `a`, if given) as up to four disjoint, non-empty bands: the
/// rows above and below `b`, and the parts of `b`'s rows left and right of it.
pub(super) fn subtract_rect(a: [u32; 4], b: Option<[u32; 4]>) -> Vec<[u32; 4]> {
    let Some(b) = b else {
        return vec![a];
    };
    let (ax1, ay1, bx1, by1) = (a[0] + a[2], a[1] + a[3], b[0] + b[2], b[1] + b[3]);
    [
        [a[0], a[1], a[2], b[1] - a[1]],
        [a[0], by1, a[2], ay1 - by1],
        [a[0], b[1], b[0] - a[0], b[3]],
        [bx1, b[1], ax1 - bx1, b[3]],
    ]
    .into_iter()
    .filter(|r| r[2] > 0 && r[3] > 0)
    .collect()
}

/// Smallest rectangle `[x, y, w, h]` holding both (`None` if both are).
pub(super) fn union_rect(a: Option<[u32; 4]>, b: Option<[u32; 4]>) -> Option<[u32; 4]> {
    match (a, b) {
        (None, r) | (r, None) => r,
        (Some(a), Some(b)) => {
            let (x0, y0) = (a[0].min(b[0]), a[1].min(b[1]));
            let x1 = (a[0] + a[2]).max(b[0] + b[2]);
            let y1 = (a[1] + a[3]).max(b[1] + b[3]);
            Some([x0, y0, x1 - x0, y1 - y0])
        }
    }
}

/// Which pixels the collimator exposes (decided at pixel centres, as the CPU).
pub(super) fn exposed_mask(projection: &Projection) -> Vec<bool> {
    let w = projection.detector_pixels[0] as usize;
    let n = w * projection.detector_pixels[1] as usize;
    (0..n)
        .map(|p| projection.is_exposed([(p % w) as f64 + 0.5, (p / w) as f64 + 0.5]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every sample of `a` is covered exactly once by `b` (if any, inside `a`) and the bands
    /// `subtract_rect` returns, for every placement of `b` on a small grid.
    #[test]
    fn the_needle_box_and_the_bands_cover_the_rectangle_once() {
        let a = [2, 3, 7, 5];
        let mut boxes = vec![None];
        for x in 2..9 {
            for y in 3..8 {
                for w in 1..=9 - x {
                    for h in 1..=8 - y {
                        boxes.push(Some([x, y, w, h]));
                    }
                }
            }
        }
        for b in boxes {
            let mut count = [[0u8; 12]; 12];
            for r in b.into_iter().chain(subtract_rect(a, b)) {
                assert!(r[2] > 0 && r[3] > 0, "{b:?}: empty band {r:?}");
                for y in r[1]..r[1] + r[3] {
                    for x in r[0]..r[0] + r[2] {
                        count[y as usize][x as usize] += 1;
                    }
                }
            }
            for (y, row) in count.iter().enumerate() {
                for (x, &c) in row.iter().enumerate() {
                    let inside = (2..9).contains(&x) && (3..8).contains(&y);
                    assert_eq!(
                        c,
                        u8::from(inside),
                        "{b:?}: sample ({x}, {y}) covered {c} times"
                    );
                }
            }
            assert_eq!(intersect_rect(a, a), Some(a));
            if let Some(b) = b {
                assert_eq!(intersect_rect(a, b), Some(b));
            }
        }
    }
}
