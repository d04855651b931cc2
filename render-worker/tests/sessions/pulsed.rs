//! Pulsed fluoroscopy: the learner's pulse rate (4, 7.5, 15 or 30 per second, 7.5 by default)
//! sets the live dose rate and how often live images are made, is logged and replayed, and is
//! checked; sessions recorded before pulsing keep the continuous beam.

use render_worker::session::*;
use serde_json::json;

use std::sync::Arc;

use super::support::{Driver, config, env, fluoro_only, place, pose, stoppable_drafting_env};

fn pulse_rate(pps: f64) -> Command {
    serde_json::from_value(json!({ "type": "pulse_rate", "pps": pps })).unwrap()
}

/// Live images acquired so far.
fn live_images(s: &Session) -> Vec<u64> {
    s.snapshot().modalities["fluoroscopy"]["images"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|i| i["live"] == true)
        .map(|i| i["t_ms"].as_u64().unwrap())
        .collect()
}

/// A single shot of 0.1 s at 2 mA is 0.2 mAs; ten seconds of live fluoroscopy at `pps` deliver
/// `pps / 30` of the continuous 20 mAs (each pulse one video frame's charge), so the kerma of the
/// live run is `100 * pps / 30` shots' worth. The fluoroscopy time is the pedal time whatever the
/// rate. Exact up to round-off (1e-9 relative: the same kerma per mAs and skin distance).
#[test]
fn live_dose_follows_the_pulse_rate() {
    for pps in [4.0, 7.5, 15.0, 30.0] {
        let mut d = Driver::new();
        // A technique set by hand (the brightness control would step it after each frame).
        d.ok(400, Command::Technique { kvp: 80, ma: 2.0 });
        d.ok(500, Command::Shot);
        let shot = d.s.measurements()["air_kerma_mgy"];
        d.ok(600, pulse_rate(pps));
        d.ok(1000, Command::Live { on: true });
        d.ok(11_000, Command::Live { on: false });
        let m = d.s.measurements();
        let want = 1.0 + 100.0 * pps / 30.0;
        assert!(
            (m["air_kerma_mgy"] / shot - want).abs() < 1e-9 * want,
            "{pps} pps: {} shots' worth, expected {want}",
            m["air_kerma_mgy"] / shot
        );
        assert!((m["fluoro_time_s"] - 10.1).abs() < 1e-9, "{pps} pps");
    }
    // A new session runs at 7.5 pulses per second until the learner picks another rate, and a
    // change of rate mid-run books the seconds before it at the old rate.
    let mut d = Driver::new();
    d.ok(400, Command::Technique { kvp: 80, ma: 2.0 });
    d.ok(500, Command::Shot);
    let shot = d.s.measurements()["air_kerma_mgy"];
    d.ok(1000, Command::Live { on: true });
    d.ok(5000, pulse_rate(30.0));
    d.ok(7000, Command::Live { on: false });
    let ratio = d.s.measurements()["air_kerma_mgy"] / shot;
    let want = 1.0 + 4.0 * 10.0 * 0.25 + 2.0 * 10.0;
    assert!((ratio - want).abs() < 1e-9 * want, "{ratio} vs {want}");
}

/// While live runs, a change is imaged at most once per pulse (pulses on a grid from the pedal
/// press): a C-arm drag of about 60 poses a second makes about 7.5 images a second at 7.5 pps and
/// about 30 at 30 pps; the last pose waits for the next pulse (a tick in it images it), and after
/// the pedal is released nothing more is imaged (last-image hold).
#[test]
fn live_images_come_at_most_one_per_pulse() {
    for (pps, lo, hi) in [(7.5, 7, 9), (30.0, 28, 31)] {
        let mut d = Driver::new();
        d.ok(0, pulse_rate(pps));
        d.ok(1000, Command::Live { on: true });
        // A drag for one second: a pose every 16 ms (about 60 a second).
        let mut t = 1000;
        let mut k = 0;
        while t < 2000 {
            t += 16;
            k += 1;
            d.ok(t, pose(f64::from(k) * 0.1, 0.0));
        }
        let times = live_images(&d.s);
        let n = times.len();
        eprintln!("{pps} pps: {n} live images in a 1 s drag of {k} poses");
        assert!(
            (lo..=hi).contains(&n),
            "{pps} pps: {n} live images in 1 s: {times:?}"
        );
        let period = 1000.0 / pps;
        let pulse = |t: u64| ((t - 1000) as f64 / period).floor() as u64;
        for w in times.windows(2) {
            assert!(
                pulse(w[1]) > pulse(w[0]),
                "{pps} pps: two images in one pulse: {times:?}"
            );
        }
        // The last pose is imaged by the first logged moment a period after the last image.
        let last = *times.last().unwrap();
        let imaged_pose = |s: &Session| {
            s.snapshot().modalities["fluoroscopy"]["images"]
                .as_array()
                .unwrap()
                .last()
                .unwrap()["projection"]["orbital_deg"]
                .as_f64()
                .unwrap()
        };
        let final_pose = f64::from(k) * 0.1;
        let due = 1000 + ((pulse(last) + 1) as f64 * period).ceil() as u64;
        if imaged_pose(&d.s) != final_pose {
            d.ok(due.max(t + 1), Command::Tick);
        }
        assert_eq!(imaged_pose(&d.s), final_pose, "{pps} pps");
        // Released: later changes and ticks image nothing.
        let released = live_images(&d.s).len();
        d.ok(due.max(t + 1) + 10, Command::Live { on: false });
        d.ok(due.max(t + 1) + 20, pose(-10.0, 0.0));
        d.ok(due.max(t + 1) + 500, Command::Tick);
        assert_eq!(
            live_images(&d.s).len(),
            released,
            "{pps} pps: last-image hold"
        );
    }
}

/// The rate is one of four, named in the error otherwise; the command is logged and replays
/// bit for bit, ticks and all.
#[test]
fn the_pulse_rate_is_checked_logged_and_replayed() {
    let mut d = Driver::new();
    for bad in [json!(10.0), json!(0.0), json!(-7.5), json!(1e9)] {
        let c: Command =
            serde_json::from_value(json!({ "type": "pulse_rate", "pps": bad })).unwrap();
        let e = d.err(c);
        assert_eq!(e.field, "command.pps", "{bad}: {e}");
    }
    for bad in [
        json!({ "type": "pulse_rate", "pps": "7.5" }),
        json!({ "type": "pulse_rate" }),
        json!({ "type": "pulse_rate", "pps": 7.5, "extra": 1 }),
    ] {
        let c: Command = serde_json::from_value(bad.clone()).unwrap();
        let e = d.err(c);
        assert!(e.field.starts_with("command"), "{bad}: {e}");
    }
    let ack = d.ok(100, pulse_rate(15.0));
    assert_eq!(ack.outcome["pulse_rate_pps"], 15.0);
    d.ok(200, place([12.0, -100.0, 1.0], [0.0, 1.0, 0.05]));
    d.ok(300, Command::Live { on: true });
    for (k, t) in (310..900).step_by(30).enumerate() {
        if k % 3 == 2 {
            d.ok(t as u64, Command::Tick);
        } else {
            d.ok(t as u64, Command::NeedleFeed { mm: 1.0 });
        }
    }
    d.ok(950, pulse_rate(4.0));
    d.ok(1200, Command::NeedleFeed { mm: 1.0 });
    d.ok(1500, Command::Live { on: false });
    let initial = Session::new(env(), config()).snapshot();
    let replayed = Session::restore(env(), &initial, d.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), d.s.snapshot().to_bytes());
    assert_eq!(replayed.measurements(), d.s.measurements());
}

/// A session whose state has no pulse rate, as one recorded before pulsing.
fn recorded_before_pulsing() -> Session {
    let mut snapshot = Session::new(env(), config()).snapshot();
    let fluoro = snapshot.modalities.get_mut("fluoroscopy").unwrap();
    assert_eq!(
        fluoro["pulse_rate_pps"], 7.5,
        "a new session starts at 7.5 pps"
    );
    // Recorded before pulsing, so also before the brightness control and the detector's noise.
    for field in ["pulse_rate_pps", "brightness", "detector_noise", "temporal"] {
        fluoro.as_object_mut().unwrap().remove(field);
    }
    Session::restore(env(), &snapshot, &[]).unwrap()
}

/// A session recorded before pulsing runs the continuous beam: every change while live is imaged
/// at once and a live second books the full current, so its replay gives what was recorded.
#[test]
fn a_session_recorded_before_pulsing_keeps_the_continuous_beam() {
    let apply = |s: &mut Session, seq: u64, t: u64, command: Command| {
        s.apply(Envelope { seq, command }, t).unwrap();
    };
    let mut s = recorded_before_pulsing();
    apply(&mut s, 1, 1000, Command::Live { on: true });
    for k in 1..=10 {
        apply(&mut s, 1 + k, 1000 + 16 * k, pose(k as f64, 0.0));
    }
    assert_eq!(live_images(&s).len(), 11, "every change imaged at once");
    let mut s = recorded_before_pulsing();
    apply(&mut s, 1, 500, Command::Shot);
    let shot = s.measurements()["air_kerma_mgy"];
    apply(&mut s, 2, 1000, Command::Live { on: true });
    apply(&mut s, 3, 11_000, Command::Live { on: false });
    let ratio = s.measurements()["air_kerma_mgy"] / shot;
    assert!((ratio - 101.0).abs() < 1e-6, "{ratio}");
}

/// A tick a little early for the pulse a waiting change is due at is applied at that pulse
/// (the host asks `Session::tick_time` before applying a tick): within a quarter period before
/// it (33 ms at 7.5 pulses per second, 8 ms at 30), never earlier, and not once the pedal is
/// released.
#[test]
fn an_early_tick_is_held_for_the_pulse_a_waiting_change_is_due_at() {
    for (pps, due, hold_ms) in [(7.5, 1134, 33), (30.0, 1034, 8)] {
        let mut d = Driver::new();
        d.ok(0, pulse_rate(pps));
        d.ok(1000, Command::Live { on: true });
        // A pose in the pulse that imaged the pedal press waits for the next one.
        d.ok(1010, pose(3.0, 0.0));
        assert_eq!(live_images(&d.s), [1000], "{pps} pps");
        for now in [due - hold_ms, due - 1] {
            assert_eq!(d.s.tick_time(now), due, "{pps} pps, tick at {now}");
        }
        for now in [due - hold_ms - 1, 1011, due, due + 40] {
            assert_eq!(d.s.tick_time(now), now, "{pps} pps, tick at {now}");
        }
        // The host applies the held tick at `due`: the pose is imaged by that pulse.
        let at = d.s.tick_time(due - 3);
        let ack = d.ok(at, Command::Tick);
        assert_eq!(ack.t_ms, due);
        assert_eq!(live_images(&d.s), [1000, due], "{pps} pps");
        // Released with a change waiting: nothing is held.
        d.ok(due + 5, pose(6.0, 0.0));
        d.ok(due + 6, Command::Live { on: false });
        assert_eq!(
            d.s.tick_time(due + 2 * (due - 1000) - 3),
            due + 2 * (due - 1000) - 3
        );
    }
}

/// A C-arm move stops only the fluoroscopy work it makes obsolete (see
/// `render_worker::interrupt`; the flag raised as the session thread raises it for a
/// `carm_pose`). A shot's full frame behind its draft is finished (the shot stays on screen
/// with the beam off, whatever the C-arm does); a live image's full frame is stopped and its
/// view stays dirty; once a move waits for the next pulse, the drafted live image is not
/// refined at all (a live drag shows drafts); the pulse's new image is drafted and refined, and
/// a replay of the log renders it bit for bit.
#[test]
fn a_carm_move_stops_the_refinement_of_a_live_image_but_not_of_a_shot() {
    use render_worker::interrupt::watching;
    use std::sync::atomic::AtomicBool;
    let Some(e) = stoppable_drafting_env() else {
        return;
    };
    let initial_env = e.clone();
    let mut s = Session::new(e, config());
    let initial = s.snapshot();
    let raised = Arc::new(AtomicBool::new(true));
    let mut seq = 0;
    let mut at = |s: &mut Session, t: u64, command: Command| {
        seq += 1;
        s.apply(Envelope { seq, command }, t).unwrap();
    };
    let refine = |s: &mut Session| {
        let _w = watching(&raised);
        s.render_dirty_unless_superseded(&fluoro_only()).unwrap()
    };
    // A shot after a move: drafted, and its full frame is drawn under the raised flag.
    at(&mut s, 100, pose(20.0, 5.0));
    at(&mut s, 150, Command::Shot);
    assert_eq!(s.render_drafts(&fluoro_only()).unwrap().len(), 1);
    let (full, stopped) = refine(&mut s);
    assert!(
        !stopped && full.len() == 1 && !full[0].draft,
        "a shot is refined"
    );
    // Live, the C-arm moved: the pulse's image is drafted, its refinement stopped.
    at(&mut s, 200, Command::Live { on: true });
    let _ = s.render_dirty(&fluoro_only()).unwrap();
    at(&mut s, 250, pose(24.0, 5.0));
    at(&mut s, 400, Command::Tick);
    assert_eq!(s.render_drafts(&fluoro_only()).unwrap().len(), 1);
    let (full, stopped) = refine(&mut s);
    assert!(
        stopped && full.is_empty(),
        "a live image's refinement stops"
    );
    assert!(s.has_dirty(&fluoro_only()), "and its view stays dirty");
    // A move waiting for the next pulse: the drafted image is not refined.
    at(&mut s, 410, pose(28.0, 5.0));
    assert!(!s.has_dirty(&fluoro_only()), "replaced at the next pulse");
    // The next pulse images the move: drafted, then refined (nothing raised).
    at(&mut s, 560, Command::Tick);
    assert_eq!(s.render_drafts(&fluoro_only()).unwrap().len(), 1);
    let full = s.render_dirty(&fluoro_only()).unwrap();
    assert!(full.len() == 1 && !full[0].draft);
    let mut r = Session::restore(initial_env, &initial, s.log()).unwrap();
    let replayed = r.render_dirty(&fluoro_only()).unwrap();
    assert!(replayed[0].image == full[0].image, "the replay renders it");
}

/// A live image that no draft stands for on screen (a renderer without drafts, or a region too
/// small to get a draft scene) is rendered in full even when the next C-arm move already waits
/// for the pulse after it: only a drafted image may be skipped for the view that replaces it.
/// Otherwise a learner who drags the C-arm under live fluoroscopy sees no image until the drag
/// ends. The session thread's order: a pulse's image, its draft pass (which draws nothing
/// here), the next move, then the full frames of the dirty views.
#[test]
fn a_live_image_without_a_draft_is_rendered_while_the_next_move_waits() {
    let mut s = Session::new(env(), config());
    let mut seq = 0;
    let mut at = |s: &mut Session, t: u64, command: Command| {
        seq += 1;
        s.apply(Envelope { seq, command }, t).unwrap();
    };
    at(&mut s, 100, Command::Live { on: true });
    assert_eq!(s.render_dirty(&fluoro_only()).unwrap().len(), 1);
    for k in 1..=3u64 {
        // 7.5 pulses per second: a move 20 ms into a pulse waits for the next one.
        let pulse = 100 + 133 * k + 1;
        at(&mut s, pulse - 113, pose(20.0 + k as f64, 5.0));
        at(&mut s, pulse, Command::Tick);
        assert!(
            s.render_drafts(&fluoro_only()).unwrap().is_empty(),
            "no draft"
        );
        at(&mut s, pulse + 10, pose(20.5 + k as f64, 5.0));
        let frames = s.render_dirty(&fluoro_only()).unwrap();
        assert!(
            frames.len() == 1 && !frames[0].draft,
            "pulse {k}: the new image is rendered, not skipped for the waiting move"
        );
    }
}
