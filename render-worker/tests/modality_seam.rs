//! The modality seam (issue 14): a modality that this crate does not ship plugs into a session
//! through the factory alone, reacts to world changes and to simulated time, renders its own
//! view, adds its own measurements, and replays bit-identically from the log.
//!
//! The test modality is a toy "ultrasound" probe: it stores the probe pose, counts needle
//! moves, integrates a quantity that decays with simulated time (as a contrast cloud would
//! spread), and draws a grey image whose brightness depends on all three.

use std::collections::BTreeSet;
use std::sync::Arc;

use render_worker::session::demo::{demo_region, demo_station};
use render_worker::session::*;
use serde::{Deserialize, Serialize};
use sim_core::rubric::Measurements;

/// Decay rate of the toy quantity, per second (our choice: visible within a few ticks).
const DECAY_PER_S: f64 = 0.5;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct ProbeState {
    position_mm: [f64; 3],
    needle_moves: u32,
    /// Decays as exp(-DECAY_PER_S t); set to 1 by each probe pose.
    level: f64,
    /// Time of the last update, ms.
    t_ms: u64,
}

struct ToyProbe {
    state: ProbeState,
    rendered: Option<u64>,
    changes: u64,
}

impl ToyProbe {
    fn new() -> ToyProbe {
        ToyProbe {
            state: ProbeState {
                position_mm: [0.0; 3],
                needle_moves: 0,
                level: 0.0,
                t_ms: 0,
            },
            rendered: None,
            changes: 0,
        }
    }
}

impl Modality for ToyProbe {
    fn name(&self) -> &'static str {
        "ultrasound"
    }

    fn accepts(&self) -> &'static [CommandClass] {
        &[CommandClass::Ultrasound]
    }

    fn views(&self) -> &'static [ViewId] {
        &[ViewId::Ultrasound]
    }

    fn apply(
        &mut self,
        command: &Command,
        world: &World,
    ) -> Result<serde_json::Value, CommandError> {
        match command {
            Command::ProbePose { position_mm, .. } => {
                self.state.position_mm = *position_mm;
                self.state.level = 1.0;
                self.state.t_ms = world.clock_ms;
                self.changes += 1;
                Ok(serde_json::json!({ "level": self.state.level }))
            }
            other => Err(CommandError::field(
                "command.type",
                ErrorCode::ModalityUnavailable,
                format!("the toy probe does not handle {}", other.name()),
            )),
        }
    }

    fn advance(&mut self, from_ms: u64, world: &World) {
        assert_eq!(
            from_ms,
            self.state.t_ms.max(from_ms),
            "time never goes back"
        );
        let dt_s = (world.clock_ms - self.state.t_ms) as f64 / 1000.0;
        self.state.level *= (-DECAY_PER_S * dt_s).exp();
        self.state.t_ms = world.clock_ms;
        if self.state.level > 0.0 {
            self.changes += 1;
        }
    }

    fn world_changed(&mut self, change: &WorldChange, _world: &World) {
        if *change == WorldChange::Needle {
            self.state.needle_moves += 1;
            self.changes += 1;
        }
    }

    fn dirty_views(&self) -> Vec<ViewId> {
        if self.rendered != Some(self.changes) && self.changes > 0 {
            vec![ViewId::Ultrasound]
        } else {
            Vec::new()
        }
    }

    fn render(
        &mut self,
        _view: ViewId,
        _world: &World,
    ) -> Result<Option<ViewImage>, ModalityError> {
        self.rendered = Some(self.changes);
        let grey = (255.0 * self.state.level).round() as u8;
        let moves = self.state.needle_moves as u8;
        Ok(Some(ViewImage {
            width: 32,
            height: 16,
            pixels: (0..32 * 16)
                .map(|i| grey.wrapping_add(moves).wrapping_add((i % 32) as u8))
                .collect(),
        }))
    }

    fn measure(&self, _world: &World, out: &mut Measurements) {
        out.insert("toy_level_ratio".into(), self.state.level);
        out.insert(
            "toy_needle_moves_count".into(),
            f64::from(self.state.needle_moves),
        );
    }

    fn record(&self) -> serde_json::Value {
        serde_json::json!({ "position_mm": self.state.position_mm })
    }

    fn state(&self) -> serde_json::Value {
        serde_json::to_value(&self.state).unwrap_or_default()
    }

    fn restore(&mut self, state: serde_json::Value) -> Result<(), ModalityError> {
        self.state = serde_json::from_value(state).map_err(|e| ModalityError::State {
            modality: "ultrasound",
            message: e.to_string(),
        })?;
        self.rendered = None;
        self.changes = 1;
        Ok(())
    }
}

fn env(factory: ModalityFactory) -> SessionEnv {
    let region = Arc::new(demo_region());
    let (station, sha) = demo_station(&["ultrasound"]);
    let mut env = SessionEnv::new(
        Arc::new(StationContext::new(station, sha, &region)),
        region,
        Backends::cpu(1),
    );
    env.modalities = factory;
    env
}

fn config() -> SessionConfig {
    SessionConfig {
        fluoro: FluoroConfig {
            detector_pixels: 64,
            detector_mm: 300.0,
            supersample: 1,
            noise: true,
        },
        seed: 11,
    }
}

fn script() -> Vec<(u64, Command)> {
    vec![
        (0, Command::Shot),
        (
            100,
            Command::ProbePose {
                position_mm: [0.0, -120.0, 0.0],
                beam_dir: [0.0, 1.0, 0.0],
                marker_dir: [1.0, 0.0, 0.0],
            },
        ),
        (600, Command::Tick),
        (
            700,
            Command::NeedlePlace {
                instrument: "spinal-22g".into(),
                entry_mm: [12.0, -100.0, 0.0],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
        ),
        (900, Command::NeedleFeed { mm: 10.0 }),
        (2900, Command::Tick),
        (3000, Command::Shot),
    ]
}

/// Runs `script` rendering both views after every step; returns every frame.
fn run(s: &mut Session, script: &[(u64, Command)]) -> Vec<RenderedView> {
    let views: BTreeSet<ViewId> = [ViewId::Fluoroscopy, ViewId::Ultrasound].into();
    let mut frames = Vec::new();
    for (k, (t, c)) in script.iter().enumerate() {
        s.apply(
            Envelope {
                seq: k as u64 + 1,
                command: c.clone(),
            },
            *t,
        )
        .unwrap_or_else(|e| panic!("{c:?}: {e}"));
        frames.extend(s.render_dirty(&views).unwrap());
    }
    frames
}

#[test]
fn a_new_modality_plugs_in_through_the_factory_alone() {
    // Without it, the station's ultrasound is reported unavailable and probe commands refused.
    let without = ModalityFactory::empty()
        .with(
            "fluoroscopy",
            render_worker::session::modalities::fluoro::build,
        )
        .with(
            "contrast",
            render_worker::session::modalities::contrast::build,
        );
    let plain = Session::new(env(without), config());
    assert_eq!(plain.unavailable_modalities(), ["ultrasound".to_string()]);
    assert_eq!(plain.views(), [ViewId::Fluoroscopy]);

    let factory = ModalityFactory::standard().with("ultrasound", |_| Box::new(ToyProbe::new()));
    let mut s = Session::new(env(factory.clone()), config());
    assert!(s.unavailable_modalities().is_empty());
    assert_eq!(s.modality_names(), ["fluoroscopy", "ultrasound"]);
    let frames = run(&mut s, &script());
    let us: Vec<&RenderedView> = frames
        .iter()
        .filter(|f| f.view == ViewId::Ultrasound)
        .collect();
    let fl = frames
        .iter()
        .filter(|f| f.view == ViewId::Fluoroscopy)
        .count();
    assert_eq!(fl, 2, "two shots, nothing else exposes");
    // Every step from the probe pose on changes the toy image (the pose itself, then each
    // advance of the clock while the level is above zero, and each needle move): six renders.
    assert_eq!(us.len(), 6);
    // The level decayed over the simulated 2.9 s since the probe was placed at 0.1 s.
    let m = s.measurements();
    let expected = (-DECAY_PER_S * 2.9).exp();
    assert!((m["toy_level_ratio"] - expected).abs() < 1e-12, "{m:?}");
    assert_eq!(m["toy_needle_moves_count"], 2.0);
    // Fluoroscopy measurements are still there, next to the new modality's.
    assert_eq!(m["fluoro_acquisitions_count"], 2.0);
    // The record carries the new modality's settings.
    let record = s.score().record;
    assert!(record.modalities.contains_key("ultrasound"));
}

#[test]
fn time_dependent_modalities_replay_bit_identically_from_the_log() {
    let factory = ModalityFactory::standard().with("ultrasound", |_| Box::new(ToyProbe::new()));
    let mut live = Session::new(env(factory.clone()), config());
    let initial = live.snapshot();
    let frames = run(&mut live, &script());
    // From the initial snapshot and the log: the same state bytes, the same last frames.
    let mut replayed = Session::restore(env(factory.clone()), &initial, live.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), live.snapshot().to_bytes());
    let views: BTreeSet<ViewId> = [ViewId::Fluoroscopy, ViewId::Ultrasound].into();
    let last = replayed.render_dirty(&views).unwrap();
    for v in &last {
        let live_last = frames.iter().rev().find(|f| f.view == v.view).unwrap();
        assert_eq!(v.image, live_last.image, "{:?}", v.view);
    }
    // From a snapshot in the middle plus the whole log.
    let mut half = Session::new(env(factory.clone()), config());
    let script = script();
    run(&mut half, &script[..3]);
    let middle = half.snapshot();
    let restored = Session::restore(env(factory), &middle, live.log()).unwrap();
    assert_eq!(restored.snapshot().to_bytes(), live.snapshot().to_bytes());
    // A tick is logged like any command and advances nothing but time.
    assert!(live.log().iter().any(|e| e.command == Command::Tick));
}

#[test]
fn injections_need_a_modality_that_handles_them_and_are_recorded_in_the_world() {
    // No modality handles contrast at this station: refused as before, nothing recorded.
    let mut s = Session::new(env(ModalityFactory::standard()), config());
    let e = s
        .apply(
            Envelope {
                seq: 1,
                command: Command::Inject {
                    agent: Agent::Contrast,
                    volume_ml: 1.0,
                    rate_ml_per_s: 0.2,
                },
            },
            0,
        )
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::ModalityUnavailable);
    assert!(s.world().injections.is_empty());
    // A stand-in contrast handler (accepts the class, keeps no state): the world records the
    // injection and every modality hears of it.
    struct Sink(Vec<WorldChange>);
    impl Modality for Sink {
        fn name(&self) -> &'static str {
            "ultrasound"
        }
        fn accepts(&self) -> &'static [CommandClass] {
            &[CommandClass::Contrast]
        }
        fn views(&self) -> &'static [ViewId] {
            &[]
        }
        fn apply(&mut self, _: &Command, _: &World) -> Result<serde_json::Value, CommandError> {
            Ok(serde_json::Value::Null)
        }
        fn world_changed(&mut self, change: &WorldChange, _: &World) {
            self.0.push(change.clone());
        }
        fn dirty_views(&self) -> Vec<ViewId> {
            Vec::new()
        }
        fn render(&mut self, _: ViewId, _: &World) -> Result<Option<ViewImage>, ModalityError> {
            Ok(None)
        }
        fn measure(&self, _: &World, out: &mut Measurements) {
            out.insert("heard_changes_count".into(), self.0.len() as f64);
        }
        fn record(&self) -> serde_json::Value {
            serde_json::Value::Null
        }
        fn state(&self) -> serde_json::Value {
            serde_json::Value::Null
        }
        fn restore(&mut self, _: serde_json::Value) -> Result<(), ModalityError> {
            Ok(())
        }
    }
    let factory = ModalityFactory::standard().with("ultrasound", |_| Box::new(Sink(Vec::new())));
    let mut s = Session::new(env(factory.clone()), config());
    let initial = s.snapshot();
    let inject = Command::Inject {
        agent: Agent::Saline,
        volume_ml: 2.0,
        rate_ml_per_s: 0.5,
    };
    s.apply(
        Envelope {
            seq: 1,
            command: inject,
        },
        250,
    )
    .unwrap();
    assert_eq!(s.world().injections.len(), 1);
    let i = &s.world().injections[0];
    assert_eq!((i.t_ms, i.agent, i.volume_ml), (250, Agent::Saline, 2.0));
    assert_eq!(s.measurements()["heard_changes_count"], 1.0);
    // The ledger is part of the state: a replay has it, and so does a snapshot round trip.
    let r = Session::restore(env(factory), &initial, s.log()).unwrap();
    assert_eq!(r.world().injections, s.world().injections);
    assert_eq!(r.snapshot().to_bytes(), s.snapshot().to_bytes());
}
