//! Sessions: command validation, on-demand rendering, needle and scoring, snapshot and exact
//! replay, the websocket protocol over channels, and one real socket.
//!
//! Scenes are the analytic demo region (boxes with known geometry) at 128 x 128 pixels, so each
//! frame renders in milliseconds.

use std::collections::BTreeSet;
use std::sync::Arc;

use render_worker::session::demo::{FACET_NORMAL_AZIMUTH_DEG, demo_region, demo_station};
use render_worker::session::frame::EncodedFrame;
use render_worker::session::protocol::parse_client_message;
use render_worker::session::*;
use sim_core::rubric::Outcome;

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

pub(crate) fn fluoro_only() -> BTreeSet<ViewId> {
    [ViewId::Fluoroscopy].into()
}

/// A session driven with an automatic sequence number.
pub(crate) struct Driver {
    s: Session,
    seq: u64,
}

impl Driver {
    fn new() -> Driver {
        Driver {
            s: Session::new(env(), config()),
            seq: 0,
        }
    }
    fn ok(&mut self, t_ms: u64, command: Command) -> Ack {
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
    fn err(&mut self, command: Command) -> CommandError {
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

#[test]
fn invalid_commands_are_rejected_naming_the_field_and_nothing_is_logged() {
    let mut d = Driver::new();
    let cases: Vec<(Command, &str, ErrorCode)> = vec![
        (
            pose(f64::NAN, 0.0),
            "command.orbital_deg",
            ErrorCode::NotFinite,
        ),
        (
            pose(0.0, 90.0),
            "command.angular_deg",
            ErrorCode::OutOfRange,
        ),
        (
            Command::CarmPose {
                orbital_deg: 0.0,
                angular_deg: 0.0,
                table_mm: [0.0, f64::INFINITY, 0.0],
            },
            "command.table_mm[1]",
            ErrorCode::NotFinite,
        ),
        (
            Command::Technique { kvp: 81, ma: 2.0 },
            "command.kvp",
            ErrorCode::OutOfRange,
        ),
        (
            Command::Technique { kvp: 80, ma: -1.0 },
            "command.ma",
            ErrorCode::OutOfRange,
        ),
        (
            Command::NeedleFeed { mm: -3.0 },
            "command.mm",
            ErrorCode::OutOfRange,
        ),
        (
            Command::NeedleRoll { deg: f64::NAN },
            "command.deg",
            ErrorCode::NotFinite,
        ),
        (
            Command::Inject {
                agent: Agent::Contrast,
                volume_ml: 250.0,
                rate_ml_per_s: 0.2,
            },
            "command.volume_ml",
            ErrorCode::OutOfRange,
        ),
        (
            Command::Inject {
                agent: Agent::Saline,
                volume_ml: 2.0,
                rate_ml_per_s: 0.0,
            },
            "command.rate_ml_per_s",
            ErrorCode::OutOfRange,
        ),
        (
            place([0.0; 3], [0.0, 0.0, 0.0]),
            "command.direction",
            ErrorCode::Invalid,
        ),
        // Station-dependent rejections.
        (
            Command::NeedleFeed { mm: 5.0 },
            "command.type",
            ErrorCode::State,
        ),
        (
            Command::Annotate {
                pixel: [10.0, 10.0],
                label: "behind_l4".into(),
            },
            "command.type",
            ErrorCode::State,
        ),
        (
            Command::NeedlePlace {
                instrument: "tuohy".into(),
                entry_mm: [0.0; 3],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
            "command.instrument",
            ErrorCode::InstrumentUnavailable,
        ),
        (
            Command::NeedlePlace {
                instrument: "contrast-syringe".into(),
                entry_mm: [0.0; 3],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
            "command.instrument",
            ErrorCode::InstrumentUnavailable,
        ),
        (
            place([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            "command.entry_mm",
            ErrorCode::Invalid,
        ),
    ];
    for (c, field, code) in cases {
        let e = d.err(c.clone());
        assert_eq!((e.field.as_str(), e.code), (field, code), "{c:?}: {e}");
    }
    assert!(d.s.log().is_empty(), "rejected commands must not be logged");
    // Sequence numbers: 0 is refused, a repeat with another command is refused, an identical
    // re-send is acknowledged as a duplicate and not applied twice.
    let e =
        d.s.apply(
            Envelope {
                seq: 0,
                command: Command::Shot,
            },
            0,
        )
        .unwrap_err();
    assert_eq!((e.field.as_str(), e.code), ("seq", ErrorCode::Sequence));
    d.ok(10, Command::Shot);
    let dup =
        d.s.apply(
            Envelope {
                seq: 1,
                command: Command::Shot,
            },
            20,
        )
        .unwrap();
    assert!(dup.duplicate);
    let e =
        d.s.apply(
            Envelope {
                seq: 1,
                command: pose(5.0, 0.0),
            },
            20,
        )
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::Sequence);
    assert_eq!(d.s.log().len(), 1);
    assert_eq!(d.s.measurements()["fluoro_acquisitions_count"], 1.0);
}

#[test]
fn modalities_the_station_lacks_are_refused_with_a_clear_message() {
    let mut d = Driver::new();
    for c in [
        Command::ProbePose {
            position_mm: [0.0, -120.0, 0.0],
            beam_dir: [0.0, 1.0, 0.0],
            marker_dir: [1.0, 0.0, 0.0],
        },
        Command::ProbeSettings {
            depth_mm: Some(60.0),
            gain_db: Some(10.0),
            tgc_db: None,
            focus_mm: None,
            frequency_mhz: Some(5.0),
            dynamic_range_db: None,
        },
        Command::Inject {
            agent: Agent::Contrast,
            volume_ml: 1.0,
            rate_ml_per_s: 0.2,
        },
    ] {
        let e = d.err(c);
        assert_eq!(
            (e.field.as_str(), e.code),
            ("command.type", ErrorCode::ModalityUnavailable)
        );
        assert!(
            e.message.contains("modality not available at this station"),
            "{}",
            e.message
        );
    }
    // A station that lists ultrasound builds it (its views beside fluoroscopy's), and the
    // fluoroscopy-only session never built anything for ultrasound. A worker without an
    // implementation reports it unavailable (modality_seam).
    let s = Session::new(env_with(&["ultrasound"]), config());
    assert!(s.unavailable_modalities().is_empty());
    assert_eq!(s.modality_names(), ["fluoroscopy", "ultrasound"]);
    assert_eq!(
        s.views(),
        [ViewId::Fluoroscopy, ViewId::Ultrasound, ViewId::Placement]
    );
    let fluoro_only = Session::new(env(), config());
    assert!(fluoro_only.unavailable_modalities().is_empty());
    assert_eq!(fluoro_only.views(), [ViewId::Fluoroscopy]);
}

#[test]
fn client_messages_name_the_field_of_a_parse_error() {
    let e = parse_client_message(
        r#"{"type":"command","seq":3,"command":{"type":"carm_pose","angular_deg":0}}"#,
    )
    .unwrap_err();
    assert_eq!(e.0, Some(3));
    assert_eq!(e.1.field, "command.orbital_deg", "{:?}", e.1);
    let e = parse_client_message(
        r#"{"type":"command","seq":3,"command":{"type":"technique","kvp":80,"ma":"high"}}"#,
    )
    .unwrap_err();
    assert_eq!(e.1.field, "command.ma", "{:?}", e.1);
    let e = parse_client_message(r#"{"type":"command","seq":3,"command":{"type":"warp_drive"}}"#)
        .unwrap_err();
    assert!(e.1.field.starts_with("command"), "{:?}", e.1);
    let e = parse_client_message(r#"{"type":"command","seq":-1,"command":{"type":"shot"}}"#)
        .unwrap_err();
    assert_eq!(e.1.field, "seq");
    let e = parse_client_message("not json").unwrap_err();
    assert_eq!(e.1.code, ErrorCode::Malformed);
    let ok = parse_client_message(
        r#"{"type":"command","seq":4,"command":{"type":"needle_feed","mm":2.5}}"#,
    )
    .unwrap();
    assert_eq!(
        ok,
        protocol::ClientMessage::Command {
            seq: 4,
            command: Command::NeedleFeed { mm: 2.5 }
        }
    );
}

#[test]
fn frames_are_rendered_only_on_exposure_and_only_for_visible_views() {
    let mut d = Driver::new();
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "no image before any exposure"
    );
    d.ok(0, pose(20.0, 5.0));
    d.ok(0, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0]));
    d.ok(0, Command::NeedleFeed { mm: 20.0 });
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "moving without exposure keeps the last image"
    );
    d.ok(100, Command::Shot);
    assert!(
        d.s.render_dirty(&BTreeSet::new()).unwrap().is_empty(),
        "hidden views are not rendered"
    );
    let frames = d.s.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].input_seq, 4);
    assert_eq!((frames[0].image.width, frames[0].image.height), (128, 128));
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "nothing changed since"
    );
    // The image is not blank: bone and needle make a range of grey levels.
    let px = &frames[0].image.pixels;
    let (lo, hi) = (px.iter().min().unwrap(), px.iter().max().unwrap());
    assert!(hi - lo > 60, "grey range {lo}..{hi}");
}

#[test]
fn live_fluoroscopy_renders_on_every_change_and_books_its_time() {
    let mut d = Driver::new();
    d.ok(1000, Command::Live { on: true });
    assert_eq!(d.s.render_dirty(&fluoro_only()).unwrap().len(), 1);
    d.ok(1500, pose(-15.0, 0.0));
    let a = d.s.render_dirty(&fluoro_only()).unwrap();
    d.ok(1700, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0]));
    let b = d.s.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(
        (a.len(), b.len()),
        (1, 1),
        "a pose change and a needle move each make a live frame"
    );
    assert_ne!(a[0].image, b[0].image, "the needle appears");
    d.ok(3000, Command::Live { on: false });
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "beam off: last image hold"
    );
    d.ok(4000, Command::Shot);
    let m = d.s.measurements();
    // Live from 1000 to 3000 ms (2 s) plus one shot (SHOT_EXPOSURE_MS = 100 ms).
    assert_eq!(m["fluoro_exposure_s"], 2.1);
    assert_eq!(m["fluoro_acquisitions_count"], 2.0);
    // Clock never runs backwards: an earlier time stamp is applied "now".
    let ack = d.ok(10, Command::Shot);
    assert_eq!(ack.t_ms, 4000);
}

#[test]
fn needle_meets_bone_and_tip_measurements_follow_it() {
    let mut d = Driver::new();
    // Straight in from behind at x = 12 mm: the L4 body's posterior face is at y = -15 mm.
    d.ok(0, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0]));
    let ack = d.ok(0, Command::NeedleFeed { mm: 50.0 });
    // 100 substeps of 0.5 mm: exact up to summation rounding.
    assert!((ack.outcome["depth_mm"].as_f64().unwrap() - 50.0).abs() < 1e-9);
    let ack = d.ok(0, Command::NeedleFeed { mm: 50.0 });
    let tip = ack.outcome["tip_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect::<Vec<_>>();
    // Perpendicular incidence arrests the tip at the surface (within the needle model's 1 um
    // contact gap plus its look-ahead rounding; 0.01 mm is far below any scored distance).
    assert!((tip[1] + 15.0).abs() < 0.01, "tip {tip:?}");
    assert!(
        ack.outcome["outcome"]["stop"]["Arrested"].is_object(),
        "{}",
        ack.outcome
    );
    let m = d.s.measurements();
    // Target (12, -18, 0): 3 mm behind the arrested tip.
    assert!((m["tip_to_target_mm"] - 3.0).abs() < 0.01, "{m:?}");
    assert!((m["needle_depth_mm"] - 85.0).abs() < 0.01);
    assert_eq!(m["dural_puncture_bool"], 0.0);
    d.ok(0, Command::NeedleWithdraw { mm: 50.0 });
    d.ok(0, Command::NeedleWithdraw { mm: 35.0 });
    // Through the midline the tip crosses the dural sac (y -35 to -20 at |x| < 8).
    d.ok(0, place([0.0, -100.0, 20.0], [0.0, 1.0, 0.0]));
    d.ok(0, Command::NeedleFeed { mm: 50.0 });
    assert_eq!(
        d.s.measurements()["dural_puncture_bool"],
        0.0,
        "tip at y = -50 is still behind the sac"
    );
    d.ok(0, Command::NeedleFeed { mm: 20.0 });
    assert_eq!(d.s.measurements()["dural_puncture_bool"], 1.0);
    d.ok(0, Command::NeedleWithdraw { mm: 50.0 });
    assert_eq!(
        d.s.measurements()["dural_puncture_bool"],
        1.0,
        "a puncture is remembered"
    );
}

#[test]
fn view_alignment_is_scored_from_the_anatomy() {
    let mut d = Driver::new();
    d.ok(0, pose(0.0, 10.0));
    d.ok(0, Command::Shot);
    let m = d.s.measurements();
    // The demo L4 inferior endplate is the plane z = -13: a 10 degree cranial beam is 10 degrees
    // off it (the estimate averages exact box-face normals, so only rounding remains).
    assert!((m["ap_endplate_tilt_deg"] - 10.0).abs() < 1e-9, "{m:?}");
    d.ok(0, pose(5.0, -1.5));
    d.ok(0, Command::Shot);
    assert!(
        (d.s.measurements()["ap_endplate_tilt_deg"] - 1.5).abs() < 1e-9,
        "best AP view counts"
    );
    // The facet joint normal is horizontal at azimuth -40 degrees; the beam (-sin o, cos o, 0)
    // lies in the joint plane at orbital o = -40.
    let m = d.s.measurements();
    // Beam . normal = -cos(a) sin(o + 40): the best view so far is (0, 10) with
    // asin(cos 10 sin 40) = 39.27 degrees (tolerance: that of the estimate, see below).
    let before = m["beam_to_joint_plane_deg"];
    let expected = (10f64.to_radians().cos() * 40f64.to_radians().sin())
        .asin()
        .to_degrees();
    assert!((before - expected).abs() < 0.5, "{before} vs {expected}");
    d.ok(0, pose(FACET_NORMAL_AZIMUTH_DEG, 0.0));
    d.ok(0, Command::Shot);
    let m = d.s.measurements();
    // The joint normal is estimated from the two block faces over 2000 probe directions; the
    // mean of the exact face normals makes it exact up to rounding, 0.5 degrees leaves margin
    // for the probe choosing a direction that hits a block edge.
    assert!(m["beam_to_joint_plane_deg"] < 0.5, "{m:?}");
    // Target x = 12 is right of the midline: an orbital of -40 is contralateral for it.
    assert_eq!(m["clo_angle_deg"], 40.0);
    assert!(!m.contains_key("ipsilateral_oblique_deg"));
    // Annotation on the last image: the target's own projection has zero error.
    let proj = sim_core::fluoro::Projection {
        orbital_deg: FACET_NORMAL_AZIMUTH_DEG,
        detector_pixels: [128, 128],
        pixel_pitch_mm: [300.0 / 128.0; 2],
        ..Default::default()
    };
    let px = proj.project_point([12.0, -18.0, 0.0]).unwrap();
    let ack = d.ok(
        0,
        Command::Annotate {
            pixel: px,
            label: "behind_l4".into(),
        },
    );
    assert!(ack.outcome["annotation_error_mm"].as_f64().unwrap() < 1e-9);
    let ack = d.ok(
        0,
        Command::Annotate {
            pixel: [px[0] + 10.0, px[1]],
            label: "behind_l4".into(),
        },
    );
    // 10 pixels of 2.34 mm on the detector, at the target's magnification (~2.0), is ~11.6 mm.
    let e = ack.outcome["annotation_error_mm"].as_f64().unwrap();
    assert!((e - 11.6).abs() < 0.5, "{e}");
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

#[test]
fn restore_from_any_snapshot_plus_the_log_is_bit_identical() {
    let steps = script();
    let mut a = Session::new(env(), config());
    let initial = a.snapshot();
    run(&mut a, &steps[..7], 1);
    let middle = a.snapshot();
    run(&mut a, &steps[7..], 8);
    let final_state = a.snapshot().to_bytes();
    let frame = final_frame(&mut a);
    for (name, snap) in [("initial", &initial), ("middle", &middle)] {
        let mut b = Session::restore(env(), snap, a.log()).unwrap();
        assert_eq!(
            b.snapshot().to_bytes(),
            final_state,
            "state from the {name} snapshot"
        );
        assert_eq!(
            final_frame(&mut b),
            frame,
            "frame bytes from the {name} snapshot"
        );
    }
    // The snapshot survives JSON (as it travels between workers).
    let json = serde_json::to_string(&middle).unwrap();
    let back: SessionSnapshot = serde_json::from_str(&json).unwrap();
    assert_eq!(back, middle);
    // A different noise seed gives a different frame: the comparison above can fail.
    let mut c = Session::new(
        env(),
        SessionConfig {
            seed: 8,
            ..config()
        },
    );
    run(&mut c, &steps, 1);
    assert_ne!(final_frame(&mut c), frame);
    // A snapshot of another station is refused.
    let e = Session::restore(env_with(&["ultrasound"]), &middle, a.log()).unwrap_err();
    assert!(e.to_string().contains("station"), "{e}");
}

#[test]
fn a_submitted_attempt_replays_to_the_same_score_and_final_frame() {
    let mut steps = script();
    steps.push((2500, Command::Submit));
    let mut a = Session::new(env(), config());
    let initial = a.snapshot();
    run(&mut a, &steps, 1);
    let result = a.result().cloned().expect("submitted");
    let frame = final_frame(&mut a);
    // Every criterion of the demo rubric is measured, so the outcome is decided.
    assert!(
        result.rubric.incomplete_criteria.is_empty(),
        "{:?}",
        result.rubric.incomplete_criteria
    );
    assert_ne!(result.rubric.outcome, Outcome::Incomplete);
    assert_eq!(result.record.log_len, steps.len() - 1);
    assert_eq!(result.record.station_id, "demo-station");
    assert!(result.record.code_revision.starts_with("render-worker "));
    assert_eq!(result.record.renderer.kind, "cpu-reference");
    assert_eq!(result.record.modalities["fluoroscopy"]["kvp"], 75);
    let e = a
        .apply(
            Envelope {
                seq: 99,
                command: Command::Shot,
            },
            3000,
        )
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::State, "read-only after submit");
    // Faculty review: replay from the initial snapshot and the log.
    let review = replay_attempt(env(), &initial, a.log()).unwrap();
    assert_eq!(review.result.as_ref(), Some(&result));
    assert_eq!(review.final_state, a.snapshot());
    let reviewed = &review.final_frames[0];
    let mut live = EncodedFrame::parse(&frame).unwrap();
    live.frame_seq = 0;
    assert_eq!(
        reviewed, &live,
        "the review shows the live session's last frame, byte for byte"
    );
    let mut b = Session::restore(env(), &initial, a.log()).unwrap();
    assert_eq!(b.result(), Some(&result));
    assert_eq!(
        serde_json::to_vec(b.result().unwrap()).unwrap(),
        serde_json::to_vec(&result).unwrap()
    );
    assert_eq!(final_frame(&mut b), frame);
}

/// Runs `steps` on a CPU-reference session and a GPU session; returns the fraction of pixels of
/// the final frame within one grey level, and the largest difference.
fn gpu_vs_cpu(steps: &[(u64, Command)]) -> Option<(f64, i32)> {
    let ctx = render_worker::gpu::context_for_tests()?;
    let mut gpu_env = env();
    gpu_env.backends = Backends::gpu(ctx);
    let mut cpu = Session::new(env(), config());
    let mut gpu = Session::new(gpu_env, config());
    // Render after every step, as a session thread does, so renderer state carries over.
    let (mut c, mut g) = (None, None);
    for (k, (t, command)) in steps.iter().enumerate() {
        for (s, last) in [(&mut cpu, &mut c), (&mut gpu, &mut g)] {
            let env = Envelope {
                seq: k as u64 + 1,
                command: command.clone(),
            };
            s.apply(env, *t).unwrap();
            if let Some(f) = s.render_dirty(&fluoro_only()).unwrap().pop() {
                *last = Some(f.image);
            }
        }
    }
    let (c, g) = (c.unwrap(), g.unwrap());
    // State and scores do not depend on the renderer.
    assert_eq!(cpu.snapshot().to_bytes(), gpu.snapshot().to_bytes());
    assert_eq!(cpu.measurements(), gpu.measurements());
    assert_eq!(gpu.score().record.renderer.kind, "gpu");
    let diffs: Vec<i32> = c
        .pixels
        .iter()
        .zip(&g.pixels)
        .map(|(a, b)| (i32::from(*a) - i32::from(*b)).abs())
        .collect();
    let within_one = diffs.iter().filter(|&&d| d <= 1).count() as f64 / diffs.len() as f64;
    let max = diffs.iter().copied().max().unwrap_or(0);
    eprintln!(
        "GPU vs CPU session frame: {:.1} % of pixels within one grey level, max difference {max}",
        100.0 * within_one
    );
    Some((within_one, max))
}

#[test]
fn gpu_backend_session_matches_the_cpu_reference_session() {
    // AP views, needle in, live and single shots, technique change.
    let steps = vec![
        (100, Command::Technique { kvp: 75, ma: 2.5 }),
        (200, place([12.0, -100.0, 1.0], [0.0, 1.0, 0.05])),
        (300, Command::NeedleFeed { mm: 30.0 }),
        (400, Command::Live { on: true }),
        (500, Command::NeedleFeed { mm: 15.0 }),
        (600, Command::Live { on: false }),
        (700, Command::Shot),
    ];
    let Some((within_one, _)) = gpu_vs_cpu(&steps) else {
        return;
    };
    // render-worker/tests/fluoro.rs shows interior pixels within one grey level (2e-3 in ln T);
    // silhouette pixels of the demo's box edges, supersampled differently, are about 1.5 % of
    // this 128 x 128 view (measured 98.7 % within one level when written), so 97 %.
    assert!(within_one >= 0.97, "{within_one}");
}

/// Regression test: in the scripted attempt, the live frame made when the C-arm turns to orbital
/// -20 degrees with the needle 60 mm in differed from the CPU reference almost everywhere (0.3 %
/// of pixels within one grey level, up to 65 levels) although the two transmissions agreed (the
/// ROI median of `ln T` within 0.005). The cause was the automatic brightness, metered on the
/// noisy frame: with about 12 quanta per pixel behind the spine, the median was one of a few
/// integer counts 0.087 apart in `ln T`, and the small difference flipped it by one count (6
/// grey levels everywhere). sim-core now meters on the noise-free transmission
/// (`sim_core::fluoro::render::finish_frame`).
#[test]
fn gpu_session_oblique_view_with_needle_matches_the_cpu() {
    let steps = script()[..9].to_vec();
    let Some((within_one, _)) = gpu_vs_cpu(&steps) else {
        return;
    };
    assert!(within_one >= 0.97, "{within_one}");
}

/// The real facet station on the procedural phantom (coarse 4 mm grid, built in memory): targets
/// land in the phantom's frame, and the scorers' anatomy-derived references are plausible.
#[test]
fn facet_station_runs_on_the_phantom() {
    use sim_core::anatomy::phantom::{self, PhantomParams};
    let started = std::time::Instant::now();
    let asset = phantom::build(&PhantomParams::with_voxel_mm(4.0), &mut |_| {}).unwrap();
    let region = Arc::new(Region::from_asset(&asset));
    eprintln!(
        "phantom 4 mm built and loaded in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let file = sim_core::rubric::load_station_dir(&dir)
        .unwrap()
        .into_iter()
        .find(|f| f.station.id == "l4-l5-left-facet")
        .expect("facet station");
    let ctx = StationContext::new(file.station, sha256_hex(file.text.as_bytes()), &region);
    // The station's targets are authored relative to the L4 body centre (its frame note).
    let l4 = region.landmarks["L4_body_centre"];
    let t = ctx.targets["left_l4_l5_facet_inferior_recess"];
    assert_eq!(t, [-21.0 + l4[0], -40.0 + l4[1], -24.0 + l4[2]]);
    // The L4 inferior endplate normal points caudally (within the lordotic tilt, < 30 degrees of
    // -z: the phantom's levels tilt by at most about 15 degrees).
    let n = anatomy::endplate_normal(&region, "L4", "L5").expect("endplate");
    let off_axis_deg = n.dot(glam::DVec3::NEG_Z).acos().to_degrees();
    eprintln!("L4 inferior endplate normal {n:?}, {off_axis_deg:.1} degrees from -z");
    assert!(off_axis_deg < 30.0);
    // The left L4-L5 facet joint: the phantom builds it at 45 degrees to the sagittal plane
    // (`FACET_ANGLE_DEG` in sim-core's phantom model), normal (cos 45, -sin 45, 0) before the
    // level's tilt about x. The estimate from 4 mm meshes is allowed 20 degrees.
    // The estimate from 4 mm meshes of a 2 mm gap, against a nominal normal that leaves out the
    // level's tilt about x (about 10 degrees, like the endplate's), is allowed 30 degrees
    // (measured 21 when written).
    let j = anatomy::facet_joint_normal(&region, t).expect("facet joint");
    let truth = glam::DVec3::new(1.0, -1.0, 0.0).normalize();
    let err = j.dot(truth).abs().min(1.0).acos().to_degrees();
    eprintln!("left L4-L5 facet normal estimate {j:?}: {err:.1} degrees from the model's");
    assert!(err < 30.0);
    // Squaring the endplate: the beam (0, cos a, sin a) is parallel to it at
    // tan a = -n_y / n_z (a caudal tilt for this lordotic level).
    let square_deg = (-n.y / n.z).atan().to_degrees();
    let env = SessionEnv::new(Arc::new(ctx), region, Backends::cpu(0));
    let mut s = Session::new(env, config());
    s.apply(
        Envelope {
            seq: 1,
            command: Command::Shot,
        },
        0,
    )
    .unwrap();
    let m = s.measurements();
    eprintln!("{m:?}");
    // The AP beam is +y: its angle to the endplate plane is asin |n_y|.
    assert!((m["ap_endplate_tilt_deg"] - n.y.abs().asin().to_degrees()).abs() < 1e-9);
    s.apply(
        Envelope {
            seq: 2,
            command: pose(0.0, square_deg),
        },
        0,
    )
    .unwrap();
    s.apply(
        Envelope {
            seq: 3,
            command: Command::Shot,
        },
        0,
    )
    .unwrap();
    assert!(s.measurements()["ap_endplate_tilt_deg"] < 1e-6);
    // The ipsilateral oblique at the model's 45 degrees (orbital -45 for a left joint, see
    // `scoring`) puts the beam in the joint plane, to within the estimate's error.
    s.apply(
        Envelope {
            seq: 4,
            command: pose(-45.0, 0.0),
        },
        0,
    )
    .unwrap();
    s.apply(
        Envelope {
            seq: 5,
            command: Command::Shot,
        },
        0,
    )
    .unwrap();
    let m = s.measurements();
    eprintln!("{m:?}");
    assert_eq!(m["ipsilateral_oblique_deg"], 45.0);
    assert!(m["beam_to_joint_plane_deg"] < 10.0, "{m:?}");
    let f = s.render_dirty(&fluoro_only()).unwrap().pop().unwrap();
    let (lo, hi) = f
        .image
        .pixels
        .iter()
        .fold((255u8, 0u8), |(l, h), &p| (l.min(p), h.max(p)));
    assert!(hi - lo > 60, "grey range {lo}..{hi}");
}

/// The scripted session of `frames_of_a_scripted_session_are_pinned`: shots, C-arm moves, a
/// live run with needle motion, an annotation and a submit, rendering after every step.
fn scripted_frames_sha256(env: SessionEnv) -> (String, usize) {
    use sha2::{Digest, Sha256};
    let steps: Vec<(u64, Command)> = vec![
        (0, Command::Shot),
        (100, pose(-30.0, 5.0)),
        (200, Command::Shot),
        (300, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0])),
        (400, Command::Live { on: true }),
        (500, Command::NeedleFeed { mm: 20.0 }),
        (600, Command::NeedleRoll { deg: 90.0 }),
        (700, pose(15.0, -10.0)),
        (800, Command::Technique { kvp: 95, ma: 3.5 }),
        (900, Command::NeedleWithdraw { mm: 5.0 }),
        (1000, Command::Live { on: false }),
        (
            1100,
            Command::Annotate {
                pixel: [64.0, 64.0],
                label: "target".into(),
            },
        ),
        (1200, Command::Submit),
    ];
    let mut s = Session::new(env, config());
    let mut h = Sha256::new();
    let mut frames = 0;
    for (k, (t, command)) in steps.into_iter().enumerate() {
        let env = Envelope {
            seq: k as u64 + 1,
            command,
        };
        s.apply(env, t).unwrap();
        for f in s.render_dirty(&fluoro_only()).unwrap() {
            h.update(f.input_seq.to_le_bytes());
            h.update(f.t_ms.to_le_bytes());
            h.update(&f.image.pixels);
            frames += 1;
        }
    }
    (hex::encode(h.finalize()), frames)
}

/// Pins the frames of a scripted session: a restructuring of the session code must leave every
/// pixel as it was. Hashes recorded before the modality seam of issue 14 moved the fluoroscopy
/// modality into its own folder (commit 3baf252). The GPU hash is pinned only on the software
/// adapter it was recorded on (another driver or vector width rounds differently).
#[test]
fn frames_of_a_scripted_session_are_pinned() {
    let (cpu, n) = scripted_frames_sha256(env());
    eprintln!("scripted session, CPU reference: {n} frames, sha256 {cpu}");
    assert_eq!(n, 8);
    assert_eq!(
        cpu,
        "46845c29b961755f6987ea9a78e173e848112eabb0386a518704740a34839355"
    );
    if let Some(ctx) = render_worker::gpu::context_for_tests() {
        let adapter = ctx.summary.name.clone();
        let mut gpu_env = env();
        gpu_env.backends = Backends::gpu(ctx);
        let (gpu, n) = scripted_frames_sha256(gpu_env);
        eprintln!("scripted session, GPU ({adapter}): {n} frames, sha256 {gpu}");
        assert_eq!(n, 8);
        if adapter == "llvmpipe (LLVM 15.0.6, 256 bits)" {
            assert_eq!(
                gpu,
                "ecbc106b6ca2d30445360918924e8276b2ac7a9a2a269fffd05e0bd633e13df1"
            );
        }
    }
}

/// What the server's log cannot store is refused before it is acknowledged (issue 20, point 3):
/// NUL in text fields, and sequence numbers above a PostgreSQL `bigint`.
#[test]
fn commands_the_log_cannot_store_are_refused_naming_the_field() {
    let mut s = Session::new(env(), config());
    let cases = [
        (u64::MAX, Command::Shot, "seq", ErrorCode::Sequence),
        (
            (i64::MAX as u64) + 1,
            Command::Shot,
            "seq",
            ErrorCode::Sequence,
        ),
        (
            1,
            Command::Annotate {
                pixel: [1.0, 1.0],
                label: "tar\0get".into(),
            },
            "command.label",
            ErrorCode::Invalid,
        ),
        (
            1,
            Command::NeedlePlace {
                instrument: "spinal\0".into(),
                entry_mm: [12.0, -100.0, 0.0],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
            "command.instrument",
            ErrorCode::Invalid,
        ),
    ];
    for (seq, command, field, code) in cases {
        let e = s.apply(Envelope { seq, command }, 0).unwrap_err();
        assert_eq!((e.field.as_str(), e.code), (field, code), "{e}");
    }
    assert!(s.log().is_empty());
    // The largest storable sequence number is accepted.
    s.apply(
        Envelope {
            seq: i64::MAX as u64,
            command: Command::Shot,
        },
        0,
    )
    .unwrap();
}

/// Unknown fields are refused, naming them (issue 20, point 8), in the envelope and in every
/// command, unit commands included (serde alone ignores those).
#[test]
fn unknown_fields_in_messages_and_commands_are_refused() {
    for (text, field) in [
        (
            r#"{"type":"command","seq":1,"command":{"type":"shot"},"extra":1}"#,
            "extra",
        ),
        (
            r#"{"type":"command","seq":1,"command":{"type":"shot","x":1}}"#,
            "command.x",
        ),
        (
            r#"{"type":"command","seq":1,"command":{"type":"submit","score":1}}"#,
            "command.score",
        ),
        (
            r#"{"type":"command","seq":1,"command":{"type":"carm_pose","orbital_deg":0,"angular_deg":0,"zoom":2}}"#,
            "command.zoom",
        ),
        (
            r#"{"type":"views","visible":["fluoroscopy"],"all":true}"#,
            "all",
        ),
    ] {
        let (_, e) = parse_client_message(text).unwrap_err();
        assert_eq!(e.field, field, "{text}: {e}");
        assert_eq!(e.code, ErrorCode::Malformed);
    }
    // The same messages without the extra field parse.
    for text in [
        r#"{"type":"command","seq":1,"command":{"type":"shot"}}"#,
        r#"{"type":"command","seq":1,"command":{"type":"carm_pose","orbital_deg":0,"angular_deg":0}}"#,
        r#"{"type":"views","visible":["fluoroscopy"]}"#,
    ] {
        assert!(parse_client_message(text).is_ok(), "{text}");
    }
}
