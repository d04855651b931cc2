//! Snapshots and exact replay: a session restored from any snapshot plus its log reaches
//! bit-identical state and frames, and a submitted attempt replays to the same score and final
//! frame.

use render_worker::session::frame::EncodedFrame;
use render_worker::session::*;
use sim_core::rubric::Outcome;

use super::support::{config, env, env_with, final_frame, run, script};

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
