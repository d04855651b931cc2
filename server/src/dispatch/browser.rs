//! The writing half of the browser's websocket: a task of its own, so that the relay never
//! waits on a browser that does not read.
//!
//! # Why a task
//! Before, the relay sent to the browser inline. A client that sent hundreds of commands
//! without reading filled its socket, the relay's send waited, the relay stopped reading the
//! worker, the worker stopped reading the relay, and the relay's send to the worker waited too:
//! a cycle of bounded channels that wedged the connection. Now the relay
//! hands texts to this task through an unbounded queue and never awaits the browser; what
//! bounds the queue is the relay's admission rule: it stops *reading* the browser while too many
//! answers wait here ([`BrowserWriter::unsent`]), so TCP backpressure holds a client that runs
//! too far ahead, and nothing in the server waits on anything that waits on it.
//!
//! Frames are not queued: the newest frame of each view replaces an unsent older one, so a slow
//! browser skips frames (as the worker's own connection does) and never holds more than one
//! frame per view here.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use axum::extract::ws::{CloseFrame, Message, WebSocket};
use futures::SinkExt;
use futures::stream::SplitSink;
use tokio::sync::{Notify, mpsc, watch};

/// How long the end of a connection waits for queued answers to reach a browser that does not
/// read before giving up on it. Simulator choice: long enough for a slow network to take the
/// last acknowledgements, short enough that a client that stopped reading cannot hold the relay.
const FINAL_FLUSH: Duration = Duration::from_secs(5);

enum Out {
    Text(String),
    Close(Option<CloseFrame>),
}

/// Frames waiting to be sent: the newest of each view (by the frame header's view code).
type LatestFrames = Arc<Mutex<BTreeMap<u8, Vec<u8>>>>;

/// Handle of the writer task of one browser connection.
pub struct BrowserWriter {
    queue: mpsc::UnboundedSender<Out>,
    frames: LatestFrames,
    frame_ready: Arc<Notify>,
    unsent: Arc<AtomicUsize>,
    /// Texts sent so far; the sender is dropped (`changed()` fails) when the browser is gone.
    pub sent: watch::Receiver<u64>,
    task: tokio::task::JoinHandle<()>,
}

impl BrowserWriter {
    /// Starts the writer over the socket's sending half.
    pub fn start(mut tx: SplitSink<WebSocket, Message>) -> BrowserWriter {
        let (queue, mut rx) = mpsc::unbounded_channel::<Out>();
        let frames: LatestFrames = Arc::default();
        let frame_ready = Arc::new(Notify::new());
        let unsent = Arc::new(AtomicUsize::new(0));
        let (sent_tx, sent) = watch::channel(0u64);
        let (f, ready, left) = (frames.clone(), frame_ready.clone(), unsent.clone());
        let task = tokio::spawn(async move {
            loop {
                tokio::select! {
                    biased;
                    m = rx.recv() => match m {
                        Some(Out::Text(t)) => {
                            let ok = tx.send(Message::Text(t.into())).await.is_ok();
                            left.fetch_sub(1, Ordering::SeqCst);
                            if !ok {
                                break;
                            }
                            sent_tx.send_modify(|n| *n += 1);
                        }
                        Some(Out::Close(frame)) => {
                            let _ = tx.send(Message::Close(frame)).await;
                            break;
                        }
                        None => {
                            let _ = tx.send(Message::Close(None)).await;
                            break;
                        }
                    },
                    () = ready.notified() => {
                        let latest = f.lock().map(|mut m| std::mem::take(&mut *m)).unwrap_or_default();
                        for (_, b) in latest {
                            if tx.send(Message::Binary(b.into())).await.is_err() {
                                return;
                            }
                        }
                    }
                }
            }
        });
        BrowserWriter {
            queue,
            frames,
            frame_ready,
            unsent,
            sent,
            task,
        }
    }

    /// Queues a text (never waits). False when the browser is gone.
    pub fn text(&self, text: String) -> bool {
        self.unsent.fetch_add(1, Ordering::SeqCst);
        if self.queue.send(Out::Text(text)).is_err() {
            self.unsent.fetch_sub(1, Ordering::SeqCst);
            return false;
        }
        true
    }

    /// Offers a frame (never waits): it replaces an unsent older frame of the same view.
    pub fn frame(&self, bytes: Vec<u8>) {
        // Byte 5 of the header is the view (see `render_worker::session::frame`).
        let view = bytes.get(5).copied().unwrap_or(0);
        if let Ok(mut m) = self.frames.lock() {
            m.insert(view, bytes);
        }
        self.frame_ready.notify_one();
    }

    /// Texts queued and not yet written to the socket.
    pub fn unsent(&self) -> usize {
        self.unsent.load(Ordering::SeqCst)
    }

    /// Sends what is queued, then a close frame with `code` and `reason` (`None`: a plain
    /// close), waiting at most [`FINAL_FLUSH`] for a browser that does not read.
    pub async fn close(self, code_reason: Option<(u16, String)>) {
        let frame = code_reason.map(|(code, reason)| CloseFrame {
            code,
            reason: reason.into(),
        });
        let _ = self.queue.send(Out::Close(frame));
        let BrowserWriter { queue, task, .. } = self;
        drop(queue);
        let abort = task.abort_handle();
        if tokio::time::timeout(FINAL_FLUSH, task).await.is_err() {
            abort.abort();
        }
    }
}
