//! The temporal chain of live fluoroscopy: detector lag and the recursive filter leave a
//! fading trail of moving steel, keep a still scene exact, follow the learner's level, and
//! replay (and restore mid-run) bit for bit.

use render_worker::session::*;
use serde_json::{Value, json};

use super::support::{Driver, env, fluoro_only, place};

fn level(name: &str) -> Command {
    serde_json::from_value(json!({ "type": "recursive_filter", "level": name })).unwrap()
}

/// The demo station without quantum noise (so a still region is the same in every frame).
fn quiet() -> SessionConfig {
    let mut c = super::support::config();
    c.fluoro.noise = false;
    c
}

/// A session on `quiet()`; `chain: false` gives one recorded before the temporal chain.
fn session(chain: bool) -> Driver {
    let mut initial = Session::new(env(), quiet()).snapshot();
    if !chain {
        let f = initial.modalities.get_mut("fluoroscopy").unwrap();
        assert!(f.as_object_mut().unwrap().remove("temporal").is_some());
    }
    Driver {
        s: Session::restore(env(), &initial, &[]).unwrap(),
        seq: 0,
    }
}

/// A live run in which the needle advances 4 mm a pulse; the frame displayed after each step.
fn needle_run(d: &mut Driver) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    d.ok(100, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0]));
    d.ok(150, Command::NeedleFeed { mm: 20.0 });
    d.ok(200, Command::Live { on: true });
    for k in 0..5u64 {
        // A pulse apart at 7.5 pulses per second.
        d.ok(340 + 140 * k, Command::NeedleFeed { mm: 4.0 });
        if let Some(f) = d.s.render_dirty(&fluoro_only()).unwrap().pop() {
            out.push(f.image.pixels);
        }
    }
    out
}

fn images(d: &Driver) -> Vec<Value> {
    d.s.snapshot().modalities["fluoroscopy"]["images"]
        .as_array()
        .unwrap()
        .clone()
}

#[test]
fn lag_and_filter_trail_moving_steel_and_keep_still_pixels() {
    let (mut with, mut without) = (session(true), session(false));
    let a = needle_run(&mut with);
    let b = needle_run(&mut without);
    assert_eq!(a.len(), b.len());
    assert!(a.len() >= 4, "{} live frames", a.len());
    // The first frame of the run is itself; the later ones differ only where the needle
    // moved (the still anatomy is the same, bit for bit, since the weights sum to 2^16).
    assert_eq!(a[0], b[0]);
    let last = a.len() - 1;
    let changed: Vec<usize> = (0..a[last].len()).filter(|&p| a[last][p] != b[last][p]).collect();
    assert!(!changed.is_empty(), "no trail");
    let moved: Vec<usize> = (0..b[last].len()).filter(|&p| b[last][p] != b[0][p]).collect();
    assert!(
        changed.iter().all(|p| moved.contains(p)),
        "{} pixels changed outside the needle's path",
        changed.iter().filter(|p| !moved.contains(p)).count()
    );
    // The trail: where the needle was in the first frame but is no longer, the filtered frame
    // still shows part of it (darker than the raw frame there: steel is dark in fluoroscopy).
    let trail = (0..b[0].len())
        .filter(|&p| b[0][p] < b[last][p] && a[last][p] < b[last][p])
        .count();
    assert!(trail > 0, "no fading trail where the needle was");
    // Every live image records its run and level; shots none.
    for i in images(&with) {
        assert_eq!(i["live"] == true, i.get("run").is_some(), "{i}");
        assert_eq!(i["live"] == true, i["filter"] == "low", "{i}");
    }
    for i in images(&without) {
        assert!(i.get("run").is_none() && i.get("filter").is_none(), "{i}");
    }
}

#[test]
fn lag_and_filter_follow_the_level_and_refuse_others() {
    let mut frames = Vec::new();
    for name in ["off", "low", "high"] {
        let mut d = session(true);
        d.ok(50, level(name));
        frames.push(needle_run(&mut d).pop().unwrap());
        assert!(images(&d).iter().filter(|i| i["live"] == true).all(|i| i["filter"] == name));
    }
    // Three levels, three different last frames (off still carries the detector's lag).
    assert_ne!(frames[0], frames[1]);
    assert_ne!(frames[1], frames[2]);
    let mut d = session(true);
    let before = d.s.snapshot().to_bytes();
    let e = d.err(level("max"));
    assert_eq!(e.field, "command.level", "{e}");
    assert!(e.message.contains("off, low or high"), "{e}");
    let e = d.err(serde_json::from_value(json!({ "type": "recursive_filter" })).unwrap());
    assert!(e.message.contains("level"), "{e}");
    assert_eq!(d.s.snapshot().to_bytes(), before);
}

/// The displayed frame is a function of the images alone: a replay, and a session restored in
/// the middle of the run (whose earlier raw frames this process never rendered), show it bit
/// for bit.
#[test]
fn lag_and_filter_replay_and_restore_mid_run_bit_identically() {
    let mut d = session(true);
    let shown = needle_run(&mut d);
    let initial = session(true).s.snapshot();
    let mut replayed = Session::restore(env(), &initial, d.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), d.s.snapshot().to_bytes());
    let f = replayed.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(&f.last().unwrap().image.pixels, shown.last().unwrap());
    // Restored from a snapshot taken in the middle of the run, then the rest of the log.
    let mut part = session(true);
    let log = d.s.log().to_vec();
    let cut = log.len() - 2;
    for e in &log[..cut] {
        let envelope = Envelope {
            seq: e.seq,
            command: e.command.clone(),
        };
        part.s.apply(envelope, e.t_ms).unwrap();
    }
    let mid = part.s.snapshot();
    let mut restored = Session::restore(env(), &mid, &log).unwrap();
    let f = restored.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(&f.last().unwrap().image.pixels, shown.last().unwrap());
}

/// A C-arm move restarts the filter (motion-detecting): the first frame at the new pose is the
/// raw frame, the same as a session without the chain shows.
#[test]
fn lag_and_filter_restart_when_the_carm_moves() {
    let frames = |chain: bool| {
        let mut d = session(chain);
        // A technique set by hand, so that no brightness step adds a frame at the new pose.
        d.ok(60, Command::Technique { kvp: 80, ma: 2.0 });
        needle_run(&mut d);
        d.ok(1200, super::support::pose(12.0, 0.0));
        // The next pulse images the new pose (if the move came within a pulse already imaged).
        d.ok(1400, Command::Tick);
        let p = d.s.snapshot().modalities["fluoroscopy"]["images"]
            .as_array()
            .unwrap()
            .last()
            .unwrap()["projection"]["orbital_deg"]
            .clone();
        assert_eq!(p, 12.0, "the last image is at the new pose");
        d.s.render_dirty(&fluoro_only()).unwrap().pop().unwrap().image.pixels
    };
    assert_eq!(frames(true), frames(false));
}
