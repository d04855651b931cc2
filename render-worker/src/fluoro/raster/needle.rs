//! The needle's passes on the CPU, over the needle's box of samples: its hull interval and
//! chord per sample (`lbuffer.wgsl`'s `fs_needle`), then the part of each anatomy chord it
//! occupies (`fs_displaced`). Distances along a sample's ray are the plane's axial depth (see
//! the module doc) times the ray's length per unit of axial depth, in f64; entering or
//! leaving is the rasteriser's facing, as in the geometric pass, so the crossings of each
//! closed mesh pair up on every sample.

use super::{ChunkBoxes, CpuGeometry, Frame, NotDrawn, SampleProjection, SampleRect, setup};
use crate::interrupt::Interrupt;

/// The needle as its passes read it.
pub(crate) struct NeedleTriangles<'a> {
    /// Its triangles, mm (outward counter-clockwise, as the anatomy's).
    pub(crate) triangles: &'a [[[f64; 3]; 3]],
    /// Distance from the source its chord is summed relative to (the GPU's `needle_ref`), mm.
    pub(crate) reference_mm: f64,
}

/// What the resolve reads of the needle within its box (row-major over the box): the displaced
/// L-buffer (four channels per sample) and the needle's summed signed distances from its
/// reference (one per sample: its chord, mm).
pub(crate) struct NeedleSums {
    pub(crate) d: Vec<f32>,
    pub(crate) chord: Vec<f32>,
}

impl CpuGeometry {
    /// The needle's and the displaced pass over `rect` (the needle's box of samples of `p`'s
    /// target): `displaced[m]` are drawn mesh `m`'s displaced weights; the anatomy is culled
    /// with `boxes`, on `threads` threads (0: every core). Never interrupted: a needle's box
    /// is a small part of a frame.
    pub(crate) fn needle_passes(
        &self,
        needle: &NeedleTriangles<'_>,
        displaced: &[[f32; 4]],
        p: &SampleProjection,
        boxes: &ChunkBoxes,
        rect: &SampleRect,
        threads: usize,
    ) -> Result<NeedleSums, NotDrawn> {
        let frame = Frame::new(p)?;
        let n = rect.len();
        let at = |i: usize, j: usize| rect.index(i, j);
        let distance = |i: usize, j: usize, depth: f64| {
            depth * frame.distance_per_depth(i as f64 + 0.5, j as f64 + 0.5)
        };
        // The hull: nearest entering and farthest leaving distance (the GPU's Min-blended
        // target); the chord: signed distances from the reference, summed.
        let mut hull = vec![(f64::INFINITY, f64::NEG_INFINITY); n];
        let mut chord = vec![0f64; n];
        for t in needle.triangles {
            let Some(span) = setup(&frame, t, rect)? else {
                continue;
            };
            span.for_each(|i, j, depth| {
                let k = at(i, j);
                let t = distance(i, j, depth);
                let h = &mut hull[k];
                if span.entering {
                    h.0 = h.0.min(t);
                } else {
                    h.1 = h.1.max(t);
                }
                chord[k] += span.sign() * (t - needle.reference_mm);
            });
        }
        let mut d = vec![0f32; 4 * n];
        let hull = &hull;
        self.banded(
            p,
            boxes,
            rect,
            (&mut d, None),
            (threads, &Interrupt::default()),
            |band, span, mesh| {
                let weights = displaced[mesh].map(|x| span.sign() * f64::from(x));
                span.for_each(|i, j, depth| {
                    let (t0, t1) = hull[at(i, j)];
                    if t1 > t0 {
                        let inside = distance(i, j, depth).clamp(t0, t1) - t0;
                        let o = 4 * band.rect.index(i, j);
                        for (sum, wc) in band.a[o..o + 4].iter_mut().zip(weights) {
                            *sum += wc * inside;
                        }
                    }
                });
            },
        )?;
        Ok(NeedleSums {
            d,
            chord: chord.iter().map(|&c| c as f32).collect(),
        })
    }
}
