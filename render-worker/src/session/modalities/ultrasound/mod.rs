//! The ultrasound modality: a probe from the tray on the skin, the scanner's controls, the
//! B-mode view (`sim_core::ultrasound`, or its GPU path), the placement view (the outside of
//! the body with the probe and the needle, where the probe is dragged) and the scorers of
//! ultrasound-guided needling ([`scorers`]).
//!
//! # Probe on the skin
//! Every pose a command asks for is put on the skin: the face centre moves along the central
//! beam line to where it meets the region's `skin` structure from outside, within
//! [`MAX_PROBE_SNAP_MM`]; a pose farther from the body, a beam that does not point into the skin
//! (more than [`MAX_BEAM_TO_NORMAL_DEG`] from the inward surface normal) or a face outside the
//! scannable crop (see [`medium`]) is refused naming the field. Slides keep the probe's angle
//! and follow the skin; drags on the placement view put the probe where the pixel shows skin,
//! with the beam along the inward normal there and the marker kept.
//!
//! # Frames
//! A frame depends on the probe, pose, settings, the needle shaft and the session's speckle seed
//! (fixed per session: the speckle belongs to the tissue). While frozen, the scene of the moment
//! of freezing is held in the state, so the held image survives a restore and its scorers read
//! what the learner saw. Only changes of the displayed scene make the B-mode view dirty; the
//! placement view is dirty when the probe or the needle moves.

pub mod backend;
pub mod medium;
pub mod placement;
mod scene;
pub mod scorers;

use std::sync::Arc;

use glam::DVec3;
use serde::{Deserialize, Serialize};
use sim_core::rubric::Measurements;
use sim_core::ultrasound::{
    NeedleView, ProbeKind, ProbePose, Sampling, ScanGeometry, ScanRequest, Settings,
    UltrasoundError,
};

pub use backend::{
    CpuUltrasoundBackend, GpuUltrasoundBackend, UltrasoundBackend, UltrasoundRenderError,
    UltrasoundRenderer,
};
pub use medium::AcousticVolume;
pub use scene::{ScanScene, needle_shaft, scene_needle_view};

use super::modality::{DraftUse, Modality, ModalityContext, ModalityError, ModalitySpec};
use crate::session::anatomy::primary_target;
use crate::session::command::{
    Command, CommandError, CommandSpec, Engagement, ErrorCode, MAX_PROBE_SNAP_MM,
};
use crate::session::image::{ViewId, ViewImage};
use crate::session::region::Region;
use crate::session::world::{World, WorldChange};

/// Largest angle between the beam and the skin's inward normal under the face, degrees.
/// Simulator choice: a face tilted further no longer couples to the skin.
pub const MAX_BEAM_TO_NORMAL_DEG: f64 = 60.0;
/// Tray instrument kind of an ultrasound probe.
pub const PROBE_KIND: &str = "ultrasound-probe";
/// Mixed into the session seed for the tissue's speckle field.
const SPECKLE_SEED_SALT: u64 = 0x756c_7472_6173_6f75;

/// Serializable ultrasound state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UltrasoundState {
    /// Tray id of the probe in hand.
    pub instrument: Option<String>,
    /// The array in use.
    pub probe: ProbeKind,
    /// The probe on the skin.
    pub pose: ProbePose,
    /// Scanner controls (`frozen` included).
    pub settings: Settings,
    /// The scene held on screen while frozen.
    pub frozen_scene: Option<ScanScene>,
    /// Seed of the tissue's speckle.
    pub seed: u64,
    /// Scan site (centre of the scannable crop), model frame, mm.
    pub site_mm: [f64; 3],
    /// Needle-use history for the scorers.
    pub history: scorers::History,
}

/// The ultrasound modality.
pub struct UltrasoundModality {
    state: UltrasoundState,
    backend: Arc<dyn UltrasoundBackend>,
    renderer: Option<Box<dyn UltrasoundRenderer>>,
    region: Arc<Region>,
    volume: Option<Arc<AcousticVolume>>,
    /// Bumped when the displayed B-mode scene may have changed / when the probe or needle moved.
    versions: [u64; 2],
    rendered: [Option<u64>; 2],
    /// The B-mode version last drafted in a live session (one draft per image).
    drafted: Option<u64>,
    /// The scene of the last full B-mode frame: an image of the same scene (freeze, unfreeze
    /// with nothing moved) gets no draft.
    full_scene: Option<ScanScene>,
}

impl std::fmt::Debug for UltrasoundModality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UltrasoundModality")
            .field("state", &self.state)
            .field("backend", &self.backend.describe())
            .finish()
    }
}

/// The array a tray probe is: the id's first word (`linear-probe`, `curvilinear-probe`).
pub fn probe_kind_of(instrument_id: &str) -> Option<ProbeKind> {
    if instrument_id.starts_with("curvilinear") {
        Some(ProbeKind::Curvilinear)
    } else if instrument_id.starts_with("linear") {
        Some(ProbeKind::Linear)
    } else {
        None
    }
}

/// Where the face of a probe aimed along `beam` through `position` meets the skin, with the
/// skin's outward normal there; `Err` names what is wrong.
pub fn snap_to_skin(
    region: &Region,
    position: DVec3,
    beam: DVec3,
) -> Result<(DVec3, DVec3), &'static str> {
    let skin = region
        .entry("skin")
        .ok_or("this region has no skin surface to scan on")?;
    let origin = position - beam * MAX_PROBE_SNAP_MM;
    let hit = region.scene.entries()[skin]
        .bvh
        .first_hit(
            origin.to_array(),
            beam.to_array(),
            0.0,
            2.0 * MAX_PROBE_SNAP_MM,
        )
        .ok_or("the probe is off the body: no skin within 40 mm along the beam")?;
    if !hit.hit.entering {
        return Err("the probe face is inside the body: put it on the skin");
    }
    let normal = DVec3::from_array(hit.normal);
    if beam.dot(-normal) < MAX_BEAM_TO_NORMAL_DEG.to_radians().cos() {
        return Err("the beam must point into the skin (within 60 degrees of its normal)");
    }
    Ok((DVec3::from_array(hit.point_mm), normal))
}

/// Where a beam along `beam` first meets the skin on its way to `point` from outside the body
/// (from [`START_SEARCH_MM`] away), if it does.
pub fn first_skin_along(region: &Region, point: DVec3, beam: DVec3) -> Option<DVec3> {
    let skin = region.entry("skin")?;
    let origin = point - beam * START_SEARCH_MM;
    let hit = region.scene.entries()[skin].bvh.first_hit(
        origin.to_array(),
        beam.to_array(),
        0.0,
        START_SEARCH_MM,
    )?;
    hit.hit.entering.then(|| DVec3::from_array(hit.point_mm))
}

/// How far outside a point the start pose's skin search begins, mm. Simulator choice: farther
/// than any target lies under the skin of the back.
pub const START_SEARCH_MM: f64 = 400.0;

/// The scan site of a station: its primary target, else the L4 body centre.
fn site_of(ctx: &ModalityContext<'_>) -> [f64; 3] {
    primary_target(ctx.station)
        .or_else(|| ctx.region.landmarks.get("L4_body_centre").copied())
        .unwrap_or([0.0; 3])
}

/// Builds the modality for a session.
pub fn build(ctx: &ModalityContext<'_>) -> Box<dyn Modality> {
    let site = site_of(ctx);
    let instrument = ctx
        .station
        .station
        .instruments
        .iter()
        .find(|i| i.kind == PROBE_KIND && probe_kind_of(&i.id).is_some())
        .map(|i| i.id.clone());
    let probe = instrument
        .as_deref()
        .and_then(probe_kind_of)
        .unwrap_or(ProbeKind::Curvilinear);
    // Start on the midline at the site's level in a transverse view, beam anterior (+y), the
    // marker towards the patient's right (+x): the learner finds the target from there.
    let beam = DVec3::Y;
    let position = first_skin_along(ctx.region, DVec3::new(0.0, site[1], site[2]), beam)
        .unwrap_or(DVec3::new(0.0, site[1] - 60.0, site[2]));
    let settings = Settings::default_for(&probe.spec());
    Box::new(UltrasoundModality {
        state: UltrasoundState {
            instrument,
            probe,
            pose: ProbePose {
                position_mm: position,
                beam_dir: beam,
                marker_dir: DVec3::X,
            },
            settings,
            frozen_scene: None,
            seed: ctx.config.seed ^ SPECKLE_SEED_SALT,
            site_mm: site,
            history: scorers::History::default(),
        },
        backend: ctx
            .renderers
            .get::<Arc<dyn UltrasoundBackend>>(SPEC.name)
            .cloned()
            .unwrap_or_else(|| Arc::new(CpuUltrasoundBackend)),
        renderer: None,
        region: Arc::clone(ctx.region),
        volume: None,
        versions: [0, 0],
        rendered: [None, None],
        drafted: None,
        full_scene: None,
    })
}

/// `scene` with its `frozen` flag cleared: the freeze button changes what is held, not the
/// image of the scene.
fn unfrozen(scene: ScanScene) -> ScanScene {
    ScanScene {
        settings: Settings {
            frozen: false,
            ..scene.settings
        },
        ..scene
    }
}

/// Maps a sim-core settings field to the command's.
fn settings_error(e: &UltrasoundError) -> CommandError {
    let field = match e {
        UltrasoundError::OutOfRange { field, .. }
        | UltrasoundError::NonFinite { field, .. }
        | UltrasoundError::Degenerate { field } => field.replace("settings.", "command."),
    };
    let code = match e {
        UltrasoundError::OutOfRange { .. } => ErrorCode::OutOfRange,
        UltrasoundError::NonFinite { .. } => ErrorCode::NotFinite,
        UltrasoundError::Degenerate { .. } => ErrorCode::Invalid,
    };
    CommandError::field(&field, code, e.to_string())
}

impl UltrasoundModality {
    /// The current state.
    pub fn ultrasound_state(&self) -> &UltrasoundState {
        &self.state
    }

    /// The scene on screen: the held one while frozen, else the live one.
    pub fn displayed_scene(&self, world: &World) -> ScanScene {
        self.state
            .frozen_scene
            .unwrap_or_else(|| self.live_scene(world))
    }

    /// The scene the probe sees now (what a frame would show unfrozen).
    pub fn live_scene(&self, world: &World) -> ScanScene {
        ScanScene {
            probe: self.state.probe,
            pose: self.state.pose,
            settings: self.state.settings,
            needle: needle_shaft(world),
        }
    }

    /// The B-mode image of the displayed scene: the full frame by the session's renderer, or
    /// (`draft`) the draft by the CPU reference.
    fn scan_displayed(&mut self, world: &World, draft: bool) -> Result<ViewImage, ModalityError> {
        let scene = self.displayed_scene(world);
        let volume = self.volume();

        let spec = scene.probe.spec();
        let sampling = Sampling::for_settings(&spec, &scene.settings);
        let req = ScanRequest {
            probe: scene.probe,
            pose: scene.pose,
            settings: scene.settings,
            sampling: if draft { sampling.draft() } else { sampling },
            medium: &volume.indexed,
            needle: scene.needle,
            targets: &[],
            seed: self.state.seed,
        };
        let frame = if draft {
            sim_core::ultrasound::scan(&req).map_err(UltrasoundRenderError::from)
        } else {
            let renderer = self.renderer.get_or_insert_with(|| self.backend.renderer());
            renderer.scan(&req, &volume)
        }
        .map_err(|e| match e {
            UltrasoundRenderError::Interrupted => ModalityError::Interrupted {
                modality: "ultrasound",
            },
            e => ModalityError::Render {
                modality: "ultrasound",
                message: e.to_string(),
            },
        })?;
        Ok(ViewImage {
            width: frame.width as u32,
            height: frame.height as u32,
            pixels: frame.pixels,
        })
    }

    /// The scan geometry and what the displayed image shows of the needle.
    pub fn displayed_needle_view(&self, world: &World) -> Option<NeedleView> {
        scene_needle_view(&self.displayed_scene(world))
    }

    fn volume(&mut self) -> Arc<AcousticVolume> {
        Arc::clone(
            self.volume
                .get_or_insert_with(|| medium::acoustic_volume(&self.region, self.state.site_mm)),
        )
    }

    /// Puts a requested pose on the skin and inside the scannable crop, or names the field.
    fn place(
        &mut self,
        position: DVec3,
        beam: DVec3,
        marker: DVec3,
        field: &str,
    ) -> Result<(), CommandError> {
        let invalid = |m: &str| CommandError::field(field, ErrorCode::Invalid, m.to_string());
        let beam = beam
            .try_normalize()
            .ok_or_else(|| invalid("zero beam direction"))?;
        let (face, _) = snap_to_skin(&self.region, position, beam).map_err(invalid)?;
        let (xs, zs) = medium::probe_area(self.state.site_mm);
        if !((xs[0]..=xs[1]).contains(&face.x) && (zs[0]..=zs[1]).contains(&face.z)) {
            return Err(invalid(&format!(
                "outside the scannable area of this station (x {:.0} to {:.0} mm, z {:.0} to {:.0} mm)",
                xs[0], xs[1], zs[0], zs[1]
            )));
        }
        let pose = ProbePose {
            position_mm: face,
            beam_dir: beam,
            marker_dir: marker,
        };
        pose.frame().map_err(|_| {
            CommandError::field(
                field,
                ErrorCode::Invalid,
                "the marker direction must not be along the beam",
            )
        })?;
        let frame = pose.frame().expect("checked above");
        self.state.pose = ProbePose {
            position_mm: face,
            beam_dir: frame.beam,
            marker_dir: -frame.lateral,
        };
        self.moved();
        Ok(())
    }

    /// The probe or its controls changed.
    fn moved(&mut self) {
        self.versions[1] += 1;
        if self.state.frozen_scene.is_none() {
            self.versions[0] += 1;
        }
    }

    /// What every acknowledgement of an ultrasound command carries: the probe, its pose and
    /// controls, and the image geometry the client draws its scales with.
    pub fn outcome(&self, world: &World) -> serde_json::Value {
        let scene = self.displayed_scene(world);
        let spec = scene.probe.spec();
        let sampling = Sampling::for_settings(&spec, &scene.settings);
        let image = scene.pose.frame().ok().map(|frame| {
            let geo = ScanGeometry {
                spec,
                frame,
                lines: sampling.lines,
                depth_mm: scene.settings.depth_mm,
            };
            let (x0, x1, y0, y1) = geo.image_extent_mm();
            let p = sampling.pixel_mm;
            serde_json::json!({
                "width": ((x1 - x0) / p).floor() as usize + 1,
                "height": ((y1 - y0) / p).floor() as usize + 1,
                "pixel_mm": p,
                "origin_mm": [x0, y0],
                "depth_mm": scene.settings.depth_mm,
                "focus_mm": scene.settings.focus_mm,
                "marker_side": "left",
            })
        });
        let view = self.displayed_needle_view(world);
        serde_json::json!({
            "instrument": self.state.instrument,
            "probe": self.state.probe,
            "band_mhz": [spec.band_mhz.0, spec.band_mhz.1],
            "depth_range_mm": [spec.depth_range_mm.0, spec.depth_range_mm.1],
            "position_mm": self.state.pose.position_mm.to_array(),
            "beam_dir": self.state.pose.beam_dir.to_array(),
            "marker_dir": self.state.pose.marker_dir.to_array(),
            "settings": self.state.settings,
            "frozen": self.state.frozen_scene.is_some(),
            "image": image,
            "needle_in_slice": view.is_some_and(|v| v.in_slice.is_some()),
            "tip_in_slice": view.is_some_and(|v| v.tip_in_slice),
        })
    }

    fn set_settings(&mut self, s: Settings) -> Result<(), CommandError> {
        s.validate(&self.state.probe.spec())
            .map_err(|e| settings_error(&e))?;
        self.state.settings = s;
        self.moved();
        Ok(())
    }
}

/// Rotates `v` about unit `axis` by `deg` (right-handed).
fn rotate(v: DVec3, axis: DVec3, deg: f64) -> DVec3 {
    glam::DQuat::from_axis_angle(axis, deg.to_radians()) * v
}

/// What the ultrasound modality offers: the B-mode image, the placement view, and the probe's
/// commands.
pub static SPEC: ModalitySpec = ModalitySpec {
    name: "ultrasound",
    label: "ultrasound",
    views: &[ViewId::ULTRASOUND, ViewId::PLACEMENT],
    commands: &[
        CommandSpec::new("probe_select", Some(Engagement::ViewChanged)).superseding(),
        CommandSpec::new("probe_pose", Some(Engagement::ViewChanged)).superseding(),
        CommandSpec::new("probe_move", Some(Engagement::ViewChanged)).superseding(),
        CommandSpec::new("probe_drag", Some(Engagement::ViewChanged)).superseding(),
        CommandSpec::new("probe_settings", Some(Engagement::ViewChanged)).superseding(),
        CommandSpec::new("probe_freeze", None),
    ],
    constants: &[],
};

impl Modality for UltrasoundModality {
    fn spec(&self) -> &'static ModalitySpec {
        &SPEC
    }

    fn apply(
        &mut self,
        command: &Command,
        world: &World,
    ) -> Result<serde_json::Value, CommandError> {
        let frame = self.state.pose.frame().expect("the state's pose is valid");
        match command {
            Command::ProbeSelect { instrument } => {
                let on_tray = world
                    .station
                    .station
                    .instruments
                    .iter()
                    .any(|i| &i.id == instrument && i.kind == PROBE_KIND);
                let kind = probe_kind_of(instrument)
                    .filter(|_| on_tray)
                    .ok_or_else(|| {
                        CommandError::field(
                            "command.instrument",
                            ErrorCode::InstrumentUnavailable,
                            format!(
                                "{instrument} is not an ultrasound probe on this station's tray"
                            ),
                        )
                    })?;
                if self.state.frozen_scene.is_some() {
                    return Err(CommandError::field(
                        "command.type",
                        ErrorCode::State,
                        "unfreeze before changing the probe",
                    ));
                }
                self.state.instrument = Some(instrument.clone());
                if kind != self.state.probe {
                    self.state.probe = kind;
                    self.state.settings = Settings::default_for(&kind.spec());
                }
                self.moved();
            }
            Command::ProbePose {
                position_mm,
                beam_dir,
                marker_dir,
            } => {
                self.place(
                    DVec3::from_array(*position_mm),
                    DVec3::from_array(*beam_dir),
                    DVec3::from_array(*marker_dir),
                    "command.position_mm",
                )?;
            }
            Command::ProbeMove {
                slide_mm,
                tilt_deg,
                rotate_deg,
            } => {
                let marker = -frame.lateral;
                let position = frame.origin + marker * slide_mm[0] + frame.elevation * slide_mm[1];
                // Rock about the elevation axis (towards the marker), tilt about the marker axis.
                let mut beam = rotate(frame.beam, frame.elevation, tilt_deg[0]);
                let mut m = rotate(marker, frame.elevation, tilt_deg[0]);
                beam = rotate(beam, m, tilt_deg[1]);
                m = rotate(m, beam, *rotate_deg);
                let field = if slide_mm.iter().any(|v| *v != 0.0) {
                    "command.slide_mm"
                } else {
                    "command.tilt_deg"
                };
                self.place(position, beam, m, field)?;
            }
            Command::ProbeDrag { pixel } => {
                let cam = placement::Camera::for_site(&self.region, self.state.site_mm);
                let (p, n) =
                    placement::skin_at_pixel(&self.region, &cam, *pixel).ok_or_else(|| {
                        CommandError::field(
                            "command.pixel",
                            ErrorCode::Invalid,
                            "no skin under this pixel of the placement view",
                        )
                    })?;
                let beam = -n;
                let marker = -frame.lateral;
                let m = marker - beam * marker.dot(beam);
                let m = if m.length() > 1e-3 {
                    m
                } else {
                    frame.elevation
                };
                self.place(p - beam, beam, m, "command.pixel")?;
            }
            Command::ProbeSettings {
                depth_mm,
                gain_db,
                tgc_db,
                focus_mm,
                frequency_mhz,
                dynamic_range_db,
            } => {
                let mut s = self.state.settings;
                if let Some(d) = depth_mm {
                    // Keep the focus inside a shallower image.
                    s.focus_mm = s.focus_mm.min(*d);
                    s.depth_mm = *d;
                }
                s.gain_db = gain_db.unwrap_or(s.gain_db);
                s.tgc_db = tgc_db.unwrap_or(s.tgc_db);
                s.focus_mm = focus_mm.unwrap_or(s.focus_mm);
                s.frequency_mhz = frequency_mhz.unwrap_or(s.frequency_mhz);
                s.dynamic_range_db = dynamic_range_db.unwrap_or(s.dynamic_range_db);
                if s != self.state.settings {
                    if self.state.frozen_scene.is_some() {
                        return Err(CommandError::field(
                            "command.type",
                            ErrorCode::State,
                            "unfreeze before changing the scanner's controls",
                        ));
                    }
                    self.set_settings(s)?;
                }
            }
            Command::ProbeFreeze { on } => {
                if *on != self.state.frozen_scene.is_some() {
                    let mut s = self.state.settings;
                    s.frozen = *on;
                    self.state.settings = s;
                    self.state.frozen_scene = None;
                    if *on {
                        self.state.frozen_scene = Some(self.live_scene(world));
                    }
                    self.versions[0] += 1;
                }
            }
            other => {
                return Err(CommandError::field(
                    "command.type",
                    ErrorCode::ModalityUnavailable,
                    format!("ultrasound does not handle {}", other.name()),
                ));
            }
        }
        Ok(self.outcome(world))
    }

    fn world_changed(&mut self, change: &WorldChange, world: &World) {
        if *change == WorldChange::CArm {
            self.versions[1] += 1;
            return;
        }
        if *change != WorldChange::Needle {
            return;
        }
        self.versions[1] += 1;
        if self.state.frozen_scene.is_none() {
            self.versions[0] += 1;
        }
        let view = scene_needle_view(&self.live_scene(world));
        let depth = world.needle.as_ref().map_or(0.0, |n| n.state.buried_mm());
        self.state.history.needle_moved(depth, view);
    }

    fn needle_feedback(&self, world: &World) -> Option<serde_json::Value> {
        let view = self.displayed_needle_view(world);
        Some(serde_json::json!({
            "needle_in_slice": view.is_some_and(|v| v.in_slice.is_some()),
            "tip_in_slice": view.is_some_and(|v| v.tip_in_slice),
            "frozen": self.state.frozen_scene.is_some(),
        }))
    }

    /// Before the first input: the acoustic volume of the station's scan site is painted (about
    /// half a second for the 4 mm phantom, once per process and site), so the first B-mode
    /// frame costs only its scan. It is a pure function of the region and the site: nothing a
    /// client or a replay sees changes.
    fn prefetch(&mut self, _world: &World) -> Result<(), ModalityError> {
        self.volume();
        Ok(())
    }

    fn dirty_views(&self) -> Vec<ViewId> {
        [ViewId::ULTRASOUND, ViewId::PLACEMENT]
            .into_iter()
            .zip(self.versions.iter().zip(&self.rendered))
            .filter(|(_, (v, r))| **r != Some(**v))
            .map(|(view, _)| view)
            .collect()
    }

    fn render(&mut self, view: ViewId, world: &World) -> Result<Option<ViewImage>, ModalityError> {
        match view {
            ViewId::ULTRASOUND => {
                let frame = self.scan_displayed(world, false)?;
                self.full_scene = Some(self.displayed_scene(world));
                self.rendered[0] = Some(self.versions[0]);
                Ok(Some(frame))
            }
            ViewId::PLACEMENT => {
                let cam = placement::Camera::for_site(&self.region, self.state.site_mm);
                let image = placement::render(
                    &self.region,
                    &cam,
                    &self.state.pose,
                    self.state.probe,
                    world,
                );
                self.rendered[1] = Some(self.versions[1]);
                Ok(Some(image))
            }
            _ => Ok(None),
        }
    }

    /// The B-mode image drafted with [`Sampling::draft`] by the CPU reference (the same
    /// image on every machine, so a replay renders the draft that was shown). Live, only where
    /// the backend's full frame is slow ([`UltrasoundBackend::drafts`]) and once per image; the
    /// placement view has none, and neither has an image of the scene on screen (freezing).
    fn render_draft(
        &mut self,
        view: ViewId,
        world: &World,
        use_: DraftUse,
    ) -> Result<Option<ViewImage>, ModalityError> {
        if view != ViewId::ULTRASOUND {
            return Ok(None);
        }
        if use_ == DraftUse::Live
            && (!self.backend.drafts()
                || self.drafted == Some(self.versions[0])
                || self.full_scene.map(unfrozen) == Some(unfrozen(self.displayed_scene(world))))
        {
            return Ok(None);
        }
        let frame = self.scan_displayed(world, true)?;
        if use_ == DraftUse::Live {
            self.drafted = Some(self.versions[0]);
        }
        Ok(Some(frame))
    }

    fn measure(&self, world: &World, out: &mut Measurements) {
        scorers::measure(
            &self.state.pose,
            &self.state.history,
            &self.displayed_scene(world),
            world,
            out,
        );
    }

    fn record(&self) -> serde_json::Value {
        serde_json::json!({
            "instrument": self.state.instrument,
            "probe": self.state.probe,
            "pose": self.state.pose,
            "settings": self.state.settings,
            "renderer": self.backend.describe(),
        })
    }

    fn state(&self) -> serde_json::Value {
        serde_json::to_value(&self.state).unwrap_or(serde_json::Value::Null)
    }

    fn restore(&mut self, state: serde_json::Value) -> Result<(), ModalityError> {
        let s: UltrasoundState =
            serde_json::from_value(state).map_err(|e| ModalityError::State {
                modality: "ultrasound",
                message: e.to_string(),
            })?;
        s.pose.frame().map_err(|e| ModalityError::State {
            modality: "ultrasound",
            message: e.to_string(),
        })?;
        s.settings
            .validate(&s.probe.spec())
            .map_err(|e| ModalityError::State {
                modality: "ultrasound",
                message: e.to_string(),
            })?;
        self.state = s;
        self.versions = [self.versions[0] + 1, self.versions[1] + 1];
        Ok(())
    }
}
