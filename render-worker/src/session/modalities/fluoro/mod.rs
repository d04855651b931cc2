//! The fluoroscopy modality: C-arm pose and technique, shots and live runs, the displayed image,
//! annotations on it, and its scorers (view alignment, annotation error, shot count, exposure).
//!
//! A C-arm only makes a new image when the beam is on: moving the C-arm or the needle without
//! exposure leaves the last image on screen (last-image hold). So a shot, or any change while
//! live fluoroscopy runs, is what makes the view dirty; nothing else renders.
//!
//! Each image records everything that decides its pixels when it is acquired (projection,
//! technique, the needle shaft, the noise seed), so a frame rendered later (after the client
//! caught up, or after a restore) is exactly the image of that moment.

mod backend;
pub mod brightness;
pub mod collimator;
pub mod dose;
pub mod draft;
mod exposure;
pub mod magnification;
pub mod pulse;
mod render;
pub mod scatter;
mod state;
mod steel;
pub mod temporal;

use std::sync::Arc;

use glam::DVec3;
use sim_core::fluoro::brightness::Technique;
use sim_core::fluoro::receptor::{Distortion, ReceptorKind};
use sim_core::fluoro::{Collimation, IodineField, Projection};
use sim_core::rubric::Measurements;

pub use super::modality::DraftUse;
pub use crate::session::config::FluoroConfig;
pub use backend::{
    BackendProfile, CpuFluoroBackend, FluoroBackend, FluoroRenderError, FluoroRenderer,
    GpuFluoroBackend,
};
use dose::DoseTally;
pub use state::{AcquiredImage, Annotation, FluoroState};
pub use steel::{NEEDLE_FACETS, NeedleShaft, needle_meshes};

use super::modality::{Modality, ModalityContext, ModalityError, ModalitySpec};
use crate::session::anatomy::{
    angle_to_plane_deg, endplate_normal, facet_joint_normal, primary_target, target_side,
};
use crate::session::command::{Command, CommandError, CommandSpec, Engagement, ErrorCode};
use crate::session::image::{ViewId, ViewImage};
use crate::session::world::ImageRayError;
use crate::session::world::{World, WorldChange};

/// Fluoroscopy time booked for one single-shot acquisition, ms. Simulator choice: C-arms display
/// fluoroscopy time in 0.1 s steps, and a single pulse-and-hold shot books one step.
pub const SHOT_EXPOSURE_MS: u64 = 100;
/// Mean detected quanta per pixel at 1 mA of an image recorded before the detector model
/// (without [`AcquiredImage::mas`]). Simulator choice of that time: a few thousand quanta per
/// pixel at typical fluoroscopy currents (2 to 3 mA) gives visible but not dominant grain.
pub const PHOTONS_PER_PIXEL_PER_MA: f64 = 1500.0;
/// An acquisition counts as an AP view when its orbital rotation is within this many degrees of
/// zero. Simulator choice: beyond 10 degrees a view is read as oblique.
pub const AP_MAX_OBLIQUITY_DEG: f64 = 10.0;

/// The endplate that `ap_endplate_tilt_deg` measures, as (vertebra, the one below): the first
/// pair whose landmarks the region has. The L4 inferior endplate on lumbar regions, the C7
/// inferior endplate (squared for the C7-T1 interlaminar approach) on the cervical phantom.
pub const AP_ENDPLATES: [(&str, &str); 2] = [("L4", "L5"), ("C7", "T1")];
/// An acquisition counts as an oblique view from this orbital rotation on (same choice).
pub const OBLIQUE_MIN_DEG: f64 = 10.0;
/// The fluoroscopy modality.
pub struct FluoroModality {
    state: FluoroState,
    backend: Arc<dyn FluoroBackend>,
    /// Index of the last image rendered (`None`: none yet), not part of the state.
    rendered: Option<u64>,
    /// Index of the last image a live draft was rendered for, not part of the state.
    drafted: Option<u64>,
    /// The view last prefetched, not part of the state.
    prefetched: Option<Projection>,
    /// Created on the first render.
    renderer: Option<Box<dyn FluoroRenderer>>,
    /// The iodine field of the last image acquired in this process (not part of the state: it
    /// is the world's field of that moment, see [`AcquiredImage::iodine_version`]).
    image_iodine: Option<Arc<IodineField>>,
    /// The automatic brightness control's metering of the current view.
    metering: brightness::MeteringCache,
    /// Raw frames of the latest live images, for the temporal chain.
    raw_frames: temporal::RawFrames,
}

impl std::fmt::Debug for FluoroModality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FluoroModality")
            .field("state", &self.state)
            .field("backend", &self.backend.profile())
            .finish()
    }
}

impl FluoroModality {
    /// A C-arm in the AP position at 80 kVp / 2 mA under automatic brightness control on the
    /// standard curve, centred on `isocentre_mm`.
    pub fn new(
        config: FluoroConfig,
        isocentre_mm: [f64; 3],
        seed: u64,
        backend: Arc<dyn FluoroBackend>,
        receptor: ReceptorKind,
    ) -> FluoroModality {
        FluoroModality {
            state: FluoroState {
                config,
                isocentre_mm,
                orbital_deg: 0.0,
                angular_deg: 0.0,
                table_mm: [0.0; 3],
                // 80 kVp: the methods page's starting beam; 2 mA: a typical fluoroscopy current.
                kvp: 80,
                ma: 2.0,
                live_since_ms: None,
                exposure_ms: 0,
                shots: 0,
                live_runs: 0,
                pulse_rate_pps: Some(pulse::DEFAULT_PULSE_RATE_PPS),
                pulse_pending: false,
                images: Vec::new(),
                annotations: Vec::new(),
                seed,
                dose: DoseTally::default(),
                brightness: Some(brightness::BrightnessState::on(brightness::DEFAULT_CURVE)),
                detector_noise: true,
                collimator: None,
                field_mm: None,
                temporal: Some(temporal::TemporalState {
                    level: temporal::DEFAULT_LEVEL,
                }),
                scatter: Some(scatter::ScatterState { grid: true }),
                receptor: Some(receptor),
            },
            backend,
            rendered: None,
            drafted: None,
            prefetched: None,
            renderer: None,
            image_iodine: None,
            metering: brightness::MeteringCache::default(),
            raw_frames: temporal::RawFrames::default(),
        }
    }

    /// The technique of the image on display and of the next exposure, for acknowledgements.
    fn technique_json(&self) -> serde_json::Value {
        brightness::technique_json(
            self.state
                .images
                .last()
                .map(|i| (i.kvp, i.ma, i.detector_kerma_ngy)),
            Technique {
                kvp: self.state.kvp,
                ma: self.state.ma,
            },
            self.state.pulse_rate_pps,
            self.state.brightness,
        )
    }

    /// The current state.
    pub fn fluoro_state(&self) -> &FluoroState {
        &self.state
    }

    /// The projection of the current C-arm pose.
    pub fn projection(&self) -> Projection {
        let c = &self.state.config;
        // The blades at the detector's edges: the same as `Collimation::OPEN` for every pixel,
        // but finite, so the state survives JSON (which has no infinity).
        let field_mm = self.field_mm();
        let half_mm = 0.5 * field_mm;
        let open = Collimation {
            x_min_mm: -half_mm,
            x_max_mm: half_mm,
            y_min_mm: -half_mm,
            y_max_mm: half_mm,
            iris_radius_mm: None,
        };
        Projection {
            orbital_deg: self.state.orbital_deg,
            angular_deg: self.state.angular_deg,
            isocentre_mm: self.state.isocentre_mm,
            table_translation_mm: self.state.table_mm,
            detector_pixels: [c.detector_pixels; 2],
            pixel_pitch_mm: [field_mm / f64::from(c.detector_pixels); 2],
            collimation: self.state.collimator.map_or(open, |s| {
                magnification::clip_to_field(s.collimation(), field_mm)
            }),
            ..Projection::default()
        }
    }

    /// Side of the active detector field, mm (the full detector unless a magnification mode is on).
    pub fn field_mm(&self) -> f64 {
        self.state.field_mm.unwrap_or(self.state.config.detector_mm)
    }
}

/// A renderer's failure as the modality's.
fn render_failed(e: FluoroRenderError) -> ModalityError {
    match e {
        FluoroRenderError::Gpu(crate::fluoro::FluoroGpuError::Interrupted) => {
            ModalityError::Interrupted {
                modality: "fluoroscopy",
            }
        }
        e => ModalityError::Render {
            modality: "fluoroscopy",
            message: e.to_string(),
        },
    }
}

/// The factory's builder: a C-arm in AP centred on the L4 body centre (else the station's
/// primary target), rendering with the device's fluoroscopy backend.
pub fn build(ctx: &ModalityContext<'_>) -> Box<dyn Modality> {
    let isocentre = ctx
        .region
        .landmarks
        .get("L4_body_centre")
        .copied()
        .or_else(|| primary_target(ctx.station))
        .unwrap_or([0.0; 3]);
    Box::new(FluoroModality::new(
        ctx.config.fluoro,
        isocentre,
        ctx.config.seed,
        renderer(ctx),
        ctx.station
            .station
            .detector
            .unwrap_or(ReceptorKind::FlatPanel),
    ))
}

/// What the fluoroscopy modality offers: the C-arm image and its commands.
pub static SPEC: ModalitySpec = ModalitySpec {
    name: "fluoroscopy",
    label: "fluoroscopy",
    views: &[ViewId::FLUOROSCOPY],
    commands: &[
        CommandSpec::new("carm_pose", Some(Engagement::ViewChanged)).superseding(),
        CommandSpec::new("technique", Some(Engagement::ViewChanged)),
        CommandSpec::new("shot", Some(Engagement::ImageAcquired)),
        CommandSpec::new("live", Some(Engagement::ImageAcquired)),
        CommandSpec::new("annotate", None),
        CommandSpec::new(pulse::PULSE_RATE_KIND, None),
        CommandSpec::new(brightness::BRIGHTNESS_KIND, None),
        CommandSpec::new(collimator::COLLIMATION_KIND, Some(Engagement::ViewChanged)),
        CommandSpec::new(
            magnification::MAGNIFICATION_KIND,
            Some(Engagement::ViewChanged),
        )
        .superseding(),
        CommandSpec::new(temporal::FILTER_KIND, None),
        CommandSpec::new(scatter::GRID_KIND, Some(Engagement::ViewChanged)),
    ],
    constants: &[("default_pulse_rate_pps", pulse::DEFAULT_PULSE_RATE_PPS)],
};

/// The device's fluoroscopy renderer, or the CPU reference on all cores when the device offers
/// none (a host built with renderers for other modalities only).
fn renderer(ctx: &ModalityContext<'_>) -> Arc<dyn FluoroBackend> {
    ctx.renderers
        .get::<Arc<dyn FluoroBackend>>(SPEC.name)
        .cloned()
        .unwrap_or_else(|| Arc::new(CpuFluoroBackend { threads: 0 }))
}

impl Modality for FluoroModality {
    fn spec(&self) -> &'static ModalitySpec {
        &SPEC
    }

    /// Stopping live fluoroscopy acquires nothing; starting it does.
    fn engagement(&self, command: &Command) -> Option<Engagement> {
        match command {
            Command::Live { on: false } => None,
            other => crate::session::command::engagement_of(SPEC.commands, other.name()),
        }
    }

    fn apply(
        &mut self,
        command: &Command,
        world: &World,
    ) -> Result<serde_json::Value, CommandError> {
        let now = world.clock_ms;
        let live = self.state.live_since_ms.is_some();
        match command {
            Command::CarmPose {
                orbital_deg,
                angular_deg,
                table_mm,
            } => {
                self.book_live(world);
                self.state.orbital_deg = *orbital_deg;
                self.state.angular_deg = *angular_deg;
                self.state.table_mm = *table_mm;
                self.live_change(world);
            }
            Command::Technique { kvp, ma } => {
                self.book_live(world);
                // A technique set by hand turns the automatic control off.
                self.state.brightness = None;
                self.state.kvp = *kvp;
                self.state.ma = *ma;
                self.live_change(world);
            }
            Command::Shot => {
                self.state.shots += 1;
                self.state.exposure_ms += SHOT_EXPOSURE_MS;
                let p = self.projection();
                self.state.dose.book(
                    &world.region,
                    &p,
                    self.state.kvp,
                    self.state.ma,
                    SHOT_EXPOSURE_MS as f64 / 1000.0,
                );
                self.acquire(world, false);
            }
            Command::Live { on: true } => {
                if !live {
                    self.state.live_runs += 1;
                    self.state.live_since_ms = Some(now);
                    self.state.dose.live_booked_to_ms = Some(now);
                    self.state.pulse_pending = false;
                    self.acquire(world, true);
                }
            }
            Command::Live { on: false } => {
                self.book_live(world);
                self.state.dose.live_booked_to_ms = None;
                // The pedal is released: the last pulse's image stays (last-image hold).
                self.state.pulse_pending = false;
                if let Some(since) = self.state.live_since_ms.take() {
                    self.state.exposure_ms += now.saturating_sub(since);
                }
            }
            Command::Annotate { pixel, label } => {
                let Some(image) = self.state.images.last() else {
                    return Err(CommandError::field(
                        "command.type",
                        ErrorCode::State,
                        "no fluoroscopy image to annotate yet: take a shot first",
                    ));
                };
                let [w, h] = image.projection.detector_pixels;
                if !(0.0..=f64::from(w)).contains(&pixel[0])
                    || !(0.0..=f64::from(h)).contains(&pixel[1])
                {
                    return Err(CommandError::field(
                        "command.pixel",
                        ErrorCode::OutOfRange,
                        format!("{pixel:?} is outside the {w} x {h} image"),
                    ));
                }
                self.state.annotations.push(Annotation {
                    pixel: *pixel,
                    label: label.clone(),
                    projection: image.projection,
                    t_ms: now,
                });
                let error =
                    annotation_error_mm(self.state.annotations.last(), self.state.receptor, world);
                return Ok(serde_json::json!({ "annotation_error_mm": error }));
            }
            Command::Modality(c) if c.kind() == pulse::PULSE_RATE_KIND => {
                let pps = pulse::parse(c)?;
                // The live run so far is booked at the rate it ran at.
                self.book_live(world);
                self.state.pulse_rate_pps = Some(pps);
            }
            Command::Modality(c) if c.kind() == collimator::COLLIMATION_KIND => {
                let setting = collimator::parse(c, self.state.config.detector_mm)?;
                // A live run so far is booked with the field it had.
                self.book_live(world);
                self.state.collimator = Some(setting);
                self.live_change(world);
            }
            Command::Modality(c) if c.kind() == scatter::GRID_KIND => {
                let grid = scatter::parse(c)?;
                self.state.scatter = Some(scatter::ScatterState { grid });
                self.live_change(world);
            }
            Command::Modality(c) if c.kind() == temporal::FILTER_KIND => {
                let level = temporal::parse(c)?;
                self.state.temporal = Some(temporal::TemporalState { level });
            }
            Command::Modality(c) if c.kind() == magnification::MAGNIFICATION_KIND => {
                let field = magnification::parse(c, self.state.config.detector_mm)?;
                self.book_live(world);
                self.state.field_mm = (field != self.state.config.detector_mm).then_some(field);
                self.live_change(world);
            }
            Command::Modality(c) if c.kind() == brightness::BRIGHTNESS_KIND => {
                let curve = brightness::parse(c)?;
                // The next frame follows the new curve from the current technique.
                self.state.brightness = Some(brightness::BrightnessState::on(curve));
            }
            other => {
                return Err(CommandError::field(
                    "command.type",
                    ErrorCode::ModalityUnavailable,
                    format!("fluoroscopy does not handle {}", other.name()),
                ));
            }
        }
        Ok(serde_json::json!({
            "technique": self.technique_json(),
            "field_mm": self.field_mm(),
            "detector_mm": self.state.config.detector_mm,
            "grid": self.state.scatter.map(|s| if s.grid { "in" } else { "out" }),
            "detector": self.state.receptor.map(ReceptorKind::name),
            "air_gap_mm": self.state.images.last().and_then(|i| i.scatter).map(|s| s.air_gap_mm),
            "collimation": self.state.collimator,
            "recursive_filter": self.state.temporal.map(|t| t.level),
            "pulse_rate_pps": self.state.pulse_rate_pps,
            "acquisitions": self.state.shots + self.state.live_runs,
            "exposure_s": self.exposure_ms_at(now) as f64 / 1000.0,
            "image": self.state.images.last().map(|i| i.index),
            // The C-arm's angles as its console shows them, now and for the image on screen
            // (a client's orientation markers follow the image, also after a reconnect).
            "carm_deg": [self.state.orbital_deg, self.state.angular_deg],
            "image_carm_deg": self.state.images.last()
                .map(|i| [i.projection.orbital_deg, i.projection.angular_deg]),
            "dose": self.dose_json(world),
        }))
    }

    /// A change that waited for the next pulse is imaged once a pulse period has passed (the
    /// clock moves only by logged commands, so replay images it at the same moment).
    fn advance(&mut self, _from_ms: u64, world: &World) {
        if self.state.pulse_pending {
            self.live_change(world);
        }
    }

    fn prefetch_pending(&self) -> bool {
        let view = Some(self.projection());
        self.backend.prefetches()
            && self.state.live_since_ms.is_none()
            && self.displayed_projection() != view
            && self.prefetched != view
    }

    fn tick_hold_until(&self, now_ms: u64) -> Option<u64> {
        let (since, pps) = (self.state.live_since_ms?, self.state.pulse_rate_pps?);
        if !self.state.pulse_pending {
            return None;
        }
        let last = self.state.images.last().map(|i| i.t_ms);
        let due = pulse::next_pulse_ms(Some(pps), since, last)?;
        let hold_ms = pulse::TICK_HOLD_PERIOD_FRACTION * 1000.0 / pps;
        (due > now_ms && (due - now_ms) as f64 <= hold_ms).then_some(due)
    }

    fn world_changed(&mut self, change: &WorldChange, world: &World) {
        match change {
            WorldChange::Needle | WorldChange::Marker => self.live_change(world),
            // Injected fluid shows through the contrast modality's iodine field, which makes
            // its own world change when it does.
            WorldChange::FluidInjected(_) => {}
            // The C-arm is this modality's own: its commands acquire what they need.
            WorldChange::CArm => {}
            // Live fluoroscopy shows the contrast spreading: a new image whenever the field is
            // newer than the last image's.
            WorldChange::Iodine => {
                let imaged = self.state.images.last().and_then(|i| i.iodine_version);
                if imaged != Some(world.iodine_version) {
                    self.live_change(world);
                }
            }
        }
    }

    fn displayed_projection(&self) -> Option<Projection> {
        self.state.images.last().map(|i| i.projection)
    }

    fn image_ray(&self, pixel: [f64; 2]) -> Option<Result<(DVec3, DVec3), ImageRayError>> {
        let Some(image) = self.state.images.last() else {
            return Some(Err(ImageRayError::NoImage {
                modality: SPEC.name,
            }));
        };
        let [w, h] = image.projection.detector_pixels;
        if !(0.0..=f64::from(w)).contains(&pixel[0]) || !(0.0..=f64::from(h)).contains(&pixel[1]) {
            return Some(Err(ImageRayError::OutsideImage {
                pixel,
                width: w,
                height: h,
            }));
        }
        let r =
            image
                .projection
                .pixel_ray(undistorted(self.state.receptor, &image.projection, pixel));
        Some(Ok((
            DVec3::from_array(r.origin_mm),
            DVec3::from_array(r.dir),
        )))
    }

    fn carm(&self) -> Option<crate::session::world::CArmAxis> {
        let p = self.projection();
        Some(crate::session::world::CArmAxis {
            isocentre_mm: p.effective_isocentre_mm(),
            beam_dir: p.frame().normal,
        })
    }

    fn dirty_views(&self) -> Vec<ViewId> {
        let last = self.state.images.last().map(|i| i.index);
        // A live image whose draft is on screen and which the next pulse replaces with another
        // view (a C-arm move waits for it) is not refined: a live drag shows drafts, as a drag
        // with the beam off does, and the view the C-arm comes to rest at gets its full frame.
        let replaced = self.state.live_since_ms.is_some()
            && self.state.pulse_pending
            && self.drafted == last
            && self.displayed_projection() != Some(self.projection());
        if last.is_some() && last != self.rendered && !replaced {
            vec![ViewId::FLUOROSCOPY]
        } else {
            Vec::new()
        }
    }

    fn render(&mut self, _view: ViewId, world: &World) -> Result<Option<ViewImage>, ModalityError> {
        let Some((image, _, iodine)) = self.displayed(world) else {
            return Ok(None);
        };
        // Only a live image is made obsolete by a C-arm move (the next pulse images the move);
        // a shot stays on screen whatever the C-arm does with the beam off, so its full frame
        // is finished (see `crate::interrupt`).
        let _unwatched = self
            .state
            .live_since_ms
            .is_none()
            .then(crate::interrupt::unwatched);
        let frame = self.render_raw(&image, iodine.as_deref(), world)?;
        let frame = self.temporal_chain(&image, frame, iodine, world)?;
        // Only now: a failed history render leaves the view dirty.
        self.rendered = Some(image.index);
        Ok(Some(frame))
    }

    fn render_draft(
        &mut self,
        _view: ViewId,
        world: &World,
        use_: DraftUse,
    ) -> Result<Option<ViewImage>, ModalityError> {
        let Some((image, settings, iodine)) = self.displayed(world) else {
            return Ok(None);
        };
        // One draft per image in a live session: the next frame of it is the full one.
        if use_ == DraftUse::Live && self.drafted == Some(image.index) {
            return Ok(None);
        }
        let draft = self
            .renderer(world)?
            .render_draft(
                image.needle.as_ref(),
                &image.projection,
                &settings,
                iodine.as_deref(),
                use_,
            )
            .map_err(render_failed)?;
        // Only a draft that was drawn is on screen (a region without a draft scene gets none).
        if use_ == DraftUse::Live && draft.is_some() {
            self.drafted = Some(image.index);
        }
        Ok(draft.map(Into::into))
    }

    fn prefetch(&mut self, world: &World) -> Result<(), ModalityError> {
        // The next shot's view (the C-arm as it stands, the steel as it lies, the technique as
        // set): before the first image, and once a moved C-arm has come to rest (a learner
        // positions, then shoots). Not while live: a pulse images each change at once.
        if !self.prefetch_pending() {
            return Ok(());
        }
        let (needle, projection) = (self.instruments(world), self.projection());
        let before = self.prefetched.replace(projection);
        let settings = self.render_settings(self.state.kvp, self.state.ma, None, &projection, 0);
        let done = self
            .renderer(world)?
            .prefetch(
                needle.as_ref(),
                &projection,
                &settings,
                world.iodine.as_deref(),
            )
            .map_err(render_failed);
        // A prefetch stopped by a C-arm move (see `crate::interrupt`) prepared nothing.
        if let Err(ModalityError::Interrupted { .. }) = done {
            self.prefetched = before;
        }
        done
    }

    /// The technique of the image on display and of the next pulse, as every fluoroscopy
    /// acknowledgement carries it.
    fn tick_status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({ "technique": self.technique_json() }))
    }

    fn measure(&self, world: &World, out: &mut Measurements) {
        let s = &self.state;
        out.insert(
            "fluoro_acquisitions_count".into(),
            f64::from(s.shots + s.live_runs),
        );
        out.insert(
            "fluoro_exposure_s".into(),
            self.exposure_ms_at(world.clock_ms) as f64 / 1000.0,
        );
        out.insert(
            "fluoro_time_s".into(),
            self.exposure_ms_at(world.clock_ms) as f64 / 1000.0,
        );
        let (kerma, kap) = self.dose_at(world);
        out.insert("air_kerma_mgy".into(), kerma);
        out.insert("kerma_area_product_gycm2".into(), kap);
        let region = &world.region;
        let side = primary_target(&world.station)
            .map(|t| target_side(region, t))
            .unwrap_or(-1.0);
        let beams: Vec<(f64, DVec3)> = s
            .images
            .iter()
            .map(|i| (i.projection.orbital_deg, beam_direction(&i.projection)))
            .collect();
        if let Some(n) = AP_ENDPLATES
            .iter()
            .find_map(|(upper, lower)| endplate_normal(region, upper, lower))
        {
            let best = beams
                .iter()
                .filter(|(orb, _)| orb.abs() <= AP_MAX_OBLIQUITY_DEG)
                .map(|(_, b)| angle_to_plane_deg(*b, n))
                .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.min(v))));
            if let Some(v) = best {
                out.insert("ap_endplate_tilt_deg".into(), v);
            }
        }
        // Lateral view: the smallest angle between an image's central ray and the patient's
        // left-right axis (0 in a true lateral).
        if let Some(v) = beams
            .iter()
            .map(|(_, b)| b.x.abs().min(1.0).acos().to_degrees())
            .reduce(f64::min)
        {
            out.insert("lateral_view_residual_deg".into(), v);
        }
        // Ipsilateral oblique: the beam line runs from posterior-ipsilateral to
        // anterior-contralateral, which in this C-arm's convention is orbital = side * angle
        // (see the module doc of `scoring`).
        if let Some((orb, _)) = beams
            .iter()
            .rev()
            .find(|(o, _)| side * o >= OBLIQUE_MIN_DEG)
        {
            out.insert("ipsilateral_oblique_deg".into(), side * orb);
        }
        if let Some((orb, _)) = beams
            .iter()
            .rev()
            .find(|(o, _)| -side * o >= OBLIQUE_MIN_DEG)
        {
            out.insert("clo_angle_deg".into(), -side * orb);
        }
        if let Some(t) = primary_target(&world.station) {
            if let Some(n) = facet_joint_normal(region, t) {
                let best = beams
                    .iter()
                    .map(|(_, b)| angle_to_plane_deg(*b, n))
                    .fold(None, |m: Option<f64>, v| Some(m.map_or(v, |m| m.min(v))));
                if let Some(v) = best {
                    out.insert("beam_to_joint_plane_deg".into(), v);
                }
            }
        }
        if let Some(e) = s
            .annotations
            .iter()
            .rev()
            .find_map(|a| annotation_error_mm(Some(a), self.state.receptor, world))
        {
            out.insert("annotation_error_mm".into(), e);
        }
    }

    fn record(&self) -> serde_json::Value {
        let s = &self.state;
        serde_json::json!({
            "backend": self.backend.profile(),
            "orbital_deg": s.orbital_deg,
            "angular_deg": s.angular_deg,
            "table_mm": s.table_mm,
            "isocentre_mm": s.isocentre_mm,
            "kvp": s.kvp,
            "ma": s.ma,
            "detector_pixels": s.config.detector_pixels,
            "detector_mm": s.config.detector_mm,
            "supersample": s.config.supersample,
            "noise": s.config.noise,
        })
    }

    fn state(&self) -> serde_json::Value {
        serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null)
    }

    fn restore(&mut self, state: serde_json::Value) -> Result<(), ModalityError> {
        self.state = serde_json::from_value(state).map_err(|e| ModalityError::State {
            modality: "fluoroscopy",
            message: e.to_string(),
        })?;
        self.rendered = None;
        self.drafted = None;
        self.prefetched = None;
        self.image_iodine = None;
        // Raw frames of another timeline would be served under the same image indices.
        self.raw_frames = temporal::RawFrames::default();
        Ok(())
    }
}

/// Unit vector of the central ray (source to detector).
pub fn beam_direction(p: &Projection) -> DVec3 {
    DVec3::from_array(p.frame().normal)
}

/// Error of an annotation whose label names a target or landmark: the distance from that point
/// to the ray through the marked pixel, mm (the miss measured at the point's own depth).
pub fn annotation_error_mm(
    a: Option<&Annotation>,
    receptor: Option<ReceptorKind>,
    world: &World,
) -> Option<f64> {
    let a = a?;
    let p = DVec3::from_array(world.station.point(&world.region, &a.label)?);
    let ray = a
        .projection
        .pixel_ray(undistorted(receptor, &a.projection, a.pixel));
    let o = DVec3::from_array(ray.origin_mm);
    let d = DVec3::from_array(ray.dir);
    let v = p - o;
    Some((v - d * v.dot(d)).length())
}

/// The ideal projection's pixel shown at `pixel` of an image taken with `projection` on
/// `receptor` (an image intensifier's pincushion undone), so that what a learner points at is
/// measured in patient space.
pub fn undistorted(
    receptor: Option<ReceptorKind>,
    projection: &Projection,
    pixel: [f64; 2],
) -> [f64; 2] {
    let [w, h] = projection.detector_pixels;
    receptor
        .and_then(|k| Distortion::of(k, w, h))
        .map_or(pixel, |d| d.undistort_px(pixel))
}
