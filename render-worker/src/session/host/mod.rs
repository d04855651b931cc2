//! [`SessionHost`]: the in-process API of a worker. The server calls it directly (embedded
//! default) or through the `render-worker` binary's websocket; both speak [`super::protocol`].
//!
//! Each session runs on its own actor thread. The thread blocks on its input channel, so an idle
//! session costs no CPU; when inputs arrive it applies every queued one (inputs are never
//! dropped), acknowledges each, then renders the dirty visible views once and publishes the
//! frames on a `watch` channel, which keeps only the newest: a slow client skips frames, never
//! inputs.

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};
use sim_core::anatomy::pipeline::Progress;
use sim_core::rubric::{Station, load_station_dir};
use tokio::sync::{mpsc, oneshot, watch};

use super::command::{CommandError, Envelope, ErrorCode, LogEntry};
use super::config::SessionConfig;
use super::devices::Backends;
use super::image::ViewId;
use super::loader::RegionLoadError;
use super::machine::{Ack, Session, SessionEnv, SessionSnapshot};
use super::modalities::fluoro::{BackendProfile, FluoroBackend};
pub use super::preparation::{
    EXPECTED_BUILD_S, MAX_RETRY_AFTER_S, Pace, RegionReadiness, build_fraction,
};
use super::preparation::{QuickCheck, RegionLoader, Regions};
use super::region::Region;
use super::scoring::SubmitResult;
use super::world::StationContext;
use sim_core::hash::sha256_hex;

mod actor;

use actor::{ActorMsg, Supersede, run_actor};
pub use actor::{FrameSet, PREFETCH_AFTER_PAUSE, Reply};

/// Worker settings.
#[derive(Debug, Clone)]
pub struct HostConfig {
    /// Folder holding one folder per region (`assets/`).
    pub assets_root: PathBuf,
    /// Folder of station TOML files (`assets/stations/`).
    pub stations_dir: PathBuf,
    /// Most sessions at once.
    pub capacity: usize,
    /// Settings of new sessions.
    pub session: SessionConfig,
}

/// Why the host refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error, Serialize, Deserialize)]
pub enum HostError {
    /// No such station.
    #[error("unknown station {0}")]
    UnknownStation(String),
    /// The region could not be loaded or built.
    #[error("region: {0}")]
    Region(String),
    /// At capacity.
    #[error("worker is at capacity ({0} sessions)")]
    Full(usize),
    /// The worker drains before it exits: it takes no new sessions.
    #[error("the worker is draining before it exits; it takes no new sessions")]
    Draining,
    /// No such session.
    #[error("no session {0}")]
    NoSession(String),
    /// A snapshot and log did not restore.
    #[error("restore failed: {0}")]
    Restore(String),
    /// Stations could not be loaded.
    #[error("stations: {0}")]
    Stations(String),
    /// The station's region is still being loaded or built (the first phantom build takes tens
    /// of seconds): ask again after `retry_after_s`.
    #[error("the anatomy ({region}) is being prepared; retry after {retry_after_s} s")]
    Preparing {
        /// Region name.
        region: String,
        /// Its state (stage, fraction done, estimated time left).
        readiness: RegionReadiness,
        /// Seconds to wait before asking again.
        retry_after_s: u64,
    },
}

/// What a client needs to know about a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    /// Session id.
    pub id: String,
    /// Station id.
    pub station_id: String,
    /// Names of the views the session renders.
    pub views: Vec<String>,
    /// Modalities it runs.
    pub modalities: Vec<String>,
    /// Station modalities this worker cannot provide.
    pub unavailable_modalities: Vec<String>,
    /// The protocol's constants and what each modality offers (views with wire codes, command
    /// kinds, client constants).
    pub protocol: super::offer::ProtocolInfo,
}

/// Health and load, for `/healthz` and dispatch by least load.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Health {
    /// Always "ok" when the host answers.
    pub status: String,
    /// The fluoroscopy renderer.
    pub renderer: BackendProfile,
    /// GPU adapter, when one was opened.
    pub adapter: Option<serde_json::Value>,
    /// Most sessions.
    pub capacity: usize,
    /// Sessions now.
    pub sessions: usize,
    /// sessions / capacity.
    pub load: f64,
    /// True while the worker drains before exiting (it takes no new sessions).
    #[serde(default)]
    pub draining: bool,
    /// Readiness of each region the stations use.
    #[serde(default)]
    pub regions: BTreeMap<String, RegionReadiness>,
    /// The start-up calibration that chose the renderer and the capacity, once made (the
    /// `Calibration` of `session::calibration`, which records it here).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<serde_json::Value>,
}

/// A running session: send commands, watch frames.
#[derive(Clone)]
pub struct SessionHandle {
    /// What it is.
    pub info: SessionInfo,
    tx: mpsc::UnboundedSender<ActorMsg>,
    frames: watch::Receiver<FrameSet>,
    supersede: Supersede,
}

impl std::fmt::Debug for SessionHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SessionHandle")
            .field("info", &self.info)
            .finish()
    }
}

impl SessionHandle {
    /// Queues a command; its ack or error goes to `reply` (in order with the others sent there).
    pub fn send(
        &self,
        env: Envelope,
        reply: mpsc::UnboundedSender<Reply>,
    ) -> Result<(), CommandError> {
        let seq = env.seq;
        let moves = self.supersede.moves_a_view(&env.command);
        self.tx
            .send(ActorMsg::Command { env, reply })
            .map_err(|_| closed(seq))?;
        // Raised once the command waits: a refinement in flight then stops for it, and one
        // still waiting for its turn at the GPU targets gives its place up for any command.
        self.supersede.raise_input();
        if moves {
            self.supersede.raise();
        }
        Ok(())
    }

    /// Applies a command and waits for its acknowledgement.
    pub async fn command(&self, env: Envelope) -> Result<Ack, CommandError> {
        let seq = env.seq;
        let (tx, mut rx) = mpsc::unbounded_channel();
        self.send(env, tx)?;
        match rx.recv().await {
            Some(Reply::Ack(a)) => Ok(a),
            Some(Reply::Error { error, .. }) => Err(error),
            None => Err(closed(seq)),
        }
    }

    /// Sets which views are visible (only those are rendered).
    pub fn set_visible(&self, views: BTreeSet<ViewId>) {
        let _ = self.tx.send(ActorMsg::Visible(views));
    }

    /// The session's state and full log (for hand-over to another worker and for review).
    pub async fn snapshot(&self) -> Option<(SessionSnapshot, Vec<LogEntry>)> {
        let (tx, rx) = oneshot::channel();
        self.tx.send(ActorMsg::Snapshot(tx)).ok()?;
        rx.await.ok()
    }

    /// The current measurements and rubric result (without submitting).
    pub async fn score(&self) -> Option<SubmitResult> {
        let (tx, rx) = oneshot::channel();
        self.tx.send(ActorMsg::Score(tx)).ok()?;
        rx.await.ok()
    }

    /// Latest frames (a `watch`: only the newest is kept).
    pub fn frames(&self) -> watch::Receiver<FrameSet> {
        self.frames.clone()
    }
}

fn closed(seq: u64) -> CommandError {
    CommandError {
        field: if seq > 0 {
            "seq".into()
        } else {
            "session".into()
        },
        code: ErrorCode::NoSession,
        message: "the session has ended".into(),
    }
}

struct Inner {
    stations: BTreeMap<String, (Station, String)>,
    /// Loaded regions and the preparation of the others.
    regions: Arc<Regions>,
    sessions: Mutex<BTreeMap<String, SessionHandle>>,
    /// Threads of the session actors not yet known to have finished (see
    /// [`SessionHost::shutdown`]).
    actors: Mutex<Vec<std::thread::JoinHandle<()>>>,
    /// The renderers of new sessions (the fluoroscopy one may be replaced by a calibration).
    backends: std::sync::RwLock<Backends>,
    /// The modalities sessions are built with (the standard ones unless an embedder sets its
    /// own with [`SessionHost::set_modalities`]).
    modalities: std::sync::RwLock<super::modalities::ModalityFactory>,
    /// Most sessions (set at start, or by a calibration).
    capacity: std::sync::atomic::AtomicUsize,
    /// Set when the worker drains before exiting ([`SessionHost::start_draining`]).
    draining: std::sync::atomic::AtomicBool,
    calibration: Mutex<Option<serde_json::Value>>,
    session_config: SessionConfig,
    adapter: Option<serde_json::Value>,
}

/// The sessions of one worker.
#[derive(Clone)]
pub struct SessionHost {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for SessionHost {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SessionHost")
            .field("capacity", &self.capacity())
            .finish()
    }
}

impl SessionHost {
    /// Loads the stations of `config.stations_dir`; regions are loaded (the phantom built) on
    /// first use, from `config.assets_root`.
    pub fn new(
        config: HostConfig,
        backends: Backends,
        adapter: Option<serde_json::Value>,
    ) -> Result<SessionHost, HostError> {
        let files = load_station_dir(&config.stations_dir)
            .map_err(|e| HostError::Stations(e.to_string()))?;
        let stations = files
            .into_iter()
            .map(|f| {
                (
                    f.station.id.clone(),
                    (f.station, sha256_hex(f.text.as_bytes())),
                )
            })
            .collect();
        let root = config.assets_root.clone();
        let root_too = config.assets_root.clone();
        Ok(SessionHost::from_parts(
            stations,
            Box::new(move |name, progress| super::loader::load_region(&root, name, progress)),
            Box::new(move |name| super::loader::is_built(&root_too, name)),
            backends,
            config.capacity,
            config.session,
            adapter,
        ))
    }

    /// A host over given stations (with their file hashes) and regions (tests, benches, and a
    /// server that loaded them itself). Regions not in `regions` are refused.
    pub fn with_regions(
        stations: Vec<(Station, String)>,
        regions: Vec<Arc<Region>>,
        backends: Backends,
        capacity: usize,
        session_config: SessionConfig,
    ) -> SessionHost {
        let host = SessionHost::from_parts(
            stations
                .into_iter()
                .map(|(s, h)| (s.id.clone(), (s, h)))
                .collect(),
            Box::new(|name, _| Err(RegionLoadError::NotLoaded(name.to_string()))),
            Box::new(|_| false),
            backends,
            capacity,
            session_config,
            None,
        );
        for r in regions {
            host.inner.regions.insert(r);
        }
        host
    }

    fn from_parts(
        stations: BTreeMap<String, (Station, String)>,
        loader: Box<RegionLoader>,
        quick: Box<QuickCheck>,
        backends: Backends,
        capacity: usize,
        session_config: SessionConfig,
        adapter: Option<serde_json::Value>,
    ) -> SessionHost {
        SessionHost {
            inner: Arc::new(Inner {
                stations,
                regions: Arc::new(Regions::with_quick_check(loader, quick)),
                sessions: Mutex::new(BTreeMap::new()),
                actors: Mutex::new(Vec::new()),
                backends: std::sync::RwLock::new(backends),
                modalities: std::sync::RwLock::new(super::modalities::ModalityFactory::standard()),
                capacity: capacity.into(),
                draining: false.into(),
                calibration: Mutex::new(None),
                session_config,
                adapter,
            }),
        }
    }

    /// Station ids served.
    pub fn station_ids(&self) -> Vec<String> {
        self.inner.stations.keys().cloned().collect()
    }

    /// Health and load.
    pub fn health(&self) -> Health {
        let sessions = self.inner.sessions.lock().map_or(0, |s| s.len());
        Health {
            status: "ok".into(),
            renderer: self.backends().fluoro.profile(),
            adapter: self.inner.adapter.clone(),
            capacity: self.capacity(),
            sessions,
            load: sessions as f64 / self.capacity().max(1) as f64,
            draining: self.is_draining(),
            regions: self.regions_readiness(),
            calibration: self.inner.calibration.lock().ok().and_then(|c| c.clone()),
        }
    }

    /// Stops taking new sessions (created or restored: [`HostError::Draining`]); running ones go
    /// on. For a worker that was asked to exit.
    pub fn start_draining(&self) {
        self.inner
            .draining
            .store(true, std::sync::atomic::Ordering::SeqCst);
    }

    /// Whether the host drains ([`SessionHost::start_draining`]).
    pub fn is_draining(&self) -> bool {
        self.inner
            .draining
            .load(std::sync::atomic::Ordering::SeqCst)
    }

    /// Most sessions this host takes now.
    pub fn capacity(&self) -> usize {
        self.inner
            .capacity
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Sets the most sessions; sessions beyond it that are already running keep running.
    pub fn set_capacity(&self, capacity: usize) {
        self.inner
            .capacity
            .store(capacity, std::sync::atomic::Ordering::Relaxed);
    }

    /// The configuration of this host's sessions.
    pub fn session_config(&self) -> SessionConfig {
        self.inner.session_config
    }

    /// The renderers new sessions get.
    pub fn backends(&self) -> Backends {
        self.inner
            .backends
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Renders the fluoroscopy of sessions started from now on with `fluoro` (a calibration's
    /// choice); sessions already running keep their renderer.
    pub fn set_fluoro_backend(&self, fluoro: Arc<dyn FluoroBackend>) {
        self.inner
            .backends
            .write()
            .unwrap_or_else(|p| p.into_inner())
            .fluoro = fluoro;
    }

    /// Records the calibration that health reports (serialised by its maker).
    pub fn set_calibration(&self, calibration: serde_json::Value) {
        if let Ok(mut c) = self.inner.calibration.lock() {
            *c = Some(calibration);
        }
    }

    /// The loaded region of each station that shows fluoroscopy, with the station and its file
    /// hash (what a calibration drives).
    pub fn fluoroscopy_stations(&self) -> Vec<((Station, String), Arc<Region>)> {
        self.inner
            .stations
            .values()
            .filter(|(st, _)| {
                st.modalities
                    .iter()
                    .any(|m| m.as_str() == sim_core::rubric::Modality::FLUOROSCOPY)
            })
            .filter_map(|st| Some((st.clone(), self.loaded(&st.0.region_asset())?)))
            .collect()
    }

    /// A new host over given stations with a custom region loader (`loader(name, progress)`
    /// returns the region, reporting build stages to `progress`): for tests of the preparation
    /// states, and for servers that find regions elsewhere.
    pub fn with_loader(
        stations: Vec<(Station, String)>,
        loader: impl Fn(&str, &mut dyn FnMut(&Progress)) -> Result<Region, RegionLoadError>
        + Send
        + Sync
        + 'static,
        backends: Backends,
        capacity: usize,
        session_config: SessionConfig,
    ) -> SessionHost {
        SessionHost::from_parts(
            stations
                .into_iter()
                .map(|(s, h)| (s.id.clone(), (s, h)))
                .collect(),
            Box::new(loader),
            Box::new(|_| false),
            backends,
            capacity,
            session_config,
            None,
        )
    }

    /// The regions the stations use, by name.
    fn station_regions(&self) -> BTreeSet<String> {
        self.inner
            .stations
            .values()
            .map(|(s, _)| s.region_asset())
            .collect()
    }

    fn loaded(&self, region: &str) -> Option<Arc<Region>> {
        self.inner.regions.loaded(region)
    }

    /// Readiness of one region.
    pub fn region_readiness(&self, region: &str) -> RegionReadiness {
        self.inner.regions.readiness(region)
    }

    /// Readiness of every region the stations use.
    pub fn regions_readiness(&self) -> BTreeMap<String, RegionReadiness> {
        self.station_regions()
            .into_iter()
            .map(|r| {
                let state = self.region_readiness(&r);
                (r, state)
            })
            .collect()
    }

    /// Starts loading (building, for the phantom) every region the stations use that is not
    /// loaded or being prepared yet, one after the other on a background thread, so that the
    /// first session does not wait for it. Returns at once.
    pub fn prepare_in_background(&self) {
        let todo: Vec<String> = self
            .regions_by_use()
            .into_iter()
            .filter(|r| self.inner.regions.claim(r))
            .collect();
        self.inner.regions.spawn_preparation(todo);
    }

    /// The stations' regions, those that serve the most stations first (ties by name): at a
    /// cold start the regions are built one at a time, and the region most stations use is the
    /// one a learner most likely opens first (with the default stations, the lumbar phantom's
    /// six stations before the neck's two: ready 53-57 s after a cold start instead of 68-71).
    fn regions_by_use(&self) -> Vec<String> {
        most_used_first(self.inner.stations.values().map(|(s, _)| s.region_asset()))
    }

    /// Whether a session of `station_id` can start now: `Ok` when its region is loaded; a
    /// [`HostError::Preparing`] while it is loaded or built (and the preparation is started
    /// in the background if it was not); [`HostError::Region`] with the reason if it failed.
    pub fn check_ready(&self, station_id: &str) -> Result<(), HostError> {
        let (station, _) = self
            .inner
            .stations
            .get(station_id)
            .ok_or_else(|| HostError::UnknownStation(station_id.to_string()))?;
        let region = station.region_asset();
        if self.loaded(&region).is_some() {
            return Ok(());
        }
        if !matches!(
            self.region_readiness(&region),
            RegionReadiness::Failed { .. }
        ) && self.inner.regions.claim(&region)
        {
            self.inner.regions.spawn_preparation(vec![region.clone()]);
        }
        // A region still waiting behind others is prepared next: a learner asked for it.
        self.inner.regions.prefer(&region);
        match self.region_readiness(&region) {
            RegionReadiness::Ready { .. } => Ok(()),
            RegionReadiness::Failed { reason } => Err(HostError::Region(reason)),
            readiness => {
                let remaining_s = match &readiness {
                    RegionReadiness::Building { remaining_s, .. } => *remaining_s,
                    _ => EXPECTED_BUILD_S,
                };
                Err(HostError::Preparing {
                    region,
                    retry_after_s: remaining_s.clamp(1.0, MAX_RETRY_AFTER_S).ceil() as u64,
                    readiness,
                })
            }
        }
    }

    /// The environment of a station (loads its region on first use: blocking, possibly long).
    pub fn env_for(&self, station_id: &str) -> Result<SessionEnv, HostError> {
        let (station, sha) = self
            .inner
            .stations
            .get(station_id)
            .cloned()
            .ok_or_else(|| HostError::UnknownStation(station_id.to_string()))?;
        let region = self
            .inner
            .regions
            .blocking(&station.region_asset())
            .map_err(|e| HostError::Region(e.to_string()))?;
        let mut env = SessionEnv::new(
            Arc::new(StationContext::new(station, sha, &region)),
            region,
            self.backends(),
        );
        if let Ok(f) = self.inner.modalities.read() {
            env.modalities = f.clone();
        }
        Ok(env)
    }

    /// Builds the sessions started from now on with the modalities of `factory` (the standard
    /// ones plus an embedder's own, say); sessions already running keep theirs.
    pub fn set_modalities(&self, factory: super::modalities::ModalityFactory) {
        if let Ok(mut f) = self.inner.modalities.write() {
            *f = factory;
        }
    }

    /// Creates a session at a station (blocking while a region loads the first time; call from
    /// `spawn_blocking` in async code, or use [`SessionHost::create`]).
    pub fn create_blocking(&self, station_id: &str) -> Result<SessionHandle, HostError> {
        self.check_capacity()?;
        let env = self.env_for(station_id)?;
        Ok(self.spawn(Session::new(env, self.inner.session_config)))
    }

    /// Async [`SessionHost::create_blocking`], except that it does not wait for a region being
    /// prepared: it answers [`HostError::Preparing`] instead (see [`SessionHost::check_ready`]).
    pub async fn create(&self, station_id: &str) -> Result<SessionHandle, HostError> {
        self.check_ready(station_id)?;
        let host = self.clone();
        let id = station_id.to_string();
        tokio::task::spawn_blocking(move || host.create_blocking(&id))
            .await
            .map_err(|e| HostError::Region(e.to_string()))?
    }

    /// Restores a session (from another worker) from its snapshot and full log.
    pub fn restore_blocking(
        &self,
        snapshot: &SessionSnapshot,
        log: &[LogEntry],
    ) -> Result<SessionHandle, HostError> {
        self.check_capacity()?;
        let env = self.env_for(&snapshot.station_id)?;
        let s =
            Session::restore(env, snapshot, log).map_err(|e| HostError::Restore(e.to_string()))?;
        Ok(self.spawn(s))
    }

    fn check_capacity(&self) -> Result<(), HostError> {
        if self.is_draining() {
            return Err(HostError::Draining);
        }
        let n = self.inner.sessions.lock().map_or(0, |s| s.len());
        let capacity = self.capacity();
        if n >= capacity {
            return Err(HostError::Full(capacity));
        }
        Ok(())
    }

    /// A running session by id.
    pub fn session(&self, id: &str) -> Option<SessionHandle> {
        self.inner.sessions.lock().ok()?.get(id).cloned()
    }

    /// Ends a session (its thread exits once its queue is drained).
    pub fn close(&self, id: &str) -> Result<(), HostError> {
        let h = self
            .inner
            .sessions
            .lock()
            .ok()
            .and_then(|mut s| s.remove(id))
            .ok_or_else(|| HostError::NoSession(id.to_string()))?;
        let _ = h.tx.send(ActorMsg::Close);
        Ok(())
    }

    /// Ends every session and waits until each session thread has finished, its renderer and
    /// GPU resources released. Call it before the process exits: a session thread still tearing
    /// down GPU resources while the process runs its exit handlers races with the graphics
    /// driver's own teardown (Mesa's lavapipe corrupted the heap that way in a benchmark).
    /// Sessions created afterwards run as usual.
    pub fn shutdown(&self) {
        let sessions = self
            .inner
            .sessions
            .lock()
            .map(|mut s| std::mem::take(&mut *s))
            .unwrap_or_default();
        for h in sessions.values() {
            let _ = h.tx.send(ActorMsg::Close);
        }
        drop(sessions);
        let actors = self
            .inner
            .actors
            .lock()
            .map(|mut a| std::mem::take(&mut *a))
            .unwrap_or_default();
        for a in actors {
            if a.join().is_err() {
                tracing::error!("a session thread panicked");
            }
        }
    }

    fn spawn(&self, session: Session) -> SessionHandle {
        let id = uuid::Uuid::new_v4().to_string();
        let info = SessionInfo {
            id: id.clone(),
            station_id: session.env().station.station.id.clone(),
            views: session
                .views()
                .iter()
                .map(|v| v.name().to_string())
                .collect(),
            protocol: super::offer::ProtocolInfo::of(&session),
            modalities: session
                .modality_names()
                .iter()
                .map(|s| s.to_string())
                .collect(),
            unavailable_modalities: session.unavailable_modalities().to_vec(),
        };
        let (tx, rx) = mpsc::unbounded_channel();
        let (ftx, frx) = watch::channel(FrameSet::default());
        let visible: BTreeSet<ViewId> = session.views().into_iter().collect();
        let supersede = Supersede::of(&session);
        let name = format!("session-{}", &id[..8]);
        let watched = supersede.clone();
        let spawned = std::thread::Builder::new()
            .name(name)
            .spawn(move || run_actor(session, rx, ftx, visible, watched));
        match spawned {
            Ok(t) => {
                if let Ok(mut a) = self.inner.actors.lock() {
                    a.retain(|t| !t.is_finished());
                    a.push(t);
                }
            }
            Err(e) => tracing::error!("cannot start a session thread: {e}"),
        }
        let handle = SessionHandle {
            info,
            tx,
            frames: frx,
            supersede,
        };
        if let Ok(mut s) = self.inner.sessions.lock() {
            s.insert(id, handle.clone());
        }
        handle
    }
}

/// The distinct names of `uses` (one per user), the most used first, ties by name.
fn most_used_first(uses: impl IntoIterator<Item = String>) -> Vec<String> {
    let mut count: BTreeMap<String, usize> = BTreeMap::new();
    for r in uses {
        *count.entry(r).or_default() += 1;
    }
    let mut regions: Vec<(String, usize)> = count.into_iter().collect();
    regions.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    regions.into_iter().map(|(r, _)| r).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regions_are_prepared_most_used_first_then_by_name() {
        let uses = ["b", "c", "a", "c", "b", "d", "c"].map(String::from);
        assert_eq!(most_used_first(uses), ["c", "b", "a", "d"]);
        assert!(most_used_first(Vec::new()).is_empty());
    }
}
