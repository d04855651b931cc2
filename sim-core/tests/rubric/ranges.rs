//! Measurement ranges: physically impossible values are refused, never scored, and every unit's
//! range holds at its edges (`sim_core::rubric::range`).

use sim_core::rubric::{CriterionStatus, Outcome, Station};

use super::{crit, measure, station_toml};

/// Physically impossible values are refused by the engine itself, never scored: a negative
/// distance (or -1e308) must not earn the credit of a perfect placement, whatever the tolerance.
#[test]
fn impossible_measurements_are_refused_not_scored() {
    let s = Station::from_toml_str(&station_toml(
        0.5,
        &[
            crit(
                "d",
                1.0,
                true,
                "tip_to_target_mm",
                "mm",
                r#"{ law = "lower_is_better", pass_within = 2.0, fail_beyond = 5.0 }"#,
            ),
            crit(
                "m",
                1.0,
                false,
                "tip_medial_to_pedicle_mm",
                "mm",
                r#"{ law = "lower_is_better", pass_within = 0.0, fail_beyond = 3.0 }"#,
            ),
            crit(
                "a",
                1.0,
                false,
                "beam_to_joint_plane_deg",
                "deg",
                r#"{ law = "lower_is_better", pass_within = 5.0, fail_beyond = 15.0 }"#,
            ),
            crit(
                "n",
                1.0,
                false,
                "fluoro_acquisitions_count",
                "count",
                r#"{ law = "lower_is_better", pass_within = 10.0, fail_beyond = 20.0 }"#,
            ),
            crit(
                "f",
                1.0,
                false,
                "needle_in_plane_fraction",
                "fraction",
                r#"{ law = "higher_is_better", pass_from = 0.8, fail_below = 0.2 }"#,
            ),
            crit(
                "t",
                1.0,
                false,
                "fluoro_exposure_s",
                "s",
                r#"{ law = "lower_is_better", pass_within = 30.0, fail_beyond = 60.0 }"#,
            ),
        ]
        .concat(),
    ))
    .unwrap();
    let good = [
        ("tip_to_target_mm", 1.0),
        ("tip_medial_to_pedicle_mm", -2.0), // signed: lateral of the pedicle
        ("beam_to_joint_plane_deg", 3.0),
        ("fluoro_acquisitions_count", 4.0),
        ("needle_in_plane_fraction", 0.9),
        ("fluoro_exposure_s", 12.5),
    ];
    let r = s.evaluate(&measure(&good));
    assert_eq!(r.outcome, Outcome::Met, "{r:?}");
    assert!(sim_core::rubric::check_measurements(&measure(&good)).is_ok());
    for (key, bad) in [
        ("tip_to_target_mm", -1e308),
        ("tip_to_target_mm", -0.001),
        ("tip_to_target_mm", 1e308),
        ("tip_to_target_mm", f64::NAN),
        ("tip_medial_to_pedicle_mm", -1e308),
        ("beam_to_joint_plane_deg", -3.0),
        ("beam_to_joint_plane_deg", 181.0),
        ("fluoro_acquisitions_count", -1.0),
        ("fluoro_acquisitions_count", 2.5),
        ("needle_in_plane_fraction", 1.5),
        ("fluoro_exposure_s", -1.0),
        ("fluoro_exposure_s", f64::INFINITY),
    ] {
        let mut m = measure(&good);
        m.insert(key.into(), bad);
        let r = s.evaluate(&m);
        let c = r.criteria.iter().find(|c| c.measurement == key).unwrap();
        assert_eq!(c.status, CriterionStatus::Invalid, "{key} = {bad}");
        assert_eq!(c.credit, None, "{key} = {bad}");
        assert_ne!(r.outcome, Outcome::Met, "{key} = {bad}");
        assert!(r.incomplete_criteria.contains(&c.id), "{key} = {bad}");
        let e = sim_core::rubric::check_measurements(&m).unwrap_err();
        assert!(e.to_string().contains(key), "{e}");
    }
    // Keys no criterion reads are checked by their suffix as well.
    let mut m = measure(&good);
    m.insert("needle_depth_mm".into(), 5000.0);
    assert!(
        sim_core::rubric::check_measurements(&m)
            .unwrap_err()
            .to_string()
            .contains("needle_depth_mm")
    );
    // The error says which rule the value breaks: not a number at all, or outside the range.
    use sim_core::rubric::{RangeError, Unit, check_value};
    assert_eq!(
        check_value("tip_to_target_mm", Unit::Mm, f64::INFINITY),
        Err(RangeError::NonFinite {
            key: "tip_to_target_mm".into(),
            value: f64::INFINITY
        })
    );
    assert_eq!(
        check_value("tip_to_target_mm", Unit::Mm, -0.5),
        Err(RangeError::OutOfRange {
            key: "tip_to_target_mm".into(),
            value: -0.5,
            range: "0 to 1000 mm"
        })
    );
    assert_eq!(
        check_value("tip_to_target_mm", Unit::Mm, -0.5)
            .unwrap_err()
            .to_string(),
        "tip_to_target_mm: -0.5 is outside the physical range 0 to 1000 mm"
    );
}

/// Every unit's range at its edges, for keys whether a criterion reads them or not (found by
/// cargo-mutants: the yes/no, dose and signed-angle ranges, the edges of the signed ones, and
/// non-finite values of keys without a unit were never checked). Each edge value is accepted and
/// the next representable step beyond it refused.
#[test]
fn every_unit_s_range_holds_at_its_edges() {
    use sim_core::rubric::check_measurements;
    let check = |key: &str, value: f64| check_measurements(&measure(&[(key, value)]));
    let beyond = |v: f64| if v > 0.0 { v.next_up() } else { v.next_down() };
    for (key, edges) in [
        // Signed millimetres and degrees (no `_to_` in the key): both signs up to the bound.
        ("needle_depth_mm", &[-1000.0, 1000.0][..]),
        ("ap_endplate_tilt_deg", &[-180.0, 180.0][..]),
        // Magnitudes (`_to_`): 0 up to the bound.
        ("tip_to_target_mm", &[0.0, 1000.0][..]),
        ("beam_to_joint_plane_deg", &[0.0, 180.0][..]),
        ("fluoro_exposure_s", &[0.0, 86_400.0][..]),
        ("needle_in_plane_fraction", &[0.0, 1.0][..]),
        ("fluoro_acquisitions_count", &[0.0, 1e6][..]),
        ("air_kerma_mgy", &[0.0, 1e5][..]),
        ("kerma_area_product_gycm2", &[0.0, 1e4][..]),
    ] {
        for &edge in edges {
            assert!(check(key, edge).is_ok(), "{key} = {edge}");
            let out = if edge == 0.0 { -1e-9 } else { beyond(edge) };
            let e = check(key, out).unwrap_err();
            assert!(e.to_string().contains(key), "{key} = {out}: {e}");
        }
    }
    // Yes or no: exactly 1 or 0.
    for ok in [0.0, 1.0] {
        assert!(check("bone_contact_bool", ok).is_ok());
    }
    for bad in [0.5, -1.0, 2.0] {
        assert!(check("bone_contact_bool", bad).is_err(), "{bad}");
    }
    // A key without a unit suffix takes any finite value, and no NaN or infinity.
    assert!(check("pattern", 12345.0).is_ok());
    assert!(check("pattern", -3.5).is_ok());
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        assert!(check("pattern", bad).is_err(), "{bad}");
    }
}
