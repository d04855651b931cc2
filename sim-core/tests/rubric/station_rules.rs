//! Station rules at their edges: tolerance bounds (equal bounds are a step law, a hair inverted is
//! refused), instrument lengths, modality names, target lookup and the file a parse error names
//! (`sim_core::rubric::station`; cargo-mutants found each of these unchecked).

use sim_core::rubric::{Modality, Station, StationError, load_station_dir};

use super::{crit, station_toml};

/// The problems of a station whose one criterion has tolerance `tol` (TOML inline table).
fn problems_with(tol: &str) -> Vec<String> {
    let text = station_toml(0.5, &crit("a", 1.0, false, "a_mm", "mm", tol));
    match Station::from_toml_str(&text) {
        Ok(s) => s.problems(),
        Err(StationError::Invalid { problems, .. }) => problems,
        Err(e) => panic!("{tol}: {e}"),
    }
}

#[test]
fn equal_bounds_are_a_step_and_inverted_bounds_are_refused() {
    // Equal bounds: a step law, valid (the `Tolerance` docs).
    for tol in [
        r#"{ law = "lower_is_better", pass_within = 2.0, fail_beyond = 2.0 }"#,
        r#"{ law = "near_value", value = 10.0, pass_within = 3.0, fail_beyond = 3.0 }"#,
        r#"{ law = "near_value", value = 10.0, pass_within = 0.0, fail_beyond = 0.0 }"#,
        r#"{ law = "higher_is_better", pass_from = 5.0, fail_below = 5.0 }"#,
    ] {
        assert_eq!(problems_with(tol), Vec::<String>::new(), "{tol}");
    }
    // A hair past equal: refused, naming the rule.
    for (tol, rule) in [
        (
            r#"{ law = "lower_is_better", pass_within = 2.000001, fail_beyond = 2.0 }"#,
            "pass_within (2.000001) exceeds fail_beyond (2)",
        ),
        (
            r#"{ law = "near_value", value = 10.0, pass_within = 3.000001, fail_beyond = 3.0 }"#,
            "pass_within (3.000001) exceeds fail_beyond (3)",
        ),
        (
            r#"{ law = "near_value", value = 10.0, pass_within = -0.000001, fail_beyond = 3.0 }"#,
            "pass_within (-0.000001) is negative",
        ),
        (
            r#"{ law = "higher_is_better", pass_from = 5.0, fail_below = 5.000001 }"#,
            "fail_below (5.000001) exceeds pass_from (5)",
        ),
    ] {
        let p = problems_with(tol);
        assert!(p.iter().any(|m| m.contains(rule)), "{tol}: {p:?}");
    }
}

#[test]
fn a_needle_must_have_a_positive_finite_length() {
    let base = station_toml(0.5, &super::dist("a", 1.0, false));
    let with = |len: &str| {
        base.replace(
            "[[targets]]",
            &format!(
                "[[instruments]]\nid = \"n\"\nkind = \"spinal-needle\"\nlength_mm = {len}\n\n[[targets]]"
            ),
        )
    };
    assert!(Station::from_toml_str(&with("0.001")).is_ok());
    for len in ["0.0", "-1.0", "inf", "nan"] {
        let e = Station::from_toml_str(&with(len))
            .expect_err(len)
            .to_string();
        assert!(
            e.contains("length_mm") && e.contains("must be positive"),
            "{len}: {e}"
        );
    }
}

#[test]
fn a_modality_reads_as_its_name_everywhere() {
    let m = Modality::new("fluoroscopy").unwrap();
    assert_eq!(m.as_str(), "fluoroscopy");
    assert_eq!(m.to_string(), "fluoroscopy");
    assert_eq!(String::from(m.clone()), "fluoroscopy");
    assert!(m == *"fluoroscopy");
    assert!(m != *"ultrasound");
}

#[test]
fn targets_are_found_by_name_only() {
    let s = Station::from_toml_str(&station_toml(0.5, &super::dist("a", 1.0, false))).unwrap();
    assert_eq!(s.target("t").map(|t| t.position_mm), Some([1.0, 2.0, 3.0]));
    assert!(s.target("T").is_none() && s.target("").is_none());
}

#[test]
fn a_parse_error_names_its_file_and_a_string_error_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("broken.toml");
    std::fs::write(&path, "id = ").unwrap();
    let e = load_station_dir(dir.path()).unwrap_err().to_string();
    assert!(
        e.starts_with(&format!("cannot parse station {}: ", path.display())),
        "{e}"
    );
    let e = Station::from_toml_str("id = ").unwrap_err().to_string();
    assert!(e.starts_with("cannot parse station: "), "{e}");
}

/// A station names the habitus of the lumbar phantom (its region asset becomes the variant's)
/// and the C-arm's receptor; a habitus on another region, or an unknown habitus or receptor,
/// is refused naming the field.
#[test]
fn habitus_and_detector_select_the_body_and_the_receptor() {
    use sim_core::anatomy::phantom::habitus::Habitus;
    use sim_core::fluoro::receptor::ReceptorKind;
    let base = station_toml(
        0.5,
        &crit(
            "a",
            1.0,
            false,
            "a_mm",
            "mm",
            r#"{ law = "lower_is_better", pass_within = 1.0, fail_beyond = 2.0 }"#,
        ),
    );
    let with = |line: &str| base.replacen("modalities = [", &format!("{line}\nmodalities = ["), 1);
    let plain = Station::from_toml_str(&base).expect("valid");
    assert_eq!((plain.habitus, plain.detector), (None, None));
    assert_eq!(plain.region_asset(), "lumbar-phantom");
    let obese = Station::from_toml_str(&with(
        "habitus = \"obese\"\ndetector = \"image_intensifier\"",
    ))
    .expect("valid");
    assert_eq!(obese.habitus, Some(Habitus::Obese));
    assert_eq!(obese.detector, Some(ReceptorKind::ImageIntensifier));
    assert_eq!(obese.region_asset(), "lumbar-phantom-obese");
    let average = Station::from_toml_str(&with("habitus = \"average\"")).expect("valid");
    assert_eq!(average.region_asset(), "lumbar-phantom");
    // Another region: refused.
    let cervical = with("habitus = \"slim\"").replace(
        "region = \"lumbar-phantom\"",
        "region = \"cervical-phantom\"",
    );
    match Station::from_toml_str(&cervical) {
        Err(StationError::Invalid { problems, .. }) => {
            assert!(
                problems.iter().any(|p| p.contains("habitus")),
                "{problems:?}"
            );
        }
        other => panic!("{other:?}"),
    }
    // Unknown names: parse errors naming the field.
    for (line, field) in [
        ("habitus = \"huge\"", "habitus"),
        ("detector = \"ccd\"", "detector"),
    ] {
        let e = Station::from_toml_str(&with(line)).expect_err(line);
        assert!(e.to_string().contains(field), "{line}: {e}");
    }
}
