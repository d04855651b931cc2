//! Registered render workers: registration, health polling, least-load choice, and the calls
//! that create and restore sessions on them.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use render_worker::cluster::{HttpError, HttpResponse, Registration, request};
use render_worker::session::{LogEntry, SessionSnapshot};
use serde::Serialize;

/// How often the server polls each worker's health. Simulator choice: a dead worker is noticed
/// within a second even when none of its sessions is sending (a session that is sending notices
/// at once, through its socket).
pub const POLL_INTERVAL: Duration = Duration::from_secs(1);

/// A worker that registered.
#[derive(Debug, Clone)]
pub struct RemoteWorker {
    /// What it announced.
    pub registration: Registration,
    /// Whether its last health check (or socket) succeeded.
    pub alive: bool,
    /// Last successful health check or registration.
    pub last_seen: Instant,
    /// Sessions it reported in its last health check.
    pub reported_sessions: Option<usize>,
}

/// A worker as listed by `GET /api/workers`.
#[derive(Debug, Clone, Serialize)]
pub struct WorkerView {
    /// Base URL.
    pub url: String,
    /// `alive` or `dead`.
    pub state: &'static str,
    /// Capacity.
    pub capacity: usize,
    /// Sessions the server placed there.
    pub sessions: usize,
    /// sessions / capacity.
    pub load: f64,
    /// `gpu` when an adapter is reported, else `software`.
    pub adapter_kind: &'static str,
    /// The adapter as reported.
    pub adapter: Option<serde_json::Value>,
    /// The renderer as reported.
    pub renderer: serde_json::Value,
    /// Seconds since it was last seen.
    pub last_seen_s: f64,
}

/// The registered workers.
#[derive(Debug, Clone, Default)]
pub struct Registry {
    workers: Arc<Mutex<Vec<RemoteWorker>>>,
}

impl Registry {
    /// Adds or refreshes a worker (by URL).
    pub fn register(&self, registration: Registration) {
        let Ok(mut w) = self.workers.lock() else {
            return;
        };
        match w
            .iter_mut()
            .find(|x| x.registration.url == registration.url)
        {
            Some(x) => {
                x.registration = registration;
                x.alive = true;
                x.last_seen = Instant::now();
            }
            None => {
                tracing::info!(worker = %registration.url, capacity = registration.capacity, "render worker registered");
                w.push(RemoteWorker {
                    registration,
                    alive: true,
                    last_seen: Instant::now(),
                    reported_sessions: None,
                });
            }
        }
    }

    /// Marks a worker dead (its socket failed); the poller revives it when it answers again.
    pub fn mark_dead(&self, url: &str) {
        if let Ok(mut w) = self.workers.lock()
            && let Some(x) = w.iter_mut().find(|x| x.registration.url == url)
            && x.alive
        {
            tracing::warn!(worker = %url, "render worker marked dead");
            x.alive = false;
        }
    }

    /// URLs of live workers with room, least loaded first (`placed` counts the sessions the
    /// server placed on each; the worker's own report is used when it is higher).
    pub fn by_load(&self, placed: &HashMap<String, usize>, avoid: Option<&str>) -> Vec<String> {
        let Ok(w) = self.workers.lock() else {
            return Vec::new();
        };
        let mut list: Vec<(f64, String)> = w
            .iter()
            .filter(|x| x.alive && Some(x.registration.url.as_str()) != avoid)
            .filter_map(|x| {
                let n = placed
                    .get(&x.registration.url)
                    .copied()
                    .unwrap_or(0)
                    .max(x.reported_sessions.unwrap_or(0));
                let cap = x.registration.capacity.max(1);
                (n < cap).then(|| (n as f64 / cap as f64, x.registration.url.clone()))
            })
            .collect();
        list.sort_by(|a, b| a.0.total_cmp(&b.0).then_with(|| a.1.cmp(&b.1)));
        list.into_iter().map(|(_, u)| u).collect()
    }

    /// The listing.
    pub fn views(&self, placed: &HashMap<String, usize>) -> Vec<WorkerView> {
        let Ok(w) = self.workers.lock() else {
            return Vec::new();
        };
        w.iter()
            .map(|x| {
                let n = placed.get(&x.registration.url).copied().unwrap_or(0);
                WorkerView {
                    url: x.registration.url.clone(),
                    state: if x.alive { "alive" } else { "dead" },
                    capacity: x.registration.capacity,
                    sessions: n,
                    load: n as f64 / x.registration.capacity.max(1) as f64,
                    adapter_kind: if x.registration.adapter.is_some() {
                        "gpu"
                    } else {
                        "software"
                    },
                    adapter: x.registration.adapter.clone(),
                    renderer: x.registration.renderer.clone(),
                    last_seen_s: x.last_seen.elapsed().as_secs_f64(),
                }
            })
            .collect()
    }

    /// Polls every worker's `/healthz` every [`POLL_INTERVAL`] (needs a tokio runtime; without
    /// one, as in plain unit tests, workers are only marked by their sockets).
    pub fn start_polling(&self) {
        let Ok(rt) = tokio::runtime::Handle::try_current() else {
            return;
        };
        let weak = Arc::downgrade(&self.workers);
        rt.spawn(async move {
            loop {
                tokio::time::sleep(POLL_INTERVAL).await;
                let Some(workers) = weak.upgrade() else { return };
                let urls: Vec<String> = workers.lock().map(|w| w.iter().map(|x| x.registration.url.clone()).collect()).unwrap_or_default();
                drop(workers);
                for url in urls {
                    let r = tokio::time::timeout(POLL_INTERVAL, request("GET", &format!("{url}/healthz"), None, None)).await;
                    let health = match r {
                        Ok(Ok(r)) if r.status == 200 => r.json().ok(),
                        _ => None,
                    };
                    let Some(workers) = weak.upgrade() else { return };
                    let Ok(mut w) = workers.lock() else { return };
                    if let Some(x) = w.iter_mut().find(|x| x.registration.url == url) {
                        match health {
                            Some(h) => {
                                if !x.alive {
                                    tracing::info!(worker = %url, "render worker answers again");
                                }
                                x.alive = true;
                                x.last_seen = Instant::now();
                                x.reported_sessions = h.get("sessions").and_then(|s| s.as_u64()).map(|s| s as usize);
                            }
                            None => {
                                if x.alive {
                                    tracing::warn!(worker = %url, "render worker health check failed");
                                }
                                x.alive = false;
                            }
                        }
                    }
                }
            }
        });
    }
}

/// Why a call that creates or restores a session on a registered worker failed.
#[derive(Debug, thiserror::Error)]
pub enum WorkerCallError {
    /// The request got no usable answer.
    #[error(transparent)]
    Http(#[from] HttpError),
    /// The worker answered with another status than the call expects.
    #[error("{call}: worker answered {status}: {body}")]
    Status {
        /// The call (`create`, `snapshot`, `restore`).
        call: &'static str,
        /// The HTTP status.
        status: u16,
        /// The answer's body, as text.
        body: String,
    },
    /// The answer lacks the new session's id.
    #[error("{0}: no session id in the answer")]
    NoSessionId(&'static str),
    /// The snapshot in the answer does not parse.
    #[error("snapshot: {0}")]
    Snapshot(#[source] serde_json::Error),
}

/// The errors of several workers tried in turn, in words, separated by `; `.
pub fn joined(errors: &[WorkerCallError]) -> String {
    errors
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

fn worker_error(call: &'static str, r: &HttpResponse) -> WorkerCallError {
    WorkerCallError::Status {
        call,
        status: r.status,
        body: String::from_utf8_lossy(&r.body).into_owned(),
    }
}

/// Creates a session on a worker; returns its id there and its initial snapshot.
pub async fn create_remote(
    url: &str,
    station_id: &str,
) -> Result<(String, SessionSnapshot), WorkerCallError> {
    let r = request(
        "POST",
        &format!("{url}/sessions"),
        Some(&serde_json::json!({ "station_id": station_id })),
        None,
    )
    .await?;
    if r.status != 201 {
        return Err(worker_error("create", &r));
    }
    let id = r.json()?["session"]["id"]
        .as_str()
        .ok_or(WorkerCallError::NoSessionId("create"))?
        .to_string();
    let r = request("GET", &format!("{url}/sessions/{id}/snapshot"), None, None).await?;
    if r.status != 200 {
        return Err(worker_error("snapshot", &r));
    }
    let snapshot: SessionSnapshot =
        serde_json::from_value(r.json()?["snapshot"].clone()).map_err(WorkerCallError::Snapshot)?;
    Ok((id, snapshot))
}

/// Restores a session on a worker from its initial snapshot and log; returns its id there.
pub async fn restore_remote(
    url: &str,
    snapshot: &SessionSnapshot,
    log: &[LogEntry],
) -> Result<String, WorkerCallError> {
    let body = serde_json::json!({ "snapshot": snapshot, "log": log });
    let r = request(
        "POST",
        &format!("{url}/sessions/restore"),
        Some(&body),
        None,
    )
    .await?;
    if r.status != 201 {
        return Err(worker_error("restore", &r));
    }
    Ok(r.json()?["session"]["id"]
        .as_str()
        .ok_or(WorkerCallError::NoSessionId("restore"))?
        .to_string())
}
