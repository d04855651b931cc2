//! The session state machine: the world, the station's modalities, the ordered log of accepted
//! commands, snapshots and exact replay (see the module doc of [`crate::session`]).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use sim_core::hash::sha256_hex;
use sim_core::rubric::Measurements;

use super::command::{
    Agent, CORE_COMMANDS, Command, CommandClass, CommandError, Engagement, Envelope, ErrorCode,
    LogEntry, MAX_SEQ, SyringeAction,
};
use super::config::SessionConfig;
use super::devices::Backends;
use super::error::SessionError;
use super::frame::EncodedFrame;
use super::hands;
use super::image::{ViewId, ViewImage};
use super::modalities::fluoro::DraftUse;
use super::modalities::{Modality, ModalityContext, ModalityError, ModalityFactory};
use super::region::Region;
use super::scoring::{self, ReproducibilityRecord, SubmitResult};
use super::world::{self, Injection, NeedleInstrument, StationContext, World, WorldChange};

/// Version of the snapshot format.
pub const SNAPSHOT_FORMAT: u32 = 1;

/// What a session runs against: station, anatomy, the device's renderers and the modalities
/// this worker implements (shared, read-only).
#[derive(Clone)]
pub struct SessionEnv {
    /// Station with resolved targets.
    pub station: Arc<StationContext>,
    /// Anatomy.
    pub region: Arc<Region>,
    /// The renderers of this device.
    pub backends: Backends,
    /// Builds the station's modalities.
    pub modalities: ModalityFactory,
}

impl SessionEnv {
    /// A station in a region, with `backends` and every modality this worker implements.
    pub fn new(
        station: Arc<StationContext>,
        region: Arc<Region>,
        backends: Backends,
    ) -> SessionEnv {
        SessionEnv {
            station,
            region,
            backends,
            modalities: ModalityFactory::standard(),
        }
    }
}

impl std::fmt::Debug for SessionEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SessionEnv")
            .field("station", &self.station.station.id)
            .field("region", &self.region.name)
            .field("backends", &self.backends)
            .field("modalities", &self.modalities)
            .finish()
    }
}

/// Serializable session state: with the log, everything needed to continue the session
/// anywhere.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionSnapshot {
    /// [`SNAPSHOT_FORMAT`].
    pub format: u32,
    /// Station id.
    pub station_id: String,
    /// Station revision.
    pub station_revision: u32,
    /// SHA-256 of the station file.
    pub station_sha256: String,
    /// Region name.
    pub region: String,
    /// SHA-256 over the region's file hashes (see [`region_fingerprint`]).
    pub region_fingerprint: String,
    /// Fixed settings.
    pub config: SessionConfig,
    /// Simulation time, ms.
    pub clock_ms: u64,
    /// Last accepted sequence number.
    pub last_seq: u64,
    /// Number of log entries already reflected in this state.
    pub log_len: usize,
    /// The needle.
    pub needle: Option<NeedleInstrument>,
    /// Needle geometry version.
    pub needle_version: u64,
    /// Injections so far (absent from the JSON while there are none).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub injections: Vec<Injection>,
    /// What the hands hold and have done (absent from the JSON while untouched).
    #[serde(default, skip_serializing_if = "is_default_hands")]
    pub hands: world::Hands,
    /// State of each modality by name.
    pub modalities: BTreeMap<String, serde_json::Value>,
    /// The result, once the attempt was submitted.
    pub result: Option<SubmitResult>,
    /// SHA-256 of the session's initial snapshot (for records).
    pub initial_sha256: String,
}

fn is_default_hands(h: &world::Hands) -> bool {
    *h == world::Hands::default()
}

impl SessionSnapshot {
    /// Canonical bytes (JSON): equal states give equal bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        serde_json::to_vec(self).unwrap_or_default()
    }

    /// SHA-256 of [`SessionSnapshot::to_bytes`], hex.
    pub fn sha256(&self) -> String {
        sha256_hex(&self.to_bytes())
    }
}

/// One SHA-256 over a region's file hashes (file name and hash, in name order).
pub fn region_fingerprint(region: &Region) -> String {
    let mut h = Sha256::new();
    for (k, v) in &region.asset_sha256 {
        h.update(k.as_bytes());
        h.update(b"=");
        h.update(v.as_bytes());
        h.update(b"\n");
    }
    hex::encode(h.finalize())
}

/// An acknowledgement of an accepted command.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ack {
    /// The command's sequence number.
    pub seq: u64,
    /// Simulation time it was applied at, ms.
    pub t_ms: u64,
    /// True when this sequence number had already been accepted (a re-send); nothing was applied.
    #[serde(default)]
    pub duplicate: bool,
    /// What happened (needle outcome, exposure so far, annotation error, ...).
    pub outcome: serde_json::Value,
    /// The engagement event the command stands for in the learning records, as the session core
    /// or the modality that handled it declares (absent when it is none, and on duplicates).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub engagement: Option<Engagement>,
    /// The technical result, on the acknowledgement of a submit (and only there): the one typed
    /// form in which a result leaves the worker.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub result: Option<Box<SubmitResult>>,
}

/// A rendered (not yet encoded) view.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedView {
    /// Which view.
    pub view: ViewId,
    /// Last accepted input sequence reflected.
    pub input_seq: u64,
    /// Simulation time, ms.
    pub t_ms: u64,
    /// The image.
    pub image: ViewImage,
    /// A draft shown before the full render of the same input (see `Modality::render_draft`).
    pub draft: bool,
}

/// One station attempt.
pub struct Session {
    env: SessionEnv,
    config: SessionConfig,
    world: World,
    modalities: Vec<Box<dyn Modality>>,
    log: Vec<LogEntry>,
    last_seq: u64,
    submitted: Option<SubmitResult>,
    unavailable: Vec<String>,
    initial_sha256: String,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("env", &self.env)
            .field("last_seq", &self.last_seq)
            .field("log_len", &self.log.len())
            .finish()
    }
}

impl Session {
    /// A fresh session: every modality the station lists that this worker implements, in their
    /// initial state (the C-arm in AP at the L4 body centre or the first target), no needle.
    pub fn new(env: SessionEnv, config: SessionConfig) -> Session {
        let mut modalities: Vec<Box<dyn Modality>> = Vec::new();
        let mut unavailable = Vec::new();
        let renderers = env.backends.renderers();
        let ctx = ModalityContext {
            config: &config,
            station: &env.station,
            region: &env.region,
            renderers: &renderers,
        };
        for m in &env.station.station.modalities {
            let name = m.as_str();
            match env.modalities.build(name, &ctx) {
                Some(built) => modalities.push(built),
                None => unavailable.push(name.to_string()),
            }
        }
        let mut world = World {
            region: Arc::clone(&env.region),
            station: Arc::clone(&env.station),
            clock_ms: 0,
            needle: None,
            needle_version: 0,
            injections: Vec::new(),
            iodine: None,
            iodine_version: 0,
            carm: None,
            hands: world::Hands::default(),
        };
        world.carm = modalities.iter().find_map(|m| m.carm());
        let mut s = Session {
            env,
            config,
            world,
            modalities,
            log: Vec::new(),
            last_seq: 0,
            submitted: None,
            unavailable,
            initial_sha256: String::new(),
        };
        s.initial_sha256 = s.snapshot().sha256();
        s
    }

    /// Restores a session from `snapshot` and the full `log` since the session began: the state
    /// of the snapshot is taken as is, and the entries after its `log_len` are applied again at
    /// their logged times.
    pub fn restore(
        env: SessionEnv,
        snapshot: &SessionSnapshot,
        log: &[LogEntry],
    ) -> Result<Session, SessionError> {
        if snapshot.format != SNAPSHOT_FORMAT {
            return Err(SessionError::SnapshotFormat {
                found: snapshot.format,
                expected: SNAPSHOT_FORMAT,
            });
        }
        let st = &env.station;
        if snapshot.station_id != st.station.id
            || snapshot.station_revision != st.station.revision
            || snapshot.station_sha256 != st.station_sha256
        {
            return Err(SessionError::StationMismatch {
                snapshot_station: snapshot.station_id.clone(),
                snapshot_revision: snapshot.station_revision,
                loaded_station: st.station.id.clone(),
                loaded_revision: st.station.revision,
            });
        }
        if snapshot.region != env.region.name
            || snapshot.region_fingerprint != region_fingerprint(&env.region)
        {
            return Err(SessionError::RegionMismatch(snapshot.region.clone()));
        }
        if log.len() < snapshot.log_len {
            return Err(SessionError::LogTooShort {
                log: log.len(),
                reflected: snapshot.log_len,
            });
        }
        let mut s = Session::new(env, snapshot.config);
        s.world.clock_ms = snapshot.clock_ms;
        s.world.needle = snapshot.needle.clone();
        s.world.needle_version = snapshot.needle_version;
        s.world.injections = snapshot.injections.clone();
        s.world.hands = snapshot.hands.clone();
        s.last_seq = snapshot.last_seq;
        s.initial_sha256 = snapshot.initial_sha256.clone();
        for m in &mut s.modalities {
            let state = snapshot
                .modalities
                .get(m.name())
                .ok_or_else(|| SessionError::MissingModalityState(m.name().to_string()))?;
            m.restore(state.clone())?;
        }
        s.sync_iodine();
        s.world.carm = s.modalities.iter().find_map(|m| m.carm());
        s.log = log[..snapshot.log_len].to_vec();
        s.submitted = snapshot.result.clone();
        for entry in &log[snapshot.log_len..] {
            let env = Envelope {
                seq: entry.seq,
                command: entry.command.clone(),
            };
            s.apply(env, entry.t_ms)
                .map_err(|error| SessionError::LogEntry {
                    seq: entry.seq,
                    error,
                })?;
        }
        Ok(s)
    }

    /// The serializable state.
    pub fn snapshot(&self) -> SessionSnapshot {
        SessionSnapshot {
            format: SNAPSHOT_FORMAT,
            station_id: self.env.station.station.id.clone(),
            station_revision: self.env.station.station.revision,
            station_sha256: self.env.station.station_sha256.clone(),
            region: self.env.region.name.clone(),
            region_fingerprint: region_fingerprint(&self.env.region),
            config: self.config,
            clock_ms: self.world.clock_ms,
            last_seq: self.last_seq,
            log_len: self.log.len(),
            needle: self.world.needle.clone(),
            needle_version: self.world.needle_version,
            injections: self.world.injections.clone(),
            hands: self.world.hands.clone(),
            modalities: self
                .modalities
                .iter()
                .map(|m| (m.name().to_string(), m.state()))
                .collect(),
            result: self.submitted.clone(),
            initial_sha256: self.initial_sha256.clone(),
        }
    }

    /// The ordered log of accepted commands.
    pub fn log(&self) -> &[LogEntry] {
        &self.log
    }

    /// Last accepted sequence number (0 before any).
    pub fn last_seq(&self) -> u64 {
        self.last_seq
    }

    /// The shared world (read-only).
    pub fn world(&self) -> &World {
        &self.world
    }

    /// The projection of the last fluoroscopy image on screen, if one was taken.
    pub fn displayed_projection(&self) -> Option<sim_core::fluoro::geometry::Projection> {
        self.modalities
            .iter()
            .find_map(|m| m.displayed_projection())
    }

    /// The station's views this session renders.
    pub fn views(&self) -> Vec<ViewId> {
        self.modalities
            .iter()
            .flat_map(|m| m.views().iter().copied())
            .collect()
    }

    /// What each modality of this session declares, in the station's order.
    pub fn specs(&self) -> Vec<&'static super::modalities::ModalitySpec> {
        self.modalities.iter().map(|m| m.spec()).collect()
    }

    /// Modality names this session runs.
    pub fn modality_names(&self) -> Vec<&'static str> {
        self.modalities.iter().map(|m| m.name()).collect()
    }

    /// Station modalities this worker cannot provide.
    pub fn unavailable_modalities(&self) -> &[String] {
        &self.unavailable
    }

    /// The result, once submitted.
    pub fn result(&self) -> Option<&SubmitResult> {
        self.submitted.as_ref()
    }

    /// The environment (station, region, renderer).
    pub fn env(&self) -> &SessionEnv {
        &self.env
    }

    /// Applies one command at simulation time `t_ms` (ms since the session began; the clock
    /// never goes back, so an earlier time is taken as "now"). Accepted commands are logged.
    pub fn apply(&mut self, env: Envelope, t_ms: u64) -> Result<Ack, CommandError> {
        if env.seq == 0 {
            return Err(CommandError::field(
                "seq",
                ErrorCode::Sequence,
                "sequence numbers start at 1",
            ));
        }
        if env.seq > MAX_SEQ {
            return Err(CommandError::field(
                "seq",
                ErrorCode::Sequence,
                format!("sequence numbers end at {MAX_SEQ} (2^63 - 1)"),
            ));
        }
        if env.seq <= self.last_seq {
            if let Some(e) = self.log.iter().find(|e| e.seq == env.seq) {
                if e.command == env.command {
                    return Ok(Ack {
                        seq: env.seq,
                        t_ms: e.t_ms,
                        duplicate: true,
                        engagement: None,
                        outcome: serde_json::Value::Null,
                        result: None,
                    });
                }
            }
            return Err(CommandError::field(
                "seq",
                ErrorCode::Sequence,
                format!(
                    "sequence {} is not above the last accepted {}",
                    env.seq, self.last_seq
                ),
            ));
        }
        if self.submitted.is_some() {
            return Err(CommandError::field(
                "command.type",
                ErrorCode::State,
                "the attempt was submitted; the session is read-only",
            ));
        }
        env.command.validate()?;
        let before = self.world.clock_ms;
        let iodine_before = (self.world.iodine.clone(), self.world.iodine_version);
        self.world.clock_ms = before.max(t_ms);
        if self.world.clock_ms > before {
            for m in &mut self.modalities {
                m.advance(before, &self.world);
            }
        }
        // The command sees the iodine field of its moment (a shot images it); the other
        // modalities hear of a new field once the command is accepted.
        self.sync_iodine();
        let dispatched = self.dispatch(&env.command);
        self.sync_iodine();
        match dispatched {
            Ok((outcome, engagement)) => {
                if self.world.iodine_version != iodine_before.1 {
                    self.notify(&WorldChange::Iodine);
                }
                let carm = self.modalities.iter().find_map(|m| m.carm());
                if carm != self.world.carm {
                    self.world.carm = carm;
                    self.notify(&WorldChange::CArm);
                }
                let result = (env.command == Command::Submit)
                    .then(|| self.submitted.clone().map(Box::new))
                    .flatten();
                self.last_seq = env.seq;
                self.log.push(LogEntry {
                    seq: env.seq,
                    t_ms: self.world.clock_ms,
                    command: env.command,
                });
                Ok(Ack {
                    seq: env.seq,
                    t_ms: self.world.clock_ms,
                    duplicate: false,
                    engagement,
                    outcome,
                    result,
                })
            }
            Err(e) => {
                self.world.clock_ms = before;
                (self.world.iodine, self.world.iodine_version) = iodine_before;
                Err(e)
            }
        }
    }

    /// Applies a validated command: the core's own (needle and hands, tick, submit), or the one
    /// modality whose spec declares its kind. Returns the outcome and the engagement event.
    fn dispatch(
        &mut self,
        command: &Command,
    ) -> Result<(serde_json::Value, Option<Engagement>), CommandError> {
        let core_engagement = || super::command::engagement_of(CORE_COMMANDS, command.name());
        match command.class() {
            CommandClass::Needle => Ok((self.apply_needle(command)?, core_engagement())),
            CommandClass::Session if *command == Command::Tick => {
                let mut outcome = serde_json::json!({ "t_ms": self.world.clock_ms });
                for status in self.modalities.iter().filter_map(|m| m.tick_status()) {
                    if let (Some(out), serde_json::Value::Object(fields)) =
                        (outcome.as_object_mut(), status)
                    {
                        out.extend(fields);
                    }
                }
                Ok((outcome, core_engagement()))
            }
            CommandClass::Session => {
                // The submit itself is logged by the caller; the record's log hash covers the
                // commands before it. The result travels typed in the acknowledgement.
                self.submitted = Some(self.score());
                Ok((serde_json::Value::Null, core_engagement()))
            }
            CommandClass::Modality => {
                let kind = command.name();
                let Some(m) = self.modalities.iter_mut().find(|m| m.spec().handles(kind)) else {
                    return Err(self.unhandled(kind));
                };
                let outcome = m.apply(command, &self.world)?;
                let engagement = m.engagement(command);
                if let Some(fluid) = m.take_fluid() {
                    self.record_injection(fluid.agent, fluid.volume_ml, fluid.rate_ml_per_s);
                }
                Ok((outcome, engagement))
            }
        }
    }

    /// The refusal of a command kind no modality of this session handles: which modality would
    /// (by the factory's specs), and whether the station lists it.
    fn unhandled(&self, kind: &str) -> CommandError {
        let spec = self
            .env
            .modalities
            .handler_of(kind)
            .or_else(|| ModalityFactory::standard().handler_of(kind));
        match spec {
            Some(spec) => {
                let why = if self.unavailable.iter().any(|u| u == spec.name) {
                    "is listed by this station but not implemented by this worker"
                } else {
                    "is not available at this station"
                };
                CommandError::field(
                    "command.type",
                    ErrorCode::ModalityUnavailable,
                    format!(
                        "modality not available at this station: {} {why}",
                        spec.label
                    ),
                )
            }
            None => CommandError::field(
                "command.type",
                ErrorCode::Malformed,
                format!("unknown command type {kind:?}: no modality of this worker declares it"),
            ),
        }
    }

    /// Adds an injection the contrast modality accepted to the world's ledger and tells every
    /// modality.
    fn record_injection(&mut self, agent: Agent, volume_ml: f64, rate_ml_per_s: f64) {
        let tip_mm = self
            .world
            .needle
            .as_ref()
            .map_or([0.0; 3], |n| n.state.tip_mm().to_array());
        let injection = Injection {
            t_ms: self.world.clock_ms,
            agent,
            volume_ml,
            rate_ml_per_s,
            tip_mm,
        };
        self.world.injections.push(injection.clone());
        self.notify(&WorldChange::FluidInjected(injection));
    }

    /// Puts the iodine field of the modality that makes one, at the current clock, into the
    /// world.
    fn sync_iodine(&mut self) {
        for m in &mut self.modalities {
            if let Some((version, field)) = m.iodine(&self.world) {
                if version != self.world.iodine_version || self.world.iodine.is_none() {
                    self.world.iodine = Some(field);
                    self.world.iodine_version = version;
                }
            }
        }
    }

    fn notify(&mut self, change: &WorldChange) {
        for m in &mut self.modalities {
            m.world_changed(change, &self.world);
        }
    }

    fn apply_needle(&mut self, command: &Command) -> Result<serde_json::Value, CommandError> {
        if let Command::Syringe {
            action: SyringeAction::Attach,
            ..
        } = command
        {
            if self.modalities.iter().any(|m| m.injecting()) {
                return Err(CommandError::field(
                    "command.type",
                    ErrorCode::State,
                    "a contrast injection is under way: stop it before attaching the \
                     loss-of-resistance syringe",
                ));
            }
        }
        let pixel_ray = match command {
            Command::SkinMarker {
                pixel: Some(px), ..
            } => self.modalities.iter().find_map(|m| m.image_ray(*px)),
            _ => None,
        };
        let ctx = hands::Context {
            region: &self.env.region,
            seed: self.config.seed,
            pixel_ray,
        };
        let mut effects = hands::Effects::default();
        let mut outcome = hands::apply(command, &mut self.world, &ctx, &mut effects)?;
        if effects.saline_ml > 0.0 {
            self.record_injection(Agent::Saline, effects.saline_ml, hands::LOR_FLOW_ML_PER_S);
            self.world.hands.lor_ledger_entries += 1;
        }
        if effects.marker_moved && !effects.needle_moved {
            self.notify(&WorldChange::Marker);
        }
        if effects.needle_moved {
            self.world.needle_version += 1;
            self.notify(&WorldChange::Needle);
            for m in &self.modalities {
                if let (Some(f), Some(o)) =
                    (m.needle_feedback(&self.world), outcome.as_object_mut())
                {
                    o.insert(m.name().to_string(), f);
                }
            }
        }
        Ok(outcome)
    }

    /// Every measurement the session can make now (also ones no rubric reads).
    pub fn measurements(&self) -> Measurements {
        let mut out = Measurements::new();
        scoring::measure_needle(&self.world, &mut out);
        for m in &self.modalities {
            m.measure(&self.world, &mut out);
        }
        out
    }

    /// Scores the current state against the station's rubric (what a submit returns).
    pub fn score(&self) -> SubmitResult {
        let measurements = self.measurements();
        let station = &self.env.station.station;
        let read: Measurements = measurements
            .iter()
            .filter(|(k, _)| station.rubric.criteria.iter().any(|c| &c.measurement == *k))
            .map(|(k, v)| (k.clone(), *v))
            .collect();
        let rubric = station.evaluate(&read);
        let log_bytes = serde_json::to_vec(&self.log).unwrap_or_default();
        let record = ReproducibilityRecord {
            code_revision: scoring::code_revision(),
            station_id: station.id.clone(),
            station_revision: station.revision,
            rubric_revision: station.rubric.revision,
            station_sha256: self.env.station.station_sha256.clone(),
            region: self.env.region.name.clone(),
            region_source: self.env.region.source.clone(),
            asset_sha256: self.env.region.asset_sha256.clone(),
            renderer: self.env.backends.fluoro.profile(),
            modalities: self
                .modalities
                .iter()
                .map(|m| (m.name().to_string(), m.record()))
                .collect(),
            unavailable_modalities: self.unavailable.clone(),
            log_len: self.log.len(),
            log_sha256: sha256_hex(&log_bytes),
            initial_state_sha256: self.initial_sha256.clone(),
            final_state_sha256: self.snapshot().sha256(),
        };
        SubmitResult {
            measurements,
            rubric,
            record,
        }
    }

    /// Renders every dirty view in `visible` (nothing when nothing changed).
    pub fn render_dirty(
        &mut self,
        visible: &BTreeSet<ViewId>,
    ) -> Result<Vec<RenderedView>, SessionError> {
        Ok(self.render_views(visible, None)?.0)
    }

    /// [`Session::render_dirty`] for a render that newer input may stop (its thread watches a
    /// flag, see `crate::interrupt`): a view whose render was stopped stays dirty, the views
    /// rendered before it are returned, and the flag says whether one was stopped.
    pub fn render_dirty_unless_superseded(
        &mut self,
        visible: &BTreeSet<ViewId>,
    ) -> Result<(Vec<RenderedView>, bool), SessionError> {
        self.render_views(visible, None)
    }

    /// The drafts of the dirty visible views that have one now (`DraftUse::Live`: each image
    /// is drafted once, only where its full render is expensive and the draft is ready); the
    /// views stay dirty for [`Session::render_dirty`].
    pub fn render_drafts(
        &mut self,
        visible: &BTreeSet<ViewId>,
    ) -> Result<Vec<RenderedView>, SessionError> {
        Ok(self.render_views(visible, Some(DraftUse::Live))?.0)
    }

    /// The draft of the image `view` shows now, as a replay of a draft frame renders it
    /// (waiting for the region's draft scene if it is being built); `None` where the view has
    /// no draft.
    pub fn replay_draft(&mut self, view: ViewId) -> Result<Option<RenderedView>, SessionError> {
        Ok(self
            .render_views(&BTreeSet::from([view]), Some(DraftUse::Replay))?
            .0
            .pop())
    }

    /// The full renders (`draft` `None`) or the drafts of the dirty views in `views`, and
    /// whether newer input stopped one (the rest are then left dirty too).
    fn render_views(
        &mut self,
        views: &BTreeSet<ViewId>,
        draft: Option<DraftUse>,
    ) -> Result<(Vec<RenderedView>, bool), SessionError> {
        let mut out = Vec::new();
        for m in &mut self.modalities {
            for view in m.dirty_views() {
                if !views.contains(&view) {
                    continue;
                }
                let image = match draft {
                    None => m.render(view, &self.world),
                    Some(use_) => m.render_draft(view, &self.world, use_),
                };
                let image = match image {
                    Err(ModalityError::Interrupted { .. }) => return Ok((out, true)),
                    r => r?,
                };
                if let Some(image) = image {
                    out.push(RenderedView {
                        view,
                        input_seq: self.last_seq,
                        t_ms: self.world.clock_ms,
                        image,
                        draft: draft.is_some(),
                    });
                }
            }
        }
        Ok((out, false))
    }

    /// Lets every modality prepare what its next frames will likely need
    /// ([`Modality::prefetch`]); changes nothing a client or a replay sees, only how soon the
    /// next frame comes. A failure is logged and left to the render that needs it.
    pub fn prefetch(&mut self) {
        for m in &mut self.modalities {
            match m.prefetch(&self.world) {
                Ok(()) => {}
                Err(e @ ModalityError::Interrupted { .. }) => {
                    tracing::debug!(modality = m.name(), "{e}");
                }
                Err(e) => tracing::warn!(modality = m.name(), "prefetch failed: {e}"),
            }
        }
    }

    /// The moment at which a `tick` that comes at `now_ms` should be applied: a little later
    /// when a modality images a waiting change then and the tick could be early for it (live
    /// fluoroscopy's next pulse, see [`Modality::tick_hold_until`]), else `now_ms`.
    pub fn tick_time(&self, now_ms: u64) -> u64 {
        self.modalities
            .iter()
            .filter_map(|m| m.tick_hold_until(now_ms))
            .min()
            .map_or(now_ms, |t| t.max(now_ms))
    }

    /// Whether a modality with a view in `visible` has something to prefetch
    /// ([`Modality::prefetch_pending`]): nothing is prepared for a view the client hides.
    pub fn prefetch_pending(&self, visible: &BTreeSet<ViewId>) -> bool {
        self.modalities
            .iter()
            .any(|m| m.prefetch_pending() && m.views().iter().any(|v| visible.contains(v)))
    }

    /// Whether any visible view needs rendering.
    pub fn has_dirty(&self, visible: &BTreeSet<ViewId>) -> bool {
        self.modalities
            .iter()
            .any(|m| m.dirty_views().iter().any(|v| visible.contains(v)))
    }
}

/// What a faculty review of a recorded attempt gets back.
#[derive(Debug, Clone, PartialEq)]
pub struct Replay {
    /// The replayed session (state at the end of the log; step through `log()` for a timeline).
    pub final_state: SessionSnapshot,
    /// The result, when the log ends with a submit.
    pub result: Option<SubmitResult>,
    /// The last image of each view, encoded as it was streamed (frame sequence 0).
    pub final_frames: Vec<EncodedFrame>,
}

/// Replays a recorded attempt from its initial snapshot and full log: the same state, score and
/// (with the same renderer) the same final frame bytes as the live session.
pub fn replay_attempt(
    env: SessionEnv,
    initial: &SessionSnapshot,
    log: &[LogEntry],
) -> Result<Replay, SessionError> {
    let mut s = Session::restore(env, initial, log)?;
    let views: BTreeSet<ViewId> = s.views().into_iter().collect();
    let final_frames = s
        .render_dirty(&views)?
        .into_iter()
        .map(|v| EncodedFrame::new(v.view, 0, v.input_seq, v.t_ms, &v.image))
        .collect::<Result<_, _>>()?;
    Ok(Replay {
        final_state: s.snapshot(),
        result: s.result().cloned(),
        final_frames,
    })
}
