//! Scatter in a session: the anti-scatter grid in (the default) or out, recorded with each
//! image's air gap, fogging the image and steering the brightness control, checked, logged and
//! replayed.

use render_worker::session::*;
use serde_json::{Value, json};

use super::support::{Driver, env, fluoro_only, pose};

fn grid(value: Value) -> Command {
    serde_json::from_value(json!({ "type": "grid", "grid": value })).unwrap()
}

fn images(s: &Session) -> Vec<Value> {
    s.snapshot().modalities["fluoroscopy"]["images"]
        .as_array()
        .unwrap()
        .clone()
}

/// `n` shots 100 ms apart from `t0`; the last frame.
fn settle(d: &mut Driver, t0: u64, n: u64) -> Vec<u8> {
    for k in 0..n {
        d.ok(t0 + 100 * k, Command::Shot);
    }
    d.s.render_dirty(&fluoro_only())
        .unwrap()
        .pop()
        .unwrap()
        .image
        .pixels
}

/// The grey spread of the image's middle: the 90th minus the 10th percentile of the central
/// quarter (the spine against the soft tissue beside it).
fn spread(pixels: &[u8]) -> f64 {
    let n = (pixels.len() as f64).sqrt() as usize;
    let mut v: Vec<u8> = (n * 3 / 8..n * 5 / 8)
        .flat_map(|j| (n / 4..n * 3 / 4).map(move |i| (i, j)))
        .map(|(i, j)| pixels[j * n + i])
        .collect();
    v.sort_unstable();
    f64::from(v[v.len() * 9 / 10]) - f64::from(v[v.len() / 10])
}

#[test]
fn scatter_grid_out_fogs_the_image_and_lowers_the_current() {
    let mut d = Driver::new();
    let with = settle(&mut d, 100, 4);
    let ack = d.ok(600, Command::Shot);
    assert_eq!(ack.outcome["grid"], "in");
    let gap = ack.outcome["air_gap_mm"].as_f64().unwrap();
    // The C-arm's detector is 750 mm from the isocentre; the patient's anterior skin lies
    // 100 to 300 mm in front of the spine on the default phantom.
    assert!((400.0..750.0).contains(&gap), "air gap {gap} mm");
    let ma_in = ack.outcome["technique"]["next_ma"].as_f64().unwrap();
    let kvp_in = ack.outcome["technique"]["next_kvp"].as_u64().unwrap();
    let ack = d.ok(700, grid(json!("out")));
    assert_eq!(ack.outcome["grid"], "out");
    let without = settle(&mut d, 800, 5);
    let ack = d.ok(1400, Command::Shot);
    let ma_out = ack.outcome["technique"]["next_ma"].as_f64().unwrap();
    let kvp_out = ack.outcome["technique"]["next_kvp"].as_u64().unwrap();
    // Without the grid's 0.73 on the primary the same detector kerma takes less tube output.
    assert!(
        kvp_out < kvp_in || (kvp_out == kvp_in && ma_out < 0.9 * ma_in),
        "grid in {kvp_in} kVp {ma_in} mA, out {kvp_out} kVp {ma_out} mA"
    );
    // The fog compresses the anatomy's grey range.
    let (a, b) = (spread(&with), spread(&without));
    assert!(b < a, "grey spread with the grid {a}, without {b}");
    let imgs = images(&d.s);
    assert_eq!(imgs[0]["scatter"]["grid"], true);
    assert_eq!(imgs.last().unwrap()["scatter"]["grid"], false);
    // Putting it back restores the technique the control chose before.
    d.ok(1500, grid(json!("in")));
    settle(&mut d, 1600, 5);
    let ack = d.ok(2200, Command::Shot);
    let ma_back = ack.outcome["technique"]["next_ma"].as_f64().unwrap();
    assert_eq!(
        ack.outcome["technique"]["next_kvp"].as_u64().unwrap(),
        kvp_in
    );
    assert!((ma_back / ma_in - 1.0).abs() < 0.05, "{ma_back} vs {ma_in}");
}

#[test]
fn scatter_grid_command_refuses_other_values_and_changes_nothing() {
    let mut d = Driver::new();
    d.ok(100, Command::Shot);
    let before = d.s.snapshot().to_bytes();
    for bad in [
        json!("maybe"),
        json!(true),
        json!(null),
        json!(""),
        json!("IN "),
    ] {
        let e = d.err(grid(bad.clone()));
        assert!(e.to_string().contains("grid"), "{bad}: {e}");
    }
    let e =
        d.err(serde_json::from_value(json!({ "type": "grid", "grid": "in", "extra": 1 })).unwrap());
    assert!(e.to_string().contains("extra"), "{e}");
    assert_eq!(
        d.s.snapshot().to_bytes(),
        before,
        "a refused command changes nothing"
    );
}

#[test]
fn scatter_and_grid_changes_replay_bit_identically() {
    let mut d = Driver::new();
    d.ok(100, Command::Shot);
    d.ok(200, pose(90.0, 0.0));
    d.ok(300, Command::Shot);
    d.ok(400, grid(json!("out")));
    d.ok(500, Command::Live { on: true });
    d.ok(900, grid(json!("in")));
    d.ok(1200, Command::Live { on: false });
    let shown = d.s.render_dirty(&fluoro_only()).unwrap().pop().unwrap();
    let initial = Session::new(env(), super::support::config()).snapshot();
    let mut replayed = Session::restore(env(), &initial, d.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), d.s.snapshot().to_bytes());
    let again = replayed
        .render_dirty(&fluoro_only())
        .unwrap()
        .pop()
        .unwrap();
    assert_eq!(again.image.pixels, shown.image.pixels);
    // The lateral view's air gap differs from the AP's, and every image records its own.
    let gaps: Vec<f64> = images(&d.s)
        .iter()
        .map(|i| i["scatter"]["air_gap_mm"].as_f64().unwrap())
        .collect();
    assert!(gaps.iter().all(|g| g.is_finite() && *g > 0.0), "{gaps:?}");
    assert_ne!(gaps[0], gaps[1], "{gaps:?}");
}
