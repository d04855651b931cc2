//! The relay between the browser's websocket and the worker's session: one handler per message
//! kind, around one `select!` over the worker, the browser, the log writer and a timer.
//!
//! What it keeps: the server's copy of the session log (each acknowledged command, committed by
//! [`LogWriter`] before the acknowledgement is passed on), engagement events for the learning
//! records, the submit's result (stored through [`super::results`]), and failover to another
//! worker with the unacknowledged commands sent again.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::extract::ws::{Message, WebSocket};
use futures::stream::SplitSink;
use futures::{SinkExt, StreamExt};
use render_worker::session::protocol::{
    ClientMessage, ServerMessage, WsMessage, parse_client_message,
};
use render_worker::session::{Ack, Command, LogEntry, sha256_hex};
use serde_json::json;

use super::durable::LogWriter;
use super::upstream::{UpSink, connect};
use super::{Dispatcher, LiveSession, Placement, results, store};
use crate::records::RecordsState;
use crate::records::activity::{ActivityKind, record_activity};

/// How many times in a row one connection tries to move its session before giving up.
/// Simulator choice: two dead workers in a row is already exceptional.
const MAX_FAILOVERS_IN_A_ROW: u32 = 3;

type BrowserTx = SplitSink<WebSocket, Message>;

/// Largest websocket message (and frame) a browser may send, bytes. Simulator choice: the
/// largest command (a needle placement or an annotation with a 64-character label) is well under
/// 1 KiB as JSON; 64 KiB leaves room without letting one message cost megabytes (the library
/// default was 64 MiB).
pub const MAX_CLIENT_MESSAGE_BYTES: usize = 64 * 1024;

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
        Command::Live { on: false }
        | Command::Annotate { .. }
        | Command::Tick
        | Command::Submit => {
            return None;
        }
    })
}

/// Saves the frame hash of a session (its commands are written as they are acknowledged).
pub async fn persist(records: &RecordsState, session: &LiveSession) {
    let frame = session.state.lock().await.last_frame_sha256.clone();
    if let Err(e) = store::save_frame_hash(&records.pool, session.id, frame.as_deref()).await {
        tracing::error!(session = %session.id, "saving the session's frame hash failed: {e}");
    }
}

/// What the relay does after a message.
enum Flow {
    /// Go on with this worker connection.
    Stay,
    /// Connect to the session's (possibly new) placement again.
    Reconnect,
    /// End the browser connection.
    End,
}

/// One browser connection's relay state.
struct Relay {
    dispatcher: Dispatcher,
    records: RecordsState,
    session: Arc<LiveSession>,
    generation: u64,
    browser_tx: BrowserTx,
    /// Commands sent to the worker and not yet acknowledged or rejected: re-sent after failover.
    pending: BTreeMap<u64, (String, Command)>,
    first_hello: bool,
    failovers_in_a_row: u32,
    writer: LogWriter,
    outbox: Outbox,
}

/// Relays one browser connection until it closes (or a newer connection takes over).
pub async fn relay(
    dispatcher: Dispatcher,
    records: RecordsState,
    session: Arc<LiveSession>,
    socket: WebSocket,
    generation: u64,
) {
    let (browser_tx, mut browser_rx) = socket.split();
    session.connections.fetch_add(1, Ordering::SeqCst);
    let durable_now = session.state.lock().await.durable_len;
    let writer = LogWriter::start(records.pool.clone(), session.clone(), durable_now);
    let mut r = Relay {
        dispatcher,
        records,
        session,
        generation,
        browser_tx,
        pending: BTreeMap::new(),
        first_hello: true,
        failovers_in_a_row: 0,
        writer,
        outbox: Outbox::default(),
    };
    let mut tick = tokio::time::interval(std::time::Duration::from_millis(500));
    'connection: loop {
        let placement = r.session.state.lock().await.placement.clone();
        let (mut up_tx, mut up_rx) = match connect(&r.dispatcher, &placement).await {
            Ok(u) => u,
            Err(e) => {
                tracing::warn!(session = %r.session.id, worker = %placement.worker_label(), "cannot reach the session: {e}");
                match r.failover(&placement).await {
                    true => continue 'connection,
                    false => break 'connection,
                }
            }
        };
        // Re-send what the previous worker never answered (empty on the first connection).
        for (text, _) in r.pending.values() {
            if up_tx.send(WsMessage::Text(text.clone())).await.is_err() {
                continue 'connection;
            }
        }
        loop {
            let flow = tokio::select! {
                biased;
                m = up_rx.next() => r.on_worker_message(m, &placement).await,
                m = browser_rx.next() => r.on_browser_message(m, &mut up_tx).await,
                changed = r.writer.durable.changed() => r.log_became_durable(changed.is_ok()).await,
                _ = tick.tick() => r.on_timer(&mut up_tx).await,
            };
            match flow {
                Flow::Stay => {}
                Flow::Reconnect => continue 'connection,
                Flow::End => break 'connection,
            }
        }
    }
    r.finish().await;
}

impl Relay {
    /// One message (or the end) of the worker's stream.
    async fn on_worker_message(
        &mut self,
        m: Option<Result<WsMessage, String>>,
        placement: &Placement,
    ) -> Flow {
        match m {
            Some(Ok(WsMessage::Text(t))) => {
                self.failovers_in_a_row = 0;
                // Parsed once here; the text itself is what the browser gets.
                match serde_json::from_str::<ServerMessage>(&t) {
                    Ok(ServerMessage::Hello {
                        session: info,
                        last_seq,
                    }) => self.on_hello(info, last_seq).await,
                    Ok(ServerMessage::Ack(ack)) => self.on_ack(ack, t, placement).await,
                    Ok(ServerMessage::Error { seq, .. }) => self.on_error(seq, t).await,
                    Err(_) => self.pass_text(t).await,
                }
            }
            Some(Ok(WsMessage::Binary(b))) => self.on_frame(b).await,
            Some(Ok(WsMessage::Close)) | Some(Err(_)) | None => {
                self.on_worker_gone(placement).await
            }
        }
    }

    /// The worker's greeting: the first one goes to the browser under the server's session id.
    async fn on_hello(
        &mut self,
        mut info: render_worker::session::SessionInfo,
        last_seq: u64,
    ) -> Flow {
        if !self.first_hello {
            return Flow::Stay;
        }
        self.first_hello = false;
        info.id = self.session.id.to_string();
        let hello = ServerMessage::Hello {
            session: info,
            last_seq,
        };
        let text = serde_json::to_string(&hello).unwrap_or_default();
        self.pass_text(text).await
    }

    /// An acknowledgement: log the command (durably before the browser sees the ack), record
    /// its engagement event, and on a submit store the result once its log is durable.
    async fn on_ack(&mut self, ack: Ack, text: String, placement: &Placement) -> Flow {
        let command = self.pending.remove(&ack.seq).map(|(_, c)| c);
        let Some(command) = command.filter(|_| !ack.duplicate) else {
            return self.pass_text(text).await;
        };
        let needs = {
            let mut st = self.session.state.lock().await;
            st.log.push(LogEntry {
                seq: ack.seq,
                t_ms: ack.t_ms,
                command: command.clone(),
            });
            st.log.len()
        };
        self.writer.kick();
        self.record_engagement(&command, ack.seq);
        let mut result_message = None;
        if command == Command::Submit {
            // The result is stored only after the log it scores.
            if !self.writer.wait_durable(needs).await {
                return Flow::End;
            }
            let m = results::store_result(
                &self.records,
                &self.session,
                placement,
                ack.result.as_deref(),
            )
            .await;
            result_message = Some(m);
        }
        self.outbox.push(needs, text);
        if let Some(m) = result_message {
            self.outbox.push(needs, m.to_string());
        }
        self.release().await
    }

    /// A rejection: the command is no longer pending; the browser gets the error.
    async fn on_error(&mut self, seq: Option<u64>, text: String) -> Flow {
        if let Some(seq) = seq {
            self.pending.remove(&seq);
        }
        self.pass_text(text).await
    }

    /// A frame: its hash is kept (for the records), the frame goes straight to the browser.
    async fn on_frame(&mut self, b: Vec<u8>) -> Flow {
        let jpeg = b
            .get(render_worker::session::frame::HEADER_BYTES..)
            .unwrap_or_default();
        self.session.state.lock().await.last_frame_sha256 = Some(sha256_hex(jpeg));
        match self.browser_tx.send(Message::Binary(b.into())).await {
            Ok(()) => Flow::Stay,
            Err(_) => Flow::End,
        }
    }

    /// The worker's socket ended: move the session unless a newer connection owns it.
    async fn on_worker_gone(&mut self, placement: &Placement) -> Flow {
        if self.session.generation.load(Ordering::SeqCst) != self.generation {
            return Flow::End;
        }
        match self.failover(placement).await {
            true => Flow::Reconnect,
            false => Flow::End,
        }
    }

    /// One message (or the end) of the browser's socket.
    async fn on_browser_message(
        &mut self,
        m: Option<Result<Message, axum::Error>>,
        up_tx: &mut UpSink,
    ) -> Flow {
        match m {
            Some(Ok(Message::Text(t))) => {
                let t = t.to_string();
                // Parsed once here to remember the command; the worker parses the same text.
                if let Ok(ClientMessage::Command { seq, command }) = parse_client_message(&t) {
                    self.pending.insert(seq, (t.clone(), command));
                }
                // A send failure shows up as the worker stream ending: failover re-sends.
                let _ = up_tx.send(WsMessage::Text(t)).await;
                Flow::Stay
            }
            Some(Ok(Message::Binary(b))) => {
                let _ = up_tx.send(WsMessage::Binary(b.to_vec())).await;
                Flow::Stay
            }
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => Flow::Stay,
            Some(Err(e)) => {
                // Too large a frame or message (the limits of `routes::session_socket`), or a
                // protocol violation: say which, with the RFC 6455 close code, then end.
                let text = e.to_string();
                let (code, reason) = if text.contains("too long") || text.contains("too big") {
                    (
                        1009,
                        format!("message too large: at most {MAX_CLIENT_MESSAGE_BYTES} bytes"),
                    )
                } else {
                    (1002, "websocket protocol error".to_string())
                };
                tracing::info!(session = %self.session.id, "closing the browser socket: {text}");
                let frame = axum::extract::ws::CloseFrame {
                    code,
                    reason: reason.into(),
                };
                let _ = self.browser_tx.send(Message::Close(Some(frame))).await;
                let _ = up_tx.send(WsMessage::Close).await;
                Flow::End
            }
            Some(Ok(Message::Close(_))) | None => {
                let _ = up_tx.send(WsMessage::Close).await;
                Flow::End
            }
        }
    }

    /// More of the log is durable: release the messages that waited for it.
    async fn log_became_durable(&mut self, writer_alive: bool) -> Flow {
        if !writer_alive {
            tracing::error!(session = %self.session.id, "the session's log writer stopped");
            return Flow::End;
        }
        self.release().await
    }

    /// Every half second: end this connection when a newer one took the session over.
    async fn on_timer(&mut self, up_tx: &mut UpSink) -> Flow {
        if self.session.generation.load(Ordering::SeqCst) == self.generation {
            return Flow::Stay;
        }
        let note =
            json!({ "type": "notice", "message": "this session was opened in another window" });
        let _ = self
            .browser_tx
            .send(Message::Text(note.to_string().into()))
            .await;
        let _ = up_tx.send(WsMessage::Close).await;
        Flow::End
    }

    /// Queues a text for the browser behind the log as it is now, and releases what can go.
    async fn pass_text(&mut self, text: String) -> Flow {
        let needs = self.session.state.lock().await.log.len();
        self.outbox.push(needs, text);
        self.release().await
    }

    async fn release(&mut self) -> Flow {
        match self
            .outbox
            .release(self.writer.durable_len(), &mut self.browser_tx)
            .await
        {
            true => Flow::Stay,
            false => Flow::End,
        }
    }

    /// The engagement event of an acknowledged command, recorded in the background.
    fn record_engagement(&self, command: &Command, seq: u64) {
        let Some(kind) = activity_of(command) else {
            return;
        };
        let (pool, s) = (self.records.pool.clone(), self.session.clone());
        let detail = json!({ "session_id": s.id, "seq": seq, "command": command.name() });
        tokio::spawn(async move {
            if let Err(e) = record_activity(&pool, s.attempt_id, s.learner_id, kind, detail).await {
                tracing::warn!("recording activity failed: {e}");
            }
        });
    }

    async fn failover(&mut self, failed: &Placement) -> bool {
        failover(
            &self.dispatcher,
            &self.session,
            failed,
            &mut self.failovers_in_a_row,
            &mut self.browser_tx,
        )
        .await
    }

    /// After the connection: the last log flush, the frame hash, and a submitted session's
    /// worker freed.
    async fn finish(mut self) {
        self.writer.finish().await;
        persist(&self.records, &self.session).await;
        if let Ok(mut t) = self.session.last_active.lock() {
            *t = std::time::Instant::now();
        }
        self.session.connections.fetch_sub(1, Ordering::SeqCst);
        // A submitted session is finished: free its worker (replays run from the stored log).
        if self.session.state.lock().await.result_id.is_some()
            && self.session.generation.load(Ordering::SeqCst) == self.generation
        {
            self.dispatcher.close(self.session.id).await;
        }
        let _ = self.browser_tx.send(to_axum(WsMessage::Close)).await;
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
    async fn release(&mut self, durable: usize, browser_tx: &mut BrowserTx) -> bool {
        while self
            .held
            .front()
            .is_some_and(|(needs, _)| *needs <= durable)
        {
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

/// Moves the session to another worker; tells the browser. False when it cannot.
async fn failover(
    dispatcher: &Dispatcher,
    session: &LiveSession,
    failed: &Placement,
    in_a_row: &mut u32,
    browser_tx: &mut BrowserTx,
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

fn to_axum(m: WsMessage) -> Message {
    match m {
        WsMessage::Text(t) => Message::Text(t.into()),
        WsMessage::Binary(b) => Message::Binary(b.into()),
        WsMessage::Close => Message::Close(None),
    }
}
