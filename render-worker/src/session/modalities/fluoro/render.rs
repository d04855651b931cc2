//! How the fluoroscopy modality renders an image it acquired: its render settings (the
//! detector's noise from the image's charge and pixel pitch), the session's renderer, and the
//! temporal chain of live frames ([`super::temporal`]).

use std::sync::Arc;

use sim_core::fluoro::detector::{FLAT_PANEL_DQE, detected_quanta_per_pixel};
use sim_core::fluoro::temporal::{FIRST_FRAME_LAG, HISTORY_FRAMES, combine, weights_q16};
use sim_core::fluoro::{EnergyModel, IodineField, QuantumNoise, RenderSettings};

use super::{
    AcquiredImage, FluoroModality, FluoroRenderer, PHOTONS_PER_PIXEL_PER_MA, render_failed,
};
use crate::session::image::ViewImage;
use crate::session::modalities::modality::ModalityError;
use crate::session::world::World;

impl FluoroModality {
    /// The image on display with how it is rendered: its settings and the iodine field it
    /// shows (the field it was acquired with; after a restore, which drops it, the world's,
    /// which is the same field unless contrast moved after the image without a new one).
    pub(super) fn displayed(
        &self,
        world: &World,
    ) -> Option<(AcquiredImage, RenderSettings, Option<Arc<IodineField>>)> {
        let image = self.state.images.last()?.clone();
        let pitch_mm = image.projection.pixel_pitch_mm[0];
        let settings =
            self.render_settings(image.kvp, image.ma, image.mas, pitch_mm, image.noise_seed);
        let iodine = image
            .iodine_version
            .and(self.image_iodine.clone().or_else(|| world.iodine.clone()));
        Some((image, settings, iodine))
    }

    /// How an image of technique `kvp`, `ma` and charge `mas` (see [`AcquiredImage::mas`]) on
    /// pixels of `pitch_mm` at the detector is rendered, with noise seed `seed`.
    pub(super) fn render_settings(
        &self,
        kvp: u32,
        ma: f64,
        mas: Option<f64>,
        pitch_mm: f64,
        seed: u64,
    ) -> RenderSettings {
        let photons_per_pixel = match mas {
            Some(mas) => detected_quanta_per_pixel(
                kvp,
                mas,
                self.projection().source_to_detector_mm(),
                pitch_mm * pitch_mm,
                FLAT_PANEL_DQE,
            )
            .unwrap_or(PHOTONS_PER_PIXEL_PER_MA * ma),
            None => PHOTONS_PER_PIXEL_PER_MA * ma,
        };
        RenderSettings {
            energy: EnergyModel::Spectral { kvp },
            supersample: self.state.config.supersample,
            adaptive: true,
            noise: self.state.config.noise.then_some(QuantumNoise {
                photons_per_pixel,
                seed,
            }),
            ..RenderSettings::default()
        }
    }

    /// This session's renderer, made on first use.
    pub(super) fn renderer(
        &mut self,
        world: &World,
    ) -> Result<&mut Box<dyn FluoroRenderer>, ModalityError> {
        if self.renderer.is_none() {
            self.renderer = Some(
                self.backend
                    .renderer(&world.region)
                    .map_err(render_failed)?,
            );
        }
        Ok(self.renderer.as_mut().expect("made above"))
    }

    /// Image `image`'s raw `frame` as displayed: the temporal chain's mix of its run's raw
    /// frames ([`temporal::history`]), those not kept in this process rendered again.
    pub(super) fn temporal_chain(
        &mut self,
        image: &AcquiredImage,
        frame: ViewImage,
        iodine: Option<Arc<IodineField>>,
        world: &World,
    ) -> Result<ViewImage, ModalityError> {
        let history = history(&self.state.images, image.index as usize);
        let (Some(level), true) = (image.filter, history.len() > 1) else {
            self.raw_frames.put(image.index, frame.clone());
            return Ok(frame);
        };
        let mut raws = vec![frame.clone()];
        for &j in &history[1..] {
            let index = j as u64;
            if let Some(f) = self.raw_frames.get(index) {
                raws.push(f.clone());
                continue;
            }
            let im = self.state.images[j].clone();
            let pitch_mm = im.projection.pixel_pitch_mm[0];
            let settings = self.render_settings(im.kvp, im.ma, im.mas, pitch_mm, im.noise_seed);
            let f: ViewImage = self
                .renderer(world)?
                .render(
                    im.needle.as_ref(),
                    &im.projection,
                    &settings,
                    iodine.as_deref(),
                )
                .map_err(render_failed)?
                .into();
            raws.push(f);
        }
        // Oldest first, so that the newest stay kept.
        for (k, &j) in history.iter().enumerate().rev() {
            self.raw_frames.put(j as u64, raws[k].clone());
        }
        let weights = weights_q16(level, FIRST_FRAME_LAG, raws.len());
        let refs: Vec<&[u8]> = raws.iter().map(|f| f.pixels.as_slice()).collect();
        let pixels = combine(&refs, &weights).ok_or_else(|| ModalityError::Render {
            modality: "fluoroscopy",
            message: "raw frames of a live run differ in size".into(),
        })?;
        Ok(ViewImage { pixels, ..frame })
    }
}

/// The images whose raw frames image `k` is displayed from, newest first (`k` itself first):
/// the live images of its run with its iodine field and its projection, at most
/// `HISTORY_FRAMES`; just `k` for a shot, an image without a run, or one recorded before the
/// chain. A C-arm move (or a change of field or collimation) restarts the filter, as
/// motion-detecting recursive filters do: it keeps the anatomy sharp while the C-arm turns, and
/// a drag's frames (often only drafted) are never rendered again for the history.
pub fn history(images: &[AcquiredImage], k: usize) -> Vec<usize> {
    let Some(img) = images.get(k) else {
        return Vec::new();
    };
    let mut out = vec![k];
    if !img.live || img.run.is_none() || img.filter.is_none() {
        return out;
    }
    for j in (0..k).rev() {
        let o = &images[j];
        if out.len() == HISTORY_FRAMES
            || !o.live
            || o.run != img.run
            || o.iodine_version != img.iodine_version
            || o.projection != img.projection
        {
            break;
        }
        out.push(j);
    }
    out
}
