//! The session websocket protocol, over any `Sink`/`Stream` of [`WsMessage`]s (axum's socket,
//! tokio-tungstenite, or plain channels in tests).
//!
//! Client to worker, text JSON:
//! - `{"type":"command","seq":7,"command":{"type":"carm_pose","orbital_deg":20,"angular_deg":0}}`
//! - `{"type":"views","visible":["fluoroscopy"]}`: only these views are rendered.
//!
//! Worker to client:
//! - text `{"type":"hello","session":{...SessionInfo},"last_seq":N}` on connect (a reconnecting
//!   client re-sends its commands above `last_seq`; re-sent ones at or below are acknowledged as
//!   duplicates). `session.protocol` ([`super::offer::ProtocolInfo`]) carries the frame header's
//!   constants, the views with their wire codes, the command kinds and the numbers a client
//!   needs, all read from the modalities' specs: a client copies none of them;
//! - text `{"type":"ack","seq":7,"t_ms":..,"duplicate":false,"engagement":"view_changed",
//!   "outcome":{..}}` for every accepted command, in order (the submit's outcome is the
//!   `SubmitResult`; `engagement` is the learning-record event it stands for, if any);
//! - text `{"type":"error","seq":7,"error":{"field":"command.orbital_deg","code":"out_of_range",
//!   "message":".."}}` for every rejected one;
//! - binary frames (see [`super::frame`]): the newest frame of each view. Frames that were
//!   superseded while the client was slow are skipped; acknowledgements never are.

use std::collections::BTreeMap;
use std::fmt::Display;

use futures::{Sink, SinkExt, Stream, StreamExt};
use serde::{Deserialize, Serialize};
use tokio::sync::mpsc;

use super::command::{Command, CommandError, Envelope, ErrorCode};
use super::host::{FrameSet, Reply, SessionHandle, SessionInfo};
use super::image::ViewId;
use super::machine::Ack;

/// A websocket message, independent of the websocket library.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum WsMessage {
    /// UTF-8 text.
    Text(String),
    /// Bytes.
    Binary(Vec<u8>),
    /// The peer closes.
    Close,
}

/// Messages a client sends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ClientMessage {
    /// A command.
    Command {
        /// Sequence number.
        seq: u64,
        /// The command.
        command: Command,
    },
    /// Visible views.
    Views {
        /// Views to render.
        visible: Vec<ViewId>,
    },
}

/// Text messages the worker sends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum ServerMessage {
    /// First message of a connection.
    Hello {
        /// The session.
        session: SessionInfo,
        /// Last accepted sequence number.
        last_seq: u64,
    },
    /// A command was accepted.
    Ack(Ack),
    /// A command or message was rejected.
    Error {
        /// The command's sequence number, when it could be read.
        seq: Option<u64>,
        /// What is wrong.
        error: CommandError,
    },
}

/// Parses a client's text message; errors name the offending field.
pub fn parse_client_message(text: &str) -> Result<ClientMessage, (Option<u64>, CommandError)> {
    let value: serde_json::Value = serde_json::from_str(text).map_err(|e| {
        (
            None,
            CommandError::field("message", ErrorCode::Malformed, format!("not JSON: {e}")),
        )
    })?;
    let kind = value.get("type").and_then(|t| t.as_str()).unwrap_or("");
    let allowed: &[&str] = match kind {
        "command" => &["type", "seq", "command"],
        "views" => &["type", "visible"],
        _ => &[],
    };
    if let Some(extra) = value.as_object().and_then(|o| {
        o.keys()
            .find(|k| !allowed.is_empty() && !allowed.contains(&k.as_str()))
    }) {
        let seq = value.get("seq").and_then(serde_json::Value::as_u64);
        return Err((
            seq,
            CommandError::field(
                extra,
                ErrorCode::Malformed,
                format!("unknown field `{extra}` (expected {allowed:?})"),
            ),
        ));
    }
    match kind {
        "command" => {
            let seq = value
                .get("seq")
                .and_then(serde_json::Value::as_u64)
                .ok_or_else(|| {
                    (
                        None,
                        CommandError::field(
                            "seq",
                            ErrorCode::Malformed,
                            "seq must be a positive integer",
                        ),
                    )
                })?;
            let raw = value.get("command").ok_or_else(|| {
                (
                    Some(seq),
                    CommandError::field("command", ErrorCode::Malformed, "missing command"),
                )
            })?;
            let command: Command = parse_command(raw).map_err(|e| {
                let path = e.path().to_string();
                let field = if path.is_empty() || path == "." {
                    "command".to_string()
                } else {
                    format!("command.{path}")
                };
                let message = e.inner().to_string();
                let field = if field == "command" {
                    locate_field(raw, &message)
                } else {
                    field
                };
                (
                    Some(seq),
                    CommandError {
                        field,
                        code: ErrorCode::Malformed,
                        message,
                    },
                )
            })?;
            // serde ignores unknown fields of unit variants (`shot`) in an internally tagged
            // enum: every field sent must be one the command has.
            let known = serde_json::to_value(&command).unwrap_or_default();
            if let (Some(sent), Some(known)) = (raw.as_object(), known.as_object()) {
                if let Some(extra) = sent.keys().find(|k| !known.contains_key(*k)) {
                    return Err((
                        Some(seq),
                        CommandError::field(
                            &format!("command.{extra}"),
                            ErrorCode::Malformed,
                            format!("unknown field `{extra}` of {}", command.name()),
                        ),
                    ));
                }
            }
            Ok(ClientMessage::Command { seq, command })
        }
        "views" => serde_json::from_value(value).map_err(|e| {
            (
                None,
                CommandError::field("visible", ErrorCode::Malformed, e.to_string()),
            )
        }),
        other => Err((
            None,
            CommandError::field(
                "type",
                ErrorCode::Malformed,
                format!("unknown message type {other:?} (expected \"command\" or \"views\")"),
            ),
        )),
    }
}

/// A built-in command parsed by the derived parser, so that `serde_path_to_error` sees the
/// field paths; any other kind is a modality's command (see [`Command::from_json`]).
struct Builtin(Command);

impl<'de> Deserialize<'de> for Builtin {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Builtin, D::Error> {
        Command::deserialize_builtin(d).map(Builtin)
    }
}

fn parse_command(
    raw: &serde_json::Value,
) -> Result<Command, serde_path_to_error::Error<serde_json::Error>> {
    let builtin = raw
        .get("type")
        .and_then(serde_json::Value::as_str)
        .is_none_or(|k| super::command::BUILTIN_KINDS.contains(&k));
    if builtin {
        serde_path_to_error::deserialize::<_, Builtin>(raw).map(|b| b.0)
    } else {
        serde_path_to_error::deserialize::<_, Command>(raw)
    }
}

fn quoted_after<'a>(message: &'a str, prefix: &str) -> Option<&'a str> {
    message.strip_prefix(prefix)?.split('`').next()
}

/// Names the field a command failed on. serde loses the path inside internally tagged enums, but
/// its messages name missing and unknown fields and variants; for a value of the wrong type, the
/// culprit is the field whose removal turns the error into "missing field" for that field.
fn locate_field(raw: &serde_json::Value, message: &str) -> String {
    if let Some(f) = quoted_after(message, "missing field `") {
        return format!("command.{f}");
    }
    if let Some(f) = quoted_after(message, "unknown field `") {
        return format!("command.{f}");
    }
    if message.starts_with("unknown variant") || raw.get("type").is_none() {
        return "command.type".to_string();
    }
    if let Some(obj) = raw.as_object() {
        for key in obj.keys().filter(|k| k.as_str() != "type") {
            let mut trial = obj.clone();
            trial.remove(key);
            let e = serde_json::from_value::<Command>(serde_json::Value::Object(trial)).err();
            if e.is_some_and(|e| quoted_after(&e.to_string(), "missing field `") == Some(key)) {
                return format!("command.{key}");
            }
        }
    }
    "command".to_string()
}

fn text(m: &ServerMessage) -> WsMessage {
    WsMessage::Text(serde_json::to_string(m).unwrap_or_default())
}

/// Why a client connection ended other than by the client closing it or the session ending.
/// Each variant carries the transport's own message: the sink and stream are generic, so their
/// error types are not known here.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ConnectionError {
    /// A message could not be sent to the client.
    #[error("send failed: {0}")]
    Send(String),
    /// The client's stream failed.
    #[error("receive failed: {0}")]
    Receive(String),
}

/// Serves one client connection of `handle` until the client closes or the session ends.
pub async fn serve_connection<Si, St, E>(
    handle: SessionHandle,
    mut sink: Si,
    mut stream: St,
) -> Result<(), ConnectionError>
where
    Si: Sink<WsMessage> + Unpin,
    Si::Error: Display,
    St: Stream<Item = Result<WsMessage, E>> + Unpin,
    E: Display,
{
    let send_err = |e: Si::Error| ConnectionError::Send(e.to_string());
    let last_seq = handle.snapshot().await.map_or(0, |(s, _)| s.last_seq);
    sink.send(text(&ServerMessage::Hello {
        session: handle.info.clone(),
        last_seq,
    }))
    .await
    .map_err(send_err)?;
    let (reply_tx, mut reply_rx) = mpsc::unbounded_channel::<Reply>();
    let mut frames = handle.frames();
    let mut sent: BTreeMap<ViewId, u64> = BTreeMap::new();
    let current = frames.borrow_and_update().clone();
    send_new_frames(&current, &mut sent, &mut sink)
        .await
        .map_err(send_err)?;
    let mut frames_open = true;
    loop {
        tokio::select! {
            biased;
            r = reply_rx.recv() => {
                let Some(r) = r else { break };
                let m = match r {
                    Reply::Ack(a) => ServerMessage::Ack(a),
                    Reply::Error { seq, error } => ServerMessage::Error { seq, error },
                };
                sink.send(text(&m)).await.map_err(send_err)?;
            }
            msg = stream.next() => match msg {
                None | Some(Ok(WsMessage::Close)) => break,
                Some(Err(e)) => return Err(ConnectionError::Receive(e.to_string())),
                Some(Ok(WsMessage::Binary(_))) => {
                    let error = CommandError::field("message", ErrorCode::Malformed, "binary client messages are not understood; send JSON text");
                    sink.send(text(&ServerMessage::Error { seq: None, error })).await.map_err(send_err)?;
                }
                Some(Ok(WsMessage::Text(t))) => match parse_client_message(&t) {
                    Ok(ClientMessage::Command { seq, command }) => {
                        if let Err(error) = handle.send(Envelope { seq, command }, reply_tx.clone()) {
                            sink.send(text(&ServerMessage::Error { seq: Some(seq), error })).await.map_err(send_err)?;
                            break;
                        }
                    }
                    Ok(ClientMessage::Views { visible }) => handle.set_visible(visible.into_iter().collect()),
                    Err((seq, error)) => {
                        sink.send(text(&ServerMessage::Error { seq, error })).await.map_err(send_err)?;
                    }
                },
            },
            changed = frames.changed(), if frames_open => {
                if changed.is_err() {
                    // The session ended: deliver what is pending, then stop.
                    frames_open = false;
                    continue;
                }
                let set = frames.borrow_and_update().clone();
                send_new_frames(&set, &mut sent, &mut sink).await.map_err(send_err)?;
            }
        }
    }
    let _ = sink.close().await;
    Ok(())
}

async fn send_new_frames<Si>(
    set: &FrameSet,
    sent: &mut BTreeMap<ViewId, u64>,
    sink: &mut Si,
) -> Result<(), Si::Error>
where
    Si: Sink<WsMessage> + Unpin,
{
    for (view, f) in set.iter() {
        if sent.get(view).is_none_or(|&s| f.frame_seq > s) {
            sink.send(WsMessage::Binary(f.to_bytes())).await?;
            sent.insert(*view, f.frame_seq);
        }
    }
    Ok(())
}
