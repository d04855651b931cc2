//! HTTP routes of dispatch for browsers: start a session, its websocket, replay (the render
//! workers' routes are in `worker_routes`).

use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::Router;
use axum::extract::State;
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::ws::rejection::WebSocketUpgradeRejection;
use axum::http::header::{CONTENT_TYPE, HOST, ORIGIN, RETRY_AFTER};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use render_worker::session::{LogEntry, Session, SessionSnapshot, ViewId};
use serde::{Deserialize, Serialize};
use serde_json::json;
use utoipa::{IntoParams, OpenApi, ToSchema};
use uuid::Uuid;

use super::recorded::{parse_recorded, recorded_session, visible_attempt};
use super::route_state::{Caller, DispatchState};
use super::{
    Dispatcher, LiveSession, PlaceError, SessionRecord, TakeoverError, relay, revoke, store, verify,
};
use super::{debrief, worker_routes};
use crate::error::ApiError;
use crate::records::RecordsState;
use crate::records::activity::{ActivityKind, record_activity};
use crate::records::auth::CurrentUser;
use crate::records::extract::{ApiPath, ApiQuery};
use crate::records::results::ReplayVerdict;

/// Seconds a learner refused for capacity is asked to wait (`Retry-After`). Simulator choice: a
/// live session ends by submit or by its idle limit, so slots free up within minutes; half a
/// minute lets the client retry without hammering a full server.
const AT_CAPACITY_RETRY_S: u64 = 30;

/// A live simulation session, as its learner sees it.
#[derive(Debug, Serialize, ToSchema)]
pub struct SessionView {
    /// The server's id of the session.
    pub session_id: Uuid,
    /// Its attempt.
    pub attempt_id: Uuid,
    /// Its station.
    pub station_id: String,
    /// Path of its websocket (`GET`, upgrade), relative to the server.
    #[schema(example = "/api/sessions/00000000-0000-0000-0000-000000000000/ws")]
    pub ws: String,
    /// Where it runs: `in-process` or the worker's URL.
    pub worker: String,
    /// Times it was moved to another worker after one failed.
    #[schema(minimum = 0)]
    pub failovers: u32,
    /// Commands acknowledged so far.
    #[schema(minimum = 0)]
    pub log_len: u64,
    /// Sequence number of the last acknowledged command (0 before the first).
    #[schema(minimum = 0)]
    pub last_seq: u64,
    /// The learner submitted it (it takes no more commands).
    pub submitted: bool,
}

/// What a recorded session stored, or what replaying its log produced.
#[derive(Debug, Serialize, ToSchema)]
pub struct ReplaySide {
    /// The stored result (recorded side only; absent before a submit).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub result_id: Option<Uuid>,
    /// Measurements by key (`null` when there are none).
    #[schema(value_type = Option<Object>)]
    pub measurements: serde_json::Value,
    /// Rubric score.
    pub score: Option<f64>,
    /// Rubric outcome (`met`, `not_met`, `incomplete`).
    pub outcome: Option<String>,
    /// Hash of the session's final state.
    pub final_state_sha256: Option<String>,
    /// Hash of the last image shown (recorded) or rendered (replayed).
    pub final_frame_sha256: Option<String>,
}

/// The recorded log of an attempt's session and a full replay checked against the record.
#[derive(Debug, Serialize, ToSchema)]
pub struct ReplayView {
    /// The recorded session.
    pub session_id: Uuid,
    /// Its station.
    pub station_id: String,
    /// Every acknowledged command in order: `{seq, t_ms, command}`.
    #[schema(value_type = Vec<Object>)]
    pub timeline: Vec<LogEntry>,
    /// What was stored.
    pub recorded: ReplaySide,
    /// What the replay produced.
    pub replayed: ReplaySide,
    /// Measurement keys whose replayed value differs from the stored one.
    pub differing_measurements: Vec<String>,
    /// The replay reproduced measurements, score, outcome, final state and final image exactly.
    pub identical: bool,
}

/// The `step` of a replayed frame.
#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct StepQuery {
    /// Commands of the log applied before the image is taken; a step beyond the log's length
    /// shows the image after the whole log.
    #[param(minimum = 0, maximum = 4294967295_u64)]
    step: u32,
    /// `full` (default): the image of record; `draft`: the draft preview a live session showed
    /// of the same image before it (marked as a draft in its frame header), 204 where the
    /// image has none.
    #[serde(default)]
    #[param(inline)]
    quality: FrameQuality,
    /// `fluoroscopy` (default), `ultrasound` (the B-mode image) or `placement` (the external
    /// view of the probe and needle); 204 when the session had no image of that view yet.
    #[serde(default)]
    #[param(inline)]
    view: ReplayedView,
}

/// Which view of a replayed session.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
enum ReplayedView {
    /// The fluoroscopy image.
    #[default]
    Fluoroscopy,
    /// The ultrasound B-mode image.
    Ultrasound,
    /// The ultrasound placement view.
    Placement,
}

/// Which rendering of a replayed image.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize, ToSchema)]
#[serde(rename_all = "lowercase")]
enum FrameQuality {
    /// The full frame.
    #[default]
    Full,
    /// The draft preview shown before it.
    Draft,
}

/// The OpenAPI description of the dispatch routes (merged into `/api/openapi.json`).
#[derive(OpenApi)]
#[openapi(
    paths(start_session, session_info, session_ws, replay, replay_frame, debrief::debrief, debrief::reveal, worker_routes::register_worker, worker_routes::list_workers),
    components(schemas(SessionView, ReplayView, ReplaySide, worker_routes::WorkerRegistration)),
    tags((name = "sessions", description = "Live simulation sessions, their websocket, replay and render workers"))
)]
pub struct DispatchApi;

/// The dispatch routes' OpenAPI description, with the workers' bearer scheme.
pub fn openapi() -> utoipa::openapi::OpenApi {
    use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
    let mut doc = DispatchApi::openapi();
    doc.components
        .get_or_insert_with(Default::default)
        .add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some("The cluster token (PAINSIM_WORKER_TOKEN)"))
                    .build(),
            ),
        );
    doc
}

/// The dispatch routes.
pub fn router<S: Clone + Send + Sync + 'static>(
    records: RecordsState,
    dispatcher: Dispatcher,
) -> Router<S> {
    dispatcher.attach_records(&records);
    Router::new()
        .route("/api/attempts/{attempt_id}/session", post(start_session))
        .route("/api/attempts/{attempt_id}/replay", get(replay))
        .route("/api/attempts/{attempt_id}/replay/frame", get(replay_frame))
        .route("/api/attempts/{attempt_id}/debrief", get(debrief::debrief))
        .route("/api/attempts/{attempt_id}/reveal", get(debrief::reveal))
        .route("/api/sessions/{session_id}", get(session_info))
        .route("/api/sessions/{session_id}/ws", get(session_ws))
        .route(
            "/api/workers",
            post(worker_routes::register_worker).get(worker_routes::list_workers),
        )
        .with_state({
            verify::start_verifier(records.clone(), &dispatcher, verify::VERIFY_EVERY);
            revoke::start_listener(records.revocations.subscribe(), &dispatcher);
            super::notices::start(&dispatcher);
            DispatchState {
                records,
                dispatcher,
            }
        })
}

fn session_json(s: &LiveSession, st: &SessionRecord) -> SessionView {
    SessionView {
        session_id: s.id,
        attempt_id: s.attempt_id,
        station_id: s.station_id.clone(),
        ws: format!("/api/sessions/{}/ws", s.id),
        worker: st.placement.worker_label(),
        failovers: st.failovers,
        log_len: st.log.len() as u64,
        last_seq: st.log.last().map_or(0, |e| e.seq),
        submitted: st.result_id.is_some(),
    }
}

/// `POST /api/attempts/{attempt_id}/session`: the learner's live session for an attempt (the
/// running one, or a new one on the least loaded worker). Records `session_launched`.
#[utoipa::path(post, path = "/api/attempts/{attempt_id}/session", tag = "sessions",
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses(
        (status = 200, description = "The attempt's running (or resumed) session", body = SessionView),
        (status = 201, description = "A new session", body = SessionView),
        (status = 400, description = "Malformed attempt id"),
        (status = 401), (status = 403, description = "Not the attempt's learner, or CSRF token missing"),
        (status = 404, description = "No such attempt visible to the caller"),
        (status = 409, description = "The attempt is submitted or approved"),
        (status = 429, description = "The per-user or per-course limit of live sessions is reached; the body names which (`scope`, `setting`, `limit`)"),
        (status = 503, description = "No render worker can take it, or the anatomy is being prepared (`Retry-After`)"),
    ))]
async fn start_session(
    State(state): State<DispatchState>,
    Caller(user): Caller,
    ApiPath(attempt_id): ApiPath<Uuid>,
) -> Result<Response, ApiError> {
    let (learner, station_id, attempt_state, course_id) =
        visible_attempt(&state, &user, attempt_id).await?;
    if learner != user.id {
        return Err(ApiError::Forbidden(
            "only the attempt's learner drives its session".into(),
        ));
    }
    if !["in_progress", "returned"].contains(&attempt_state.as_str()) {
        return Err(ApiError::Conflict(format!(
            "the attempt is {attempt_state}; a session can be opened while it is in progress or returned"
        )));
    }
    if let Some(s) = state
        .dispatcher
        .current_session_of_attempt(attempt_id)
        .await?
    {
        let st = s.state.lock().await;
        return Ok((StatusCode::OK, axum::Json(session_json(&s, &st))).into_response());
    }
    // A session of this attempt that the server no longer holds (it restarted, or the session
    // was closed): continue it from its recorded snapshot and log.
    let stored = store::resumable_session(&state.records.pool, attempt_id).await?;
    // One user, or one course, cannot take the render workers from everyone: a new or resumed
    // session needs both under their limits (the running one above is always returned).
    if let Some(refused) =
        over_session_limit(&state.dispatcher, user.id, course_id, attempt_id).await
    {
        return Ok(refused);
    }
    if let Err(e) = state.dispatcher.check_local_ready(&station_id).await {
        return Ok(not_placed(attempt_id, e));
    }
    if let Some((id, initial)) = stored {
        // Another replica relays it now: its websocket, through any replica, takes it over
        // (restoring it here now would only be undone).
        if let Some(view) = held_elsewhere(&state, id, attempt_id, &station_id).await? {
            return Ok((StatusCode::OK, axum::Json(view)).into_response());
        }
        // Taken over (another replica may have held it), then restored from its durable log.
        let stored = super::takeover::Stored {
            id,
            attempt_id,
            course_id,
            learner_id: user.id,
            station_id,
            initial,
        };
        let session = match state
            .dispatcher
            .adopt(&state.records.pool, stored, false)
            .await
        {
            Ok(s) => s,
            Err(TakeoverError::Database(e)) => return Err(ApiError::Database(e)),
            Err(TakeoverError::Restore(e)) => {
                tracing::error!(attempt = %attempt_id, "the recorded session could not be resumed: {e}");
                return Err(ApiError::Unavailable("render worker"));
            }
            Err(e) => return Err(ApiError::Internal(format!("resuming the session: {e}"))),
        };
        let worker = session.state.lock().await.placement.worker_label();
        record_activity(
            &state.records.pool,
            attempt_id,
            user.id,
            ActivityKind::SessionLaunched,
            json!({ "session_id": id, "worker": worker, "resumed": true }),
        )
        .await?;
        let st = session.state.lock().await;
        return Ok((StatusCode::OK, axum::Json(session_json(&session, &st))).into_response());
    }
    let (placement, initial) = match state.dispatcher.place_new(&station_id).await {
        Ok(p) => p,
        Err(e) => return Ok(not_placed(attempt_id, e)),
    };
    let id = Uuid::new_v4();
    store::insert_session(
        &state.records.pool,
        id,
        attempt_id,
        user.id,
        &station_id,
        &initial,
    )
    .await?;
    let worker = placement.worker_label();
    let record = SessionRecord {
        placement,
        initial,
        log: Vec::new(),
        durable_len: 0,
        last_frame_sha256: None,
        result_id: None,
        failovers: 0,
        epoch: 0,
    };
    state.dispatcher.record_placement(id, &record).await;
    let session = Arc::new(LiveSession::new(
        id, attempt_id, course_id, user.id, station_id, record,
    ));
    state.dispatcher.insert(session.clone());
    record_activity(
        &state.records.pool,
        attempt_id,
        user.id,
        ActivityKind::SessionLaunched,
        json!({ "session_id": id, "worker": worker }),
    )
    .await?;
    let st = session.state.lock().await;
    Ok((StatusCode::CREATED, axum::Json(session_json(&session, &st))).into_response())
}

/// 429 when `user` holds the per-user limit of live sessions, or `course` the per-course one;
/// the body names which (`scope`: `user` or `course`), its setting and its value.
async fn over_session_limit(
    d: &Dispatcher,
    user: Uuid,
    course: Uuid,
    attempt: Uuid,
) -> Option<Response> {
    let idle_s = d.session_idle().as_secs();
    // Every replica's sessions count (the shared state), this replica's alone without it.
    let (of_user, of_course) = match d.live_sessions_elsewhere(user, course, attempt).await {
        Some(counts) => counts,
        None => (
            d.live_sessions_of(user).await,
            d.live_sessions_of_course(course).await,
        ),
    };
    let (scope, limit, setting, whose) = if of_user >= d.sessions_per_user() {
        let limit = d.sessions_per_user();
        (
            "user",
            limit,
            "PAINSIM_SESSIONS_PER_USER",
            format!("at most {limit} live sessions per user"),
        )
    } else if of_course >= d.sessions_per_course() {
        let limit = d.sessions_per_course();
        (
            "course",
            limit,
            "PAINSIM_SESSIONS_PER_COURSE",
            format!("at most {limit} live sessions per course"),
        )
    } else {
        return None;
    };
    let body = json!({ "error": {
        "code": "session_limit",
        "message": format!("{whose} ({setting}): submit or leave one (a session closes after {idle_s} s without a command) before opening another"),
        "scope": scope,
        "limit": limit,
        "setting": setting,
    } });
    Some((StatusCode::TOO_MANY_REQUESTS, axum::Json(body)).into_response())
}

/// The answer when no session could be placed: while the anatomy is being prepared, 503 with
/// `Retry-After` and a body the web client shows as progress (code `anatomy_preparing`, the
/// region's stage, fraction done and estimated seconds left); when its preparation failed, 503
/// with the reason (code `anatomy_failed`); otherwise the generic unavailable error.
fn not_placed(attempt_id: Uuid, e: PlaceError) -> Response {
    match e {
        PlaceError::Preparing {
            region,
            readiness,
            retry_after_s,
        } => {
            let body = json!({ "error": {
                "code": "anatomy_preparing",
                "message": format!("the anatomy ({region}) is being prepared; retry after {retry_after_s} s"),
                "retry_after_s": retry_after_s,
                "region": region,
                "readiness": readiness,
            } });
            (
                StatusCode::SERVICE_UNAVAILABLE,
                [(RETRY_AFTER, retry_after_s.to_string())],
                axum::Json(body),
            )
                .into_response()
        }
        PlaceError::AnatomyFailed(reason) => {
            tracing::error!(attempt = %attempt_id, "the anatomy could not be prepared: {reason}");
            let body = json!({ "error": {
                "code": "anatomy_failed",
                "message": format!("the anatomy could not be prepared: {reason}"),
            } });
            (StatusCode::SERVICE_UNAVAILABLE, axum::Json(body)).into_response()
        }
        PlaceError::AtCapacity { capacity } => {
            tracing::warn!(attempt = %attempt_id, capacity, "session refused: every slot is taken");
            let body = json!({ "error": {
                "code": "at_capacity",
                "message": format!(
                    "all {capacity} live-session slots of this server are in use; sessions already \
                     running are not affected. Try again in {AT_CAPACITY_RETRY_S} s"
                ),
                "capacity": capacity,
                "retry_after_s": AT_CAPACITY_RETRY_S,
            } });
            (
                StatusCode::SERVICE_UNAVAILABLE,
                [(RETRY_AFTER, AT_CAPACITY_RETRY_S.to_string())],
                axum::Json(body),
            )
                .into_response()
        }
        PlaceError::Failed(e) => {
            tracing::error!(attempt = %attempt_id, "no session could be created: {e}");
            ApiError::Unavailable("render worker").into_response()
        }
    }
}

/// The view of stored session `id` when another replica holds it live (its placement row names
/// another replica), from the shared state.
async fn held_elsewhere(
    state: &DispatchState,
    id: Uuid,
    attempt_id: Uuid,
    station_id: &str,
) -> Result<Option<SessionView>, ApiError> {
    let pool = &state.records.pool;
    let Some((replica, worker)) = super::cluster::placement_of(pool, id).await? else {
        return Ok(None);
    };
    if replica == state.dispatcher.replica() {
        return Ok(None);
    }
    let (log_len, last_seq) = store::log_extent(pool, id).await?;
    Ok(Some(SessionView {
        session_id: id,
        attempt_id,
        station_id: station_id.to_string(),
        ws: format!("/api/sessions/{id}/ws"),
        worker: worker.unwrap_or_else(|| format!("in-process ({replica})")),
        failovers: 0,
        log_len: log_len.max(0) as u64,
        last_seq: last_seq.max(0) as u64,
        submitted: false,
    }))
}

/// The session, for its learner.
async fn owned_session(
    state: &DispatchState,
    user: &CurrentUser,
    session_id: Uuid,
) -> Result<Arc<LiveSession>, ApiError> {
    let s = state
        .dispatcher
        .session(session_id)
        .ok_or_else(|| ApiError::NotFound("session".into()))?;
    if s.learner_id != user.id {
        // Not revealing whose it is: faculty review through the replay instead.
        return Err(ApiError::NotFound("session".into()));
    }
    Ok(s)
}

/// `GET /api/sessions/{session_id}`: where it runs and how far it is (its learner only).
#[utoipa::path(get, path = "/api/sessions/{session_id}", tag = "sessions",
    params(("session_id" = Uuid, Path, description = "Session id")),
    responses((status = 200, body = SessionView), (status = 400, description = "Malformed session id"), (status = 401),
        (status = 404, description = "No live session of the caller's with this id")))]
async fn session_info(
    State(state): State<DispatchState>,
    Caller(user): Caller,
    ApiPath(session_id): ApiPath<Uuid>,
) -> Result<axum::Json<SessionView>, ApiError> {
    let held = match state.dispatcher.session(session_id) {
        Some(s) => state.dispatcher.unless_stale(s).await?,
        None => None,
    };
    if let Some(s) = held {
        let s = owned_session(&state, &user, s.id).await?;
        let st = s.state.lock().await;
        return Ok(axum::Json(session_json(&s, &st)));
    }
    // Held by another replica: what the shared state says of it.
    let stored = store::stored_session(&state.records.pool, session_id).await?;
    let Some((attempt_id, learner, _, station_id, _, None)) = stored else {
        return Err(ApiError::NotFound("session".into()));
    };
    if learner != user.id {
        return Err(ApiError::NotFound("session".into()));
    }
    held_elsewhere(&state, session_id, attempt_id, &station_id)
        .await?
        .map(axum::Json)
        .ok_or_else(|| ApiError::NotFound("session".into()))
}

/// Browsers send cookies with cross-site websocket handshakes; a handshake whose `Origin` is
/// not this server's own host is refused (cross-site websocket hijacking).
fn same_origin(headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(ORIGIN).and_then(|o| o.to_str().ok()) else {
        return true; // Not a browser (tests, benches, tools): cookies are not ambient there.
    };
    let host = headers
        .get(HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or("");
    origin
        .split_once("://")
        .is_some_and(|(_, rest)| rest == host)
}

/// `GET /api/sessions/{session_id}/ws`: the session protocol, relayed (its learner only).
#[utoipa::path(get, path = "/api/sessions/{session_id}/ws", tag = "sessions",
    params(("session_id" = Uuid, Path, description = "Session id"),
        ("Connection" = String, Header, description = "The handshake (RFC 6455 section 4.1)", example = "Upgrade", pattern = "^[Uu]pgrade$"),
        ("Upgrade" = String, Header, description = "The protocol", example = "websocket", pattern = "^websocket$"),
        ("Sec-WebSocket-Version" = String, Header, description = "Only version 13", example = "13", pattern = "^13$"),
        ("Sec-WebSocket-Key" = String, Header, description = "16 random bytes, base64", example = "dGhlIHNhbXBsZSBub25jZQ==", pattern = "^[A-Za-z0-9+/]{22}==$")),
    responses(
        (status = 101, description = "Switching to the session protocol (render_worker::session::protocol): JSON text messages, JPEG frames as binary; messages over 64 KiB close the socket with 1009"),
        (status = 400, description = "Malformed session id, or not a websocket handshake (or a connection that cannot be upgraded)"),
        (status = 401), (status = 403, description = "A handshake from another origin"),
        (status = 404, description = "No live session of the caller's with this id"),
        (status = 429, description = "Resuming a session nobody holds would pass the per-user or per-course limit of live sessions"),
        (status = 503, description = "No render worker could take the session over"),
    ))]
async fn session_ws(
    State(state): State<DispatchState>,
    Caller(user): Caller,
    ApiPath(session_id): ApiPath<Uuid>,
    headers: HeaderMap,
    upgrade: Result<WebSocketUpgrade, WebSocketUpgradeRejection>,
) -> Result<Response, ApiError> {
    if !same_origin(&headers) {
        return Err(ApiError::Forbidden("websocket from another origin".into()));
    }
    if !state.dispatcher.may_connect(session_id, user.id).await? {
        return Err(ApiError::NotFound("session".into()));
    }
    let upgrade = upgrade.map_err(|r| {
        ApiError::BadRequest(format!("not a websocket handshake: {}", r.body_text()))
    })?;
    // RFC 6455 section 4.1: the key is 16 random bytes in base64 (24 characters ending in "==").
    let key_ok = headers
        .get("sec-websocket-key")
        .and_then(|k| k.to_str().ok())
        .is_some_and(|k| {
            k.len() == 24
                && k.ends_with("==")
                && k[..22]
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'+' || b == b'/')
        });
    if !key_ok {
        return Err(ApiError::BadRequest(
            "not a websocket handshake: Sec-WebSocket-Key must be 16 bytes in base64".into(),
        ));
    }
    // A session nobody holds (closed, or its replica gone) resumes here: under the same limits
    // as opening it again (`start_session`).
    let pool = &state.records.pool;
    if state.dispatcher.session(session_id).is_none()
        && super::cluster::placement_of(pool, session_id)
            .await?
            .is_none()
        && let Some((attempt_id, _, course_id, ..)) =
            store::stored_session(pool, session_id).await?
        && let Some(refused) =
            over_session_limit(&state.dispatcher, user.id, course_id, attempt_id).await
    {
        return Ok(refused);
    }
    // Any replica relays any session: this connection takes it over (see `takeover`).
    let s = match state
        .dispatcher
        .session_for_connection(session_id, user.id)
        .await
    {
        Ok(s) => s,
        Err(TakeoverError::NotFound) => return Err(ApiError::NotFound("session".into())),
        Err(TakeoverError::Database(e)) => return Err(ApiError::Database(e)),
        Err(TakeoverError::Restore(e)) => {
            tracing::error!(session = %session_id, "the session could not be taken over: {e}");
            return Err(ApiError::Unavailable("render worker"));
        }
        Err(e) => return Err(ApiError::Internal(format!("taking the session over: {e}"))),
    };
    let generation = s.generation.fetch_add(1, Ordering::SeqCst) + 1;
    let (dispatcher, records) = (state.dispatcher.clone(), state.records.clone());
    Ok(upgrade
        .max_message_size(relay::MAX_CLIENT_MESSAGE_BYTES)
        .max_frame_size(relay::MAX_CLIENT_MESSAGE_BYTES)
        .on_upgrade(move |socket| relay::relay(dispatcher, records, s, socket, generation)))
}

/// Replays `log` from `initial` on the replay host: the session and its displayed image of
/// `view`.
async fn replay_to(
    state: &DispatchState,
    station_id: String,
    initial: SessionSnapshot,
    log: Vec<LogEntry>,
    view: ViewId,
    draft: bool,
) -> Result<(Session, Option<Vec<u8>>), ApiError> {
    verify::replay_on(
        state.dispatcher.inner.replay.clone(),
        station_id,
        initial,
        log,
        view,
        draft,
    )
    .await
}

/// `GET /api/attempts/{attempt_id}/replay`: the recorded log (the timeline) of the attempt's
/// session, and a full replay checked against what was recorded: score, final state and final
/// frame. Faculty of the course, admins and the learner.
#[utoipa::path(get, path = "/api/attempts/{attempt_id}/replay", tag = "sessions",
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 200, body = ReplayView), (status = 400, description = "Malformed attempt id"), (status = 401),
        (status = 404, description = "No such attempt visible to the caller, or no recorded session"),
        (status = 409, description = "The caller is the learner and the attempt is not submitted yet"),
        (status = 503, description = "The anatomy is being prepared")))]
async fn replay(
    State(state): State<DispatchState>,
    Caller(user): Caller,
    ApiPath(attempt_id): ApiPath<Uuid>,
) -> Result<axum::Json<ReplayView>, ApiError> {
    let (session_id, station_id, initial, result_id, final_state, final_frame, score, outcome) =
        recorded_session(&state, &user, attempt_id).await?;
    let (initial, log) = parse_recorded(&state, session_id, initial).await?;
    let (s, jpeg) = replay_to(
        &state,
        station_id.clone(),
        initial,
        log.clone(),
        ViewId::FLUOROSCOPY,
        false,
    )
    .await?;
    let measurements: Option<serde_json::Value> = match result_id {
        Some(id) => {
            sqlx::query_scalar("SELECT measurements FROM technical_results WHERE id = $1")
                .bind(id)
                .fetch_optional(&state.records.pool)
                .await?
        }
        None => None,
    };
    let recorded = verify::Recorded {
        measurements: measurements.unwrap_or(serde_json::Value::Null),
        score,
        outcome: outcome.clone(),
        final_state_sha256: final_state.clone(),
        final_frame_sha256: final_frame.clone(),
    };
    let (verdict, detail) = verify::compare(&recorded, &s, jpeg.as_deref());
    let text = |v: &serde_json::Value| v.as_str().map(str::to_owned);
    let replayed = ReplaySide {
        result_id: None,
        measurements: detail["measurements"]["replayed"].clone(),
        score: detail["score"]["replayed"].as_f64(),
        outcome: text(&detail["outcome"]["replayed"]),
        final_state_sha256: text(&detail["final_state_sha256"]["replayed"]),
        final_frame_sha256: text(&detail["final_frame_sha256"]["replayed"]),
    };
    let differing_measurements = detail["measurements"]["differing_keys"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|k| k.as_str().map(str::to_owned))
                .collect()
        })
        .unwrap_or_default();
    Ok(axum::Json(ReplayView {
        session_id,
        station_id,
        timeline: log,
        recorded: ReplaySide {
            result_id,
            measurements: recorded.measurements,
            score,
            outcome,
            final_state_sha256: final_state,
            final_frame_sha256: final_frame,
        },
        replayed,
        differing_measurements,
        identical: result_id.is_some() && verdict == ReplayVerdict::Identical,
    }))
}

/// `GET /api/attempts/{attempt_id}/replay/frame?step=k`: the JPEG on screen after the first `k`
/// recorded commands (all of them when `k` is beyond the log; 204 before the first image);
/// `&quality=draft`: the draft shown before it.
#[utoipa::path(get, path = "/api/attempts/{attempt_id}/replay/frame", tag = "sessions",
    params(("attempt_id" = Uuid, Path, description = "Attempt id"), StepQuery),
    responses((status = 200, description = "The image on screen after `step` commands", content_type = "image/jpeg"),
        (status = 204, description = "No image yet at that step"),
        (status = 400, description = "Malformed id or step"), (status = 401),
        (status = 404, description = "No such attempt visible to the caller, or no recorded session"),
        (status = 409, description = "The caller is the learner and the attempt is not submitted yet"),
        (status = 503, description = "The anatomy is being prepared")))]
async fn replay_frame(
    State(state): State<DispatchState>,
    Caller(user): Caller,
    ApiPath(attempt_id): ApiPath<Uuid>,
    ApiQuery(q): ApiQuery<StepQuery>,
) -> Result<Response, ApiError> {
    let (session_id, station_id, initial, ..) = recorded_session(&state, &user, attempt_id).await?;
    let (initial, mut log) = parse_recorded(&state, session_id, initial).await?;
    // A step beyond the log shows the last image: the log of a live session still grows.
    log.truncate(usize::try_from(q.step).unwrap_or(usize::MAX));
    let draft = q.quality == FrameQuality::Draft;
    let view = match q.view {
        ReplayedView::Fluoroscopy => ViewId::FLUOROSCOPY,
        ReplayedView::Ultrasound => ViewId::ULTRASOUND,
        ReplayedView::Placement => ViewId::PLACEMENT,
    };
    let (_, jpeg) = replay_to(&state, station_id, initial, log, view, draft).await?;
    Ok(match jpeg {
        Some(j) => ([(CONTENT_TYPE, "image/jpeg")], j).into_response(),
        None => StatusCode::NO_CONTENT.into_response(),
    })
}
