//! Magnification modes: a smaller central detector field over the same pixels, the anatomy shown
//! larger, the kerma-area product following the field, the brightness control aiming higher;
//! checked, logged and replayed.

use render_worker::session::*;
use serde_json::{Value, json};
use sim_core::fluoro::Projection;

use super::support::{Driver, config, env, fluoro_only};

fn magnification(field_mm: f64) -> Command {
    serde_json::from_value(json!({ "type": "magnification", "field_mm": field_mm })).unwrap()
}

fn last_image(d: &Driver) -> Value {
    d.s.snapshot().modalities["fluoroscopy"]["images"]
        .as_array()
        .unwrap()
        .last()
        .unwrap()
        .clone()
}

#[test]
fn magnification_shows_the_centre_larger_with_a_smaller_field() {
    let mut d = Driver::new();
    d.ok(50, Command::Technique { kvp: 80, ma: 2.0 });
    d.ok(100, Command::Shot);
    let normal: Projection = serde_json::from_value(last_image(&d)["projection"].clone()).unwrap();
    let k0 = d.s.measurements();
    let ack = d.ok(200, magnification(150.0));
    assert_eq!(ack.outcome["field_mm"], 150.0);
    d.ok(300, Command::Shot);
    let k1 = d.s.measurements();
    let mag: Projection = serde_json::from_value(last_image(&d)["projection"].clone()).unwrap();
    // Half the field over the same pixels: half the pitch, a point off the centre twice as far
    // from the image centre.
    assert_eq!(mag.detector_pixels, normal.detector_pixels);
    assert!((mag.pixel_pitch_mm[0] * 2.0 - normal.pixel_pitch_mm[0]).abs() < 1e-12);
    let iso = normal.effective_isocentre_mm();
    let off = [iso[0] + 20.0, iso[1], iso[2] + 10.0];
    let c = f64::from(normal.detector_pixels[0]) / 2.0;
    let (a, b) = (normal.project_point(off).unwrap(), mag.project_point(off).unwrap());
    for axis in 0..2 {
        assert!(((b[axis] - c) - 2.0 * (a[axis] - c)).abs() < 1e-9, "{a:?} {b:?}");
    }
    // The same technique (set by hand): the same skin kerma, a quarter of the field's KAP.
    let kap = |m: &sim_core::rubric::Measurements, n: &sim_core::rubric::Measurements| {
        m["kerma_area_product_gycm2"] - n.get("kerma_area_product_gycm2").copied().unwrap_or(0.0)
    };
    let kerma = |m: &sim_core::rubric::Measurements, n: &sim_core::rubric::Measurements| {
        m["air_kerma_mgy"] - n.get("air_kerma_mgy").copied().unwrap_or(0.0)
    };
    let empty = sim_core::rubric::Measurements::new();
    let (kap_normal, kap_mag) = (kap(&k0, &empty), kap(&k1, &k0));
    assert!((kap_mag / kap_normal - 0.25).abs() < 1e-12, "{kap_mag} / {kap_normal}");
    assert!((kerma(&k1, &k0) / kerma(&k0, &empty) - 1.0).abs() < 1e-12);
    // Back to the full field.
    d.ok(400, magnification(300.0));
    d.ok(500, Command::Shot);
    let back: Projection = serde_json::from_value(last_image(&d)["projection"].clone()).unwrap();
    assert_eq!(back, normal);
    assert!(d.s.snapshot().modalities["fluoroscopy"].get("field_mm").is_none());
}

#[test]
fn magnification_raises_the_brightness_target_by_the_field_ratio() {
    let target = sim_core::fluoro::brightness::BrightnessCurve::Standard.target_ngy_per_frame();
    let mut d = Driver::new();
    d.ok(100, magnification(150.0));
    for k in 0..6 {
        d.ok(200 + 100 * k, Command::Shot);
    }
    let kerma = last_image(&d)["detector_kerma_ngy"].as_f64().unwrap();
    assert!((kerma / (2.0 * target) - 1.0).abs() <= 0.05, "{kerma} vs {}", 2.0 * target);
    // The shutters clip to the active field: blades wider than it change nothing.
    d.ok(
        800,
        serde_json::from_value(json!({ "type": "collimation", "width_mm": 300.0, "height_mm": 200.0 }))
            .unwrap(),
    );
    d.ok(900, Command::Shot);
    let p: Projection = serde_json::from_value(last_image(&d)["projection"].clone()).unwrap();
    assert_eq!((p.collimation.x_min_mm, p.collimation.x_max_mm), (-75.0, 75.0));
    assert_eq!((p.collimation.y_min_mm, p.collimation.y_max_mm), (-75.0, 75.0));
}

#[test]
fn magnification_refuses_other_fields_and_replays() {
    let mut d = Driver::new();
    d.ok(100, Command::Shot);
    let before = d.s.snapshot().to_bytes();
    for bad in [json!(151.0), json!(0.0), json!(-150.0), json!(1e300)] {
        let c: Command =
            serde_json::from_value(json!({ "type": "magnification", "field_mm": bad })).unwrap();
        let e = d.err(c);
        assert_eq!(e.field, "command.field_mm", "{bad}: {e}");
        assert!(e.message.contains("300, 225, 150"), "{e}");
    }
    let e = d.err(serde_json::from_value(json!({ "type": "magnification" })).unwrap());
    assert!(e.message.contains("field_mm"), "{e}");
    assert_eq!(d.s.snapshot().to_bytes(), before);
    d.ok(200, Command::Live { on: true });
    d.ok(500, magnification(225.0));
    d.ok(800, Command::Live { on: false });
    d.ok(900, Command::Shot);
    let initial = Session::new(env(), config()).snapshot();
    let mut replayed = Session::restore(env(), &initial, d.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), d.s.snapshot().to_bytes());
    let a = d.s.render_dirty(&fluoro_only()).unwrap();
    let b = replayed.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(a[0].image.pixels, b[0].image.pixels);
}
