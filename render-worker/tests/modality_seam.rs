//! The modality seam: a modality that this crate does not ship, with its own name, its own
//! command kind and its own view, plugs into a session through the factory alone, reacts to
//! world changes and to simulated time, renders its own view, adds its own measurements, and
//! replays bit-identically from the log. (`server/tests/modality_extension.rs` streams such a
//! modality's frames through the real server.)
//!
//! The test modality is a toy probe: it stores the probe position, counts needle moves,
//! integrates a quantity that decays with simulated time (as a contrast cloud would spread),
//! and draws a grey image whose brightness depends on all three.

use std::collections::BTreeSet;
use std::sync::Arc;

use render_worker::session::demo::{demo_region, demo_station};
use render_worker::session::*;
use serde::{Deserialize, Serialize};
use sim_core::rubric::Measurements;

/// Decay rate of the toy quantity, per second. Simulator choice: visible within a few ticks.
const DECAY_PER_S: f64 = 0.5;

/// The toy probe's view; its wire code is one no built-in view uses.
const TOY_VIEW: ViewId = ViewId::new("toy_probe", 200);

/// What the toy probe declares: its own name, command kind and view.
static TOY_SPEC: ModalitySpec = ModalitySpec {
    name: "toy_probe",
    label: "toy probe",
    views: &[TOY_VIEW],
    commands: &[CommandSpec::new(
        "toy_probe_place",
        Some(Engagement::ViewChanged),
    )],
    constants: &[("decay_per_s", DECAY_PER_S)],
};

/// The fields of a `toy_probe_place` command.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Place {
    position_mm: [f64; 3],
}

/// A `toy_probe_place` command.
fn place(position_mm: [f64; 3]) -> Command {
    Command::from_json(serde_json::json!({ "type": "toy_probe_place", "position_mm": position_mm }))
        .unwrap()
}

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
    fn spec(&self) -> &'static ModalitySpec {
        &TOY_SPEC
    }

    fn apply(
        &mut self,
        command: &Command,
        world: &World,
    ) -> Result<serde_json::Value, CommandError> {
        match command {
            Command::Modality(c) if c.kind() == "toy_probe_place" => {
                let Place { position_mm } = c.parse()?;
                if position_mm.iter().any(|v| !v.is_finite()) {
                    return Err(CommandError::field(
                        "command.position_mm",
                        ErrorCode::NotFinite,
                        "the position must be finite",
                    ));
                }
                self.state.position_mm = position_mm;
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
            vec![TOY_VIEW]
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
            modality: "toy_probe",
            message: e.to_string(),
        })?;
        self.rendered = None;
        self.changes = 1;
        Ok(())
    }
}

fn env(factory: ModalityFactory) -> SessionEnv {
    let region = Arc::new(demo_region());
    let (station, sha) = demo_station(&["toy_probe"]);
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
        (100, place([0.0, -120.0, 0.0])),
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
    let views: BTreeSet<ViewId> = [ViewId::FLUOROSCOPY, TOY_VIEW].into();
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

/// The standard modalities plus the toy probe, registered through the factory alone.
fn with_toy() -> ModalityFactory {
    ModalityFactory::standard()
        .with(&TOY_SPEC, |_| Box::new(ToyProbe::new()))
        .expect("the toy probe's name, command kind and view are new")
}

#[test]
fn a_new_modality_plugs_in_through_the_factory_alone() {
    // Without it, the station's toy probe is reported unavailable and its commands refused.
    let mut plain = Session::new(env(ModalityFactory::standard()), config());
    assert_eq!(plain.unavailable_modalities(), ["toy_probe".to_string()]);
    assert_eq!(plain.views(), [ViewId::FLUOROSCOPY]);
    let e = plain
        .apply(
            Envelope {
                seq: 1,
                command: place([0.0; 3]),
            },
            0,
        )
        .unwrap_err();
    assert_eq!(
        (e.field.as_str(), e.code),
        ("command.type", ErrorCode::Malformed)
    );
    assert!(e.message.contains("toy_probe_place"), "{e}");

    let mut s = Session::new(env(with_toy()), config());
    assert!(s.unavailable_modalities().is_empty());
    assert_eq!(s.modality_names(), ["fluoroscopy", "toy_probe"]);
    assert_eq!(s.views(), [ViewId::FLUOROSCOPY, TOY_VIEW]);
    // What the session offers a client comes from the specs: the toy's view with its wire
    // code, its command kind with its engagement, its constants.
    let offer = ProtocolInfo::of(&s);
    assert!(
        offer
            .views
            .iter()
            .any(|v| v.name == "toy_probe" && v.code == 200 && v.modality == "toy_probe")
    );
    let kind = offer
        .commands
        .iter()
        .find(|c| c.kind == "toy_probe_place")
        .unwrap();
    assert_eq!(kind.modality.as_deref(), Some("toy_probe"));
    assert_eq!(kind.engagement, Some(Engagement::ViewChanged));
    assert_eq!(offer.constants["toy_probe"]["decay_per_s"], DECAY_PER_S);
    let frames = run(&mut s, &script());
    let toy: Vec<&RenderedView> = frames.iter().filter(|f| f.view == TOY_VIEW).collect();
    let fl = frames
        .iter()
        .filter(|f| f.view == ViewId::FLUOROSCOPY)
        .count();
    assert_eq!(fl, 2, "two shots, nothing else exposes");
    // Every step from the probe placement on changes the toy image (the placement itself, then
    // each advance of the clock while the level is above zero, and each needle move): six
    // renders.
    assert_eq!(toy.len(), 6);
    // Its frames encode with its own wire code and parse back to its view.
    let f =
        EncodedFrame::new(toy[0].view, 1, toy[0].input_seq, toy[0].t_ms, &toy[0].image).unwrap();
    assert_eq!(f.to_bytes()[5], 200);
    assert_eq!(EncodedFrame::parse(&f.to_bytes()).unwrap().view, TOY_VIEW);
    // The level decayed over the simulated 2.9 s since the probe was placed at 0.1 s.
    let m = s.measurements();
    let expected = (-DECAY_PER_S * 2.9).exp();
    assert!((m["toy_level_ratio"] - expected).abs() < 1e-12, "{m:?}");
    assert_eq!(m["toy_needle_moves_count"], 2.0);
    // Fluoroscopy measurements are still there, next to the new modality's.
    assert_eq!(m["fluoro_acquisitions_count"], 2.0);
    // The record carries the new modality's settings.
    let record = s.score().record;
    assert!(record.modalities.contains_key("toy_probe"));
}

#[test]
fn a_modality_command_is_validated_by_its_modality_and_logged_as_sent() {
    let mut s = Session::new(env(with_toy()), config());
    // A field the toy does not know is named in the error, as for a built-in command.
    let bad = Command::from_json(serde_json::json!({
        "type": "toy_probe_place", "position_mm": [0.0, 0.0, 0.0], "speed": 3
    }))
    .unwrap();
    let e = s
        .apply(
            Envelope {
                seq: 1,
                command: bad,
            },
            0,
        )
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::Malformed);
    assert!(e.message.contains("speed"), "{e}");
    assert!(s.log().is_empty(), "a refused command is not logged");
    // An accepted one is logged in its JSON form and parses back to the same command.
    let ack = s
        .apply(
            Envelope {
                seq: 2,
                command: place([1.0, 2.0, 3.0]),
            },
            10,
        )
        .unwrap();
    assert_eq!(ack.engagement, Some(Engagement::ViewChanged));
    let logged = serde_json::to_value(&s.log()[0]).unwrap();
    assert_eq!(
        logged["command"],
        serde_json::json!({ "type": "toy_probe_place", "position_mm": [1.0, 2.0, 3.0] })
    );
    let back: LogEntry = serde_json::from_value(logged).unwrap();
    assert_eq!(back, s.log()[0]);
    // A modality cannot take a kind another one (or the session core) handles, nor a view
    // code another view has.
    static THIEF: ModalitySpec = ModalitySpec {
        name: "thief",
        label: "thief",
        views: &[],
        commands: &[CommandSpec::new("carm_pose", None)],
        constants: &[],
    };
    assert!(matches!(
        ModalityFactory::standard().with(&THIEF, |_| Box::new(ToyProbe::new())),
        Err(RegistrationError::CommandKind {
            kind: "carm_pose",
            ..
        })
    ));
    static CLASH: ModalitySpec = ModalitySpec {
        name: "clash",
        label: "clash",
        views: &[ViewId::new("clash", 0)],
        commands: &[],
        constants: &[],
    };
    assert!(matches!(
        ModalityFactory::standard().with(&CLASH, |_| Box::new(ToyProbe::new())),
        Err(RegistrationError::View { .. })
    ));
}

#[test]
fn time_dependent_modalities_replay_bit_identically_from_the_log() {
    let factory = with_toy();
    let mut live = Session::new(env(factory.clone()), config());
    let initial = live.snapshot();
    let frames = run(&mut live, &script());
    // From the initial snapshot and the log: the same state bytes, the same last frames.
    let mut replayed = Session::restore(env(factory.clone()), &initial, live.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), live.snapshot().to_bytes());
    let views: BTreeSet<ViewId> = [ViewId::FLUOROSCOPY, TOY_VIEW].into();
    let last = replayed.render_dirty(&views).unwrap();
    assert_eq!(last.len(), 2);
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
    // The station lists no contrast: refused, nothing recorded.
    let mut s = Session::new(env(ModalityFactory::standard()), config());
    let inject = Command::Inject {
        agent: Agent::Saline,
        volume_ml: 2.0,
        rate_ml_per_s: 0.5,
    };
    let e = s
        .apply(
            Envelope {
                seq: 1,
                command: inject.clone(),
            },
            0,
        )
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::ModalityUnavailable);
    assert!(e.message.contains("contrast injection"), "{e}");
    assert!(s.world().injections.is_empty());
    // A stand-in injector (declares the inject kind, delivers what it is asked to, keeps no
    // state): the world records the injection and every modality hears of it.
    struct Sink {
        heard: Vec<WorldChange>,
        delivered: Option<FluidDelivery>,
    }
    static SINK: ModalitySpec = ModalitySpec {
        name: "toy_probe",
        label: "stand-in injector",
        views: &[],
        commands: &[CommandSpec::new("inject", Some(Engagement::Injection))],
        constants: &[],
    };
    impl Modality for Sink {
        fn spec(&self) -> &'static ModalitySpec {
            &SINK
        }
        fn apply(&mut self, c: &Command, _: &World) -> Result<serde_json::Value, CommandError> {
            if let Command::Inject {
                agent,
                volume_ml,
                rate_ml_per_s,
            } = *c
            {
                self.delivered = Some(FluidDelivery {
                    agent,
                    volume_ml,
                    rate_ml_per_s,
                });
            }
            Ok(serde_json::Value::Null)
        }
        fn take_fluid(&mut self) -> Option<FluidDelivery> {
            self.delivered.take()
        }
        fn world_changed(&mut self, change: &WorldChange, _: &World) {
            self.heard.push(change.clone());
        }
        fn dirty_views(&self) -> Vec<ViewId> {
            Vec::new()
        }
        fn render(&mut self, _: ViewId, _: &World) -> Result<Option<ViewImage>, ModalityError> {
            Ok(None)
        }
        fn measure(&self, _: &World, out: &mut Measurements) {
            out.insert("heard_changes_count".into(), self.heard.len() as f64);
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
    let factory = ModalityFactory::empty()
        .with(
            &render_worker::session::modalities::fluoro::SPEC,
            render_worker::session::modalities::fluoro::build,
        )
        .and_then(|f| {
            f.with(&SINK, |_| {
                Box::new(Sink {
                    heard: Vec::new(),
                    delivered: None,
                })
            })
        })
        .unwrap();
    let mut s = Session::new(env(factory.clone()), config());
    let initial = s.snapshot();
    let ack = s
        .apply(
            Envelope {
                seq: 1,
                command: inject,
            },
            250,
        )
        .unwrap();
    assert_eq!(ack.engagement, Some(Engagement::Injection));
    assert_eq!(s.world().injections.len(), 1);
    let i = &s.world().injections[0];
    assert_eq!((i.t_ms, i.agent, i.volume_ml), (250, Agent::Saline, 2.0));
    assert_eq!(s.measurements()["heard_changes_count"], 1.0);
    // The ledger is part of the state: a replay has it, and so does a snapshot round trip.
    let r = Session::restore(env(factory), &initial, s.log()).unwrap();
    assert_eq!(r.world().injections, s.world().injections);
    assert_eq!(r.snapshot().to_bytes(), s.snapshot().to_bytes());
}
