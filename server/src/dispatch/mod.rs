//! Dispatch of live simulation sessions to render workers, and the browser's websocket.
//!
//! # Where sessions run
//! A session runs on the in-process worker (a [`SessionHost`] inside the server, the embedded
//! default), or on a separate `render-worker` process that registered itself at
//! `POST /api/workers` with the cluster token (`PAINSIM_WORKER_TOKEN`). New sessions go to the
//! registered worker with the least load (sessions placed there over its capacity); without a
//! live registered worker they stay in-process. The server polls each worker's `/healthz`.
//!
//! # The browser's websocket goes through the server
//! `GET /api/sessions/{id}/ws` is authenticated by the session cookie and only the attempt's
//! learner may drive it. The server relays the session protocol
//! (`render_worker::session::protocol`) to the worker and watches it: every acknowledged command
//! is appended to the server's own copy of the session log, in memory and in
//! `live_session_commands` (committed before the acknowledgement is passed on, so a server that
//! dies loses nothing the browser saw acknowledged: see `durable`), engagement events go to the
//! learning records, and the submit's result is stored as the
//! attempt's technical result, then sent to the browser as `{"type":"technical_result", ...}`.
//!
//! # Limits and endings
//! A user holds at most `PAINSIM_SESSIONS_PER_USER` live sessions and a course's attempts at
//! most `PAINSIM_SESSIONS_PER_COURSE` (429 `session_limit`, `scope` naming which). The server
//! ends a session itself, with a close code and reason on its sockets and an audit entry, when it
//! got no command for `PAINSIM_LIVE_SESSION_IDLE_SECS` (code [`CLOSE_IDLE`], 4001; audit
//! `session_closed_idle`) or when the database refuses its log for good (code
//! [`CLOSE_LOG_REFUSED`], 1011; audit `session_ended_log_refused`), or when the learner's
//! account is revoked (code [`CLOSE_REVOKED`], 4003); in each case the slot is freed and opening
//! the attempt again resumes from the stored log.
//!
//! # Failover
//! Because the server holds the initial snapshot and every acknowledged command, it can rebuild
//! a session anywhere: when a remote worker's socket fails, the session is restored on another
//! worker from snapshot + log and the commands the browser sent that were not yet acknowledged
//! are sent again. Commands are never applied twice (the worker acknowledges a re-sent sequence
//! number as a duplicate) and never lost (the browser's socket stays open throughout).
//!
//! # Replay
//! `GET /api/attempts/{id}/replay` gives faculty of the course (and the learner) the recorded
//! log; `.../replay/frame?step=k` renders the image on screen after the first `k` commands, by
//! restoring the session from its initial snapshot and that prefix of the log. The full replay
//! is checked against the stored result: same measurements, score, outcome, final state hash and
//! final frame. `verify` runs that check in the background for every stored result and appends
//! its verdict to the records (`result_replay_checks`), so faculty see it in the queue, the
//! review screen and the CSV export.

mod browser;
mod cluster;
mod debrief;
mod disclosure;
mod dispatcher;
mod durable;
mod notices;
mod recorded;
mod registry;
mod relay;
mod replica;
mod results;
mod revoke;
mod route_state;
mod routes;
mod store;
mod takeover;
mod upstream;
mod verify;
mod worker_routes;

pub use cluster::{ClusterStatus, WorkerCounts};
pub use dispatcher::*;
pub use registry::{
    DEAD_AFTER, Heartbeat, PLACEMENT_STALE_AFTER, Registry, WorkerCallError, WorkerView,
};
pub use relay::{MAX_CLIENT_MESSAGE_BYTES, MAX_IN_FLIGHT, MAX_UNREAD_ANSWERS};
pub use routes::{DispatchApi, openapi, router};
pub use takeover::TakeoverError;
