//! How the fluoroscopy modality renders an image it acquired: its render settings (the
//! detector's noise from the image's charge and pixel pitch), the session's renderer, and the
//! temporal chain of live frames ([`super::temporal`]).

use std::sync::Arc;

use sim_core::fluoro::detector::{FLAT_PANEL_DQE, detected_quanta_per_pixel};
use sim_core::fluoro::receptor::ReceptorSettings;
use sim_core::fluoro::scatter::superposition::ScatterSettings;
use sim_core::fluoro::temporal::{FIRST_FRAME_LAG, HISTORY_FRAMES, combine, weights_q16};
use sim_core::fluoro::{EnergyModel, IodineField, Projection, QuantumNoise, RenderSettings};

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
        let settings = self.image_settings(&image);
        let iodine = image
            .iodine_version
            .and(self.image_iodine.clone().or_else(|| world.iodine.clone()));
        Some((image, settings, iodine))
    }

    /// How acquired image `image` is rendered.
    fn image_settings(&self, image: &AcquiredImage) -> RenderSettings {
        let (kvp, ma, mas) = (image.kvp, image.ma, image.mas);
        RenderSettings {
            scatter: image.scatter.map(|s| ScatterSettings {
                kvp,
                grid: s.grid,
                air_gap_mm: s.air_gap_mm,
                pixel_pitch_mm: image.projection.pixel_pitch_mm[0],
            }),
            receptor: self.state.receptor.map(|kind| ReceptorSettings {
                kind,
                pixel_pitch_mm: image.projection.pixel_pitch_mm[0],
            }),
            ..self.render_settings(kvp, ma, mas, &image.projection, image.noise_seed)
        }
    }

    /// How an image of technique `kvp`, `ma` and charge `mas` (see [`AcquiredImage::mas`]) taken
    /// with `projection` (its pixel pitch and focal distance set the detected quanta) is
    /// rendered, with noise seed `seed`.
    pub(super) fn render_settings(
        &self,
        kvp: u32,
        ma: f64,
        mas: Option<f64>,
        projection: &Projection,
        seed: u64,
    ) -> RenderSettings {
        let pitch_mm = projection.pixel_pitch_mm[0];
        let photons_per_pixel = match mas {
            Some(mas) => detected_quanta_per_pixel(
                kvp,
                mas,
                projection.source_to_detector_mm(),
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

    /// The raw (unfiltered) frame of acquired image `image`, showing `iodine`.
    pub(super) fn render_raw(
        &mut self,
        image: &AcquiredImage,
        iodine: Option<&IodineField>,
        world: &World,
    ) -> Result<ViewImage, ModalityError> {
        let settings = self.image_settings(image);
        Ok(self
            .renderer(world)?
            .render(image.needle.as_ref(), &image.projection, &settings, iodine)
            .map_err(render_failed)?
            .into())
    }

    /// Image `image`'s raw `frame` as displayed: the temporal chain's mix of its run's raw
    /// frames ([`history`]), those not kept in this process rendered again.
    pub(super) fn temporal_chain(
        &mut self,
        image: &AcquiredImage,
        frame: ViewImage,
        iodine: Option<Arc<IodineField>>,
        world: &World,
    ) -> Result<ViewImage, ModalityError> {
        let history = history(&self.state.images, image.index as usize);
        let Some(level) = image.filter.filter(|_| history.len() > 1) else {
            // A live frame may be the history of the next one; a shot never is.
            if image.filter.is_some() {
                self.raw_frames.put(image.index, frame.clone());
            }
            return Ok(frame);
        };
        // The cache keeps exactly this history (at most `HISTORY_FRAMES`, its capacity): the
        // missing raw frames are rendered into it, then combined from it without copies.
        let indices: Vec<u64> = history.iter().map(|&j| j as u64).collect();
        self.raw_frames.keep_only(&indices);
        for &j in &history[1..] {
            if self.raw_frames.get(j as u64).is_none() {
                let old = self.state.images[j].clone();
                let raw = self.render_raw(&old, iodine.as_deref(), world)?;
                self.raw_frames.put(j as u64, raw);
            }
        }
        let (width, height) = (frame.width, frame.height);
        self.raw_frames.put(image.index, frame);
        let refs: Vec<&[u8]> = indices
            .iter()
            .filter_map(|&j| self.raw_frames.get(j).map(|f| f.pixels.as_slice()))
            .collect();
        let weights = weights_q16(level, FIRST_FRAME_LAG, refs.len());
        let pixels = combine(&refs, &weights)
            .filter(|_| refs.len() == indices.len())
            .ok_or_else(|| ModalityError::Render {
                modality: "fluoroscopy",
                message: "raw frames of a live run differ in size".into(),
            })?;
        Ok(ViewImage {
            width,
            height,
            pixels,
        })
    }
}

/// The images whose raw frames image `k` is displayed from, newest first (`k` itself first):
/// the live images of its run with its iodine field and its projection, at most
/// `HISTORY_FRAMES`; just `k` for a shot, an image without a run, or one recorded before the
/// chain. A C-arm move (or a change of field, collimation or grid) restarts the filter, as
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
            || o.scatter.map(|s| s.grid) != img.scatter.map(|s| s.grid)
        {
            break;
        }
        out.push(j);
    }
    out
}
