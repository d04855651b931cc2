//! The dispatcher: where each live session runs (in-process or on a registered worker), the
//! server's copy of each session, placement, failover and closing (see [`super`]).

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use super::registry::{self, WorkerView};
use render_worker::session::host::RegionReadiness;
use render_worker::session::modalities::fluoro::{FluoroRenderError, FluoroRenderer};
use render_worker::session::region::Region;
use render_worker::session::{
    BackendProfile, Backends, FluoroBackend, HostConfig, HostError, LogEntry, SessionConfig,
    SessionHost, SessionSnapshot,
};
use uuid::Uuid;

/// Where a session runs now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Placement {
    /// On the in-process host, under the host's session id.
    Local {
        /// Id of the session in the host.
        worker_session: String,
    },
    /// On a registered worker.
    Remote {
        /// Worker base URL.
        worker_url: String,
        /// Id of the session on that worker.
        worker_session: String,
    },
}

impl Placement {
    /// `in-process` or the worker URL.
    pub fn worker_label(&self) -> String {
        match self {
            Placement::Local { .. } => "in-process".into(),
            Placement::Remote { worker_url, .. } => worker_url.clone(),
        }
    }
}

/// A live session as the server sees it.
#[derive(Debug)]
pub struct LiveSession {
    /// Server-side session id (stable across failover).
    pub id: Uuid,
    /// The attempt it belongs to.
    pub attempt_id: Uuid,
    /// The course of that attempt (for the per-course limit).
    pub course_id: Uuid,
    /// The learner who drives it.
    pub learner_id: Uuid,
    /// Station id.
    pub station_id: String,
    /// Placement, initial snapshot and the log of acknowledged commands.
    pub state: tokio::sync::Mutex<SessionRecord>,
    /// Increases with every new browser connection; an older connection ends when it sees a
    /// newer one (one driver at a time: a reloaded page takes over).
    pub generation: std::sync::atomic::AtomicU64,
    /// Open browser connections.
    pub connections: std::sync::atomic::AtomicUsize,
    /// When the last connection ended (or the session was created).
    pub last_active: Mutex<std::time::Instant>,
    /// When the browser last sent a command (or the session was created): the idle limit
    /// ([`Dispatcher::session_idle`]) counts from here, connected or not.
    pub last_command: Mutex<std::time::Instant>,
    /// Set when the server ends the session (idle, or its log refused): the close code and
    /// reason its connections close with.
    pub ended: tokio::sync::watch::Sender<Option<(u16, String)>>,
}

impl LiveSession {
    /// A session just created or resumed.
    pub fn new(
        id: Uuid,
        attempt_id: Uuid,
        course_id: Uuid,
        learner_id: Uuid,
        station_id: String,
        record: SessionRecord,
    ) -> LiveSession {
        LiveSession {
            id,
            attempt_id,
            course_id,
            learner_id,
            station_id,
            state: tokio::sync::Mutex::new(record),
            generation: std::sync::atomic::AtomicU64::new(0),
            connections: std::sync::atomic::AtomicUsize::new(0),
            last_active: Mutex::new(std::time::Instant::now()),
            last_command: Mutex::new(std::time::Instant::now()),
            ended: tokio::sync::watch::Sender::new(None),
        }
    }

    /// Notes that the browser sent a command now.
    pub fn touch_command(&self) {
        if let Ok(mut t) = self.last_command.lock() {
            *t = std::time::Instant::now();
        }
    }

    /// Time since the last command.
    pub fn idle_for(&self) -> std::time::Duration {
        self.last_command
            .lock()
            .map(|t| t.elapsed())
            .unwrap_or_default()
    }

    /// Ends the session on the server's side: its connections close with `code` and `reason`
    /// (the first reason given stays).
    pub fn end(&self, code: u16, reason: &str) {
        self.ended.send_if_modified(|e| {
            if e.is_some() {
                return false;
            }
            *e = Some((code, reason.to_string()));
            true
        });
    }

    /// Why the server ended the session, if it did.
    pub fn end_reason(&self) -> Option<(u16, String)> {
        self.ended.borrow().clone()
    }
}

/// Close code when the session's log cannot be stored (RFC 6455: internal error).
pub const CLOSE_LOG_REFUSED: u16 = 1011;
/// Close code when the session was closed for want of commands (application range 4000-4999).
pub const CLOSE_IDLE: u16 = 4001;
/// Close code when the learner's account was revoked (disabled, or its password reset).
pub const CLOSE_REVOKED: u16 = 4003;
/// Close code when another connection (perhaps through another server replica) took the
/// session over and this one's log appends were refused (fenced).
pub const CLOSE_TAKEN_OVER: u16 = 4009;

/// How long a session with no browser connected stays on its worker. Simulator choice: a
/// learner who steps away for a few minutes comes back to a running session; after that the
/// worker's capacity is freed, and opening the attempt again resumes the session from its
/// recorded log. A session without commands closes sooner, at [`Dispatcher::session_idle`]
/// (default [`DEFAULT_SESSION_IDLE`]), whether a browser is connected or not.
pub const IDLE_CLOSE: std::time::Duration = std::time::Duration::from_secs(20 * 60);

/// Default longest time a session stays open without a command, connected or not. Simulator
/// choice: a learner thinking over an image sends no command for a minute or two; ten minutes
/// without one means nobody is driving, and the slot is worth more to someone else (the
/// session resumes from its log when the attempt is opened again).
pub const DEFAULT_SESSION_IDLE: std::time::Duration = std::time::Duration::from_secs(10 * 60);

/// Default most live (unsubmitted) sessions of one course at once. Simulator choice: six of
/// the in-process worker's default eight slots, so one course's lab cannot take the whole
/// worker from the others; a deployment with remote workers raises it.
pub const DEFAULT_SESSIONS_PER_COURSE: usize = 6;

/// Sessions the server's in-process worker hosts at once until the start-up calibration sets
/// its capacity (`PAINSIM_IN_PROCESS_CAPACITY` unset). Simulator choice: a small lab group on the
/// one machine of the embedded default, as a `render-worker`'s default.
pub const DEFAULT_IN_PROCESS_CAPACITY: usize = 8;

/// The server's copy of a session.
#[derive(Debug, Clone)]
pub struct SessionRecord {
    /// Where it runs.
    pub placement: Placement,
    /// Its initial state.
    pub initial: SessionSnapshot,
    /// Every acknowledged command, in order.
    pub log: Vec<LogEntry>,
    /// How many of `log`'s first entries are in `live_session_commands` (see `durable`).
    pub durable_len: usize,
    /// SHA-256 of the newest fluoroscopy frame's JPEG sent to the browser (the image the
    /// replay check re-renders; other views' frames are not recorded).
    pub last_frame_sha256: Option<String>,
    /// Set once the submit was stored.
    pub result_id: Option<Uuid>,
    /// How many times it was restored on another worker.
    pub failovers: u32,
    /// The epoch this replica holds the session at (`live_sessions.epoch` after its takeover):
    /// the log is appended under it, and refused once another connection took the session
    /// over.
    pub epoch: i64,
}

/// Why a session could not be placed.
#[derive(Debug, Clone)]
pub enum PlaceError {
    /// The station's anatomy is still being prepared: ask again after `retry_after_s`.
    Preparing {
        /// Region name.
        region: String,
        /// Its state.
        readiness: RegionReadiness,
        /// Seconds to wait.
        retry_after_s: u64,
    },
    /// The anatomy could not be prepared.
    AnatomyFailed(String),
    /// Every session slot of the in-process worker is taken (and no registered worker took it).
    AtCapacity {
        /// The worker's capacity, sessions.
        capacity: usize,
    },
    /// No worker could take it.
    Failed(String),
}

impl From<HostError> for PlaceError {
    fn from(e: HostError) -> PlaceError {
        match e {
            HostError::Preparing {
                region,
                readiness,
                retry_after_s,
            } => PlaceError::Preparing {
                region,
                readiness,
                retry_after_s,
            },
            HostError::Region(reason) => PlaceError::AnatomyFailed(reason),
            HostError::Full(capacity) => PlaceError::AtCapacity { capacity },
            other => PlaceError::Failed(other.to_string()),
        }
    }
}

/// Why a recorded session could not be restored on any worker.
#[derive(Debug, thiserror::Error)]
pub enum RestoreError {
    /// The in-process restore task did not finish (it panicked or was cancelled).
    #[error(transparent)]
    Task(#[from] tokio::task::JoinError),
    /// The in-process host refused the snapshot and log.
    #[error(transparent)]
    Host(#[from] HostError),
    /// No in-process host, and every registered worker failed (their errors, in turn).
    #[error("no worker could take the session over: {}", registry::joined(.0))]
    NoWorker(Vec<registry::WorkerCallError>),
}

/// Settings of dispatch, read with the rest of the configuration by [`crate::config`] (whose
/// table names each variable). The stations are the learning records' (`PAINSIM_STATIONS_DIR`).
/// Its `Debug` leaves the cluster token out (the configuration may be logged).
#[derive(Clone)]
pub struct DispatchConfig {
    /// Region folders (`PAINSIM_ASSETS_DIR`).
    pub assets_root: std::path::PathBuf,
    /// Sessions the in-process worker takes (`PAINSIM_IN_PROCESS_CAPACITY`; 0: none); `None`:
    /// from the start-up calibration ([`DEFAULT_IN_PROCESS_CAPACITY`] until it is made).
    pub in_process_capacity: Option<usize>,
    /// Token workers present to register (`PAINSIM_WORKER_TOKEN`); `None` refuses
    /// registrations.
    pub worker_token: Option<String>,
    /// Whether the server starts loading (building) the stations' anatomy at start-up
    /// (`PAINSIM_PREPARE_ANATOMY`).
    pub prepare_at_start: bool,
    /// Most live sessions of one user (`PAINSIM_SESSIONS_PER_USER`).
    pub sessions_per_user: usize,
    /// Most live sessions of one course (`PAINSIM_SESSIONS_PER_COURSE`).
    pub sessions_per_course: usize,
    /// Longest time a live session stays open without a command
    /// (`PAINSIM_LIVE_SESSION_IDLE_SECS`).
    pub live_session_idle: std::time::Duration,
    /// This replica's name in the shared state (`PAINSIM_REPLICA_ID`); `None`: host and pid.
    pub replica_id: Option<String>,
}

impl std::fmt::Debug for DispatchConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DispatchConfig")
            .field("assets_root", &self.assets_root)
            .field("in_process_capacity", &self.in_process_capacity)
            .field("worker_token", &self.worker_token.as_ref().map(|_| "<set>"))
            .field("prepare_at_start", &self.prepare_at_start)
            .field("sessions_per_user", &self.sessions_per_user)
            .field("sessions_per_course", &self.sessions_per_course)
            .field("live_session_idle", &self.live_session_idle)
            .field("replica_id", &self.replica_id)
            .finish()
    }
}

/// The in-process worker's renderer: the GPU renderer once the server's GPU is open and passed
/// its self-test (a real adapter or lavapipe), the CPU reference before that, without one, or
/// when the start-up calibration ([`crate::workers::Workers::calibrate_in_background`]) measured
/// the CPU reference faster.
/// A session keeps the renderer it got at its first exposure (or, on the GPU, when its thread
/// prefetched its first view, before any input); a session that began in the first seconds
/// after start-up, before the GPU was ready, may therefore render on the CPU while its record
/// (read at submit) names the GPU.
///
/// The GPU renderers are the worker's ([`crate::workers::Workers::gpu_renderers`]), made once
/// and shared by every session.
struct InProcessBackend {
    workers: crate::workers::Workers,
}

impl InProcessBackend {
    fn new(workers: crate::workers::Workers) -> InProcessBackend {
        InProcessBackend { workers }
    }

    /// The GPU renderers once the worker's GPU is ready, unless the start-up calibration found
    /// the CPU reference faster on this machine.
    fn gpu(&self) -> Option<&crate::workers::GpuRenderers> {
        if self.workers.prefers_cpu() {
            return None;
        }
        self.workers.gpu_renderers()
    }

    pub(super) fn current(&self) -> Arc<dyn FluoroBackend> {
        match self.gpu() {
            Some(r) => Arc::clone(&r.fluoro),
            None => Backends::cpu(0).fluoro,
        }
    }

    fn current_ultrasound(
        &self,
    ) -> Arc<dyn render_worker::session::modalities::ultrasound::UltrasoundBackend> {
        // The calibration times fluoroscopy only; ultrasound keeps its own choice.
        match self.workers.gpu_renderers() {
            Some(r) => Arc::clone(&r.ultrasound),
            None => Backends::cpu(0).ultrasound,
        }
    }
}

impl render_worker::session::modalities::ultrasound::UltrasoundBackend for InProcessBackend {
    fn describe(&self) -> String {
        self.current_ultrasound().describe()
    }

    fn renderer(
        &self,
    ) -> Box<dyn render_worker::session::modalities::ultrasound::UltrasoundRenderer> {
        self.current_ultrasound().renderer()
    }
}

impl FluoroBackend for InProcessBackend {
    fn profile(&self) -> BackendProfile {
        self.current().profile()
    }

    fn renderer(&self, region: &Arc<Region>) -> Result<Box<dyn FluoroRenderer>, FluoroRenderError> {
        self.current().renderer(region)
    }

    fn prefetches(&self) -> bool {
        self.current().prefetches()
    }

    fn finish_background_work(&self) {
        self.current().finish_background_work();
    }

    fn prepare(&self, region: &Arc<Region>) -> Result<bool, FluoroRenderError> {
        self.current().prepare(region)
    }
}

pub(super) struct Inner {
    pub(super) local: Option<SessionHost>,
    pub(super) replay: SessionHost,
    pub(super) remote: registry::Registry,
    pub(super) sessions: Mutex<HashMap<Uuid, Arc<LiveSession>>>,
    pub(super) worker_token: Option<String>,
    pub(super) sessions_per_user: std::sync::atomic::AtomicUsize,
    pub(super) sessions_per_course: std::sync::atomic::AtomicUsize,
    /// [`Dispatcher::session_idle`], ms.
    pub(super) session_idle_ms: std::sync::atomic::AtomicU64,
    /// Wakes the reapers when the idle limit changes.
    pub(super) reaper_wake: Arc<tokio::sync::Notify>,
    /// The learning records, for audit entries of sessions the server ends.
    pub(super) records: Mutex<Option<crate::records::RecordsState>>,
    /// This replica's name in the shared state.
    pub(super) replica: Mutex<String>,
    /// One lock per session that this replica is loading and restoring from the database, so
    /// that two connections to the same stored session restore it once (different sessions
    /// restore at the same time).
    pub(super) adopting: Mutex<HashMap<Uuid, Arc<tokio::sync::Mutex<()>>>>,
}

/// Default most live (unsubmitted) sessions one user holds at once. Simulator choice: a learner
/// works one attempt at a time; two leaves room for a second tab or a resumed attempt while no
/// single learner can fill an in-process worker (capacity 8).
pub const DEFAULT_SESSIONS_PER_USER: usize = 2;

/// Session dispatch: the in-process host, registered workers, and the live sessions.
#[derive(Clone)]
pub struct Dispatcher {
    pub(super) inner: Arc<Inner>,
}

impl std::fmt::Debug for Dispatcher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dispatcher")
            .field("in_process", &self.inner.local.is_some())
            .finish()
    }
}

impl Dispatcher {
    /// A dispatcher over an in-process host (`local`, `None` for remote-only), a host used for
    /// replays, and the cluster token, with the default limits ([`Dispatcher::from_config`]
    /// applies the configured ones).
    pub fn new(
        local: Option<SessionHost>,
        replay: SessionHost,
        worker_token: Option<String>,
    ) -> Dispatcher {
        let d = Dispatcher {
            inner: Arc::new(Inner {
                local,
                replay,
                remote: registry::Registry::default(),
                sessions: Mutex::new(HashMap::new()),
                worker_token,
                sessions_per_user: std::sync::atomic::AtomicUsize::new(DEFAULT_SESSIONS_PER_USER),
                sessions_per_course: std::sync::atomic::AtomicUsize::new(
                    DEFAULT_SESSIONS_PER_COURSE,
                ),
                session_idle_ms: std::sync::atomic::AtomicU64::new(
                    DEFAULT_SESSION_IDLE.as_millis() as u64,
                ),
                reaper_wake: Arc::new(tokio::sync::Notify::new()),
                records: Mutex::new(None),
                replica: Mutex::new(super::cluster::default_replica_id()),
                adopting: Mutex::new(HashMap::new()),
            }),
        };
        d.start_reaper(IDLE_CLOSE);
        d
    }

    /// Closes, every quarter of the shorter limit, the sessions no browser has been connected
    /// to for `idle`, and the sessions that got no command for [`Dispatcher::session_idle`]
    /// (connected or not: their browsers get close code [`CLOSE_IDLE`], and the
    /// closing is audited).
    pub fn start_reaper(&self, idle: std::time::Duration) {
        let Ok(rt) = tokio::runtime::Handle::try_current() else {
            return;
        };
        let weak = Arc::downgrade(&self.inner);
        let wake = self.inner.reaper_wake.clone();
        rt.spawn(async move {
            loop {
                // Holds the dispatcher only while reaping, so a dropped one ends the task.
                let period = match weak.upgrade() {
                    Some(inner) => Dispatcher { inner }.session_idle().min(idle) / 4,
                    None => return,
                };
                tokio::select! {
                    () = tokio::time::sleep(period.max(std::time::Duration::from_millis(20))) => {}
                    () = wake.notified() => {}
                }
                let Some(inner) = weak.upgrade() else { return };
                Dispatcher { inner }.reap(idle).await;
            }
        });
    }

    /// One round of [`Dispatcher::start_reaper`].
    async fn reap(&self, idle: std::time::Duration) {
        let command_idle = self.session_idle();
        for s in self.all_sessions() {
            let connected = s.connections.load(std::sync::atomic::Ordering::SeqCst);
            // A copy that another replica took over (nobody connected here) frees its worker
            // slot now rather than at its idle limit.
            if connected == 0 && matches!(self.unless_stale(s.clone()).await, Ok(None)) {
                tracing::info!(session = %s.id, "forgot a session that another replica holds now");
                continue;
            }
            if s.idle_for() >= command_idle {
                let secs = command_idle.as_secs_f64();
                tracing::info!(session = %s.id, connected, "closing a session that got no command for {secs} s (it resumes from its log)");
                s.end(
                    CLOSE_IDLE,
                    &format!("idle: no command for {secs} s; open the attempt again to resume"),
                );
                let Some(records) = self.records() else {
                    self.close(s.id).await;
                    continue;
                };
                let detail = serde_json::json!({ "attempt_id": s.attempt_id, "idle_s": secs, "connected": connected });
                self.end_session(&records, s.id, "session_closed_idle", detail)
                    .await;
            } else if connected == 0 && s.last_active.lock().is_ok_and(|t| t.elapsed() >= idle) {
                tracing::info!(session = %s.id, "closing an idle session (it resumes from its log)");
                self.close(s.id).await;
            }
        }
    }

    /// Most time a session stays open without a command (`PAINSIM_LIVE_SESSION_IDLE_SECS`).
    pub fn session_idle(&self) -> std::time::Duration {
        std::time::Duration::from_millis(
            self.inner
                .session_idle_ms
                .load(std::sync::atomic::Ordering::Relaxed),
        )
    }

    /// Sets the idle limit instead of `PAINSIM_LIVE_SESSION_IDLE_SECS` (tests use a short one).
    pub fn set_session_idle(&self, idle: std::time::Duration) {
        self.inner.session_idle_ms.store(
            (idle.as_millis() as u64).max(1),
            std::sync::atomic::Ordering::Relaxed,
        );
        self.inner.reaper_wake.notify_waiters();
    }

    /// The learning records the sessions' audit entries go to (set by the dispatch routes).
    pub(super) fn records(&self) -> Option<crate::records::RecordsState> {
        self.inner.records.lock().ok().and_then(|r| r.clone())
    }

    /// Attaches the learning records: their database is the shared state (registered workers,
    /// placements), swept by this replica from now on.
    pub(super) fn attach_records(&self, records: &crate::records::RecordsState) {
        let first = match self.inner.records.lock() {
            Ok(mut r) => {
                let first = r.is_none();
                *r = Some(records.clone());
                first
            }
            Err(_) => false,
        };
        if first {
            self.inner.remote.attach(&records.pool);
            let weak = Arc::downgrade(&self.inner);
            super::cluster::start_sweeper(
                records.pool.clone(),
                self.inner.remote.clone(),
                self.replica(),
                move || weak.upgrade().map(|inner| Dispatcher { inner }.held()),
            );
        }
    }

    /// Ends a session the server gave up on (the caller set its end reason): writes the audit
    /// entry `action` with `detail` (once, by whoever removes the session), then frees its
    /// worker slot.
    pub async fn end_session(
        &self,
        records: &crate::records::RecordsState,
        id: Uuid,
        action: &str,
        detail: serde_json::Value,
    ) {
        let Some(s) = self.take(id) else {
            return;
        };
        let r = crate::records::history::audit(
            &records.pool,
            None,
            action,
            "live_session",
            &id.to_string(),
            detail,
        )
        .await;
        if let Err(e) = r {
            tracing::error!(session = %id, "writing the audit entry {action} failed: {e}");
        }
        self.close_taken(&s).await;
    }

    /// The default: an in-process host over the stations of `stations_dir` and `config`'s
    /// regions (regions load on first use) rendering with `backends`, with `config`'s limits.
    pub fn from_config(
        config: &DispatchConfig,
        stations_dir: &std::path::Path,
        backends: Backends,
    ) -> Result<Dispatcher, HostError> {
        let host = SessionHost::new(
            HostConfig {
                assets_root: config.assets_root.clone(),
                stations_dir: stations_dir.to_path_buf(),
                capacity: config
                    .in_process_capacity
                    .unwrap_or(DEFAULT_IN_PROCESS_CAPACITY),
                session: SessionConfig::default(),
            },
            backends,
            None,
        )?;
        let d = Dispatcher::new(Some(host.clone()), host, config.worker_token.clone());
        d.apply_limits(config);
        Ok(d)
    }

    /// Sets the per-user, per-course and idle limits of `config`, and the replica's name.
    fn apply_limits(&self, config: &DispatchConfig) {
        if let Some(id) = &config.replica_id {
            self.set_replica(id);
        }
        self.set_sessions_per_user(config.sessions_per_user);
        self.set_sessions_per_course(config.sessions_per_course);
        self.set_session_idle(config.live_session_idle);
    }

    /// The dispatcher of [`crate::app`]: `state.dispatcher` when set, else the default
    /// from `config` over the stations of `stations_dir`. A station folder that does not load
    /// leaves an in-process host without stations (start-up reports the folder).
    pub fn for_app(
        attached: Option<&Dispatcher>,
        workers: &crate::workers::Workers,
        config: &DispatchConfig,
        stations_dir: &std::path::Path,
    ) -> Dispatcher {
        if let Some(d) = attached {
            return d.clone();
        }
        let in_process = Arc::new(InProcessBackend::new(workers.clone()));
        let backends = Backends::new(in_process.clone(), in_process);
        Dispatcher::from_config(config, stations_dir, backends).unwrap_or_else(|e| {
            tracing::error!("no in-process sessions: {e}");
            let empty = SessionHost::with_regions(
                Vec::new(),
                Vec::new(),
                Backends::cpu(0),
                0,
                SessionConfig::default(),
            );
            let d = Dispatcher::new(None, empty, config.worker_token.clone());
            d.apply_limits(config);
            d
        })
    }

    /// The in-process host, if any.
    pub fn local_host(&self) -> Option<&SessionHost> {
        self.inner.local.as_ref()
    }

    /// Registered workers as reported by `GET /api/workers`, from the shared state.
    pub async fn workers(&self) -> Result<Vec<WorkerView>, sqlx::Error> {
        self.inner.remote.views().await
    }

    /// The registered workers in the shared state.
    pub fn registry(&self) -> &registry::Registry {
        &self.inner.remote
    }

    /// Every live session this replica holds.
    pub(super) fn all_sessions(&self) -> Vec<Arc<LiveSession>> {
        self.inner
            .sessions
            .lock()
            .map(|m| m.values().cloned().collect())
            .unwrap_or_default()
    }

    /// A live session by id.
    pub fn session(&self, id: Uuid) -> Option<Arc<LiveSession>> {
        self.inner.sessions.lock().ok()?.get(&id).cloned()
    }

    /// The live, not yet submitted session of an attempt, if one exists.
    pub async fn session_of_attempt(&self, attempt_id: Uuid) -> Option<Arc<LiveSession>> {
        let list: Vec<Arc<LiveSession>> = self
            .inner
            .sessions
            .lock()
            .ok()?
            .values()
            .filter(|s| s.attempt_id == attempt_id)
            .cloned()
            .collect();
        for s in list {
            if s.state.lock().await.result_id.is_none() {
                return Some(s);
            }
        }
        None
    }

    /// Whether a session of `station_id` can start (or resume) on the in-process worker now.
    /// Only asked when that is where it would go: with a live registered worker it is placed
    /// there. Starts preparing the station's region in the background if nobody has.
    pub(super) async fn check_local_ready(&self, station_id: &str) -> Result<(), PlaceError> {
        let Some(host) = &self.inner.local else {
            return Ok(());
        };
        if !self.inner.remote.by_load(None).await.is_empty() {
            return Ok(());
        }
        host.check_ready(station_id).map_err(PlaceError::from)
    }

    /// Starts loading (building, for the phantom) the in-process worker's regions in the
    /// background (see [`SessionHost::prepare_in_background`]).
    pub fn prepare_in_background(&self) {
        if let Some(h) = &self.inner.local {
            h.prepare_in_background();
        }
    }

    /// Most live sessions one user may hold.
    pub fn sessions_per_user(&self) -> usize {
        self.inner
            .sessions_per_user
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Sets the per-user limit (at least 1), instead of `PAINSIM_SESSIONS_PER_USER`: for the
    /// load bench, whose simulated learners share one account.
    pub fn set_sessions_per_user(&self, limit: usize) {
        self.inner
            .sessions_per_user
            .store(limit.max(1), std::sync::atomic::Ordering::Relaxed);
    }

    /// Most live sessions of one course.
    pub fn sessions_per_course(&self) -> usize {
        self.inner
            .sessions_per_course
            .load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Sets the per-course limit (at least 1), instead of `PAINSIM_SESSIONS_PER_COURSE`.
    pub fn set_sessions_per_course(&self, limit: usize) {
        self.inner
            .sessions_per_course
            .store(limit.max(1), std::sync::atomic::Ordering::Relaxed);
    }

    /// Live (not submitted) sessions of `user`.
    pub async fn live_sessions_of(&self, user: Uuid) -> usize {
        self.live_sessions_where(|s| s.learner_id == user).await
    }

    /// Live (not submitted) sessions of attempts in `course`.
    pub async fn live_sessions_of_course(&self, course: Uuid) -> usize {
        self.live_sessions_where(|s| s.course_id == course).await
    }

    async fn live_sessions_where(&self, keep: impl Fn(&LiveSession) -> bool) -> usize {
        let list: Vec<Arc<LiveSession>> = self
            .inner
            .sessions
            .lock()
            .map(|m| m.values().filter(|s| keep(s)).cloned().collect())
            .unwrap_or_default();
        let mut n = 0;
        for s in list {
            if s.state.lock().await.result_id.is_none() {
                n += 1;
            }
        }
        n
    }

    /// Sessions the in-process worker holds and could hold (`None` without one).
    pub fn local_capacity(&self) -> Option<(usize, usize)> {
        self.inner.local.as_ref().map(|h| {
            let health = h.health();
            (health.sessions, health.capacity)
        })
    }

    /// Readiness of the in-process worker's regions (empty without one).
    pub fn anatomy(&self) -> std::collections::BTreeMap<String, RegionReadiness> {
        self.inner
            .local
            .as_ref()
            .map(SessionHost::regions_readiness)
            .unwrap_or_default()
    }

    /// Creates a session for a station on the least loaded worker (excluding `avoid`), returning
    /// its placement and initial snapshot.
    pub(super) async fn place_new(
        &self,
        station_id: &str,
    ) -> Result<(Placement, SessionSnapshot), PlaceError> {
        let mut errors = Vec::new();
        for url in self.inner.remote.by_load(None).await {
            match registry::create_remote(&url, station_id).await {
                Ok((worker_session, snapshot)) => {
                    return Ok((
                        Placement::Remote {
                            worker_url: url,
                            worker_session,
                        },
                        snapshot,
                    ));
                }
                Err(e) => {
                    tracing::warn!(worker = %url, "session creation failed: {e}");
                    errors.push(e);
                }
            }
        }
        let Some(host) = &self.inner.local else {
            return Err(PlaceError::Failed(if errors.is_empty() {
                "no render worker is registered".into()
            } else {
                registry::joined(&errors)
            }));
        };
        let h = host.create(station_id).await?;
        let (snapshot, _) = h
            .snapshot()
            .await
            .ok_or_else(|| PlaceError::Failed("the new session ended at once".into()))?;
        Ok((
            Placement::Local {
                worker_session: h.info.id.clone(),
            },
            snapshot,
        ))
    }

    /// Restores a recorded session on a live registered worker by least load, else in-process.
    pub(super) async fn restore_anywhere(
        &self,
        record: &SessionRecord,
    ) -> Result<Placement, RestoreError> {
        let nowhere = Placement::Local {
            worker_session: String::new(),
        };
        self.restore_elsewhere(&nowhere, record).await
    }

    /// Restores `record`'s session on a worker other than the failed one: a live registered
    /// worker by least load, else the in-process host.
    pub(super) async fn restore_elsewhere(
        &self,
        failed: &Placement,
        record: &SessionRecord,
    ) -> Result<Placement, RestoreError> {
        if let Placement::Remote { worker_url, .. } = failed {
            self.inner
                .remote
                .mark_dead(worker_url, &self.replica())
                .await;
        }
        let avoid = match failed {
            Placement::Remote { worker_url, .. } => Some(worker_url.as_str()),
            Placement::Local { .. } => None,
        };
        let mut errors = Vec::new();
        for url in self.inner.remote.by_load(avoid).await {
            match registry::restore_remote(&url, &record.initial, &record.log).await {
                Ok(worker_session) => {
                    return Ok(Placement::Remote {
                        worker_url: url,
                        worker_session,
                    });
                }
                Err(e) => errors.push(e),
            }
        }
        if let Some(host) = &self.inner.local {
            let (h, initial, log) = (host.clone(), record.initial.clone(), record.log.clone());
            let handle =
                tokio::task::spawn_blocking(move || h.restore_blocking(&initial, &log)).await??;
            return Ok(Placement::Local {
                worker_session: handle.info.id.clone(),
            });
        }
        Err(RestoreError::NoWorker(errors))
    }

    pub(super) fn insert(&self, s: Arc<LiveSession>) {
        if let Ok(mut m) = self.inner.sessions.lock() {
            m.insert(s.id, s);
        }
    }

    /// Ends a session on its worker and forgets it; false when it was not held (any more).
    pub async fn close(&self, id: Uuid) -> bool {
        let Some(s) = self.take(id) else {
            return false;
        };
        self.close_taken(&s).await;
        true
    }

    /// Forgets `s` if it is the copy this replica holds under its id; false otherwise.
    pub(super) fn take_exact(&self, s: &Arc<LiveSession>) -> bool {
        let Ok(mut m) = self.inner.sessions.lock() else {
            return false;
        };
        if m.get(&s.id).is_some_and(|held| Arc::ptr_eq(held, s)) {
            m.remove(&s.id);
            return true;
        }
        false
    }

    /// Forgets a session (whoever takes it ends it).
    pub(super) fn take(&self, id: Uuid) -> Option<Arc<LiveSession>> {
        self.inner.sessions.lock().ok()?.remove(&id)
    }

    /// Ends a session taken from the map on its worker, and removes its placement.
    async fn close_taken(&self, s: &LiveSession) {
        let (placement, epoch) = {
            let st = s.state.lock().await;
            (st.placement.clone(), st.epoch)
        };
        if let Some(pool) = self.pool()
            && let Err(e) = super::cluster::release(&pool, s.id, epoch).await
        {
            tracing::error!(session = %s.id, "removing the session's placement failed: {e}");
        }
        self.end_on_worker(placement).await;
    }

    /// Ends a session on the worker it was placed on.
    pub(super) async fn end_on_worker(&self, placement: Placement) {
        match placement {
            Placement::Local { worker_session } => {
                if let Some(h) = &self.inner.local {
                    let _ = h.close(&worker_session);
                }
            }
            Placement::Remote {
                worker_url,
                worker_session,
            } => {
                let _ = render_worker::cluster::request(
                    "DELETE",
                    &format!("{worker_url}/sessions/{worker_session}"),
                    None,
                    None,
                )
                .await;
            }
        }
    }
}
