//! The renderer's shared vocabulary, below every pass: constants, the slot layouts, the vertex
//! format, pixel rectangles and their arithmetic, the error and the public result types. It
//! imports nothing from the passes.

use bytemuck::{Pod, Zeroable};
use sim_core::fluoro::spectrum::UnknownKvp;
use sim_core::fluoro::{FluoroMaterial, Projection};
use sim_core::material::MaterialClass;
use thiserror::Error;

use crate::gpu::GpuError;

/// Number of per-pixel chord channels
/// [`GpuFluoroRenderer::render_chords`](super::GpuFluoroRenderer::render_chords) returns (one
/// per [`FluoroMaterial`], in [`FluoroMaterial::index`] order).
pub const CHANNELS: usize = FluoroMaterial::COUNT;

/// Why the GPU renderer could not be built or could not render.
#[derive(Debug, Error)]
pub enum FluoroGpuError {
    /// Device-level failure (no adapter, readback).
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The device lacks a feature the L-buffer needs.
    #[error(
        "the GPU device lacks {0:?}, needed for additive blending into 32-bit float render targets"
    )]
    MissingFeature(wgpu::Features),
    /// The adapter cannot write storage buffers from fragment shaders (the resolve pass does).
    #[error("the GPU adapter lacks {0:?}, needed by the resolve pass")]
    MissingDownlevel(wgpu::DownlevelFlags),
    /// The requested tube voltage has no committed spectrum.
    #[error(transparent)]
    UnknownKvp(#[from] UnknownKvp),
    /// Newer input made the frame obsolete before its CPU pass was done (see
    /// `crate::interrupt`): nothing of it is kept.
    #[error("the frame was superseded by newer input")]
    Interrupted,
}

/// A rectangle of the detector sampled `n x n` per pixel: sample `(i, j)` of it lies at
/// continuous pixel coordinates `origin + ((i, j) + 0.5) / n` (the CPU's stratified sub-pixel
/// positions). The full image is `origin 0, n 1`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct PixelRect {
    pub(super) origin: [u32; 2],
    pub(super) n: u32,
    /// Samples per axis (pixels x n).
    pub(super) size: [u32; 2],
}

impl PixelRect {
    pub(super) fn full(p: &Projection) -> PixelRect {
        PixelRect {
            origin: [0, 0],
            n: 1,
            size: p.detector_pixels,
        }
    }

    /// Which set of targets and uniforms it uses.
    pub(super) fn index(&self) -> usize {
        usize::from(self.n > 1)
    }
}

/// What
/// [`GpuFluoroRenderer::render_transmission`](super::GpuFluoroRenderer::render_transmission)
/// returns: the per-pixel transmission (pixel centres, 0 behind the collimator), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GpuTransmission {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Transmission per pixel.
    pub transmission: Vec<f32>,
}

/// Wall-clock phases of the last frame rendered by
/// [`GpuFluoroRenderer::render_frame`](super::GpuFluoroRenderer::render_frame) (or the
/// transmission calls), ms. GPU work is measured from submit to the end of the wait for the
/// read-back (lavapipe runs it on the CPU); `cpu_*` are work on the calling thread.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameTimings {
    /// Recording passes and uploading uniforms.
    pub encode_ms: f64,
    /// Submit until the read-back buffer is mapped (rasterising, resolve, copy).
    pub gpu_ms: f64,
    /// Copying the mapped read-back into the frame.
    pub readback_ms: f64,
    /// Needle-edge flags and averaging the supersampled region.
    pub supersample_ms: f64,
    /// sim-core's finishing step (noise, brightness, tone map, shutters).
    pub finish_ms: f64,
    /// Transmission samples resolved on the GPU (full image and supersampled region).
    pub resolved_samples: u64,
    /// Whether the full-image geometric L-buffer was reused.
    pub geometry_reused: bool,
    /// Whether the whole transmission was reused (nothing changed).
    pub frame_reused: bool,
    /// Whether the detector signal (scatter, glare, receptor) was reused too: only the noise
    /// and the display were done.
    pub signal_reused: bool,
}

impl FrameTimings {
    /// Sum of the phases, ms.
    pub fn total_ms(&self) -> f64 {
        self.encode_ms + self.gpu_ms + self.readback_ms + self.supersample_ms + self.finish_ms
    }
}

/// Channels of the `Rgba32Float` L-buffer targets (the geometric one and the displaced one).
/// Transmission layout: (water-basis `sum mu_60 L`, bone-basis `sum mu_60 L`, both net of what
/// the needle displaces; cortical and cancellous geometric `L` for the clamp).
pub(super) const SLOTS: usize = 4;

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct Vertex {
    pub(super) pos: [f32; 3],
    pub(super) mesh: u32,
    /// Outward unit normal of the vertex's triangle (f64 cross product; zero if degenerate).
    pub(super) normal: [f32; 3],
    pub(super) pad: u32,
}

/// Chord-layout channels: 0..11, tissue `i`'s chord net of the needle (for the two bone
/// classes: geometric); 11 and 12, the cortical and cancellous parts the needle displaces.
pub(super) const CHORD_CHANNELS: usize = CHANNELS + 1;

/// L-buffer passes for `GpuFluoroRenderer::render_chords`, four channels each.
pub(super) const CHORD_PASSES: usize = CHORD_CHANNELS.div_ceil(SLOTS);

pub(super) const CORTICAL: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::CorticalBone);

pub(super) const CANCELLOUS: FluoroMaterial = FluoroMaterial::Tissue(MaterialClass::Cancellous);

/// Which passes `LBuffer::encode` records.
#[derive(Debug, Clone, Copy)]
pub(super) struct Passes {
    pub(super) geometry: bool,
    pub(super) needle: bool,
    pub(super) displaced: bool,
}

impl Passes {
    pub(super) const ALL: Passes = Passes {
        geometry: true,
        needle: true,
        displaced: true,
    };
}

/// The slot layout of one pass.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Layout {
    Transmission,
    Chords(usize),
}

/// Marker of "no needle on this pixel" in the hull target (as in the shader).
pub(super) const NO_NEEDLE: f64 = 1.0e30;

/// A [`PixelRect`] recorded for resolve and read-back.
#[derive(Debug, Clone)]
pub(super) struct Pending {
    pub(super) ri: usize,
    pub(super) rows: std::ops::Range<u32>,
    /// The resolved columns of those rows (the read-back holds whole rows; outside these
    /// columns it is whatever the pooled buffer held).
    pub(super) cols: std::ops::Range<u32>,
    /// Bytes to read back (0: nothing was resolved).
    pub(super) bytes: u64,
    pub(super) needle_rect: Option<[u32; 4]>,
}

/// Resolved rows of one [`PixelRect`] (whole rows; only `cols` of them were resolved).
pub(super) struct PixelRectOut {
    pub(super) rows: std::ops::Range<u32>,
    pub(super) cols: std::ops::Range<u32>,
    pub(super) data: Vec<f32>,
    pub(super) needle_rect: Option<[u32; 4]>,
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
