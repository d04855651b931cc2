//! Typed session commands, their validation, and the ordered log of accepted commands.
//!
//! A command arrives in an [`Envelope`] with a client sequence number. Validation happens once,
//! here, before anything touches the state: every rejection is a [`CommandError`] naming the
//! offending field (`command.orbital_deg`, `seq`, ...), never a panic. Accepted commands are
//! appended to the session's log as [`LogEntry`]s stamped with the simulation clock, which is
//! all that replay needs.

use serde::{Deserialize, Serialize};
use sim_core::needle::NeedleCommand;

mod extension;
mod spec;

pub use extension::{BUILTIN_KINDS, ModalityCommand};
pub use spec::{CORE_COMMANDS, CommandSpec, Engagement, engagement_of, is_snake_case};

/// Largest |orbital| rotation, degrees. Simulator choice: beyond both true laterals (90) with
/// margin; mobile C-arms reach about +-95 to +-135 depending on the model.
pub const MAX_ORBITAL_DEG: f64 = 135.0;
/// Largest |angular| (cranio-caudal) rotation, degrees. Simulator choice: mobile C-arms tilt
/// about +-40 to +-45; steeper than that the tube hits the table.
pub const MAX_ANGULAR_DEG: f64 = 45.0;
/// Largest table translation on each axis, mm. Simulator choice: a lumbar procedure moves the
/// table by centimetres; 300 mm bounds a typo without restricting real use.
pub const MAX_TABLE_MM: f64 = 300.0;
/// Tube current range, mA. Simulator choice: continuous fluoroscopy on mobile C-arms runs at
/// about 0.5 to 10 mA, pulsed up to about 20 mA.
pub const MA_RANGE: (f64, f64) = (0.1, 20.0);
/// Largest single needle feed or withdrawal, mm. Simulator choice: a hand movement; longer moves
/// are several commands (and the whole needle is 89 to 150 mm long).
pub const MAX_NEEDLE_STEP_MM: f64 = 50.0;
/// Largest single hub roll, degrees (two turns). Simulator choice.
pub const MAX_ROLL_DEG: f64 = 720.0;
/// Largest volume of one injection, ml. Simulator choice: diagnostic contrast and therapeutic
/// injections at the lumbar spine are 0.5 to 10 ml; 20 ml rejects absurd values (a typo of
/// 200 ml) while leaving room for a large epidural volume.
pub const MAX_INJECTION_ML: f64 = 20.0;
/// Largest injection rate, ml/s. Simulator choice: hand injection through a spinal needle is
/// well below 1 ml/s; 2 ml/s bounds it.
pub const MAX_INJECTION_RATE_ML_PER_S: f64 = 2.0;
/// Farthest the probe face may be put from the skin along its beam line, mm (it is then moved
/// onto the skin). Simulator choice: a drag ends within a few millimetres of the surface; 40 mm
/// off the body is a probe in the air, refused.
pub const MAX_PROBE_SNAP_MM: f64 = 40.0;
/// Largest single probe slide, mm. Simulator choice: a hand movement (keyboard steps are 1 to
/// 5 mm); a drag on the placement view moves farther in one command.
pub const MAX_PROBE_SLIDE_MM: f64 = 100.0;
/// Largest single probe tilt, degrees. Simulator choice: beyond 60 degrees the face no longer
/// sits on the skin.
pub const MAX_PROBE_TILT_DEG: f64 = 60.0;
/// Largest hub tilt per command on each axis, degrees. Simulator choice: a hand correction is a
/// few degrees; the total deviation is bounded by `sim_core::needle::hub::MAX_HUB_DEVIATION_DEG`.
pub const MAX_TILT_DEG: f64 = 20.0;
/// Largest single plunger step, ml. Simulator choice: loss-of-resistance checks press 0.1 to
/// 0.5 ml at a time; 2 ml bounds a typo.
pub const MAX_PLUNGER_STEP_ML: f64 = 2.0;
/// Longest annotation label, characters.
pub const MAX_LABEL_CHARS: usize = 64;
/// Longest instrument id, characters. Simulator choice: tray ids are short slugs
/// (`spinal-22g`); the bound keeps every string a command logs small.
pub const MAX_INSTRUMENT_CHARS: usize = 64;

/// What an operator can do at a station. JSON form: `{"type": "carm_pose", "orbital_deg": 20,
/// ...}`.
///
/// Commands of a modality this crate does not define travel as [`Command::Modality`] with the
/// same JSON shape (`{"type": "<kind the modality declares>", ...}`); see [`ModalityCommand`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(
    remote = "Self",
    tag = "type",
    rename_all = "snake_case",
    deny_unknown_fields
)]
pub enum Command {
    /// Move the C-arm (absolute pose).
    CarmPose {
        /// Orbital rotation, degrees: positive LAO, negative RAO (see `sim_core::fluoro::geometry`).
        orbital_deg: f64,
        /// Angular rotation, degrees: positive cranial, negative caudal.
        angular_deg: f64,
        /// Table translation in model axes, mm.
        #[serde(default)]
        table_mm: [f64; 3],
    },
    /// Tube voltage and current.
    Technique {
        /// Tube voltage, kVp (a committed spectrum: 40 to 120 in steps of 5).
        kvp: u32,
        /// Tube current, mA.
        ma: f64,
    },
    /// One fluoroscopic acquisition (a single exposure).
    Shot,
    /// Start or stop live (continuous) fluoroscopy.
    Live {
        /// True starts, false stops.
        on: bool,
    },
    /// Put a needle from the tray at a skin entry point (only while no needle is in tissue).
    NeedlePlace {
        /// Instrument id from the station's tray.
        instrument: String,
        /// Skin entry point, model frame, mm.
        entry_mm: [f64; 3],
        /// Direction of insertion (need not be unit length).
        direction: [f64; 3],
        /// Where the bevel faces (projected onto the plane normal to `direction`).
        bevel_reference: [f64; 3],
    },
    /// Advance the needle, mm of hub travel.
    NeedleFeed {
        /// Hub travel, mm.
        mm: f64,
    },
    /// Roll the needle hub, degrees.
    NeedleRoll {
        /// Hub rotation, degrees.
        deg: f64,
    },
    /// Pull the needle back along its tract, mm.
    NeedleWithdraw {
        /// Hub travel, mm.
        mm: f64,
    },
    /// Put the radio-opaque skin marker (a clamp tip) on the skin: where the ray through `pixel`
    /// of the displayed fluoroscopy image meets the skin on the X-ray source's side, or where the
    /// C-arm's central beam line through `position_mm` does. Exactly one of the two.
    SkinMarker {
        /// Continuous pixel coordinates `[x, y]` on the displayed fluoroscopy image.
        #[serde(default)]
        pixel: Option<[f64; 2]>,
        /// A point near the skin, model frame, mm (snapped along the beam within
        /// [`MAX_PROBE_SNAP_MM`]).
        #[serde(default)]
        position_mm: Option<[f64; 3]>,
    },
    /// Puncture the skin at the marker with a needle from the tray (only while no needle is in
    /// tissue). The marker is taken away.
    NeedlePuncture {
        /// Instrument id from the station's tray.
        instrument: String,
        /// Direction of insertion (default: down the C-arm's central beam).
        #[serde(default)]
        direction: Option<[f64; 3]>,
        /// Where the bevel faces (default: cranial).
        #[serde(default)]
        bevel_reference: Option<[f64; 3]>,
    },
    /// Tilt the needle hub, degrees (both default to 0): `cc_deg` > 0 aims the needle more
    /// cranially (the hub moves caudally), `ml_deg` > 0 aims it towards the patient's left.
    NeedleTilt {
        /// Cranio-caudal aim change, degrees.
        #[serde(default)]
        cc_deg: f64,
        /// Medio-lateral aim change towards the patient's left, degrees.
        #[serde(default)]
        ml_deg: f64,
    },
    /// Attach or detach the loss-of-resistance syringe.
    Syringe {
        /// What to do.
        action: SyringeAction,
        /// What the syringe holds (attach only; default saline).
        #[serde(default)]
        medium: Option<sim_core::needle::LorMedium>,
    },
    /// Press the loss-of-resistance plunger by a step, ml.
    Plunger {
        /// Plunger travel as volume, ml.
        ml: f64,
    },
    /// Hold constant pressure on the loss-of-resistance plunger while advancing (or release).
    PlungerHold {
        /// True holds.
        on: bool,
    },
    /// Draw back on the syringe to see what comes back through the needle.
    Aspirate,
    /// Mark a point on the current fluoroscopy image.
    Annotate {
        /// Continuous pixel coordinates `[x, y]` on the detector (top-left corner is `[0, 0]`).
        pixel: [f64; 2],
        /// What the mark names (a station target or an anatomical landmark).
        label: String,
    },
    /// Pick up an ultrasound probe from the tray (needs an ultrasound station).
    ProbeSelect {
        /// Instrument id of an `ultrasound-probe` on the station's tray (`linear-probe`,
        /// `curvilinear-probe`: the id's first word names the array).
        instrument: String,
    },
    /// Put the probe on the skin (absolute pose, needs an ultrasound station). The face is
    /// placed where the central beam line through `position_mm` meets the skin, within
    /// [`MAX_PROBE_SNAP_MM`]; farther from the body it is refused.
    ProbePose {
        /// Probe face centre, model frame, mm.
        position_mm: [f64; 3],
        /// Direction of the central scan line into the body (need not be unit length).
        beam_dir: [f64; 3],
        /// Direction of the orientation marker (the image's left edge); its component along
        /// the beam is removed.
        marker_dir: [f64; 3],
    },
    /// Move the probe relative to its pose (keyboard and touch controls): slide on the skin,
    /// tilt, rotate. Every field defaults to 0.
    ProbeMove {
        /// Slide along the marker direction and across the scan plane (elevation), mm; the face
        /// follows the skin.
        #[serde(default)]
        slide_mm: [f64; 2],
        /// Rock (heel-toe: about the elevation axis, the beam turning towards the marker for
        /// positive values, in the scan plane) and tilt (fanning: about the marker axis, the
        /// slice sweeping towards +elevation for positive values), degrees.
        #[serde(default)]
        tilt_deg: [f64; 2],
        /// Rotation about the beam, degrees (right-handed).
        #[serde(default)]
        rotate_deg: f64,
    },
    /// Put the probe where a pixel of the placement view shows skin, keeping its rotation
    /// (dragging the probe on the external view).
    ProbeDrag {
        /// Continuous pixel coordinates `[x, y]` on the placement view (top-left is `[0, 0]`).
        pixel: [f64; 2],
    },
    /// Scanner controls (needs an ultrasound station). Absent fields keep their value.
    ProbeSettings {
        /// Display depth, mm (within the probe's range).
        #[serde(default)]
        depth_mm: Option<f64>,
        /// Overall gain, dB.
        #[serde(default)]
        gain_db: Option<f64>,
        /// Time-gain compensation per depth band, dB (shallow first).
        #[serde(default)]
        tgc_db: Option<[f64; sim_core::ultrasound::TGC_BANDS]>,
        /// Transmit focus depth, mm.
        #[serde(default)]
        focus_mm: Option<f64>,
        /// Centre frequency, MHz (within the probe's band).
        #[serde(default)]
        frequency_mhz: Option<f64>,
        /// Displayed dynamic range, dB.
        #[serde(default)]
        dynamic_range_db: Option<f64>,
    },
    /// Freeze or unfreeze the ultrasound image.
    ProbeFreeze {
        /// True freezes.
        on: bool,
    },
    /// Inject through the needle (needs contrast transport at the station).
    Inject {
        /// What is injected.
        agent: Agent,
        /// Volume, ml.
        volume_ml: f64,
        /// Rate, ml/s.
        rate_ml_per_s: f64,
    },
    /// Stop the injection under way (the plunger released); what was delivered stays.
    InjectStop,
    /// Let simulated time pass: the clock moves to the moment the command is applied and
    /// nothing else changes, so a modality that evolves over time (contrast spreading) steps to
    /// it. Logged like every command, so replay steps the same way.
    Tick,
    /// End the attempt and score it.
    Submit,
    /// A command of a modality registered with the
    /// [`ModalityFactory`](crate::session::modalities::ModalityFactory) whose kind is not one
    /// of the built-in kinds above; the modality that declares the kind validates its fields.
    #[serde(skip)]
    Modality(ModalityCommand),
}

/// What to do with the loss-of-resistance syringe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SyringeAction {
    /// Put it on the needle hub.
    Attach,
    /// Take it off.
    Detach,
}

/// An injectable agent. JSON: `"contrast"`, `"saline"`, `"local_anaesthetic"` or
/// `{"diluted_contrast": {"stock_percent": 50}}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Agent {
    /// Iodinated contrast, undiluted stock.
    Contrast,
    /// Normal saline.
    Saline,
    /// Local anaesthetic (no iodine; the same hydraulics as saline).
    LocalAnaesthetic,
    /// Contrast diluted with saline to a percentage of stock (1 to 100).
    DilutedContrast {
        /// Iodine concentration as a percentage of stock.
        stock_percent: u8,
    },
}

impl Agent {
    /// Iodine per unit volume as a fraction of stock contrast.
    pub fn stock_fraction(self) -> f64 {
        match self {
            Agent::Contrast => 1.0,
            Agent::Saline | Agent::LocalAnaesthetic => 0.0,
            Agent::DilutedContrast { stock_percent } => f64::from(stock_percent) / 100.0,
        }
    }
}

/// Which part of the session handles a command: the session core (needle and hands, submit and
/// tick) or a modality. Which modality is data: the command kinds each modality declares in its
/// [`ModalitySpec`](crate::session::modalities::ModalitySpec).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CommandClass {
    /// The needle and the learner's hands (an instrument, shared by every modality).
    Needle,
    /// Submit and tick.
    Session,
    /// A modality's command, routed by its kind.
    Modality,
}

impl Command {
    /// The part of the session that handles this command.
    pub fn class(&self) -> CommandClass {
        match self {
            Command::NeedlePlace { .. }
            | Command::NeedleFeed { .. }
            | Command::NeedleRoll { .. }
            | Command::NeedleWithdraw { .. }
            | Command::SkinMarker { .. }
            | Command::NeedlePuncture { .. }
            | Command::NeedleTilt { .. }
            | Command::Syringe { .. }
            | Command::Plunger { .. }
            | Command::PlungerHold { .. }
            | Command::Aspirate => CommandClass::Needle,
            Command::Tick | Command::Submit => CommandClass::Session,
            _ => CommandClass::Modality,
        }
    }

    /// The snake_case name used in JSON (`"carm_pose"`, ...).
    pub fn name(&self) -> &str {
        match self {
            Command::Modality(c) => c.kind(),
            Command::CarmPose { .. } => "carm_pose",
            Command::Technique { .. } => "technique",
            Command::Shot => "shot",
            Command::Live { .. } => "live",
            Command::NeedlePlace { .. } => "needle_place",
            Command::NeedleFeed { .. } => "needle_feed",
            Command::NeedleRoll { .. } => "needle_roll",
            Command::NeedleWithdraw { .. } => "needle_withdraw",
            Command::SkinMarker { .. } => "skin_marker",
            Command::NeedlePuncture { .. } => "needle_puncture",
            Command::NeedleTilt { .. } => "needle_tilt",
            Command::Syringe { .. } => "syringe",
            Command::Plunger { .. } => "plunger",
            Command::PlungerHold { .. } => "plunger_hold",
            Command::Aspirate => "aspirate",
            Command::Annotate { .. } => "annotate",
            Command::ProbeSelect { .. } => "probe_select",
            Command::ProbePose { .. } => "probe_pose",
            Command::ProbeMove { .. } => "probe_move",
            Command::ProbeDrag { .. } => "probe_drag",
            Command::ProbeSettings { .. } => "probe_settings",
            Command::ProbeFreeze { .. } => "probe_freeze",
            Command::Inject { .. } => "inject",
            Command::InjectStop => "inject_stop",
            Command::Tick => "tick",
            Command::Submit => "submit",
        }
    }

    /// The needle command, for the three needle motions.
    pub fn needle_command(&self) -> Option<NeedleCommand> {
        match *self {
            Command::NeedleFeed { mm } => Some(NeedleCommand::Feed { mm }),
            Command::NeedleRoll { deg } => Some(NeedleCommand::Roll { deg }),
            Command::NeedleWithdraw { mm } => Some(NeedleCommand::Withdraw { mm }),
            _ => None,
        }
    }

    /// Checks every field's value (finite, in range). Station-dependent checks (is the modality
    /// there, is the instrument on the tray) happen in the session.
    pub fn validate(&self) -> Result<(), CommandError> {
        match self {
            Command::CarmPose {
                orbital_deg,
                angular_deg,
                table_mm,
            } => {
                range(
                    "command.orbital_deg",
                    *orbital_deg,
                    -MAX_ORBITAL_DEG,
                    MAX_ORBITAL_DEG,
                )?;
                range(
                    "command.angular_deg",
                    *angular_deg,
                    -MAX_ANGULAR_DEG,
                    MAX_ANGULAR_DEG,
                )?;
                for (a, v) in table_mm.iter().enumerate() {
                    range(
                        &format!("command.table_mm[{a}]"),
                        *v,
                        -MAX_TABLE_MM,
                        MAX_TABLE_MM,
                    )?;
                }
                Ok(())
            }
            Command::Technique { kvp, ma } => {
                if !sim_core::fluoro::Spectrum::available_kvp().contains(kvp) {
                    return Err(CommandError::field(
                        "command.kvp",
                        ErrorCode::OutOfRange,
                        format!("{kvp} kVp has no spectrum (40 to 120 kVp in steps of 5)"),
                    ));
                }
                range("command.ma", *ma, MA_RANGE.0, MA_RANGE.1)
            }
            Command::Modality(c) => c.validate(),
            Command::Shot
            | Command::Live { .. }
            | Command::Tick
            | Command::Submit
            | Command::InjectStop
            | Command::PlungerHold { .. }
            | Command::Aspirate => Ok(()),
            Command::SkinMarker { pixel, position_mm } => match (pixel, position_mm) {
                (Some(px), None) => {
                    for (a, v) in px.iter().enumerate() {
                        finite(&format!("command.pixel[{a}]"), *v)?;
                    }
                    Ok(())
                }
                (None, Some(p)) => {
                    for (a, v) in p.iter().enumerate() {
                        range(&format!("command.position_mm[{a}]"), *v, -1000.0, 1000.0)?;
                    }
                    Ok(())
                }
                _ => Err(CommandError::field(
                    "command.pixel",
                    ErrorCode::Invalid,
                    "give exactly one of pixel and position_mm",
                )),
            },
            Command::NeedlePuncture {
                instrument,
                direction,
                bevel_reference,
            } => {
                instrument_id("command.instrument", instrument)?;
                if let Some(d) = direction {
                    unit_vector("command.direction", *d)?;
                }
                if let Some(b) = bevel_reference {
                    unit_vector("command.bevel_reference", *b)?;
                }
                Ok(())
            }
            Command::NeedleTilt { cc_deg, ml_deg } => {
                range("command.cc_deg", *cc_deg, -MAX_TILT_DEG, MAX_TILT_DEG)?;
                range("command.ml_deg", *ml_deg, -MAX_TILT_DEG, MAX_TILT_DEG)
            }
            Command::Syringe { action, medium } => {
                if *action == SyringeAction::Detach && medium.is_some() {
                    return Err(CommandError::field(
                        "command.medium",
                        ErrorCode::Invalid,
                        "a medium is given only when attaching",
                    ));
                }
                Ok(())
            }
            Command::Plunger { ml } => {
                range("command.ml", *ml, 0.0, MAX_PLUNGER_STEP_ML)?;
                if *ml == 0.0 {
                    return Err(CommandError::field(
                        "command.ml",
                        ErrorCode::OutOfRange,
                        "a plunger step moves more than 0 ml",
                    ));
                }
                Ok(())
            }
            Command::NeedlePlace {
                instrument,
                entry_mm,
                direction,
                bevel_reference,
            } => {
                instrument_id("command.instrument", instrument)?;
                for (a, v) in entry_mm.iter().enumerate() {
                    range(&format!("command.entry_mm[{a}]"), *v, -1000.0, 1000.0)?;
                }
                unit_vector("command.direction", *direction)?;
                unit_vector("command.bevel_reference", *bevel_reference)?;
                Ok(())
            }
            Command::NeedleFeed { mm } => range("command.mm", *mm, 0.0, MAX_NEEDLE_STEP_MM),
            Command::NeedleWithdraw { mm } => range("command.mm", *mm, 0.0, MAX_NEEDLE_STEP_MM),
            Command::NeedleRoll { deg } => range("command.deg", *deg, -MAX_ROLL_DEG, MAX_ROLL_DEG),
            Command::Annotate { pixel, label } => {
                for (a, v) in pixel.iter().enumerate() {
                    finite(&format!("command.pixel[{a}]"), *v)?;
                }
                no_nul("command.label", label)?;
                if label.trim().is_empty() || label.chars().count() > MAX_LABEL_CHARS {
                    return Err(CommandError::field(
                        "command.label",
                        ErrorCode::Invalid,
                        format!("label must be 1 to {MAX_LABEL_CHARS} characters"),
                    ));
                }
                Ok(())
            }
            Command::ProbeSelect { instrument } => {
                instrument_id("command.instrument", instrument)?;
                Ok(())
            }
            Command::ProbePose {
                position_mm,
                beam_dir,
                marker_dir,
            } => {
                for (a, v) in position_mm.iter().enumerate() {
                    range(&format!("command.position_mm[{a}]"), *v, -1000.0, 1000.0)?;
                }
                unit_vector("command.beam_dir", *beam_dir)?;
                unit_vector("command.marker_dir", *marker_dir)
            }
            Command::ProbeMove {
                slide_mm,
                tilt_deg,
                rotate_deg,
            } => {
                for (a, v) in slide_mm.iter().enumerate() {
                    range(
                        &format!("command.slide_mm[{a}]"),
                        *v,
                        -MAX_PROBE_SLIDE_MM,
                        MAX_PROBE_SLIDE_MM,
                    )?;
                }
                for (a, v) in tilt_deg.iter().enumerate() {
                    range(
                        &format!("command.tilt_deg[{a}]"),
                        *v,
                        -MAX_PROBE_TILT_DEG,
                        MAX_PROBE_TILT_DEG,
                    )?;
                }
                range("command.rotate_deg", *rotate_deg, -360.0, 360.0)
            }
            Command::ProbeDrag { pixel } => {
                for (a, v) in pixel.iter().enumerate() {
                    range(&format!("command.pixel[{a}]"), *v, -1.0e4, 1.0e4)?;
                }
                Ok(())
            }
            Command::ProbeSettings {
                depth_mm,
                gain_db,
                tgc_db,
                focus_mm,
                frequency_mhz,
                dynamic_range_db,
            } => {
                // Probe-independent bounds here (the probe's own ranges are checked by the
                // modality against the probe in use): sim_core::ultrasound::Settings::validate.
                let opt = |f: &str, v: Option<f64>, lo: f64, hi: f64| match v {
                    Some(v) => range(f, v, lo, hi),
                    None => Ok(()),
                };
                opt("command.depth_mm", *depth_mm, 10.0, 240.0)?;
                opt("command.gain_db", *gain_db, -30.0, 60.0)?;
                if let Some(t) = tgc_db {
                    for (i, v) in t.iter().enumerate() {
                        range(&format!("command.tgc_db[{i}]"), *v, -30.0, 30.0)?;
                    }
                }
                opt("command.focus_mm", *focus_mm, 5.0, 240.0)?;
                opt("command.frequency_mhz", *frequency_mhz, 2.0, 12.0)?;
                opt("command.dynamic_range_db", *dynamic_range_db, 20.0, 100.0)
            }
            Command::ProbeFreeze { .. } => Ok(()),
            Command::Inject {
                agent,
                volume_ml,
                rate_ml_per_s,
            } => {
                if let Agent::DilutedContrast { stock_percent } = agent {
                    if !(1..=100).contains(stock_percent) {
                        return Err(CommandError::field(
                            "command.agent.stock_percent",
                            ErrorCode::OutOfRange,
                            format!("{stock_percent} must be 1 to 100 (% of stock)"),
                        ));
                    }
                }
                positive_at_most("command.volume_ml", *volume_ml, MAX_INJECTION_ML)?;
                positive_at_most(
                    "command.rate_ml_per_s",
                    *rate_ml_per_s,
                    MAX_INJECTION_RATE_ML_PER_S,
                )
            }
        }
    }
}

fn finite(field: &str, v: f64) -> Result<(), CommandError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(CommandError::field(
            field,
            ErrorCode::NotFinite,
            format!("{v} is not a finite number"),
        ))
    }
}

fn range(field: &str, v: f64, lo: f64, hi: f64) -> Result<(), CommandError> {
    finite(field, v)?;
    if v < lo || v > hi {
        return Err(CommandError::field(
            field,
            ErrorCode::OutOfRange,
            format!("{v} is outside [{lo}, {hi}]"),
        ));
    }
    Ok(())
}

fn positive_at_most(field: &str, v: f64, hi: f64) -> Result<(), CommandError> {
    finite(field, v)?;
    if v <= 0.0 || v > hi {
        return Err(CommandError::field(
            field,
            ErrorCode::OutOfRange,
            format!("{v} must be > 0 and at most {hi}"),
        ));
    }
    Ok(())
}

fn unit_vector(field: &str, v: [f64; 3]) -> Result<(), CommandError> {
    for (a, x) in v.iter().enumerate() {
        finite(&format!("{field}[{a}]"), *x)?;
    }
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if len < 1e-9 {
        return Err(CommandError::field(
            field,
            ErrorCode::Invalid,
            "zero-length direction",
        ));
    }
    Ok(())
}

/// A command with the client's sequence number. Sequence numbers increase strictly (gaps are
/// allowed); re-sending an already accepted command with its number is acknowledged again
/// without being applied twice (a client reconnecting after a lost connection re-sends what it
/// has not seen acknowledged).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Envelope {
    /// Client sequence number, >= 1.
    pub seq: u64,
    /// The command.
    pub command: Command,
}

/// One accepted command, as logged.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LogEntry {
    /// The client's sequence number.
    pub seq: u64,
    /// Simulation time at which it was applied, ms since the session started.
    pub t_ms: u64,
    /// The command.
    pub command: Command,
}

/// The named option `value` of a command's field `field` (`parse` knows the names), or a
/// field-named error listing `choices`.
pub fn named_choice<T>(
    field: &str,
    value: &str,
    parse: impl Fn(&str) -> Option<T>,
    choices: &str,
) -> Result<T, CommandError> {
    parse(value).ok_or_else(|| {
        CommandError::field(
            &format!("command.{field}"),
            ErrorCode::Invalid,
            format!(
                "unknown {field} {:?}: choose {choices}",
                value.chars().take(40).collect::<String>()
            ),
        )
    })
}

/// Refuses text holding a NUL: the server's copy of the log (PostgreSQL text and jsonb) cannot
/// store one, so such a command must never be acknowledged.
/// A tray instrument id: no NUL, 1 to [`MAX_INSTRUMENT_CHARS`] characters.
fn instrument_id(field: &str, id: &str) -> Result<(), CommandError> {
    no_nul(field, id)?;
    if id.is_empty() || id.chars().count() > MAX_INSTRUMENT_CHARS {
        return Err(CommandError::field(
            field,
            ErrorCode::Invalid,
            format!("instrument id must be 1 to {MAX_INSTRUMENT_CHARS} characters"),
        ));
    }
    Ok(())
}

fn no_nul(field: &str, text: &str) -> Result<(), CommandError> {
    if text.contains('\0') {
        return Err(CommandError::field(
            field,
            ErrorCode::Invalid,
            "must not contain NUL characters (U+0000)",
        ));
    }
    Ok(())
}

/// Largest sequence number, the largest the server's log stores (a PostgreSQL `bigint`).
pub const MAX_SEQ: u64 = i64::MAX as u64;

/// Machine-readable reason of a rejection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// Not valid JSON or not a known message or command.
    Malformed,
    /// A number that is NaN or infinite.
    NotFinite,
    /// A number outside its allowed range.
    OutOfRange,
    /// Any other bad value.
    Invalid,
    /// The sequence number is not above the last accepted one.
    Sequence,
    /// The station has no such modality (ultrasound at a fluoroscopy station, ...).
    ModalityUnavailable,
    /// The instrument is not on this station's tray.
    InstrumentUnavailable,
    /// The command does not fit the current state (needle not placed, session submitted...).
    State,
    /// The session does not exist or has ended.
    NoSession,
}

/// Why a command (or message) was rejected: the field, a code and a sentence.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, thiserror::Error)]
#[error("{field}: {message}")]
pub struct CommandError {
    /// Path of the offending field, e.g. `command.orbital_deg`, `seq`, `command.type`.
    pub field: String,
    /// Machine-readable reason.
    pub code: ErrorCode,
    /// What is wrong, for people.
    pub message: String,
}

impl CommandError {
    /// An error about `field`.
    pub fn field(field: &str, code: ErrorCode, message: impl Into<String>) -> CommandError {
        CommandError {
            field: field.to_string(),
            code,
            message: message.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_shape_and_field_names_in_errors() {
        let c: Command =
            serde_json::from_str(r#"{"type":"carm_pose","orbital_deg":20,"angular_deg":-5}"#)
                .unwrap();
        assert_eq!(
            c,
            Command::CarmPose {
                orbital_deg: 20.0,
                angular_deg: -5.0,
                table_mm: [0.0; 3]
            }
        );
        let e = Command::CarmPose {
            orbital_deg: f64::NAN,
            angular_deg: 0.0,
            table_mm: [0.0; 3],
        }
        .validate()
        .unwrap_err();
        assert_eq!(
            (e.field.as_str(), e.code),
            ("command.orbital_deg", ErrorCode::NotFinite)
        );
        let e = Command::CarmPose {
            orbital_deg: 0.0,
            angular_deg: 60.0,
            table_mm: [0.0; 3],
        }
        .validate()
        .unwrap_err();
        assert_eq!(
            (e.field.as_str(), e.code),
            ("command.angular_deg", ErrorCode::OutOfRange)
        );
        let e = Command::Inject {
            agent: Agent::Contrast,
            volume_ml: 500.0,
            rate_ml_per_s: 0.2,
        }
        .validate()
        .unwrap_err();
        assert_eq!(e.field, "command.volume_ml");
        let e = Command::Technique { kvp: 83, ma: 2.0 }
            .validate()
            .unwrap_err();
        assert_eq!(e.field, "command.kvp");
        assert!(Command::Technique { kvp: 85, ma: 2.0 }.validate().is_ok());
    }

    /// Every string a command carries is checked against what the server's
    /// log (PostgreSQL text and jsonb) stores before the command can be acknowledged: no NUL,
    /// bounded length; every number is finite (jsonb has no NaN or infinity).
    #[test]
    fn every_logged_string_and_number_is_storable() {
        let place = |instrument: &str, x: f64| Command::NeedlePlace {
            instrument: instrument.into(),
            entry_mm: [x, 0.0, 0.0],
            direction: [0.0, 1.0, 0.0],
            bevel_reference: [1.0, 0.0, 0.0],
        };
        let annotate = |label: &str, x: f64| Command::Annotate {
            pixel: [x, 1.0],
            label: label.into(),
        };
        let cases = [
            (place("spinal\0", 0.0), "command.instrument"),
            (
                place(&"x".repeat(MAX_INSTRUMENT_CHARS + 1), 0.0),
                "command.instrument",
            ),
            (place("", 0.0), "command.instrument"),
            (place("spinal-22g", f64::NAN), "command.entry_mm[0]"),
            (annotate("L4\0", 1.0), "command.label"),
            (
                annotate(&"x".repeat(MAX_LABEL_CHARS + 1), 1.0),
                "command.label",
            ),
            (annotate("L4", f64::INFINITY), "command.pixel[0]"),
        ];
        for (c, field) in cases {
            assert_eq!(c.validate().unwrap_err().field, field, "{c:?}");
        }
        assert!(
            place(&"x".repeat(MAX_INSTRUMENT_CHARS), 0.0)
                .validate()
                .is_ok()
        );
        // A huge but finite pixel is storable (jsonb numerics hold it) and so accepted here.
        assert!(annotate("L4", 1e308).validate().is_ok());
    }
}
