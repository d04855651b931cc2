//! The relay between the browser's websocket and the worker's session: one handler per message
//! kind, around one `select!` over the worker, the browser, the log writer and a timer.
//!
//! The relay never awaits a send to the browser or to the worker: each has a writer task
//! ([`super::browser`], `Upstream`), and the relay applies backpressure by not *reading* the
//! browser while too much waits ([`MAX_IN_FLIGHT`], [`MAX_UNREAD_ANSWERS`]). So no cycle of
//! bounded channels can wedge a connection: the worker's answers are always read, and a client
//! that sends without reading is held by TCP, not by the server.
//!
//! What it keeps: the server's copy of the session log (each acknowledged command, committed by
//! [`LogWriter`] before the acknowledgement is passed on), engagement events for the learning
//! records, the submit's result (stored through [`super::results`]), and failover to another
//! worker with the unacknowledged commands sent again.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use axum::extract::ws::{Message, WebSocket};
use futures::{SinkExt, StreamExt};
use render_worker::session::protocol::{
    ClientMessage, ServerMessage, WsMessage, parse_client_message,
};
use render_worker::session::{Ack, Command, Engagement as Declared, LogEntry, sha256_hex};
use serde_json::json;
use tokio::sync::mpsc;

use super::browser::BrowserWriter;
use super::disclosure;
use super::durable::LogWriter;
use super::upstream::{UpSink, connect};
use super::{
    CLOSE_LOG_REFUSED, CLOSE_TAKEN_OVER, Dispatcher, LiveSession, Placement, results, store,
};
use crate::records::RecordsState;
use crate::records::activity::{ActivityKind, record_activity};
use crate::records::modes::{StationMode, mode_of_attempt};

/// How many times in a row one connection tries to move its session before giving up.
/// Simulator choice: two dead workers in a row is already exceptional.
const MAX_FAILOVERS_IN_A_ROW: u32 = 3;

/// Largest websocket message (and frame) a browser may send, bytes. Simulator choice: the
/// largest command (a needle placement or an annotation with a 64-character label) is well under
/// 1 KiB as JSON; 64 KiB leaves room without letting one message cost megabytes (the library
/// default was 64 MiB).
pub const MAX_CLIENT_MESSAGE_BYTES: usize = 64 * 1024;

/// The learning-record event of an engagement the worker declared in an acknowledgement (the
/// session core or the modality that handled the command decides it; the relay keeps no list of
/// command kinds).
fn activity_of(engagement: Declared) -> ActivityKind {
    match engagement {
        Declared::ViewChanged => ActivityKind::ViewChanged,
        Declared::ImageAcquired => ActivityKind::ImageAcquired,
        Declared::NeedleAdjusted => ActivityKind::NeedleAdjusted,
        Declared::Injection => ActivityKind::Injection,
    }
}

/// Saves the frame hash of a session (its commands are written as they are acknowledged).
pub async fn persist(records: &RecordsState, session: &LiveSession) {
    let (frame, epoch) = {
        let st = session.state.lock().await;
        (st.last_frame_sha256.clone(), st.epoch)
    };
    if let Err(e) = store::save_frame_hash(&records.pool, session.id, epoch, frame.as_deref()).await
    {
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

/// Most commands sent to the worker and not yet answered. Simulator choice: far above what a
/// browser has in flight (one per input event), small enough that a flood costs little memory;
/// at the limit the relay stops reading the browser until answers come back.
pub const MAX_IN_FLIGHT: usize = 1024;

/// Most answers (acknowledgements, errors, notices) waiting for the browser to read them
/// before the relay stops reading the browser. Simulator choice: above the 10,000-command
/// burst of `tests/dispatch_hardening.rs` (a client may send that many without reading and
/// still get every answer once it reads), a few megabytes of small JSON at most; a client that
/// runs further ahead is held by TCP backpressure, never by a wedged relay.
pub const MAX_UNREAD_ANSWERS: usize = 16_384;

/// How long a relay whose browser left goes on taking the worker's answers to commands it had
/// already sent (a submit among them is then logged and its result stored, and the slot of a
/// submitted session freed). Simulator choice: the worker answers in milliseconds and the log
/// write takes a round trip; ten seconds bounds a slow database.
const DRAIN: std::time::Duration = std::time::Duration::from_secs(10);

/// A close reason fits in a control frame: at most 123 bytes (RFC 6455, 5.5).
fn close_reason(text: &str) -> String {
    let mut end = text.len().min(123);
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    text[..end].to_string()
}

/// Messages towards the worker: a task of its own, so the relay never waits on the worker
/// while the worker may be waiting on the relay (see [`super::browser`]).
struct Upstream {
    queue: mpsc::UnboundedSender<WsMessage>,
    unsent: Arc<AtomicUsize>,
}

impl Upstream {
    fn start(mut sink: UpSink) -> Upstream {
        let (queue, mut rx) = mpsc::unbounded_channel::<WsMessage>();
        let unsent = Arc::new(AtomicUsize::new(0));
        let left = unsent.clone();
        tokio::spawn(async move {
            while let Some(m) = rx.recv().await {
                let r = sink.send(m).await;
                left.fetch_sub(1, Ordering::SeqCst);
                // A send failure shows up as the worker stream ending: failover re-sends.
                if r.is_err() {
                    return;
                }
            }
        });
        Upstream { queue, unsent }
    }

    /// Queues a message for the worker (never waits).
    fn send(&self, m: WsMessage) {
        self.unsent.fetch_add(1, Ordering::SeqCst);
        if self.queue.send(m).is_err() {
            self.unsent.fetch_sub(1, Ordering::SeqCst);
        }
    }

    fn unsent(&self) -> usize {
        self.unsent.load(Ordering::SeqCst)
    }
}

/// Engagement events of one connection, recorded in order by one task (a burst of commands
/// is a queue of inserts, not thousands of tasks competing for the pool with the log writer).
struct Engagement {
    queue: mpsc::UnboundedSender<(ActivityKind, serde_json::Value)>,
}

impl Engagement {
    fn start(records: &RecordsState, session: &LiveSession) -> Engagement {
        let (queue, mut rx) = mpsc::unbounded_channel::<(ActivityKind, serde_json::Value)>();
        let pool = records.pool.clone();
        let (attempt, learner) = (session.attempt_id, session.learner_id);
        tokio::spawn(async move {
            while let Some((kind, detail)) = rx.recv().await {
                if let Err(e) = record_activity(&pool, attempt, learner, kind, detail).await {
                    tracing::warn!("recording activity failed: {e}");
                }
            }
        });
        Engagement { queue }
    }
}

/// One browser connection's relay state.
struct Relay {
    dispatcher: Dispatcher,
    records: RecordsState,
    session: Arc<LiveSession>,
    generation: u64,
    browser: BrowserWriter,
    /// Commands sent to the worker and not yet acknowledged or rejected: re-sent after failover.
    pending: BTreeMap<u64, (String, Command)>,
    first_hello: bool,
    /// The attempt's mode: what the browser may be told ([`super::disclosure`]).
    mode: StationMode,
    failovers_in_a_row: u32,
    writer: LogWriter,
    outbox: Outbox,
    engagement: Engagement,
    /// The close code and reason the browser gets when the connection ends.
    close_with: Option<(u16, String)>,
    /// Set when the browser left with commands in flight: until when their answers are awaited.
    draining: Option<tokio::time::Instant>,
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
    let browser = BrowserWriter::start(browser_tx);
    let mut browser_progress = browser.sent.clone();
    let mut ended = session.ended.subscribe();
    let mode = mode_of_attempt(&records.pool, session.attempt_id).await;
    let mut r = Relay {
        engagement: Engagement::start(&records, &session),
        dispatcher,
        records,
        session,
        generation,
        browser,
        pending: BTreeMap::new(),
        first_hello: true,
        mode,
        failovers_in_a_row: 0,
        writer,
        outbox: Outbox::default(),
        close_with: None,
        draining: None,
    };
    let mut tick = tokio::time::interval(std::time::Duration::from_millis(500));
    'connection: loop {
        if let Some(end) = r.session.end_reason() {
            r.close_with = Some(end);
            break 'connection;
        }
        let placement = r.session.state.lock().await.placement.clone();
        let (up_tx, mut up_rx) = match connect(&r.dispatcher, &placement).await {
            Ok(u) => u,
            Err(e) => {
                tracing::warn!(session = %r.session.id, worker = %placement.worker_label(), "cannot reach the session: {e}");
                match r.failover(&placement).await {
                    true => continue 'connection,
                    false => break 'connection,
                }
            }
        };
        let up = Upstream::start(up_tx);
        // Re-send what the previous worker never answered (empty on the first connection).
        for (text, _) in r.pending.values() {
            up.send(WsMessage::Text(text.clone()));
        }
        loop {
            // Backpressure: read the browser only while the worker and the browser keep up.
            let reading = r.draining.is_none()
                && r.pending.len() < MAX_IN_FLIGHT
                && up.unsent() < MAX_IN_FLIGHT
                && r.outbox.held.len() + r.browser.unsent() < MAX_UNREAD_ANSWERS;
            let drain_until = r.draining.unwrap_or_else(tokio::time::Instant::now);
            let flow = tokio::select! {
                biased;
                _ = ended.changed() => r.on_ended(),
                m = up_rx.next() => r.on_worker_message(m, &placement).await,
                changed = r.writer.durable.changed() => r.log_became_durable(changed.is_ok()).await,
                m = browser_rx.next(), if reading => r.on_browser_message(m, &up).await,
                p = browser_progress.changed(), if !reading && r.draining.is_none() => match p {
                    Ok(()) => Flow::Stay,
                    Err(_) => r.browser_gone(&up),
                },
                () = tokio::time::sleep_until(drain_until), if r.draining.is_some() => Flow::End,
                _ = tick.tick() => r.on_timer(&up),
            };
            match flow {
                Flow::Stay if r.draining.is_some() && r.pending.is_empty() => break 'connection,
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
                // Parsed once here; acknowledgements and the hello reach the browser as
                // `disclosure` rewrites them (errors too: see `error_for_browser`).
                match serde_json::from_str::<ServerMessage>(&t) {
                    Ok(ServerMessage::Hello {
                        session: info,
                        last_seq,
                    }) => self.on_hello(info, last_seq).await,
                    Ok(ServerMessage::Ack(ack)) => self.on_ack(ack, placement).await,
                    Ok(ServerMessage::Error { seq, .. }) => {
                        self.on_error(seq, disclosure::error_for_browser(t)).await
                    }
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
        let text = disclosure::hello_for_browser(&hello, self.mode);
        self.pass_text(text).await
    }

    /// An acknowledgement: log the command (durably before the browser sees the ack), record
    /// its engagement event, and on a submit store the result once its log is durable.
    async fn on_ack(&mut self, ack: Ack, placement: &Placement) -> Flow {
        let text = disclosure::ack_for_browser(&ack, self.mode);
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
        self.record_engagement(&command, ack.engagement, ack.seq);
        let mut result_message = None;
        if command == Command::Submit {
            // The result is stored only after the log it scores.
            if !self.writer.wait_durable(needs).await {
                return self.on_log_refused().await;
            }
            let m = results::store_result(
                &self.records,
                &self.session,
                placement,
                ack.result.as_deref(),
            )
            .await;
            result_message = Some(disclosure::result_for_browser(
                m,
                self.mode,
                self.session.attempt_id,
            ));
        }
        self.outbox.push(needs, text);
        if let Some(m) = result_message {
            self.outbox.push(needs, m.to_string());
        }
        self.release()
    }

    /// A rejection: the command is no longer pending; the browser gets the error.
    async fn on_error(&mut self, seq: Option<u64>, text: String) -> Flow {
        if let Some(seq) = seq {
            self.pending.remove(&seq);
        }
        self.pass_text(text).await
    }

    /// A frame: the hash of a full fluoroscopy frame is kept (for the records: the replay check
    /// re-renders the fluoroscopy view, see `verify`; ultrasound and placement frames of the
    /// same session would otherwise stand in for it), the frame goes to the browser (newest wins
    /// when the browser is slow).
    async fn on_frame(&mut self, b: Vec<u8>) -> Flow {
        use render_worker::session::frame::{FLAG_DRAFT, HEADER_BYTES};
        // A draft is never the image of record: the full frame of the same input follows it.
        let draft = b.get(6).is_some_and(|f| f & FLAG_DRAFT != 0);
        if !draft && b.get(5) == Some(&render_worker::session::ViewId::FLUOROSCOPY.code()) {
            let jpeg = b.get(HEADER_BYTES..).unwrap_or_default();
            self.session.state.lock().await.last_frame_sha256 = Some(sha256_hex(jpeg));
        }
        self.browser.frame(b);
        Flow::Stay
    }

    /// The worker's socket ended: move the session unless a newer connection owns it or the
    /// session was ended on purpose.
    async fn on_worker_gone(&mut self, placement: &Placement) -> Flow {
        if self.session.generation.load(Ordering::SeqCst) != self.generation {
            return Flow::End;
        }
        if self.session.end_reason().is_some() {
            return self.on_ended();
        }
        match self.failover(placement).await {
            true => Flow::Reconnect,
            false => Flow::End,
        }
    }

    /// The session was ended by the server (idle, or its log refused): tell the browser why.
    fn on_ended(&mut self) -> Flow {
        match self.session.end_reason() {
            Some(end) => {
                if end.0 == CLOSE_TAKEN_OVER {
                    let note = json!({ "type": "notice", "code": "taken_over", "message": end.1 });
                    let _ = self.browser.text(note.to_string());
                }
                self.close_with = Some(end);
                Flow::End
            }
            None => Flow::Stay,
        }
    }

    /// One message (or the end) of the browser's socket.
    async fn on_browser_message(
        &mut self,
        m: Option<Result<Message, axum::Error>>,
        up: &Upstream,
    ) -> Flow {
        match m {
            Some(Ok(Message::Text(t))) => {
                let t = t.to_string();
                // Parsed once here to remember the command; the worker parses the same text
                // (and answers a bad one, in order with the others).
                if let Ok(ClientMessage::Command { seq, command }) = parse_client_message(&t) {
                    self.session.touch_command();
                    self.pending.insert(seq, (t.clone(), command));
                }
                up.send(WsMessage::Text(t));
                Flow::Stay
            }
            Some(Ok(Message::Binary(b))) => {
                up.send(WsMessage::Binary(b.to_vec()));
                Flow::Stay
            }
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => Flow::Stay,
            Some(Err(e)) => {
                // Too large a frame or message (the limits of `routes::session_socket`), or a
                // protocol violation: say which, with the RFC 6455 close code, then end. A
                // socket that just went away (reset, no closing handshake) is a browser gone.
                let text = e.to_string();
                tracing::info!(session = %self.session.id, "closing the browser socket: {text}");
                if text.contains("too long") || text.contains("too big") {
                    let reason =
                        format!("message too large: at most {MAX_CLIENT_MESSAGE_BYTES} bytes");
                    self.close_with = Some((1009, reason));
                    up.send(WsMessage::Close);
                    return Flow::End;
                }
                let gone = text.contains("without closing handshake")
                    || text.contains("IO error")
                    || text.contains("Connection reset");
                if !gone {
                    self.close_with = Some((1002, "websocket protocol error".to_string()));
                }
                self.browser_gone(up)
            }
            Some(Ok(Message::Close(_))) | None => self.browser_gone(up),
        }
    }

    /// The browser left: end now, or, with commands in flight (a submit, perhaps), once their
    /// answers are in (at most [`DRAIN`]).
    fn browser_gone(&mut self, up: &Upstream) -> Flow {
        if self.pending.is_empty() {
            up.send(WsMessage::Close);
            return Flow::End;
        }
        if self.draining.is_none() {
            self.draining = Some(tokio::time::Instant::now() + DRAIN);
        }
        Flow::Stay
    }

    /// More of the log is durable: release the messages that waited for it. When the writer
    /// stopped, the log was refused for good: the session ends.
    async fn log_became_durable(&mut self, writer_alive: bool) -> Flow {
        if !writer_alive {
            return self.on_log_refused().await;
        }
        self.release()
    }

    /// The database refuses the session's log (a write that can never succeed): end the
    /// session with a close code and reason, an audit entry, and its worker slot freed. The
    /// refused commands were never acknowledged to the browser; opening the attempt again
    /// resumes from the stored log.
    async fn on_log_refused(&mut self) -> Flow {
        let failure = self.writer.failure();
        if let Some(epoch) = failure.as_ref().and_then(|f| f.fenced_at) {
            return self.on_taken_over(epoch).await;
        }
        let reason = failure
            .map(|f| f.message)
            .unwrap_or_else(|| "the session's log writer stopped".into());
        tracing::error!(session = %self.session.id, "ending the session: its log cannot be stored: {reason}");
        let message = "the session's log cannot be stored; the session is closed (open the attempt again to resume from its last stored command)";
        let short = "the session's log cannot be stored; the session is closed (reopen the attempt to resume)";
        self.session.end(CLOSE_LOG_REFUSED, &close_reason(short));
        let durable = self.writer.durable_len();
        let note = json!({ "type": "notice", "code": "log_refused", "message": message });
        let _ = self.browser.text(note.to_string());
        self.close_with = Some((CLOSE_LOG_REFUSED, close_reason(short)));
        let detail = json!({ "attempt_id": self.session.attempt_id, "reason": reason, "durable_commands": durable });
        self.dispatcher
            .end_session(
                &self.records,
                self.session.id,
                "session_ended_log_refused",
                detail,
            )
            .await;
        Flow::End
    }

    /// The database refused this copy's epoch: another connection (on another replica, or a
    /// newer one here) took the session over. Nothing refused was acknowledged; this connection
    /// ends, and this replica forgets the session unless a newer connection of its own holds it.
    async fn on_taken_over(&mut self, epoch: i64) -> Flow {
        let short = "the session was opened in another connection";
        let note = json!({ "type": "notice", "code": "taken_over", "message": short });
        let _ = self.browser.text(note.to_string());
        self.close_with = Some((CLOSE_TAKEN_OVER, short.to_string()));
        self.dispatcher
            .forget_taken_over(self.session.id, epoch)
            .await;
        Flow::End
    }

    /// Every half second: end this connection when a newer one took the session over.
    fn on_timer(&mut self, up: &Upstream) -> Flow {
        if self.session.generation.load(Ordering::SeqCst) == self.generation {
            return Flow::Stay;
        }
        let note =
            json!({ "type": "notice", "message": "this session was opened in another window" });
        let _ = self.browser.text(note.to_string());
        up.send(WsMessage::Close);
        Flow::End
    }

    /// Queues a text for the browser behind the log as it is now, and releases what can go.
    async fn pass_text(&mut self, text: String) -> Flow {
        let needs = self.session.state.lock().await.log.len();
        self.outbox.push(needs, text);
        self.release()
    }

    fn release(&mut self) -> Flow {
        let delivered = self
            .outbox
            .release(self.writer.durable_len(), &self.browser);
        if delivered {
            return Flow::Stay;
        }
        // The browser is gone: end, or first take the answers to what is in flight.
        if self.pending.is_empty() {
            return Flow::End;
        }
        self.draining
            .get_or_insert_with(|| tokio::time::Instant::now() + DRAIN);
        Flow::Stay
    }

    /// The engagement event of an acknowledged command, recorded in the background.
    fn record_engagement(&self, command: &Command, engagement: Option<Declared>, seq: u64) {
        let Some(kind) = engagement.map(activity_of) else {
            return;
        };
        let detail =
            json!({ "session_id": self.session.id, "seq": seq, "command": command.name() });
        let _ = self.engagement.queue.send((kind, detail));
    }

    async fn failover(&mut self, failed: &Placement) -> bool {
        failover(
            &self.dispatcher,
            &self.session,
            failed,
            &mut self.failovers_in_a_row,
            &self.browser,
        )
        .await
    }

    /// After the connection: the last log flush, the frame hash, a submitted session's worker
    /// freed, and the browser's socket closed (with the code and reason, if any).
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
        let close = self.close_with.take();
        self.browser.close(close).await;
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

    /// Hands the browser, in order, every message whose log prefix is durable. False when the
    /// browser is gone.
    fn release(&mut self, durable: usize, browser: &BrowserWriter) -> bool {
        while self
            .held
            .front()
            .is_some_and(|(needs, _)| *needs <= durable)
        {
            let Some((_, text)) = self.held.pop_front() else {
                break;
            };
            if !browser.text(text) {
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
    browser: &BrowserWriter,
) -> bool {
    *in_a_row += 1;
    if *in_a_row > MAX_FAILOVERS_IN_A_ROW {
        let note = json!({ "type": "notice", "message": "the session could not be moved to a working render worker" });
        let _ = browser.text(note.to_string());
        return false;
    }
    let record = session.state.lock().await.clone();
    if &record.placement != failed {
        // Another connection already moved it.
        return true;
    }
    let started = std::time::Instant::now();
    match dispatcher.restore_elsewhere(failed, &record).await {
        Ok(placement) => {
            tracing::warn!(session = %session.id, from = %failed.worker_label(), to = %placement.worker_label(), log = record.log.len(), took_ms = started.elapsed().as_millis() as u64, "session restored on another worker");
            let mut st = session.state.lock().await;
            st.placement = placement.clone();
            st.failovers += 1;
            let record = st.clone();
            drop(st);
            dispatcher.record_placement(session.id, &record).await;
            let note = json!({ "type": "notice", "message": "render worker lost; the session continues on another worker", "worker": placement.worker_label() });
            let _ = browser.text(note.to_string());
            true
        }
        Err(e) => {
            tracing::error!(session = %session.id, "failover failed: {e}");
            let note = json!({ "type": "notice", "message": format!("the session could not be moved: {e}") });
            let _ = browser.text(note.to_string());
            false
        }
    }
}
