//! The relay between the browser's websocket and the worker's session socket, with the log
//! mirror, engagement events, the submit hand-off to the learning records, and failover.

use std::collections::{BTreeMap, VecDeque};
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::extract::ws::{Message, WebSocket};
use futures::{Sink, SinkExt, Stream, StreamExt};
use render_worker::session::protocol::{
    ClientMessage, ServerMessage, WsMessage, parse_client_message, serve_connection,
};
use render_worker::session::{Command, LogEntry, SubmitResult, sha256_hex};
use serde_json::json;
use tokio_tungstenite::tungstenite::Message as TMessage;

use super::durable::LogWriter;
use super::{Dispatcher, LiveSession, Placement};
use crate::records::RecordsState;
use crate::records::activity::{ActivityKind, record_activity};
use crate::records::results::{NewResult, Reproducibility, ResultSource, submit_result_for};

type UpSink = Pin<Box<dyn Sink<WsMessage, Error = String> + Send>>;
type UpStream = Pin<Box<dyn Stream<Item = Result<WsMessage, String>> + Send>>;

/// How many times in a row one connection tries to move its session before giving up.
/// Simulator choice: two dead workers in a row is already exceptional.
const MAX_FAILOVERS_IN_A_ROW: u32 = 3;

/// Opens the worker side of a session.
async fn connect(
    dispatcher: &Dispatcher,
    placement: &Placement,
) -> Result<(UpSink, UpStream), String> {
    match placement {
        Placement::Local { worker_session } => {
            let host = dispatcher.local_host().ok_or("no in-process worker")?;
            let handle = host
                .session(worker_session)
                .ok_or("the in-process session has ended")?;
            // Bounded towards the relay: when the browser is slow, the session's connection waits
            // here and, its frames being a latest-only watch, skips superseded frames.
            let (to_relay, from_worker) = futures::channel::mpsc::channel::<WsMessage>(2);
            let (to_worker, from_relay) = futures::channel::mpsc::channel::<WsMessage>(64);
            tokio::spawn(async move {
                if let Err(e) =
                    serve_connection(handle, to_relay, from_relay.map(Ok::<_, String>)).await
                {
                    tracing::debug!("in-process session connection ended: {e}");
                }
            });
            Ok((
                Box::pin(to_worker.sink_map_err(|e| e.to_string())),
                Box::pin(from_worker.map(Ok)),
            ))
        }
        Placement::Remote {
            worker_url,
            worker_session,
        } => {
            let (authority, _) = render_worker::cluster::split_url(worker_url)?;
            let url = format!("ws://{authority}/sessions/{worker_session}/ws");
            let (ws, _) = tokio_tungstenite::connect_async(&url)
                .await
                .map_err(|e| format!("{url}: {e}"))?;
            let (sink, stream) = ws.split();
            let sink = sink.sink_map_err(|e| e.to_string()).with(|m: WsMessage| {
                futures::future::ready(Ok::<TMessage, String>(match m {
                    WsMessage::Text(t) => TMessage::text(t),
                    WsMessage::Binary(b) => TMessage::binary(b),
                    WsMessage::Close => TMessage::Close(None),
                }))
            });
            let stream = stream.filter_map(|m| {
                futures::future::ready(match m {
                    Ok(TMessage::Text(t)) => Some(Ok(WsMessage::Text(t.to_string()))),
                    Ok(TMessage::Binary(b)) => Some(Ok(WsMessage::Binary(b.to_vec()))),
                    Ok(TMessage::Close(_)) => Some(Ok(WsMessage::Close)),
                    Ok(_) => None,
                    Err(e) => Some(Err(e.to_string())),
                })
            });
            Ok((Box::pin(sink), Box::pin(stream)))
        }
    }
}

/// The engagement event a command stands for, if any.
fn activity_of(command: &Command) -> Option<ActivityKind> {
    Some(match command {
        Command::CarmPose { .. }
        | Command::ProbePose { .. }
        | Command::ProbeSettings { .. }
        | Command::Technique { .. } => ActivityKind::ViewChanged,
        Command::Shot | Command::Live { on: true } => ActivityKind::ImageAcquired,
        Command::NeedlePlace { .. }
        | Command::NeedleFeed { .. }
        | Command::NeedleRoll { .. }
        | Command::NeedleWithdraw { .. } => ActivityKind::NeedleAdjusted,
        Command::Inject { .. } => ActivityKind::Injection,
        Command::Live { on: false } | Command::Annotate { .. } | Command::Submit => return None,
    })
}

/// The learning-records form of a session's submit.
pub fn new_result(result: &SubmitResult, session_id: uuid::Uuid, worker: &str) -> NewResult {
    let r = &result.record;
    let is_sha = |h: &str| {
        h.len() == 64
            && h.bytes()
                .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())
    };
    let mut asset_hashes: BTreeMap<String, String> = r
        .asset_sha256
        .iter()
        .filter(|(_, h)| is_sha(h))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    // The station file and the whole region (its fingerprint covers every asset hash, also
    // ones that are labels rather than file hashes, as in generated test regions).
    asset_hashes.insert(
        format!("station:{}", r.station_id),
        r.station_sha256.clone(),
    );
    let mut fingerprint = String::new();
    for (k, v) in &r.asset_sha256 {
        fingerprint.push_str(&format!("{k}={v}\n"));
    }
    asset_hashes.insert(
        format!("region:{}", r.region),
        sha256_hex(fingerprint.as_bytes()),
    );
    NewResult {
        measurements: result
            .measurements
            .iter()
            .map(|(k, v)| (k.clone(), *v))
            .collect(),
        reproducibility: Reproducibility {
            code_revision: r.code_revision.chars().take(100).collect(),
            asset_hashes,
            device_profile: json!({ "renderer": r.renderer, "worker": worker, "region_source": r.region_source }),
            imaging_settings: json!({ "modalities": r.modalities, "unavailable_modalities": r.unavailable_modalities }),
            interaction_log_ref: Some(format!(
                "live_sessions/{session_id} log_len={} log_sha256={} initial={} final={}",
                r.log_len, r.log_sha256, r.initial_state_sha256, r.final_state_sha256
            )),
            server_version: None,
            activity_upto_event_id: None,
            activity_event_count: None,
        },
    }
}

fn to_axum(m: WsMessage) -> Message {
    match m {
        WsMessage::Text(t) => Message::Text(t.into()),
        WsMessage::Binary(b) => Message::Binary(b.into()),
        WsMessage::Close => Message::Close(None),
    }
}

/// Saves the frame hash of a session (its commands are written as they are acknowledged).
pub async fn persist(records: &RecordsState, session: &LiveSession) {
    let frame = session.state.lock().await.last_frame_sha256.clone();
    let r = sqlx::query("UPDATE live_sessions SET final_frame_sha256 = COALESCE($2, final_frame_sha256), updated_at = now() WHERE id = $1")
        .bind(session.id)
        .bind(frame)
        .execute(&records.pool)
        .await;
    if let Err(e) = r {
        tracing::error!(session = %session.id, "saving the session's frame hash failed: {e}");
    }
}

/// Text messages on their way to the browser, each held until the log length it needs is
/// durable (see [`super::durable`]); frames bypass it.
#[derive(Default)]
struct Outbox {
    held: VecDeque<(usize, String)>,
}

impl Outbox {
    /// Queues `text`, to be sent once `needs` log entries are durable.
    fn push(&mut self, needs: usize, text: String) {
        self.held.push_back((needs, text));
    }

    /// Sends, in order, every message whose log prefix is durable. False when the browser is gone.
    async fn release(
        &mut self,
        durable: usize,
        browser_tx: &mut futures::stream::SplitSink<WebSocket, Message>,
    ) -> bool {
        while self.held.front().is_some_and(|(needs, _)| *needs <= durable) {
            let Some((_, text)) = self.held.pop_front() else {
                break;
            };
            if browser_tx.send(Message::Text(text.into())).await.is_err() {
                return false;
            }
        }
        true
    }
}

/// Relays one browser connection until it closes (or a newer connection takes over).
pub async fn relay(
    dispatcher: Dispatcher,
    records: RecordsState,
    session: Arc<LiveSession>,
    socket: WebSocket,
    generation: u64,
) {
    let (mut browser_tx, mut browser_rx) = socket.split();
    session.connections.fetch_add(1, Ordering::SeqCst);
    // Commands sent to the worker and not yet acknowledged or rejected: re-sent after failover.
    let mut pending: BTreeMap<u64, (String, Command)> = BTreeMap::new();
    let mut first_hello = true;
    let mut failovers_in_a_row = 0u32;
    let mut tick = tokio::time::interval(std::time::Duration::from_millis(500));
    let durable_now = session.state.lock().await.durable_len;
    let mut writer = LogWriter::start(records.pool.clone(), session.clone(), durable_now);
    let mut outbox = Outbox::default();
    'connection: loop {
        let placement = session.state.lock().await.placement.clone();
        let (mut up_tx, mut up_rx) = match connect(&dispatcher, &placement).await {
            Ok(u) => u,
            Err(e) => {
                tracing::warn!(session = %session.id, worker = %placement.worker_label(), "cannot reach the session: {e}");
                if !failover(
                    &dispatcher,
                    &session,
                    &placement,
                    &mut failovers_in_a_row,
                    &mut browser_tx,
                )
                .await
                {
                    break 'connection;
                }
                continue 'connection;
            }
        };
        // Re-send what the previous worker never answered (empty on the first connection).
        for (text, _) in pending.values() {
            if up_tx.send(WsMessage::Text(text.clone())).await.is_err() {
                continue 'connection;
            }
        }
        loop {
            tokio::select! {
                biased;
                m = up_rx.next() => match m {
                    Some(Ok(WsMessage::Text(t))) => {
                        failovers_in_a_row = 0;
                        match serde_json::from_str::<ServerMessage>(&t) {
                            Ok(ServerMessage::Hello { session: mut info, last_seq }) => {
                                if first_hello {
                                    first_hello = false;
                                    info.id = session.id.to_string();
                                    let hello = ServerMessage::Hello { session: info, last_seq };
                                    let text = serde_json::to_string(&hello).unwrap_or_default();
                                    let needs = session.state.lock().await.log.len();
                                    outbox.push(needs, text);
                                    if !outbox.release(writer.durable_len(), &mut browser_tx).await {
                                        break 'connection;
                                    }
                                }
                            }
                            Ok(ServerMessage::Ack(ack)) => {
                                let command = pending.remove(&ack.seq).map(|(_, c)| c);
                                let mut result_message = None;
                                let needs = if let (Some(command), false) = (command, ack.duplicate) {
                                    let needs = {
                                        let mut st = session.state.lock().await;
                                        st.log.push(LogEntry { seq: ack.seq, t_ms: ack.t_ms, command: command.clone() });
                                        st.log.len()
                                    };
                                    writer.kick();
                                    if let Some(kind) = activity_of(&command) {
                                        let (pool, s) = (records.pool.clone(), session.clone());
                                        let detail = json!({ "session_id": s.id, "seq": ack.seq, "command": command.name() });
                                        tokio::spawn(async move {
                                            if let Err(e) = record_activity(&pool, s.attempt_id, s.learner_id, kind, detail).await {
                                                tracing::warn!("recording activity failed: {e}");
                                            }
                                        });
                                    }
                                    if command == Command::Submit {
                                        // The result is stored only after the log it scores.
                                        if !writer.wait_durable(needs).await {
                                            break 'connection;
                                        }
                                        result_message = Some(store_result(&records, &session, &placement, &ack.outcome).await);
                                    }
                                    needs
                                } else {
                                    session.state.lock().await.log.len()
                                };
                                outbox.push(needs, t);
                                if let Some(m) = result_message {
                                    outbox.push(needs, m.to_string());
                                }
                                if !outbox.release(writer.durable_len(), &mut browser_tx).await {
                                    break 'connection;
                                }
                            }
                            Ok(ServerMessage::Error { seq, .. }) => {
                                if let Some(seq) = seq {
                                    pending.remove(&seq);
                                }
                                let needs = session.state.lock().await.log.len();
                                outbox.push(needs, t);
                                if !outbox.release(writer.durable_len(), &mut browser_tx).await {
                                    break 'connection;
                                }
                            }
                            Err(_) => {
                                let needs = session.state.lock().await.log.len();
                                outbox.push(needs, t);
                                if !outbox.release(writer.durable_len(), &mut browser_tx).await {
                                    break 'connection;
                                }
                            }
                        }
                    }
                    Some(Ok(WsMessage::Binary(b))) => {
                        let jpeg = b.get(render_worker::session::frame::HEADER_BYTES..).unwrap_or_default();
                        session.state.lock().await.last_frame_sha256 = Some(sha256_hex(jpeg));
                        if browser_tx.send(Message::Binary(b.into())).await.is_err() {
                            break 'connection;
                        }
                    }
                    Some(Ok(WsMessage::Close)) | Some(Err(_)) | None => {
                        if session.generation.load(Ordering::SeqCst) != generation {
                            break 'connection;
                        }
                        if !failover(&dispatcher, &session, &placement, &mut failovers_in_a_row, &mut browser_tx).await {
                            break 'connection;
                        }
                        continue 'connection;
                    }
                },
                m = browser_rx.next() => match m {
                    Some(Ok(Message::Text(t))) => {
                        let t = t.to_string();
                        if let Ok(ClientMessage::Command { seq, command }) = parse_client_message(&t) {
                            pending.insert(seq, (t.clone(), command));
                        }
                        // A send failure shows up as the worker stream ending: failover re-sends.
                        let _ = up_tx.send(WsMessage::Text(t)).await;
                    }
                    Some(Ok(Message::Binary(b))) => {
                        let _ = up_tx.send(WsMessage::Binary(b.to_vec())).await;
                    }
                    Some(Ok(Message::Ping(_) | Message::Pong(_))) => {}
                    Some(Ok(Message::Close(_))) | Some(Err(_)) | None => {
                        let _ = up_tx.send(WsMessage::Close).await;
                        break 'connection;
                    }
                },
                changed = writer.durable.changed() => {
                    if changed.is_err() {
                        tracing::error!(session = %session.id, "the session's log writer stopped");
                        break 'connection;
                    }
                    let durable = writer.durable_len();
                    if !outbox.release(durable, &mut browser_tx).await {
                        break 'connection;
                    }
                }
                _ = tick.tick() => {
                    if session.generation.load(Ordering::SeqCst) != generation {
                        let note = json!({ "type": "notice", "message": "this session was opened in another window" });
                        let _ = browser_tx.send(Message::Text(note.to_string().into())).await;
                        let _ = up_tx.send(WsMessage::Close).await;
                        break 'connection;
                    }
                }
            }
        }
    }
    writer.finish().await;
    persist(&records, &session).await;
    if let Ok(mut t) = session.last_active.lock() {
        *t = std::time::Instant::now();
    }
    session.connections.fetch_sub(1, Ordering::SeqCst);
    // A submitted session is finished: free its worker (replays run from the stored log).
    if session.state.lock().await.result_id.is_some()
        && session.generation.load(Ordering::SeqCst) == generation
    {
        dispatcher.close(session.id).await;
    }
    let _ = browser_tx.send(to_axum(WsMessage::Close)).await;
}

/// Moves the session to another worker; tells the browser. False when it cannot.
async fn failover(
    dispatcher: &Dispatcher,
    session: &LiveSession,
    failed: &Placement,
    in_a_row: &mut u32,
    browser_tx: &mut futures::stream::SplitSink<WebSocket, Message>,
) -> bool {
    *in_a_row += 1;
    if *in_a_row > MAX_FAILOVERS_IN_A_ROW {
        let note = json!({ "type": "notice", "message": "the session could not be moved to a working render worker" });
        let _ = browser_tx
            .send(Message::Text(note.to_string().into()))
            .await;
        return false;
    }
    let record = session.state.lock().await.clone();
    if &record.placement != failed {
        // Another connection already moved it.
        return true;
    }
    match dispatcher.restore_elsewhere(failed, &record).await {
        Ok(placement) => {
            tracing::warn!(session = %session.id, from = %failed.worker_label(), to = %placement.worker_label(), log = record.log.len(), "session restored on another worker");
            let mut st = session.state.lock().await;
            st.placement = placement.clone();
            st.failovers += 1;
            drop(st);
            let note = json!({ "type": "notice", "message": "render worker lost; the session continues on another worker", "worker": placement.worker_label() });
            let _ = browser_tx
                .send(Message::Text(note.to_string().into()))
                .await;
            true
        }
        Err(e) => {
            tracing::error!(session = %session.id, "failover failed: {e}");
            let note = json!({ "type": "notice", "message": format!("the session could not be moved: {e}") });
            let _ = browser_tx
                .send(Message::Text(note.to_string().into()))
                .await;
            false
        }
    }
}

/// Stores the submit as the attempt's technical result; returns the message for the browser.
async fn store_result(
    records: &RecordsState,
    session: &LiveSession,
    placement: &Placement,
    outcome: &serde_json::Value,
) -> serde_json::Value {
    let result: SubmitResult = match serde_json::from_value(outcome.clone()) {
        Ok(r) => r,
        Err(e) => {
            return json!({ "type": "technical_result_error", "message": format!("the worker's result could not be read: {e}") });
        }
    };
    let req = new_result(&result, session.id, &placement.worker_label());
    match submit_result_for(
        records,
        session.learner_id,
        session.attempt_id,
        req,
        ResultSource::Server,
    )
    .await
    {
        Ok(view) => {
            let mut st = session.state.lock().await;
            st.result_id = Some(view.id);
            let frame = st.last_frame_sha256.clone();
            drop(st);
            let r = sqlx::query(
                "UPDATE live_sessions SET result_id = $2, final_state_sha256 = $3, final_frame_sha256 = $4, updated_at = now() WHERE id = $1",
            )
            .bind(session.id)
            .bind(view.id)
            .bind(&result.record.final_state_sha256)
            .bind(frame)
            .execute(&records.pool)
            .await;
            if let Err(e) = r {
                tracing::error!(session = %session.id, "saving the submitted session failed: {e}");
            }
            json!({ "type": "technical_result", "result": view })
        }
        Err(e) => {
            tracing::warn!(session = %session.id, "storing the technical result failed: {e}");
            json!({ "type": "technical_result_error", "message": e.to_string() })
        }
    }
}
