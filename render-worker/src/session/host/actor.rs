//! The session thread: its loop over input (commands, visibility, snapshots), the pauses in
//! which it prefetches, and its progressive frames (a draft, then the full frame at low
//! priority), published into the session's frame set.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use tokio::sync::{mpsc, oneshot, watch};

use crate::session::command::{Command, CommandError, Envelope, LogEntry};
use crate::session::frame::EncodedFrame;
use crate::session::image::ViewId;
use crate::session::machine::{Ack, Session, SessionSnapshot};
use crate::session::scoring::SubmitResult;

/// Latest frame of each view.
pub type FrameSet = Arc<BTreeMap<ViewId, Arc<EncodedFrame>>>;

/// Replies to one connection, in order.
#[derive(Debug, Clone)]
pub enum Reply {
    /// A command was accepted.
    Ack(Ack),
    /// A command was rejected.
    Error {
        /// Its sequence number.
        seq: Option<u64>,
        /// Why.
        error: CommandError,
    },
}

/// What a session thread is sent.
pub(super) enum ActorMsg {
    Command {
        env: Envelope,
        reply: mpsc::UnboundedSender<Reply>,
    },
    Visible(BTreeSet<ViewId>),
    Snapshot(oneshot::Sender<(SessionSnapshot, Vec<LogEntry>)>),
    Score(oneshot::Sender<SubmitResult>),
    Close,
}

/// What tells a session thread that the refinement it renders is obsolete: the command kinds
/// of its modalities that move a view (`CommandSpec::supersedes`), and the flag the host
/// raises when one is sent (see `crate::interrupt`).
#[derive(Clone)]
pub(super) struct Supersede {
    kinds: Arc<BTreeSet<&'static str>>,
    flag: Arc<AtomicBool>,
    /// Raised for every command sent (see `interrupt::watching_input`).
    input: Arc<AtomicBool>,
}

impl Supersede {
    /// The kinds `session`'s modalities declare, the flag lowered.
    pub(super) fn of(session: &Session) -> Supersede {
        let kinds = session
            .specs()
            .iter()
            .flat_map(|s| s.commands.iter())
            .filter(|c| c.supersedes)
            .map(|c| c.kind)
            .collect();
        Supersede {
            kinds: Arc::new(kinds),
            flag: Arc::new(AtomicBool::new(false)),
            input: Arc::new(AtomicBool::new(false)),
        }
    }

    /// Whether `command` moves a view of the session.
    pub(super) fn moves_a_view(&self, command: &Command) -> bool {
        self.kinds.contains(command.name())
    }

    /// Marks a command that moves a view as waiting.
    pub(super) fn raise(&self) {
        self.flag.store(true, Ordering::SeqCst);
    }

    /// Marks a command, whatever it does, as waiting.
    pub(super) fn raise_input(&self) {
        self.input.store(true, Ordering::SeqCst);
    }

    /// This thread's watch of both flags around work nobody waits on yet (a refinement, a
    /// prefetch): stopped by a command that moves its view (`interrupt::watching`), and out of
    /// line for any command while it waits for its turn (`interrupt::watching_input`).
    fn watched(&self) -> [crate::interrupt::Watching; 2] {
        [
            crate::interrupt::watching(&self.flag),
            crate::interrupt::watching_input(&self.input),
        ]
    }

    /// Marks nothing waiting: called by the session thread before it looks at its queue, so
    /// that only commands sent from then on raise the flag.
    fn lower(&self) {
        self.flag.store(false, Ordering::SeqCst);
        self.input.store(false, Ordering::SeqCst);
    }
}

/// How long the input must pause before the session prefetches a view it may be asked for
/// (a moved C-arm come to rest: see `Modality::prefetch_pending`). Simulator choice: a drag
/// sends a pose every pointer event (16 ms apart while the pointer moves), so 150 ms without
/// one is a C-arm set down; a learner then presses the pedal, typically a few hundred ms later,
/// and the shot finds its view prepared (a new shot of a kept view costs only noise and display).
pub const PREFETCH_AFTER_PAUSE: std::time::Duration = std::time::Duration::from_millis(150);

/// How often a session looks for input while it waits out a pause (see
/// [`PREFETCH_AFTER_PAUSE`]): what a command that comes then may wait at most. Simulator
/// choice: 2 ms, well under a frame's time, and 75 looks per pause cost no measurable CPU. (The
/// session thread waits without a runtime's timer: the runtime it was started in may end
/// before it does.)
const PAUSE_POLL: std::time::Duration = std::time::Duration::from_millis(2);

/// The session's next message, `Some(None)` when `pause` passed without one, `None` when the
/// host has gone.
fn next_message(
    rx: &mut mpsc::UnboundedReceiver<ActorMsg>,
    pause: Option<std::time::Duration>,
) -> Option<Option<ActorMsg>> {
    let Some(pause) = pause else {
        return rx.blocking_recv().map(Some);
    };
    let until = Instant::now() + pause;
    loop {
        match rx.try_recv() {
            Ok(m) => return Some(Some(m)),
            Err(mpsc::error::TryRecvError::Disconnected) => return None,
            Err(mpsc::error::TryRecvError::Empty) if Instant::now() >= until => {
                return Some(None);
            }
            Err(mpsc::error::TryRecvError::Empty) => std::thread::sleep(PAUSE_POLL),
        }
    }
}

pub(super) fn run_actor(
    mut session: Session,
    mut rx: mpsc::UnboundedReceiver<ActorMsg>,
    frames: watch::Sender<FrameSet>,
    mut visible: BTreeSet<ViewId>,
    supersede: Supersede,
) {
    // Before the first input: a learner looks at the station before the first shot, and the
    // renderer and the first view are ready by then (a command that comes sooner waits for
    // this, no longer than its own frame would have taken).
    {
        let _busy = crate::alloc::busy();
        session.prefetch();
    }
    let started = Instant::now();
    let base_ms = session.world().clock_ms;
    let mut frame_seq = 0u64;
    // The last refinement was stopped for newer input: its view is still dirty, so the input
    // is taken without waiting for more.
    let mut stopped = false;
    loop {
        let retry = std::mem::take(&mut stopped);
        let pause = if retry {
            Some(std::time::Duration::ZERO)
        } else {
            session
                .prefetch_pending(&visible)
                .then_some(PREFETCH_AFTER_PAUSE)
        };
        let first = match next_message(&mut rx, pause) {
            Some(Some(m)) => Some(m),
            // Nothing new since the stopped refinement: it is drawn again.
            Some(None) if retry => None,
            Some(None) => {
                // The input paused with a view to prepare: prepared at low priority (work
                // nobody waits on yet, see `priority`), and given up for input that moves
                // the view again (see `interrupt`; lowered first: nothing waits now).
                let _busy = crate::alloc::busy();
                let _refining = crate::priority::refining();
                supersede.lower();
                let _watching = supersede.watched();
                session.prefetch();
                continue;
            }
            None => break,
        };
        // Lowered before the queue is drained: a command that moves a view from now on is
        // one this thread has not taken yet.
        supersede.lower();
        // Stopped for nothing new (the flag was raised for a command taken just before): the
        // stopped view's draft is still the one on screen.
        let mut draft_shown = retry && first.is_none();
        let mut batch: Vec<ActorMsg> = first.into_iter().collect();
        while let Ok(m) = rx.try_recv() {
            batch.push(m);
        }
        for msg in batch {
            match msg {
                ActorMsg::Command { env, reply } => {
                    let seq = env.seq;
                    let clock = || base_ms + started.elapsed().as_millis() as u64;
                    let mut now = clock();
                    // A tick a little early for a pulse that images a waiting change is held
                    // until that pulse (see `pulse::TICK_HOLD_PERIOD_FRACTION`).
                    if env.command == Command::Tick {
                        let at = session.tick_time(now);
                        if at > now {
                            std::thread::sleep(std::time::Duration::from_millis(at - now));
                            now = clock().max(at);
                        }
                    }
                    let r = match session.apply(env, now) {
                        Ok(a) => Reply::Ack(a),
                        Err(error) => Reply::Error {
                            seq: Some(seq),
                            error,
                        },
                    };
                    let _ = reply.send(r);
                }
                ActorMsg::Visible(v) => visible = v,
                ActorMsg::Snapshot(tx) => {
                    let _ = tx.send((session.snapshot(), session.log().to_vec()));
                }
                ActorMsg::Score(tx) => {
                    let _ = tx.send(session.score());
                }
                ActorMsg::Close => return,
            }
        }
        if !session.has_dirty(&visible) {
            continue;
        }
        // A frame in flight until it is published (see `alloc::busy`: free memory goes back
        // to the system once no session has rendered for a while).
        let _busy = crate::alloc::busy();
        // Progressive frames: a draft at once where a view has one (the C-arm moved on a large
        // region), and the full frame only once no newer input waits (a drag still in flight
        // gets drafts only; the frame header marks them, see `frame`).
        match session.render_drafts(&visible) {
            Ok(drafts) if !drafts.is_empty() => {
                publish(&frames, &mut frame_seq, drafts);
                draft_shown = true;
                if !rx.is_empty() {
                    continue;
                }
            }
            Ok(_) => {}
            Err(e) => tracing::error!("draft render failed: {e}"),
        }
        // The full frame behind a draft on screen yields the cores to other sessions' first
        // frames (see `priority`), and stops when input that moves its view comes (see
        // `interrupt`): the new view's draft is drawn instead.
        let _refining = draft_shown.then(crate::priority::refining);
        let _watching = draft_shown.then(|| supersede.watched());
        match session.render_dirty_unless_superseded(&visible) {
            Ok((views, was_stopped)) => {
                if !(was_stopped && views.is_empty()) {
                    publish(&frames, &mut frame_seq, views);
                }
                stopped = was_stopped;
            }
            Err(e) => tracing::error!("render failed: {e}"),
        }
    }
}

/// Encodes `views` (numbered from `frame_seq` on) into the session's frame set.
fn publish(
    frames: &watch::Sender<FrameSet>,
    frame_seq: &mut u64,
    views: Vec<crate::session::machine::RenderedView>,
) {
    let mut set: BTreeMap<ViewId, Arc<EncodedFrame>> = (**frames.borrow()).clone();
    for v in views {
        *frame_seq += 1;
        match EncodedFrame::new(v.view, *frame_seq, v.input_seq, v.t_ms, &v.image) {
            Ok(f) => {
                set.insert(v.view, Arc::new(f.with_draft(v.draft)));
            }
            Err(e) => tracing::error!("frame encoding failed: {e}"),
        }
    }
    frames.send_replace(Arc::new(set));
}
