//! The learner's collimator: blades and iris in the detector plane, shown on the image as the
//! shutter grey, lowering the kerma-area product with the field area, checked, logged and
//! replayed.

use render_worker::session::*;
use serde_json::{Value, json};
use sim_core::fluoro::render::SHUTTER_GREY;

use super::support::{Driver, config, env, fluoro_only};

fn collimation(v: Value) -> Command {
    let mut v = v;
    v["type"] = json!("collimation");
    serde_json::from_value(v).unwrap()
}

/// A shot with a technique set by hand (so that both shots expose alike); its kerma and KAP
/// increments and the rendered frame.
fn shot(d: &mut Driver, t: u64) -> (f64, f64, Vec<u8>, u32) {
    let before = d.s.measurements();
    d.ok(t, Command::Shot);
    let after = d.s.measurements();
    let frames = d.s.render_dirty(&fluoro_only()).unwrap();
    let f = frames.last().unwrap();
    (
        after["air_kerma_mgy"] - before.get("air_kerma_mgy").copied().unwrap_or(0.0),
        after["kerma_area_product_gycm2"]
            - before
                .get("kerma_area_product_gycm2")
                .copied()
                .unwrap_or(0.0),
        f.image.pixels.clone(),
        f.image.width,
    )
}

#[test]
fn collimation_narrows_the_field_the_image_and_the_kerma_area_product() {
    let mut d = Driver::new();
    d.ok(50, Command::Technique { kvp: 80, ma: 2.0 });
    let (k_open, kap_open, open, w) = shot(&mut d, 100);
    // Half the width and half the height: a quarter of the field.
    let ack = d.ok(
        200,
        collimation(json!({ "width_mm": 150.0, "height_mm": 150.0 })),
    );
    assert_eq!(ack.outcome["collimation"]["width_mm"], 150.0);
    let (k, kap, img, _) = shot(&mut d, 300);
    assert!((k / k_open - 1.0).abs() < 1e-12, "skin kerma unchanged: {k} {k_open}");
    assert!((kap / kap_open - 0.25).abs() < 1e-12, "{kap} / {kap_open}");
    // Outside the blades (the outer quarter of each side) the shutter grey, inside the image.
    let n = w as usize;
    let at = |img: &[u8], i: usize, j: usize| img[j * n + i];
    for (i, j) in [(2, n / 2), (n - 3, n / 2), (n / 2, 2), (n / 2, n - 3), (5, 5)] {
        assert_eq!(at(&img, i, j), SHUTTER_GREY, "({i}, {j}) behind a blade");
        assert_ne!(at(&open, i, j), SHUTTER_GREY, "({i}, {j}) open before");
    }
    let inside = (n * 3 / 8..n * 5 / 8)
        .flat_map(|j| (n * 3 / 8..n * 5 / 8).map(move |i| (i, j)))
        .filter(|&(i, j)| at(&img, i, j) != SHUTTER_GREY)
        .count();
    assert!(inside > (n / 4) * (n / 4) * 9 / 10, "{inside}");
    // An iris of the blades' width: the corners of the square go dark too, and the field is
    // the disc inscribed in the square (pi / 4 of the square).
    d.ok(
        400,
        collimation(json!({ "width_mm": 150.0, "height_mm": 150.0, "iris_diameter_mm": 150.0 })),
    );
    let (_, kap_iris, img, _) = shot(&mut d, 500);
    let quarter = std::f64::consts::FRAC_PI_4;
    assert!((kap_iris / kap - quarter).abs() < 1e-9, "{}", kap_iris / kap);
    // The square spans the middle half (pixels n / 4 to 3 n / 4): its corner pixel lies about
    // 101 mm from the centre, outside the 75 mm iris.
    let corner = n / 4 + 1;
    assert_eq!(at(&img, corner, corner), SHUTTER_GREY);
    assert_ne!(at(&img, n / 2, n / 2), SHUTTER_GREY);
}

#[test]
fn collimation_refuses_what_no_collimator_can_do_and_changes_nothing() {
    let mut d = Driver::new();
    d.ok(100, Command::Shot);
    let before = d.s.snapshot().to_bytes();
    for (v, field) in [
        (json!({ "width_mm": 0.0, "height_mm": 100.0 }), "command.width_mm"),
        (json!({ "width_mm": 100.0, "height_mm": 900.0 }), "command.height_mm"),
        (json!({ "width_mm": -5.0, "height_mm": 100.0 }), "command.width_mm"),
        (
            json!({ "width_mm": 100.0, "height_mm": 100.0, "iris_diameter_mm": 1.0 }),
            "command.iris_diameter_mm",
        ),
        (
            json!({ "width_mm": 100.0, "height_mm": 100.0, "iris_diameter_mm": 1e9 }),
            "command.iris_diameter_mm",
        ),
    ] {
        let e = d.err(collimation(v.clone()));
        assert_eq!(e.field, field, "{v}: {e}");
        assert!(e.message.contains("mm"), "{e}");
    }
    // Unknown or missing fields are refused by the parser.
    let e = d.err(collimation(json!({ "width_mm": 100.0 })));
    assert!(e.message.contains("height_mm"), "{e}");
    let e = d.err(collimation(
        json!({ "width_mm": 100.0, "height_mm": 100.0, "shape": "star" }),
    ));
    assert!(e.message.contains("shape"), "{e}");
    assert_eq!(d.s.snapshot().to_bytes(), before);
}

#[test]
fn collimation_while_live_is_imaged_and_replays_bit_identically() {
    let mut d = Driver::new();
    d.ok(100, Command::Live { on: true });
    let images = |d: &Driver| {
        d.s.snapshot().modalities["fluoroscopy"]["images"]
            .as_array()
            .unwrap()
            .len()
    };
    let n0 = images(&d);
    d.ok(
        400,
        collimation(json!({ "width_mm": 120.0, "height_mm": 200.0, "iris_diameter_mm": 220.0 })),
    );
    assert_eq!(images(&d), n0 + 1, "a live change of field is imaged by its pulse");
    d.ok(900, Command::Live { on: false });
    d.ok(1000, Command::Shot);
    let initial = Session::new(env(), config()).snapshot();
    let mut replayed = Session::restore(env(), &initial, d.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), d.s.snapshot().to_bytes());
    assert_eq!(replayed.measurements(), d.s.measurements());
    let a = d.s.render_dirty(&fluoro_only()).unwrap();
    let b = replayed.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(a[0].image.pixels, b[0].image.pixels);
}
