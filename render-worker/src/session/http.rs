//! The worker's HTTP and websocket surface (used by the `render-worker` binary, tests and
//! benches; the server can mount the same router or call [`SessionHost`] directly).
//!
//! - `GET /healthz`: [`super::host::Health`] (renderer, adapter, capacity, sessions, load):
//!   the process answers (liveness).
//! - `GET /readyz`: 200 when the worker can take sessions at all, 503 while it drains before
//!   exiting (readiness: never "has free capacity", so an orchestrator removes a draining or
//!   broken worker first, never a merely busy one).
//! - `POST /sessions` with `{"station_id": "..."}`: 201 and `{"session": SessionInfo, "ws":
//!   "/sessions/{id}/ws"}`; 404 unknown station, 503 at capacity, 503 with `Retry-After` while
//!   the station's anatomy is being prepared (code `anatomy_preparing`).
//! - `POST /sessions/restore` with `{"snapshot": .., "log": [..]}`: resumes a session handed
//!   over from another worker; 201 as above.
//! - `GET /sessions/{id}/snapshot`: `{"snapshot": .., "log": [..]}`.
//! - `DELETE /sessions/{id}`: 204.
//! - `GET /sessions/{id}/ws`: the websocket of [`super::protocol`].

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use futures::{SinkExt, StreamExt};
use serde::Deserialize;

use super::command::LogEntry;
use super::host::{HostError, SessionHandle, SessionHost};
use super::machine::SessionSnapshot;
use super::protocol::{WsMessage, serve_connection};

/// The router over a host.
pub fn router(host: SessionHost) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/sessions", post(create))
        .route("/sessions/restore", post(restore))
        .route("/sessions/{id}/snapshot", get(snapshot))
        .route("/sessions/{id}", axum::routing::delete(close))
        .route("/sessions/{id}/ws", get(ws))
        .with_state(host)
}

#[derive(Deserialize)]
struct CreateBody {
    station_id: String,
}

#[derive(Deserialize)]
struct RestoreBody {
    snapshot: SessionSnapshot,
    log: Vec<LogEntry>,
}

fn error(e: &HostError) -> Response {
    if let HostError::Preparing {
        readiness,
        retry_after_s,
        ..
    } = e
    {
        let body = serde_json::json!({ "error": { "code": "anatomy_preparing", "message": e.to_string(), "retry_after_s": retry_after_s, "readiness": readiness } });
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            [(axum::http::header::RETRY_AFTER, retry_after_s.to_string())],
            Json(body),
        )
            .into_response();
    }
    let (status, code) = match e {
        HostError::UnknownStation(_) | HostError::NoSession(_) => {
            (StatusCode::NOT_FOUND, "not_found")
        }
        HostError::Full(_) => (StatusCode::SERVICE_UNAVAILABLE, "at_capacity"),
        HostError::Draining => (StatusCode::SERVICE_UNAVAILABLE, "draining"),
        HostError::Restore(_) => (StatusCode::UNPROCESSABLE_ENTITY, "restore_failed"),
        HostError::Region(_) | HostError::Stations(_) => {
            (StatusCode::INTERNAL_SERVER_ERROR, "internal")
        }
        HostError::Preparing { .. } => (StatusCode::SERVICE_UNAVAILABLE, "anatomy_preparing"),
    };
    (
        status,
        Json(serde_json::json!({ "error": { "code": code, "message": e.to_string() } })),
    )
        .into_response()
}

fn created(h: &SessionHandle) -> Response {
    let ws = format!("/sessions/{}/ws", h.info.id);
    (
        StatusCode::CREATED,
        Json(serde_json::json!({ "session": h.info, "ws": ws })),
    )
        .into_response()
}

async fn healthz(State(host): State<SessionHost>) -> Response {
    Json(host.health()).into_response()
}

/// 200 when the worker can take sessions at all (its stations' anatomy is loaded and it is not
/// draining), 503 otherwise; the body says which.
async fn readyz(State(host): State<SessionHost>) -> Response {
    let regions = host.regions_readiness();
    let anatomy_ready = regions
        .values()
        .all(|r| matches!(r, super::host::RegionReadiness::Ready { .. }));
    let draining = host.is_draining();
    let ready = anatomy_ready && !draining && !host.station_ids().is_empty();
    let status = if ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    let body =
        serde_json::json!({ "ready": ready, "draining": draining, "anatomy_ready": anatomy_ready });
    (status, Json(body)).into_response()
}

async fn create(State(host): State<SessionHost>, Json(body): Json<CreateBody>) -> Response {
    match host.create(&body.station_id).await {
        Ok(h) => created(&h),
        Err(e) => error(&e),
    }
}

async fn restore(State(host): State<SessionHost>, Json(body): Json<RestoreBody>) -> Response {
    let h = host.clone();
    let r =
        tokio::task::spawn_blocking(move || h.restore_blocking(&body.snapshot, &body.log)).await;
    match r {
        Ok(Ok(h)) => created(&h),
        Ok(Err(e)) => error(&e),
        Err(e) => error(&HostError::Restore(e.to_string())),
    }
}

async fn snapshot(State(host): State<SessionHost>, Path(id): Path<String>) -> Response {
    let Some(h) = host.session(&id) else {
        return error(&HostError::NoSession(id));
    };
    match h.snapshot().await {
        Some((snapshot, log)) => {
            Json(serde_json::json!({ "snapshot": snapshot, "log": log })).into_response()
        }
        None => error(&HostError::NoSession(id)),
    }
}

async fn close(State(host): State<SessionHost>, Path(id): Path<String>) -> Response {
    match host.close(&id) {
        Ok(()) => StatusCode::NO_CONTENT.into_response(),
        Err(e) => error(&e),
    }
}

async fn ws(
    State(host): State<SessionHost>,
    Path(id): Path<String>,
    upgrade: WebSocketUpgrade,
) -> Response {
    let Some(h) = host.session(&id) else {
        return error(&HostError::NoSession(id));
    };
    upgrade
        .max_message_size(MAX_CLIENT_MESSAGE_BYTES)
        .max_frame_size(MAX_CLIENT_MESSAGE_BYTES)
        .on_upgrade(move |socket| serve_socket(h, socket))
}

/// Largest message (and frame) a client of a session socket may send, bytes. Simulator choice:
/// commands are well under 1 KiB of JSON; the library default was 64 MiB.
pub const MAX_CLIENT_MESSAGE_BYTES: usize = 64 * 1024;

async fn serve_socket(h: SessionHandle, socket: WebSocket) {
    let (sink, stream) = socket.split();
    let sink = sink.with(|m: WsMessage| {
        futures::future::ready(Ok::<Message, axum::Error>(match m {
            WsMessage::Text(t) => Message::Text(t.into()),
            WsMessage::Binary(b) => Message::Binary(b.into()),
            WsMessage::Close => Message::Close(None),
        }))
    });
    let stream = stream.filter_map(|m| {
        futures::future::ready(match m {
            Ok(Message::Text(t)) => Some(Ok(WsMessage::Text(t.to_string()))),
            Ok(Message::Binary(b)) => Some(Ok(WsMessage::Binary(b.to_vec()))),
            Ok(Message::Close(_)) => Some(Ok(WsMessage::Close)),
            Ok(Message::Ping(_) | Message::Pong(_)) => None,
            Err(e) => Some(Err(e)),
        })
    });
    let (sink, stream) = (Box::pin(sink), Box::pin(stream));
    if let Err(e) = serve_connection(h, sink, stream).await {
        tracing::debug!("session connection ended: {e}");
    }
}
