//! The session driver the modality tests share: a session with an automatic sequence number.

use std::collections::BTreeSet;

use render_worker::session::*;

/// A session driven with an automatic sequence number.
pub(crate) struct Run {
    pub(crate) s: Session,
    pub(crate) seq: u64,
}

impl Run {
    pub(crate) fn new(env: SessionEnv, config: SessionConfig) -> Run {
        Run {
            s: Session::new(env, config),
            seq: 0,
        }
    }

    pub(crate) fn try_apply(&mut self, t_ms: u64, command: Command) -> Result<Ack, CommandError> {
        let r = self.s.apply(
            Envelope {
                seq: self.seq + 1,
                command,
            },
            t_ms,
        );
        if r.is_ok() {
            self.seq += 1;
        }
        r
    }

    pub(crate) fn ok(&mut self, t_ms: u64, command: Command) -> Ack {
        let c = command.clone();
        self.try_apply(t_ms, command)
            .unwrap_or_else(|e| panic!("{c:?} rejected: {e}"))
    }

    pub(crate) fn err(&mut self, command: Command) -> CommandError {
        let c = command.clone();
        let t = self.s.snapshot().clock_ms;
        match self.try_apply(t, command) {
            Ok(_) => panic!("{c:?} accepted"),
            Err(e) => e,
        }
    }

    /// Places the skin marker at `position_mm` (it snaps onto the skin) and returns where it
    /// landed.
    pub(crate) fn skin_marker(&mut self, t_ms: u64, position_mm: [f64; 3]) -> [f64; 3] {
        let ack = self.ok(
            t_ms,
            Command::SkinMarker {
                pixel: None,
                position_mm: Some(position_mm),
            },
        );
        serde_json::from_value(ack.outcome["marker_mm"].clone()).unwrap()
    }

    /// Attaches the loss-of-resistance syringe at `t_ms` and starts constant plunger pressure
    /// at `t_ms + 500`; returns the pressure command's acknowledgement.
    pub(crate) fn attach_lor_and_hold(&mut self, t_ms: u64) -> Ack {
        self.ok(
            t_ms,
            Command::Syringe {
                action: SyringeAction::Attach,
                medium: None,
            },
        );
        self.ok(t_ms + 500, Command::PlungerHold { on: true })
    }

    pub(crate) fn render(&mut self, view: ViewId) -> Option<ViewImage> {
        let views: BTreeSet<ViewId> = [view].into();
        self.s
            .render_dirty(&views)
            .unwrap()
            .into_iter()
            .find(|r| r.view == view)
            .map(|r| r.image)
    }
}
