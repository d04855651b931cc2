//! The frame caches (sessions: the needle moves far more often than the C-arm).
//!
//! With `GpuFluoroRenderer::caching` (the default) the renderer keeps in its [`FrameCache`],
//! between frames, the geometric L-buffer of the last projection (pass 1 is skipped while the
//! C-arm stays), the last full-image transmission without iodine ([`Resolved`]: only the union
//! of the needle's old and new pixel rectangles is resolved and read back, since outside it
//! every input of the resolve is unchanged), the last displayed transmission ([`FrameKey`]: a
//! shot with nothing changed costs only the CPU's noise and display) with its detector signal
//! (scatter, glare and the receptor's blur, which do not depend on the noise) and the exposure
//! mask ([`ExposureKey`]). These, the full image's geometric L-buffer and the needle are what a
//! renderer holds of its own between frames (at 512 x 512: 5 MB of L-buffer, 1 MB each for the
//! two kept transmissions and the signal, and the signal's mask of 0.25 MB); the anatomy is
//! shared, and so are the other targets, which a frame takes from the anatomy's pool and gives
//! back (`pipelines::TargetPool`; before, each renderer held its own, 14 MB for the full image
//! and a few MB for the supersampled needle region).
//! Each cached frame is bit-identical to a frame from scratch, and so is culling (tests in
//! `render-worker/tests/fluoro_cache.rs`; renderers sharing the pool: `anatomy.rs`'s tests).
//! The pixel-rectangle arithmetic of the partial resolve is in `types.rs`.

use sim_core::fluoro::render::DetectorSignal;
use sim_core::fluoro::{EnergyModel, Projection, RenderSettings};

use super::types::{GpuTransmission, Layout, Passes, PixelRectOut};

/// The full-image transmission of the last resolve: for which projection and energy model, the
/// needle's pixel rectangle then (where the displaced pass and the steel wrote), and the values.
/// Outside the union of that rectangle and the next frame's, every input of the resolve is the
/// same (same geometric L-buffer, no displaced part, no steel), so only that union is resolved
/// and read back again, and the result is bit-identical to a frame from scratch.
pub(super) struct Resolved {
    pub(super) projection: Projection,
    pub(super) model: EnergyModel,
    pub(super) needle_rect: Option<[u32; 4]>,
    pub(super) transmission: Vec<f32>,
}

/// Everything that decides `GpuFluoroRenderer::render_transmission_supersampled` without
/// iodine.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct FrameKey {
    pub(super) projection: Projection,
    pub(super) energy: EnergyModel,
    pub(super) supersample: u32,
    pub(super) needle_generation: u64,
}

/// What decides which pixels the beam reaches (see `Projection::is_exposed`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ExposureKey {
    pub(super) pixels: [u32; 2],
    pub(super) pitch_mm: [f64; 2],
    pub(super) collimation: sim_core::fluoro::Collimation,
}

impl ExposureKey {
    pub(super) fn of(p: &Projection) -> ExposureKey {
        ExposureKey {
            pixels: p.detector_pixels,
            pitch_mm: p.pixel_pitch_mm,
            collimation: p.collimation,
        }
    }
}

/// What the renderer keeps between frames (see the module doc). Each method says which cache it
/// reads or fills; the renderer decides when (`caching`) and records the passes.
#[derive(Default)]
pub(super) struct FrameCache {
    /// What the full-image geometric L-buffer (`Targets::a` of region 0) holds, if anything.
    geometry: Option<(Projection, Layout)>,
    /// The last full-image transmission resolve without iodine (see [`Resolved`]).
    resolved: Option<Resolved>,
    /// The last displayed-frame transmission and what decided it.
    last_frame: Option<(FrameKey, GpuTransmission)>,
    /// The detector signal (scatter, glare, receptor) of the last displayed frame's
    /// transmission, for new shots of it: only the noise and the display are redone.
    signal: Option<(FrameKey, DetectorSignal)>,
    /// The exposure mask of the last frame, reused while the detector and the collimator stay.
    exposure: Option<(ExposureKey, Vec<bool>)>,
}

/// How the full image of one frame is rendered: from scratch, or on the kept geometric
/// L-buffer and (without iodine) resolving only around the needle's old and new rectangles.
pub(super) struct FullPlan {
    /// Whether the geometric pass must be recorded.
    pub(super) geometry: bool,
    key: (Projection, Layout),
    model: EnergyModel,
    previous: Option<Resolved>,
}

impl FullPlan {
    /// The passes to record.
    pub(super) fn passes(&self) -> Passes {
        Passes {
            geometry: self.geometry,
            ..Passes::ALL
        }
    }

    /// The needle rectangle of the kept resolve, if only the rectangles are to be resolved.
    pub(super) fn previous_needle_rect(&self) -> Option<Option<[u32; 4]>> {
        self.previous.as_ref().map(|p| p.needle_rect)
    }
}

impl FrameCache {
    /// The full-image targets were replaced: nothing they held is kept.
    pub(super) fn targets_replaced(&mut self) {
        self.geometry = None;
        self.resolved = None;
    }

    /// The geometric L-buffer now holds `key` (the chord passes record it directly).
    pub(super) fn geometry_holds(&mut self, key: (Projection, Layout)) {
        self.geometry = Some(key);
    }

    /// Whether the geometric L-buffer holds `projection` (a frame of it skips pass 1).
    pub(super) fn holds_geometry_of(&self, projection: &Projection) -> bool {
        self.geometry == Some((*projection, Layout::Transmission))
    }

    /// Plans the full image of a frame, taking what the caches hold for it (nothing without
    /// `caching`); [`FrameCache::end_full`] completes it after the read-back.
    pub(super) fn plan_full(
        &mut self,
        caching: bool,
        projection: &Projection,
        model: EnergyModel,
        iodine: bool,
    ) -> FullPlan {
        let key = (*projection, Layout::Transmission);
        let geometry = !(caching && self.geometry == Some(key));
        let previous = if !geometry && !iodine {
            self.resolved
                .take()
                .filter(|r| r.projection == *projection && r.model == model)
        } else {
            None
        };
        self.resolved = None;
        // Invalidated until the frame is read back: a failure leaves no stale key behind.
        self.geometry = None;
        FullPlan {
            geometry,
            key,
            model,
            previous,
        }
    }

    /// The full-image transmission (`width` pixels a row) from its read-back `out`, kept for the
    /// next frame.
    pub(super) fn end_full(
        &mut self,
        caching: bool,
        plan: FullPlan,
        out: PixelRectOut,
        width: usize,
        iodine: bool,
    ) -> Vec<f32> {
        let FullPlan {
            key,
            model,
            previous,
            ..
        } = plan;
        let projection = &key.0;
        self.geometry = Some(key);
        let transmission = match previous {
            Some(mut p) => {
                // Only the resolved columns: the rest of the read-back rows is whatever the
                // pooled transmission buffer held.
                let cols = out.cols.start as usize..out.cols.end as usize;
                let rows = out.data.chunks_exact(width);
                for (row, data) in (out.rows.start as usize..).zip(rows) {
                    let start = row * width;
                    p.transmission[start + cols.start..start + cols.end]
                        .copy_from_slice(&data[cols.clone()]);
                }
                p.transmission
            }
            None => out.data,
        };
        if caching && !iodine {
            self.resolved = Some(Resolved {
                projection: *projection,
                model,
                needle_rect: out.needle_rect,
                transmission: transmission.clone(),
            });
        }
        transmission
    }

    /// The kept displayed-frame transmission, if it was rendered for `key`.
    pub(super) fn frame(&self, key: &FrameKey) -> Option<&GpuTransmission> {
        self.last_frame
            .as_ref()
            .filter(|(k, _)| k == key)
            .map(|(_, t)| t)
    }

    /// Forgets the kept displayed-frame transmission (and its detector signal).
    pub(super) fn forget_frame(&mut self) {
        self.last_frame = None;
        self.signal = None;
    }

    /// The kept detector signal, if it was made of the transmission of `key` under the scatter
    /// and receptor of `settings`.
    pub(super) fn signal(
        &self,
        key: &FrameKey,
        settings: &RenderSettings,
    ) -> Option<&DetectorSignal> {
        self.signal
            .as_ref()
            .filter(|(k, s)| k == key && s.serves(settings))
            .map(|(_, s)| s)
    }

    /// Keeps the detector signal of the transmission of `key`.
    pub(super) fn keep_signal(&mut self, key: FrameKey, signal: DetectorSignal) {
        self.signal = Some((key, signal));
    }

    /// Keeps a displayed-frame transmission for `key`.
    pub(super) fn keep_frame(&mut self, key: FrameKey, t: GpuTransmission) {
        self.last_frame = Some((key, t));
    }

    /// Which pixels the collimator exposes under `projection`: the kept mask while the detector
    /// and the collimator stay (it does not depend on the C-arm's pose), else a new one.
    pub(super) fn exposure_mask(&mut self, projection: &Projection) -> &[bool] {
        let key = ExposureKey::of(projection);
        if self.exposure.as_ref().is_none_or(|(k, _)| *k != key) {
            self.exposure = Some((key, exposed_mask(projection)));
        }
        &self.exposure.as_ref().expect("exposure mask").1
    }
}

/// Which pixels the collimator exposes (decided at pixel centres, as the CPU).
fn exposed_mask(projection: &Projection) -> Vec<bool> {
    let w = projection.detector_pixels[0] as usize;
    let n = w * projection.detector_pixels[1] as usize;
    (0..n)
        .map(|p| projection.is_exposed([(p % w) as f64 + 0.5, (p / w) as f64 + 0.5]))
        .collect()
}
