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
use std::time::Instant;

use serde::{Deserialize, Serialize};
use sim_core::rubric::{Station, load_station_dir};
use tokio::sync::{mpsc, oneshot, watch};

use super::command::{CommandError, Envelope, ErrorCode, LogEntry};
use super::fluoro::{BackendProfile, FluoroBackend};
use super::frame::EncodedFrame;
use super::modality::ViewId;
use super::region::Region;
use super::world::StationContext;
use super::{Ack, Session, SessionConfig, SessionEnv, SessionSnapshot, SubmitResult, sha256_hex};

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
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error, Serialize, Deserialize)]
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
    /// No such session.
    #[error("no session {0}")]
    NoSession(String),
    /// A snapshot and log did not restore.
    #[error("restore failed: {0}")]
    Restore(String),
    /// Stations could not be loaded.
    #[error("stations: {0}")]
    Stations(String),
}

/// What a client needs to know about a session.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    /// Session id.
    pub id: String,
    /// Station id.
    pub station_id: String,
    /// Views the session renders.
    pub views: Vec<ViewId>,
    /// Modalities it runs.
    pub modalities: Vec<String>,
    /// Station modalities this worker cannot provide.
    pub unavailable_modalities: Vec<String>,
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
}

/// Latest frame of each view.
pub type FrameSet = Arc<BTreeMap<ViewId, Arc<EncodedFrame>>>;

/// Replies to one connection, in order.
#[derive(Debug, Clone)]
pub enum Reply {
    /// A command was accepted.
    Ack(Ack),
    /// A command was rejected.
    Error {
        /// Its sequence number.
        seq: Option<u64>,
        /// Why.
        error: CommandError,
    },
}

enum ActorMsg {
    Command {
        env: Envelope,
        reply: mpsc::UnboundedSender<Reply>,
    },
    Visible(BTreeSet<ViewId>),
    Snapshot(oneshot::Sender<(SessionSnapshot, Vec<LogEntry>)>),
    Score(oneshot::Sender<SubmitResult>),
    Close,
}

/// A running session: send commands, watch frames.
#[derive(Clone)]
pub struct SessionHandle {
    /// What it is.
    pub info: SessionInfo,
    tx: mpsc::UnboundedSender<ActorMsg>,
    frames: watch::Receiver<FrameSet>,
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
        self.tx
            .send(ActorMsg::Command { env, reply })
            .map_err(|_| closed(seq))
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

type RegionLoader = dyn Fn(&str) -> Result<Region, String> + Send + Sync;

struct Inner {
    stations: BTreeMap<String, (Station, String)>,
    regions: Mutex<BTreeMap<String, Arc<Region>>>,
    loader: Box<RegionLoader>,
    sessions: Mutex<BTreeMap<String, SessionHandle>>,
    backend: Arc<dyn FluoroBackend>,
    capacity: usize,
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
            .field("capacity", &self.inner.capacity)
            .finish()
    }
}

impl SessionHost {
    /// Loads the stations of `config.stations_dir`; regions are loaded (the phantom built) on
    /// first use, from `config.assets_root`.
    pub fn new(
        config: HostConfig,
        backend: Arc<dyn FluoroBackend>,
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
        Ok(SessionHost::from_parts(
            stations,
            Box::new(move |name| Region::load(&root, name)),
            backend,
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
        backend: Arc<dyn FluoroBackend>,
        capacity: usize,
        session_config: SessionConfig,
    ) -> SessionHost {
        let host = SessionHost::from_parts(
            stations
                .into_iter()
                .map(|(s, h)| (s.id.clone(), (s, h)))
                .collect(),
            Box::new(|name| Err(format!("region {name} is not loaded in this host"))),
            backend,
            capacity,
            session_config,
            None,
        );
        if let Ok(mut m) = host.inner.regions.lock() {
            for r in regions {
                m.insert(r.name.clone(), r);
            }
        }
        host
    }

    fn from_parts(
        stations: BTreeMap<String, (Station, String)>,
        loader: Box<RegionLoader>,
        backend: Arc<dyn FluoroBackend>,
        capacity: usize,
        session_config: SessionConfig,
        adapter: Option<serde_json::Value>,
    ) -> SessionHost {
        SessionHost {
            inner: Arc::new(Inner {
                stations,
                regions: Mutex::new(BTreeMap::new()),
                loader,
                sessions: Mutex::new(BTreeMap::new()),
                backend,
                capacity,
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
            renderer: self.inner.backend.profile(),
            adapter: self.inner.adapter.clone(),
            capacity: self.inner.capacity,
            sessions,
            load: sessions as f64 / self.inner.capacity.max(1) as f64,
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
        let region = {
            let mut regions = self
                .inner
                .regions
                .lock()
                .map_err(|_| HostError::Region("lock poisoned".into()))?;
            match regions.get(&station.region) {
                Some(r) => Arc::clone(r),
                None => {
                    let r =
                        Arc::new((self.inner.loader)(&station.region).map_err(HostError::Region)?);
                    regions.insert(station.region.clone(), Arc::clone(&r));
                    r
                }
            }
        };
        Ok(SessionEnv {
            station: Arc::new(StationContext::new(station, sha, &region)),
            region,
            backend: Arc::clone(&self.inner.backend),
        })
    }

    /// Creates a session at a station (blocking while a region loads the first time; call from
    /// `spawn_blocking` in async code, or use [`SessionHost::create`]).
    pub fn create_blocking(&self, station_id: &str) -> Result<SessionHandle, HostError> {
        self.check_capacity()?;
        let env = self.env_for(station_id)?;
        Ok(self.spawn(Session::new(env, self.inner.session_config)))
    }

    /// Async [`SessionHost::create_blocking`].
    pub async fn create(&self, station_id: &str) -> Result<SessionHandle, HostError> {
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
        let s = Session::restore(env, snapshot, log).map_err(HostError::Restore)?;
        Ok(self.spawn(s))
    }

    fn check_capacity(&self) -> Result<(), HostError> {
        let n = self.inner.sessions.lock().map_or(0, |s| s.len());
        if n >= self.inner.capacity {
            return Err(HostError::Full(self.inner.capacity));
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

    fn spawn(&self, session: Session) -> SessionHandle {
        let id = uuid::Uuid::new_v4().to_string();
        let info = SessionInfo {
            id: id.clone(),
            station_id: session.env().station.station.id.clone(),
            views: session.views(),
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
        let name = format!("session-{}", &id[..8]);
        let spawned = std::thread::Builder::new()
            .name(name)
            .spawn(move || run_actor(session, rx, ftx, visible));
        if let Err(e) = spawned {
            tracing::error!("cannot start a session thread: {e}");
        }
        let handle = SessionHandle {
            info,
            tx,
            frames: frx,
        };
        if let Ok(mut s) = self.inner.sessions.lock() {
            s.insert(id, handle.clone());
        }
        handle
    }
}

fn run_actor(
    mut session: Session,
    mut rx: mpsc::UnboundedReceiver<ActorMsg>,
    frames: watch::Sender<FrameSet>,
    mut visible: BTreeSet<ViewId>,
) {
    let started = Instant::now();
    let base_ms = session.world().clock_ms;
    let mut frame_seq = 0u64;
    while let Some(first) = rx.blocking_recv() {
        let mut batch = vec![first];
        while let Ok(m) = rx.try_recv() {
            batch.push(m);
        }
        for msg in batch {
            match msg {
                ActorMsg::Command { env, reply } => {
                    let seq = env.seq;
                    let now = base_ms + started.elapsed().as_millis() as u64;
                    let r = match session.apply(env, now) {
                        Ok(a) => Reply::Ack(a),
                        Err(error) => Reply::Error {
                            seq: Some(seq),
                            error,
                        },
                    };
                    let _ = reply.send(r);
                }
                ActorMsg::Visible(v) => visible = v,
                ActorMsg::Snapshot(tx) => {
                    let _ = tx.send((session.snapshot(), session.log().to_vec()));
                }
                ActorMsg::Score(tx) => {
                    let _ = tx.send(session.score());
                }
                ActorMsg::Close => return,
            }
        }
        if !session.has_dirty(&visible) {
            continue;
        }
        match session.render_dirty(&visible) {
            Ok(views) => {
                let mut set: BTreeMap<ViewId, Arc<EncodedFrame>> = (**frames.borrow()).clone();
                for v in views {
                    frame_seq += 1;
                    match EncodedFrame::new(v.view, frame_seq, v.input_seq, v.t_ms, &v.image) {
                        Ok(f) => {
                            set.insert(v.view, Arc::new(f));
                        }
                        Err(e) => tracing::error!("frame encoding failed: {e}"),
                    }
                }
                frames.send_replace(Arc::new(set));
            }
            Err(e) => tracing::error!("render failed: {e}"),
        }
    }
}
