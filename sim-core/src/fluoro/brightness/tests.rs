use super::*;
use crate::fluoro::{FluoroMaterial, Scene};
use crate::material::MaterialClass;
use crate::mesh::TriMesh;

/// A trunk: soft tissue 340 mm wide (x) and 220 mm deep (y), a bone column (a vertebral body
/// 50 x 50 mm with its posterior elements) along z through it.
fn trunk(width_mm: f64, depth_mm: f64) -> Scene {
    let mut s = Scene::new();
    let (hw, hd) = (0.5 * width_mm, 0.5 * depth_mm);
    s.add(
        "trunk",
        FluoroMaterial::Tissue(MaterialClass::SoftTissue),
        &TriMesh::axis_aligned_box([-hw, -hd, -200.0], [hw, hd, 200.0]),
    );
    s.add(
        "body",
        FluoroMaterial::Tissue(MaterialClass::Cancellous),
        &TriMesh::axis_aligned_box([-25.0, -10.0, -200.0], [25.0, 40.0, 200.0]),
    );
    s.add(
        "arch",
        FluoroMaterial::Tissue(MaterialClass::CorticalBone),
        &TriMesh::axis_aligned_box([-35.0, -45.0, -200.0], [35.0, -30.0, 200.0]),
    );
    s
}

fn view(orbital_deg: f64) -> Projection {
    Projection {
        orbital_deg,
        detector_pixels: [256, 256],
        pixel_pitch_mm: [300.0 / 256.0; 2],
        ..Projection::default()
    }
}

/// A 7.5 pulse-per-second beam (each pulse a 30th of a second of current) on view `p`, the
/// skin `half_thickness_mm` from the isocentre.
fn exposure(p: &Projection, half_thickness_mm: f64) -> FrameExposure {
    FrameExposure {
        frame_s: 1.0 / 30.0,
        duty: 0.25,
        source_to_detector_mm: p.source_to_detector_mm(),
        source_to_skin_mm: p.source_to_isocentre_mm - half_thickness_mm,
    }
}

/// Runs the loop for `frames` frames from `start`; the metered kerma of each frame and the
/// technique of the last.
fn run(
    curve: BrightnessCurve,
    m: &Metering,
    e: &FrameExposure,
    start: Technique,
    frames: usize,
) -> (Vec<f64>, Vec<Step>) {
    let limits = TubeLimits::default();
    let mut t = start;
    let (mut kerma, mut steps) = (Vec::new(), Vec::new());
    for _ in 0..frames {
        let k = m.detector_kerma_ngy(t, e);
        kerma.push(k);
        let step = next_technique(curve, &limits, e, t, k);
        steps.push(step);
        t = step.technique;
    }
    (kerma, steps)
}

fn within_limits(t: Technique, e: &FrameExposure) {
    let l = TubeLimits::default();
    assert!(t.ma <= l.max_ma + 1e-12 && t.ma > 0.0, "{t:?}");
    assert!(
        f64::from(t.kvp) * t.ma * e.duty <= l.max_power_w + 1e-9,
        "{t:?}"
    );
    let rate = skin_kerma_rate_mgy_per_min(t, e);
    assert!(
        rate <= l.max_skin_kerma_rate_mgy_per_min + 1e-9,
        "{t:?}: {rate} mGy/min"
    );
    assert!(Spectrum::tungsten(t.kvp).is_ok(), "{t:?}");
}

#[test]
fn brightness_converges_within_5_percent_in_5_frames_after_a_view_change() {
    let scene = trunk(340.0, 220.0);
    let (ap, lat) = (view(0.0), view(90.0));
    let (e_ap, e_lat) = (exposure(&ap, 110.0), exposure(&lat, 170.0));
    let (m_ap, m_lat) = (meter(&scene, &ap, 12), meter(&scene, &lat, 12));
    assert!(m_ap.depths.len() > 100, "{}", m_ap.depths.len());
    for curve in BrightnessCurve::ALL {
        let target = curve.target_ngy_per_frame();
        // From a manual 80 kVp / 2 mA to AP, then the C-arm swings lateral, then back.
        let (k_ap, s_ap) = run(curve, &m_ap, &e_ap, Technique { kvp: 80, ma: 2.0 }, 8);
        let t_ap = s_ap.last().unwrap().technique;
        let (k_lat, s_lat) = run(curve, &m_lat, &e_lat, t_ap, 8);
        let t_lat = s_lat.last().unwrap().technique;
        let (k_back, s_back) = run(curve, &m_ap, &e_ap, t_lat, 8);
        for (name, k, steps, e) in [
            ("AP", &k_ap, &s_ap, &e_ap),
            ("lateral", &k_lat, &s_lat, &e_lat),
            ("AP again", &k_back, &s_back, &e_ap),
        ] {
            let first = k
                .iter()
                .position(|x| (x / target - 1.0).abs() <= 0.05)
                .unwrap_or_else(|| panic!("{curve:?} {name}: never within 5 %: {k:?}"));
            // Frame 0 is the view change itself (the old technique): frames 1 to 5 follow it.
            assert!(first <= 5, "{curve:?} {name}: frame {first}: {k:?}");
            // And from the fifth frame on it stays there.
            for x in &k[5..] {
                assert!((x / target - 1.0).abs() <= 0.05, "{curve:?} {name}: {k:?}");
            }
            for s in steps.iter() {
                within_limits(s.technique, e);
                assert_eq!(s.limited_by, None, "{curve:?} {name}: {s:?}");
            }
        }
        // The lateral view is driven hotter: a higher voltage or more current, never less.
        assert!(
            t_lat.kvp > t_ap.kvp || t_lat.kvp == t_ap.kvp && t_lat.ma > t_ap.ma,
            "{curve:?}: AP {t_ap:?}, lateral {t_lat:?}"
        );
        assert!(
            skin_kerma_rate_mgy_per_min(t_lat, &e_lat) > skin_kerma_rate_mgy_per_min(t_ap, &e_ap),
            "{curve:?}"
        );
    }
}

#[test]
fn brightness_curves_trade_voltage_for_current() {
    let scene = trunk(340.0, 220.0);
    let ap = view(0.0);
    let e = exposure(&ap, 110.0);
    let m = meter(&scene, &ap, 12);
    let end = |c| {
        run(c, &m, &e, Technique { kvp: 60, ma: 0.5 }, 8)
            .1
            .last()
            .unwrap()
            .technique
    };
    let (std, low, high) = (
        end(BrightnessCurve::Standard),
        end(BrightnessCurve::LowDose),
        end(BrightnessCurve::HighContrast),
    );
    assert!(
        low.kvp > std.kvp && std.kvp > high.kvp,
        "{low:?} {std:?} {high:?}"
    );
    // Low dose: the harder beam and the lower target give the lowest skin rate.
    let rate = |t| skin_kerma_rate_mgy_per_min(t, &e);
    assert!(rate(low) < 0.6 * rate(std), "{} {}", rate(low), rate(std));
    // High contrast: more skin dose for the same detector kerma (a softer beam).
    assert!(rate(high) > rate(std), "{} {}", rate(high), rate(std));
}

#[test]
fn brightness_stops_at_the_skin_rate_limit_on_a_large_patient() {
    // 560 mm of tissue laterally: the target is out of reach within 88 mGy/min.
    let scene = trunk(560.0, 360.0);
    let lat = view(90.0);
    // Continuous beam (duty 1): the skin limit binds before the tube's.
    let e = FrameExposure {
        duty: 1.0,
        ..exposure(&lat, 280.0)
    };
    let m = meter(&scene, &lat, 12);
    let (k, steps) = run(
        BrightnessCurve::Standard,
        &m,
        &e,
        Technique { kvp: 80, ma: 2.0 },
        6,
    );
    let last = steps.last().unwrap();
    assert!(last.limited_by.is_some(), "{last:?}");
    for s in &steps {
        within_limits(s.technique, &e);
    }
    assert!(*k.last().unwrap() < BrightnessCurve::Standard.target_ngy_per_frame());
    // The limit that binds here is the skin rate, at the top voltage or close.
    assert_eq!(last.limited_by, Some(Limit::SkinRate), "{last:?}");
    let rate = skin_kerma_rate_mgy_per_min(last.technique, &e);
    assert!(rate > 80.0 && rate <= 88.0, "{rate}");
}

#[test]
fn brightness_holds_its_technique_without_a_measurement() {
    let p = view(0.0);
    let e = exposure(&p, 110.0);
    let t = Technique { kvp: 85, ma: 1.7 };
    for bad in [f64::NAN, 0.0, -3.0, f64::INFINITY] {
        let s = next_technique(
            BrightnessCurve::Standard,
            &TubeLimits::default(),
            &e,
            t,
            bad,
        );
        assert_eq!(s.technique, t, "{bad}");
    }
    // Shutters closed over the disc: nothing metered, NaN, the technique held.
    let mut closed = p;
    closed.collimation.x_max_mm = -100.0;
    let m = meter(&trunk(340.0, 220.0), &closed, 12);
    assert!(m.depths.is_empty());
    let k = m.detector_kerma_ngy(t, &e);
    assert!(k.is_nan());
    let s = next_technique(BrightnessCurve::Standard, &TubeLimits::default(), &e, t, k);
    assert_eq!(s.technique, t);
}

#[test]
fn brightness_water_equivalent_thickness_round_trips() {
    for kvp in [60, 80, 120] {
        for mm in [0.0, 12.5, 150.0, 400.0] {
            let t = water_transmission(kvp, mm);
            let back = water_equivalent_mm(kvp, t);
            assert!((back - mm).abs() < 1e-6, "{kvp} {mm} {back}");
        }
    }
    assert_eq!(water_equivalent_mm(80, 1.5), 0.0);
    assert_eq!(water_equivalent_mm(80, f64::NAN), 0.0);
    assert_eq!(water_equivalent_mm(80, 0.0), 2000.0);
    assert!(water_equivalent_mm(83, 0.5).is_nan());
    // Between committed voltages, ln T is interpolated: at the committed ones it is exact.
    let exact = water_transmission(85, 200.0);
    assert!((water_transmission_between(85.0, 200.0) - exact).abs() < 1e-15);
    let mid = water_transmission_between(87.5, 200.0);
    assert!(mid > exact && mid < water_transmission(90, 200.0));
}

#[test]
fn brightness_curves_parse_and_are_monotone() {
    for c in BrightnessCurve::ALL {
        assert_eq!(BrightnessCurve::parse(c.name()), Some(c));
        for w in c.knots().windows(2) {
            assert!(w[1].0 >= w[0].0 && w[1].1 >= w[0].1, "{c:?}");
        }
        let (kv, ma) = c.at(1e9);
        assert_eq!((kv, ma), *c.knots().last().unwrap());
    }
    assert_eq!(BrightnessCurve::parse("auto"), None);
}

#[test]
fn brightness_follows_a_raised_target_in_magnification() {
    let scene = trunk(340.0, 220.0);
    let p = view(0.0);
    let e = exposure(&p, 110.0);
    let m = meter(&scene, &p, 12);
    let curve = BrightnessCurve::Standard;
    let target = curve.target_ngy_per_frame() * magnification_target_factor(300.0, 150.0);
    assert_eq!(magnification_target_factor(300.0, 150.0), 2.0);
    assert_eq!(magnification_target_factor(300.0, 0.0), 1.0);
    assert_eq!(magnification_target_factor(300.0, f64::NAN), 1.0);
    let mut t = Technique { kvp: 80, ma: 2.0 };
    let mut k = 0.0;
    for _ in 0..6 {
        k = m.detector_kerma_ngy(t, &e);
        t = next_technique_to(curve, target, &TubeLimits::default(), &e, t, k).technique;
    }
    assert!((k / target - 1.0).abs() <= 0.05, "{k} vs {target}");
    // A target that is no number keeps the technique.
    let held = next_technique_to(curve, f64::NAN, &TubeLimits::default(), &e, t, k);
    assert_eq!(held.technique, t);
}

#[test]
fn brightness_reaches_the_top_voltage_at_the_end_of_the_curve() {
    // A patient the curve cannot light: from 115 kVp the loop must still go to 120 kVp (no
    // hysteresis at the end of the curve) and report the binding limit.
    let scene = trunk(560.0, 360.0);
    let lat = view(90.0);
    let e = exposure(&lat, 280.0);
    let m = meter(&scene, &lat, 12);
    let limits = TubeLimits::default();
    let start = Technique { kvp: 115, ma: 6.0 };
    let k = m.detector_kerma_ngy(start, &e);
    let s = next_technique(BrightnessCurve::Standard, &limits, &e, start, k);
    assert_eq!(s.technique.kvp, 120, "{s:?}");
    assert!(s.limited_by.is_some(), "{s:?}");
    within_limits(s.technique, &e);
}

#[test]
fn brightness_leaves_a_kept_technique_that_the_limits_no_longer_allow() {
    // Settled at 7.5 pulses per second, then the learner picks 30: the detector kerma per pulse
    // is unchanged (inside the deadband), but the duty quadruples; a technique over the tube's
    // power must be left.
    let scene = trunk(340.0, 220.0);
    let lat = view(90.0);
    let e = exposure(&lat, 170.0);
    let m = meter(&scene, &lat, 12);
    let limits = TubeLimits::default();
    let over = Technique { kvp: 120, ma: 6.0 };
    let continuous = FrameExposure { duty: 1.0, ..e };
    assert!(120.0 * 6.0 > limits.max_power_w);
    // A measurement exactly on target: the deadband alone would keep it.
    let target = BrightnessCurve::Standard.target_ngy_per_frame();
    let s = next_technique(
        BrightnessCurve::Standard,
        &limits,
        &continuous,
        over,
        target,
    );
    assert_ne!(s.technique, over, "{s:?}");
    within_limits(s.technique, &continuous);
    // Rounding never lifts a capped current over its cap, nor drops it to zero.
    for ma in [0.004, 0.5, 3.333, 5.999] {
        let t = Technique { kvp: 90, ma };
        let k = m.detector_kerma_ngy(t, &e);
        let s = next_technique(BrightnessCurve::HighContrast, &limits, &continuous, t, k);
        assert!(s.technique.ma >= 0.01, "{s:?}");
        within_limits(s.technique, &continuous);
    }
}

#[test]
fn metering_gives_the_same_depths_on_any_number_of_threads() {
    let scene = trunk(340.0, 220.0);
    for v in [view(0.0), view(35.0), view(90.0)] {
        let one = meter_on(&scene, &v, 12, 1);
        assert!(one.depths.len() > 100, "{}", one.depths.len());
        for threads in [2, 3, 7] {
            let m = meter_on(&scene, &v, 12, threads);
            let bits = |m: &Metering| -> Vec<u64> {
                m.depths.iter().flatten().map(|d| d.to_bits()).collect()
            };
            assert_eq!(bits(&m), bits(&one), "{threads} threads");
            assert_eq!(m.air_gap_mm.to_bits(), one.air_gap_mm.to_bits());
        }
    }
}
