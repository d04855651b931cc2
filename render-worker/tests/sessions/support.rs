//! The fixtures the session tests share: the demo station's session environment and
//! configuration, a driver with automatic sequence numbers, command builders and the scripted
//! attempt that snapshot, replay and host tests run.

use std::collections::BTreeSet;
use std::sync::Arc;

use render_worker::session::demo::{demo_region, demo_station};
use render_worker::session::frame::EncodedFrame;
use render_worker::session::*;

pub(crate) fn config() -> SessionConfig {
    SessionConfig {
        fluoro: FluoroConfig {
            detector_pixels: 128,
            detector_mm: 300.0,
            supersample: 2,
            noise: true,
        },
        seed: 7,
    }
}

pub(crate) fn env_with(extra: &[&str]) -> SessionEnv {
    let region = Arc::new(demo_region());
    let (station, sha) = demo_station(extra);
    SessionEnv::new(
        Arc::new(StationContext::new(station, sha, &region)),
        region,
        Backends::cpu(1),
    )
}

pub(crate) fn env() -> SessionEnv {
    env_with(&[])
}

/// Backends with the GPU fluoroscopy renderer drafting on any region (drafts forced on the
/// small demo region) on `ctx`, its draft scene of the demo region built.
pub(crate) fn drafting_backends(ctx: render_worker::gpu::GpuContext) -> Backends {
    use render_worker::session::modalities::fluoro::GpuFluoroBackend;
    let fluoro = GpuFluoroBackend::new(ctx).drafting_from(Some(0));
    fluoro
        .wait_for_draft_scene(&Arc::new(demo_region()))
        .expect("the demo region gets a draft scene");
    Backends::new(Arc::new(fluoro), Backends::cpu(1).ultrasound)
}

/// The demo environment with [`drafting_backends`] on a software adapter, where the CPU draws
/// the geometric pass and newer input can stop it (see `render_worker::interrupt`); `None`
/// without an adapter, or on a GPU (it draws that pass itself: nothing on the CPU to stop).
pub(crate) fn stoppable_drafting_env() -> Option<SessionEnv> {
    let ctx = render_worker::gpu::context_for_tests()?;
    if !ctx.summary.is_software {
        return None;
    }
    let mut e = env();
    e.backends = drafting_backends(ctx);
    Some(e)
}

pub(crate) fn fluoro_only() -> BTreeSet<ViewId> {
    [ViewId::FLUOROSCOPY].into()
}

/// A session driven with an automatic sequence number.
pub(crate) struct Driver {
    pub(super) s: Session,
    pub(super) seq: u64,
}

impl Driver {
    pub(super) fn new() -> Driver {
        Driver {
            s: Session::new(env(), config()),
            seq: 0,
        }
    }
    pub(super) fn ok(&mut self, t_ms: u64, command: Command) -> Ack {
        self.seq += 1;
        self.s
            .apply(
                Envelope {
                    seq: self.seq,
                    command: command.clone(),
                },
                t_ms,
            )
            .unwrap_or_else(|e| panic!("{command:?} rejected: {e}"))
    }
    pub(super) fn err(&mut self, command: Command) -> CommandError {
        self.s
            .apply(
                Envelope {
                    seq: self.seq + 1,
                    command,
                },
                0,
            )
            .expect_err("should be rejected")
    }
}

pub(crate) fn pose(orbital_deg: f64, angular_deg: f64) -> Command {
    Command::CarmPose {
        orbital_deg,
        angular_deg,
        table_mm: [0.0; 3],
    }
}

pub(crate) fn place(entry_mm: [f64; 3], direction: [f64; 3]) -> Command {
    Command::NeedlePlace {
        instrument: "spinal-22g".into(),
        entry_mm,
        direction,
        bevel_reference: [1.0, 0.0, 0.0],
    }
}

/// A scripted attempt: C-arm moves, shots, live fluoroscopy, needle moves.
pub(crate) fn script() -> Vec<(u64, Command)> {
    vec![
        (100, pose(0.0, -2.0)),
        (200, Command::Technique { kvp: 75, ma: 2.5 }),
        (300, Command::Shot),
        (400, place([12.0, -100.0, 1.0], [0.0, 1.0, 0.05])),
        (500, Command::NeedleFeed { mm: 30.0 }),
        (600, Command::NeedleRoll { deg: 90.0 }),
        (700, Command::Live { on: true }),
        (800, Command::NeedleFeed { mm: 30.0 }),
        (900, pose(-20.0, 0.0)),
        (1400, Command::Live { on: false }),
        (1500, Command::NeedleFeed { mm: 15.0 }),
        (1600, Command::Shot),
        (
            1700,
            Command::Annotate {
                pixel: [64.0, 60.0],
                label: "behind_l4".into(),
            },
        ),
        (1800, Command::NeedleWithdraw { mm: 2.0 }),
        (1900, Command::Shot),
    ]
}

pub(crate) fn run(s: &mut Session, steps: &[(u64, Command)], first_seq: u64) {
    for (k, (t, c)) in steps.iter().enumerate() {
        s.apply(
            Envelope {
                seq: first_seq + k as u64,
                command: c.clone(),
            },
            *t,
        )
        .unwrap_or_else(|e| panic!("{c:?}: {e}"));
    }
}

pub(crate) fn final_frame(s: &mut Session) -> Vec<u8> {
    let f = s
        .render_dirty(&fluoro_only())
        .unwrap()
        .pop()
        .expect("a frame");
    EncodedFrame::new(f.view, 1, f.input_seq, f.t_ms, &f.image)
        .unwrap()
        .to_bytes()
}
