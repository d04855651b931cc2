//! Automatic brightness control in a session: each frame's technique is stepped from the
//! previous frame's metered detector kerma, reported in the acknowledgement, logged and
//! replayed; a technique set by hand turns it off, a `brightness` command chooses a curve.

use render_worker::session::*;
use serde_json::{Value, json};
use sim_core::fluoro::brightness::{
    BrightnessCurve, FrameExposure, Technique, TubeLimits, skin_kerma_rate_mgy_per_min,
};

use super::support::{Driver, config, env, pose};


fn brightness(curve: &str) -> Command {
    serde_json::from_value(json!({ "type": "brightness", "curve": curve })).unwrap()
}

fn images(s: &Session) -> Vec<Value> {
    s.snapshot().modalities["fluoroscopy"]["images"]
        .as_array()
        .unwrap()
        .clone()
}

/// The metered kerma of every image, nGy.
fn kerma(s: &Session) -> Vec<f64> {
    images(s)
        .iter()
        .map(|i| i["detector_kerma_ngy"].as_f64().unwrap())
        .collect()
}

/// `n` shots 100 ms apart from `t0`; the acknowledgements' technique objects.
fn shots(d: &mut Driver, t0: u64, n: u64) -> Vec<Value> {
    (0..n)
        .map(|k| d.ok(t0 + 100 * k, Command::Shot).outcome["technique"].clone())
        .collect()
}

#[test]
fn brightness_holds_the_detector_kerma_through_view_changes() {
    let target = BrightnessCurve::Standard.target_ngy_per_frame();
    let mut d = Driver::new();
    let ap = shots(&mut d, 100, 8);
    d.ok(1000, pose(90.0, 0.0));
    let lateral = shots(&mut d, 1100, 8);
    let k = kerma(&d.s);
    eprintln!("metered kerma per frame, nGy (AP, then lateral): {k:?}");
    assert_eq!(k.len(), 16);
    for (name, run) in [("AP", &k[..8]), ("lateral", &k[8..])] {
        // The first frame of a view is exposed with the previous view's technique; within 5
        // frames of it the metered kerma is within 5 % of the target, and stays there.
        for (i, x) in run.iter().enumerate().skip(5) {
            assert!((x / target - 1.0).abs() <= 0.05, "{name} frame {i}: {run:?}");
        }
    }
    // Every acknowledgement names the technique its shot used and the control's state.
    for t in ap.iter().chain(&lateral) {
        assert_eq!(t["brightness"], "standard", "{t}");
        assert!(t["kvp"].as_u64().is_some() && t["ma"].as_f64().is_some(), "{t}");
        assert_eq!(t["pulse_rate_pps"], 7.5, "{t}");
        assert!(t["detector_kerma_ngy"].as_f64().unwrap() > 0.0, "{t}");
    }
    let (a, l) = (ap.last().unwrap(), lateral.last().unwrap());
    let hotter = l["kvp"].as_u64() > a["kvp"].as_u64()
        || l["kvp"] == a["kvp"] && l["ma"].as_f64() > a["ma"].as_f64();
    assert!(hotter, "AP {a}, lateral {l}");
    // Every frame's technique within the tube's limits and 88 mGy/min at the skin (the
    // region's skin along the central ray, as the session meters it).
    let limits = TubeLimits::default();
    let region = env().region.clone();
    for i in images(&d.s) {
        let projection: sim_core::fluoro::Projection =
            serde_json::from_value(i["projection"].clone()).unwrap();
        let t = Technique {
            kvp: i["kvp"].as_u64().unwrap() as u32,
            ma: i["ma"].as_f64().unwrap(),
        };
        let e = FrameExposure {
            frame_s: 1.0 / 30.0,
            duty: 0.25,
            source_to_detector_mm: projection.source_to_detector_mm(),
            source_to_skin_mm: render_worker::session::modalities::fluoro::dose::source_to_skin_mm(
                &region,
                &projection,
            ),
        };
        assert!(t.ma <= limits.max_ma, "{t:?}");
        assert!(skin_kerma_rate_mgy_per_min(t, &e) <= 88.0, "{t:?}");
        // A shot: the current for 0.1 s.
        assert!((i["mas"].as_f64().unwrap() - 0.1 * t.ma).abs() < 1e-12, "{i}");
    }
}

#[test]
fn brightness_is_turned_off_by_a_manual_technique_and_on_by_a_curve() {
    let mut d = Driver::new();
    d.ok(100, Command::Technique { kvp: 70, ma: 1.0 });
    let t = shots(&mut d, 200, 3);
    for x in &t {
        assert_eq!(x["brightness"], "manual", "{x}");
        assert_eq!((x["kvp"].as_u64(), x["ma"].as_f64()), (Some(70), Some(1.0)));
    }
    let ack = d.ok(600, brightness("low_dose"));
    assert_eq!(ack.outcome["technique"]["brightness"], "low_dose");
    let t = shots(&mut d, 700, 6);
    assert_eq!(t[0]["kvp"], 70, "the first frame keeps the technique it had");
    let k = kerma(&d.s);
    let low = BrightnessCurve::LowDose.target_ngy_per_frame();
    assert!((k.last().unwrap() / low - 1.0).abs() <= 0.05, "{k:?}");
    // A curve that does not exist is refused by name, and nothing changes.
    let before = d.s.snapshot().to_bytes();
    let e = d.err(brightness("auto"));
    assert_eq!(e.field, "command.curve", "{e}");
    assert!(e.to_string().contains("standard"), "{e}");
    let e = d.err(serde_json::from_value(json!({ "type": "brightness" })).unwrap());
    assert!(e.to_string().contains("curve"), "{e}");
    assert_eq!(d.s.snapshot().to_bytes(), before);
}

/// The control's steps are part of the log's consequences: a replay from the initial state
/// gives the same techniques, the same frames, bit for bit.
#[test]
fn brightness_steps_and_live_pulses_replay_bit_identically() {
    let mut d = Driver::new();
    d.ok(100, Command::Shot);
    d.ok(200, Command::Live { on: true });
    for k in 1..=8 {
        d.ok(200 + 70 * k, pose(10.0 * k as f64, 0.0));
    }
    d.ok(900, Command::Live { on: false });
    d.ok(950, brightness("high_contrast"));
    d.ok(1000, Command::Shot);
    let live: Vec<Value> = images(&d.s)
        .into_iter()
        .filter(|i| i["live"] == true)
        .collect();
    assert!(live.len() >= 3, "{}", live.len());
    for i in &live {
        // A live pulse: a video frame's charge.
        let ma = i["ma"].as_f64().unwrap();
        assert!((i["mas"].as_f64().unwrap() - ma / 30.0).abs() < 1e-12, "{i}");
    }
    let techniques: Vec<(u64, f64)> = images(&d.s)
        .iter()
        .map(|i| (i["kvp"].as_u64().unwrap(), i["ma"].as_f64().unwrap()))
        .collect();
    assert!(
        techniques.windows(2).any(|w| w[0] != w[1]),
        "the control stepped: {techniques:?}"
    );
    let initial = Session::new(env(), config()).snapshot();
    let mut replayed = Session::restore(env(), &initial, d.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), d.s.snapshot().to_bytes());
    let fluoro = super::support::fluoro_only();
    let a = d.s.render_dirty(&fluoro).unwrap();
    let b = replayed.render_dirty(&fluoro).unwrap();
    assert_eq!(a.len(), 1);
    assert_eq!(a[0].image.pixels, b[0].image.pixels);
}

/// A session recorded before the control, the detector model and the temporal chain: its images
/// gain none of their fields (a stored result's replay compares the whole state), and its
/// technique stays where it was set.
#[test]
fn brightness_leaves_sessions_recorded_before_it_as_they_were() {
    let mut initial = Session::new(env(), config()).snapshot();
    let f = initial.modalities.get_mut("fluoroscopy").unwrap();
    for field in ["brightness", "detector_noise", "temporal", "scatter", "receptor"] {
        assert!(f.as_object_mut().unwrap().remove(field).is_some(), "{field}");
    }
    let mut d = Driver {
        s: Session::restore(env(), &initial, &[]).unwrap(),
        seq: 0,
    };
    d.ok(100, Command::Shot);
    d.ok(200, pose(90.0, 0.0));
    d.ok(300, Command::Shot);
    d.ok(400, Command::Live { on: true });
    d.ok(700, pose(80.0, 0.0));
    d.ok(900, Command::Live { on: false });
    for i in images(&d.s) {
        for field in ["mas", "detector_kerma_ngy", "run", "filter", "scatter"] {
            assert!(i.get(field).is_none(), "{field} in {i}");
        }
        assert_eq!((i["kvp"].as_u64(), i["ma"].as_f64()), (Some(80), Some(2.0)), "{i}");
    }
    let f = &d.s.snapshot().modalities["fluoroscopy"];
    for field in [
        "brightness",
        "detector_noise",
        "temporal",
        "collimator",
        "field_mm",
        "scatter",
        "receptor",
    ] {
        assert!(f.get(field).is_none(), "{field} in {f}");
    }
}

/// In a still live run the control's step is itself imaged by the next pulse (at the client's
/// logged tick), so live fluoroscopy settles without the learner moving anything.
#[test]
fn brightness_settles_during_a_still_live_run() {
    let target = BrightnessCurve::Standard.target_ngy_per_frame();
    let mut d = Driver::new();
    d.ok(100, pose(90.0, 0.0));
    d.ok(200, Command::Live { on: true });
    // Ticks at 7.5 pulses per second.
    for k in 1..=8u64 {
        d.ok(200 + 134 * k, Command::Tick);
    }
    d.ok(1500, Command::Live { on: false });
    let k = kerma(&d.s);
    assert!(k.len() >= 2, "the step was imaged: {k:?}");
    assert!(k.len() <= 6, "a settled still run stops imaging: {k:?}");
    let last = *k.last().unwrap();
    assert!((last / target - 1.0).abs() <= 0.05, "{k:?}");
}

/// Ticks image live pulses, each stepping the control: their acknowledgements carry the
/// technique as a command's do, so a client's exposure readout follows live fluoroscopy.
#[test]
fn brightness_technique_rides_on_every_tick_of_a_live_run() {
    let mut d = Driver::new();
    d.ok(100, Command::Live { on: true });
    d.ok(200, pose(90.0, 0.0));
    let mut seen = Vec::new();
    for k in 0..8u64 {
        let ack = d.ok(333 + 133 * k, Command::Tick);
        let t = &ack.outcome["technique"];
        let last = images(&d.s).pop().unwrap();
        assert_eq!(t["kvp"], last["kvp"], "tick {k}: {t} vs {last}");
        assert_eq!(t["ma"], last["ma"], "tick {k}");
        assert_eq!(t["detector_kerma_ngy"], last["detector_kerma_ngy"], "tick {k}");
        assert!(t["next_kvp"].is_u64() && t["next_ma"].is_f64(), "{t}");
        seen.push((t["kvp"].as_u64().unwrap(), t["ma"].as_f64().unwrap()));
    }
    // The lateral view's technique differs from the AP one the run started with.
    assert!(seen.windows(2).any(|w| w[0] != w[1]), "{seen:?}");
}
