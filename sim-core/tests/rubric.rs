//! Rubric engine: tolerance laws, weights, incomplete measurements, critical override, thresholds,
//! serialization, station validation, and every authored station under `assets/stations/`.

use std::collections::BTreeMap;
use std::path::PathBuf;

use sim_core::rubric::{
    CriterionStatus, Measurements, Outcome, Station, StationError, Tolerance, load_station_dir,
};

/// Exact-arithmetic expectations computed by hand; 1e-12 only absorbs floating-point rounding of
/// a handful of multiplications and one division on numbers of order 1.
const CREDIT_EPS: f64 = 1e-12;

mod ranges;
mod station_rules;

fn stations_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/stations")
}

/// A valid station whose rubric consists of the given `[[rubric.criteria]]` TOML blocks.
fn station_toml(pass_threshold: f64, criteria: &str) -> String {
    format!(
        r#"
id = "test-station"
revision = 3
title = "Test station"
region = "lumbar-phantom"
modalities = ["fluoroscopy"]
[[targets]]
name = "t"
position_mm = [1.0, 2.0, 3.0]
[rubric]
revision = 7
pass_threshold = {pass_threshold}
{criteria}
"#
    )
}

/// One criterion block.
fn crit(id: &str, weight: f64, critical: bool, measurement: &str, unit: &str, tol: &str) -> String {
    format!(
        r#"
[[rubric.criteria]]
id = "{id}"
description = "criterion {id}"
measurement = "{measurement}"
unit = "{unit}"
weight = {weight}
critical = {critical}
tolerance = {tol}
"#
    )
}

/// Shorthand for a distance criterion: full credit at <= 2 mm, zero at >= 6 mm.
fn dist(id: &str, weight: f64, critical: bool) -> String {
    crit(
        id,
        weight,
        critical,
        &format!("{id}_mm"),
        "mm",
        r#"{ law = "lower_is_better", pass_within = 2.0, fail_beyond = 6.0 }"#,
    )
}

fn measure(pairs: &[(&str, f64)]) -> Measurements {
    pairs.iter().map(|(k, v)| (k.to_string(), *v)).collect()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= CREDIT_EPS
}

#[test]
fn tolerance_laws_give_documented_credit() {
    let lower = Tolerance::LowerIsBetter {
        pass_within: 2.0,
        fail_beyond: 6.0,
    };
    let near = Tolerance::NearValue {
        value: 50.0,
        pass_within: 5.0,
        fail_beyond: 15.0,
    };
    let higher = Tolerance::HigherIsBetter {
        pass_from: 0.8,
        fail_below: 0.4,
    };
    let step = Tolerance::LowerIsBetter {
        pass_within: 0.0,
        fail_beyond: 0.0,
    };
    let yes = Tolerance::Boolean { expected: true };
    let no = Tolerance::Boolean { expected: false };
    // (law, value, expected credit; None = unusable measurement)
    let table: &[(&Tolerance, f64, Option<f64>)] = &[
        (&lower, -1.0, Some(1.0)),
        (&lower, 2.0, Some(1.0)), // on the bound: the better side
        (&lower, 3.0, Some(0.75)),
        (&lower, 4.0, Some(0.5)),
        (&lower, 5.5, Some(0.125)),
        (&lower, 6.0, Some(0.0)),
        (&lower, 100.0, Some(0.0)),
        (&near, 50.0, Some(1.0)),
        (&near, 45.0, Some(1.0)),
        (&near, 40.0, Some(0.5)), // deviation 10: halfway through the 5..15 band
        (&near, 60.0, Some(0.5)), // symmetric
        (&near, 65.0, Some(0.0)),
        (&near, 20.0, Some(0.0)),
        (&higher, 0.9, Some(1.0)),
        (&higher, 0.8, Some(1.0)),
        (&higher, 0.6, Some(0.5)),
        (&higher, 0.4, Some(0.0)),
        (&higher, 0.1, Some(0.0)),
        (&step, 0.0, Some(1.0)),
        (&step, 1e-9, Some(0.0)),
        (&yes, 1.0, Some(1.0)),
        (&yes, 0.0, Some(0.0)),
        (&no, 0.0, Some(1.0)),
        (&no, 1.0, Some(0.0)),
        (&yes, 0.5, None),
        (&no, 2.0, None),
        (&lower, f64::NAN, None),
        (&lower, f64::INFINITY, None),
        (&higher, f64::NEG_INFINITY, None),
    ];
    for (i, (law, value, want)) in table.iter().enumerate() {
        let got = law.credit(*value);
        match (want, &got) {
            (Some(w), Ok(g)) => assert!(close(*w, *g), "row {i}: {law:?} at {value}: {g} != {w}"),
            (None, Err(_)) => {}
            _ => panic!("row {i}: {law:?} at {value}: got {got:?}, want {want:?}"),
        }
    }
}

#[test]
fn weights_scale_each_criterion_in_the_aggregate() {
    // Three distance criteria with credits 1, 0.5 and 0 (at 2, 4 and 6 mm).
    // (weights, expected score = sum(w * credit) / sum(w))
    let table: &[([f64; 3], f64)] = &[
        ([1.0, 1.0, 1.0], 0.5),
        ([2.0, 1.0, 1.0], 2.5 / 4.0),
        ([1.0, 2.0, 1.0], 2.0 / 4.0),
        ([1.0, 1.0, 2.0], 1.5 / 4.0),
        ([3.0, 0.5, 0.5], 3.25 / 4.0),
        ([0.1, 0.1, 10.0], 0.15 / 10.2),
    ];
    let m = measure(&[("a_mm", 2.0), ("b_mm", 4.0), ("c_mm", 6.0)]);
    for (w, want) in table {
        let s = Station::from_toml_str(&station_toml(
            0.5,
            &[
                dist("a", w[0], false),
                dist("b", w[1], false),
                dist("c", w[2], false),
            ]
            .concat(),
        ))
        .unwrap();
        let r = s.evaluate(&m);
        assert!(
            close(r.score.unwrap(), *want),
            "weights {w:?}: {:?} != {want}",
            r.score
        );
        assert_eq!(r.measured_weight_fraction, 1.0);
        let statuses: Vec<_> = r.criteria.iter().map(|c| c.status).collect();
        assert_eq!(
            statuses,
            [
                CriterionStatus::Met,
                CriterionStatus::Partial,
                CriterionStatus::NotMet
            ]
        );
    }
}

#[test]
fn missing_or_unusable_measurements_make_the_result_incomplete_not_zero() {
    let s = Station::from_toml_str(&station_toml(
        0.5,
        &[
            dist("a", 1.0, false),
            dist("b", 3.0, false),
            crit(
                "v",
                1.0,
                false,
                "v_bool",
                "bool",
                r#"{ law = "boolean", expected = true }"#,
            ),
        ]
        .concat(),
    ))
    .unwrap();
    // (measurements, expected partial score, measured weight fraction, incomplete ids)
    let table: &[(Measurements, Option<f64>, f64, &[&str])] = &[
        // b missing: score over a and v only, NOT (1 + 0 + 1) / 5.
        (
            measure(&[("a_mm", 2.0), ("v_bool", 1.0)]),
            Some(1.0),
            2.0 / 5.0,
            &["b"],
        ),
        (measure(&[("b_mm", 4.0)]), Some(0.5), 3.0 / 5.0, &["a", "v"]),
        (measure(&[]), None, 0.0, &["a", "b", "v"]),
        // A NaN distance and a yes/no value of 0.5 are unusable: reported, not scored as zero.
        (
            measure(&[("a_mm", f64::NAN), ("b_mm", 2.0), ("v_bool", 0.5)]),
            Some(1.0),
            0.6,
            &["a", "v"],
        ),
    ];
    for (i, (m, score, fraction, ids)) in table.iter().enumerate() {
        let r = s.evaluate(m);
        assert_eq!(r.outcome, Outcome::Incomplete, "row {i}");
        assert_eq!(r.score.is_some(), score.is_some(), "row {i}");
        if let (Some(got), Some(want)) = (r.score, score) {
            assert!(close(got, *want), "row {i}: score {got} != {want}");
        }
        assert!(close(r.measured_weight_fraction, *fraction), "row {i}");
        assert_eq!(r.incomplete_criteria, *ids, "row {i}");
        for c in &r.criteria {
            let incomplete = ids.contains(&c.id.as_str());
            assert_eq!(c.credit.is_none(), incomplete, "row {i} criterion {}", c.id);
            if incomplete {
                assert!(matches!(
                    c.status,
                    CriterionStatus::Missing | CriterionStatus::Invalid
                ));
            }
        }
    }
    // The unusable value is kept (so a reviewer sees what arrived) with a reason.
    let r = s.evaluate(&measure(&[("v_bool", 0.5)]));
    let v = r.criteria.iter().find(|c| c.id == "v").unwrap();
    assert_eq!((v.status, v.value), (CriterionStatus::Invalid, Some(0.5)));
    assert!(v.note.as_deref().unwrap().contains("1 or 0"));
}

#[test]
fn measured_critical_failure_overrides_the_aggregate() {
    let s = Station::from_toml_str(&station_toml(
        0.5,
        &[
            dist("big", 100.0, false),
            dist("safety", 1.0, true),
            crit(
                "leak",
                1.0,
                true,
                "leak_bool",
                "bool",
                r#"{ law = "boolean", expected = false }"#,
            ),
            dist("other", 1.0, false),
        ]
        .concat(),
    ))
    .unwrap();
    // (measurements, outcome, critical failures)
    let table: &[(Measurements, Outcome, &[&str])] = &[
        // Score about 0.98, but the critical distance earns zero credit.
        (
            measure(&[
                ("big_mm", 0.0),
                ("safety_mm", 6.0),
                ("leak_bool", 0.0),
                ("other_mm", 0.0),
            ]),
            Outcome::NotMet,
            &["safety"],
        ),
        // Critical yes/no observation is the wrong one.
        (
            measure(&[
                ("big_mm", 0.0),
                ("safety_mm", 0.0),
                ("leak_bool", 1.0),
                ("other_mm", 0.0),
            ]),
            Outcome::NotMet,
            &["leak"],
        ),
        // Partial credit on a critical criterion is scored, not a failure.
        (
            measure(&[
                ("big_mm", 0.0),
                ("safety_mm", 5.0),
                ("leak_bool", 0.0),
                ("other_mm", 0.0),
            ]),
            Outcome::Met,
            &[],
        ),
        // Zero credit on a non-critical criterion does not override.
        (
            measure(&[
                ("big_mm", 0.0),
                ("safety_mm", 0.0),
                ("leak_bool", 0.0),
                ("other_mm", 9.0),
            ]),
            Outcome::Met,
            &[],
        ),
        // A measured critical failure wins over missing measurements: nothing can undo it.
        (measure(&[("leak_bool", 1.0)]), Outcome::NotMet, &["leak"]),
        // A MISSING critical measurement is incomplete, never a failure.
        (
            measure(&[("big_mm", 0.0), ("leak_bool", 0.0), ("other_mm", 0.0)]),
            Outcome::Incomplete,
            &[],
        ),
        // An unusable critical measurement is incomplete too.
        (
            measure(&[
                ("big_mm", 0.0),
                ("safety_mm", 0.0),
                ("leak_bool", 0.3),
                ("other_mm", 0.0),
            ]),
            Outcome::Incomplete,
            &[],
        ),
    ];
    for (i, (m, outcome, failures)) in table.iter().enumerate() {
        let r = s.evaluate(m);
        assert_eq!(r.outcome, *outcome, "row {i}: {r:#?}");
        assert_eq!(r.critical_failures, *failures, "row {i}");
        for c in &r.criteria {
            assert_eq!(
                c.critical_failure,
                failures.contains(&c.id.as_str()),
                "row {i} {}",
                c.id
            );
        }
    }
    // The override does not hide the aggregate: the first row still reports its high score.
    let r = s.evaluate(&table[0].0);
    assert!(r.score.unwrap() > 0.97);
}

#[test]
fn pass_threshold_decides_complete_results() {
    // Two equal-weight criteria; the second measured at `v` mm gives credit (6 - v) / 4.
    // (threshold, measurement of b, outcome)
    let table: &[(f64, f64, Outcome)] = &[
        (0.75, 4.0, Outcome::Met),       // score 0.75 exactly
        (0.75, 4.0001, Outcome::NotMet), // 0.7499875
        (0.75, 3.0, Outcome::Met),
        (0.5, 6.0, Outcome::Met), // score 0.5 exactly
        (0.51, 6.0, Outcome::NotMet),
        (1.0, 2.0, Outcome::Met), // threshold 1 needs full credit everywhere
        (1.0, 2.01, Outcome::NotMet),
        (0.01, 100.0, Outcome::Met),
    ];
    for (threshold, b, outcome) in table {
        let s = Station::from_toml_str(&station_toml(
            *threshold,
            &[dist("a", 1.0, false), dist("b", 1.0, false)].concat(),
        ))
        .unwrap();
        let r = s.evaluate(&measure(&[("a_mm", 2.0), ("b_mm", *b)]));
        assert_eq!(
            r.outcome, *outcome,
            "threshold {threshold}, b {b}: score {:?}",
            r.score
        );
        assert_eq!(r.pass_threshold, *threshold);
    }
    // A score that equals the threshold in exact arithmetic but not in floating point:
    // weights 0.1 and 0.2, credits 1 and 0 give 0.1 / (0.1 + 0.2) = 1/3 with rounding error.
    let s = Station::from_toml_str(&station_toml(
        1.0 / 3.0,
        &[dist("a", 0.1, false), dist("b", 0.2, false)].concat(),
    ))
    .unwrap();
    let r = s.evaluate(&measure(&[("a_mm", 0.0), ("b_mm", 6.0)]));
    assert_eq!(r.outcome, Outcome::Met, "score {:?}", r.score);
}

#[test]
fn results_carry_revisions_detail_and_unused_keys_and_serialize() {
    let s = Station::from_toml_str(&station_toml(0.9, &dist("a", 1.0, true))).unwrap();
    let r = s.evaluate(&measure(&[("a_mm", 6.5), ("a_typo_mm", 1.0)]));
    assert_eq!(
        (r.station_id.as_str(), r.station_revision, r.rubric_revision),
        ("test-station", 3, 7)
    );
    assert_eq!(r.unused_measurements, ["a_typo_mm"]);
    let json = serde_json::to_value(&r).unwrap();
    assert_eq!(json["outcome"], "not_met");
    assert_eq!(json["criteria"][0]["status"], "not_met");
    assert_eq!(json["criteria"][0]["value"], 6.5);
    assert_eq!(json["criteria"][0]["unit"], "mm");
    assert_eq!(json["criteria"][0]["critical_failure"], true);
    let text = json.to_string().to_lowercase();
    assert!(text.contains("not a certification of clinical competency"));
    assert!(
        !text.replace("clinical competency", "").contains("competen"),
        "{text}"
    );
    let back: sim_core::rubric::RubricResult = serde_json::from_value(json).unwrap();
    assert_eq!(back, r);
    assert_eq!(Outcome::NotMet.label(), "not met");
    assert_eq!(Outcome::Incomplete.as_str(), "incomplete");
}

#[test]
fn invalid_stations_are_rejected_with_the_rule_they_break() {
    let ok_crit = dist("a", 1.0, false);
    // (station TOML, fragment expected in the error message)
    let table: Vec<(String, &str)> = vec![
        (
            station_toml(0.5, &dist("a", 0.0, false)),
            "weight 0 must be positive",
        ),
        (
            station_toml(0.5, &dist("a", -2.0, false)),
            "weight -2 must be positive",
        ),
        (
            station_toml(
                0.5,
                &[dist("a", 1.0, false), dist("a", 2.0, false)].concat(),
            ),
            "not unique",
        ),
        (
            station_toml(0.0, &ok_crit),
            "pass_threshold 0 must lie in (0, 1]",
        ),
        (station_toml(1.5, &ok_crit), "pass_threshold 1.5"),
        (station_toml(0.5, "criteria = []"), "no criteria"),
        (station_toml(0.5, ""), "missing field `criteria`"),
        (
            station_toml(0.5, &ok_crit).replace("revision = 3", "revision = 0"),
            "station revision",
        ),
        (
            station_toml(0.5, &ok_crit).replace("revision = 7", "revision = 0"),
            "rubric revision",
        ),
        (
            station_toml(0.5, &ok_crit).replace("revision = 3\n", ""),
            "missing field `revision`",
        ),
        (
            station_toml(0.5, &ok_crit).replace("title", "titel"),
            "unknown field `titel`",
        ),
        (
            station_toml(0.5, &ok_crit)
                .replace("modalities = [\"fluoroscopy\"]", "modalities = []"),
            "modality",
        ),
        (
            station_toml(0.5, &ok_crit).replace("\"fluoroscopy\"", "\"X-ray\""),
            "modality \"X-ray\" must be lower-case snake case",
        ),
        (
            station_toml(0.5, &ok_crit).replace("test-station", "Test Station"),
            "station id",
        ),
        (
            station_toml(0.5, &ok_crit).replace(
                "pass_within = 2.0, fail_beyond = 6.0",
                "pass_within = 6.0, fail_beyond = 2.0",
            ),
            "exceeds fail_beyond",
        ),
        (
            station_toml(
                0.5,
                &crit(
                    "a",
                    1.0,
                    false,
                    "a_deg",
                    "mm",
                    r#"{ law = "lower_is_better", pass_within = 1.0, fail_beyond = 2.0 }"#,
                ),
            ),
            "must end in \"_mm\"",
        ),
        (
            station_toml(
                0.5,
                &crit(
                    "a",
                    1.0,
                    false,
                    "a_mm",
                    "mm",
                    r#"{ law = "boolean", expected = true }"#,
                ),
            ),
            "boolean law",
        ),
        (
            station_toml(
                0.5,
                &crit(
                    "a",
                    1.0,
                    false,
                    "a_deg",
                    "deg",
                    r#"{ law = "near_value", value = 1.0, pass_within = -1.0, fail_beyond = 2.0 }"#,
                ),
            ),
            "negative",
        ),
        (
            station_toml(
                0.5,
                &crit(
                    "a",
                    1.0,
                    false,
                    "a_mm",
                    "mm",
                    r#"{ law = "lower_is_better", pass_within = 1.0 }"#,
                ),
            ),
            "missing field `fail_beyond`",
        ),
        (
            station_toml(
                0.5,
                &crit(
                    "a",
                    1.0,
                    false,
                    "a_mm",
                    "mm",
                    r#"{ law = "lower_is_better", pass_within = 1.0, fail_beyond = 2.0, extra = 1 }"#,
                ),
            ),
            "unknown field `extra`",
        ),
        (
            station_toml(0.5, &format!("{ok_crit}target = \"nowhere\"\n")),
            "not one of the station's targets",
        ),
        (
            station_toml(0.5, &ok_crit).replace(
                "position_mm = [1.0, 2.0, 3.0]",
                "position_mm = [1.0, 2.0, 3.0]\n[[targets]]\nname = \"t\"\nposition_mm = [0.0, 0.0, 0.0]",
            ),
            "target name \"t\" is not unique",
        ),
    ];
    // The unmodified template must be valid, or every row would pass for the wrong reason.
    Station::from_toml_str(&station_toml(0.5, &ok_crit)).unwrap();
    for (i, (text, fragment)) in table.iter().enumerate() {
        let err = Station::from_toml_str(text).expect_err(&format!("row {i} should be rejected"));
        let msg = err.to_string();
        assert!(
            msg.contains(fragment),
            "row {i}: {msg:?} lacks {fragment:?}"
        );
        let is_parse = matches!(err, StationError::Parse { .. });
        assert_eq!(
            is_parse,
            fragment.contains("field")
                || fragment.contains("variant")
                || fragment.contains("snake case"),
            "row {i}"
        );
    }
}

/// A measurement earning full credit (`best`) or zero credit (`worst`) under a law.
fn extreme(t: &Tolerance, best: bool) -> f64 {
    match *t {
        Tolerance::LowerIsBetter {
            pass_within,
            fail_beyond,
        } => {
            if best {
                pass_within
            } else {
                fail_beyond
            }
        }
        Tolerance::NearValue {
            value, fail_beyond, ..
        } => {
            if best {
                value
            } else {
                value + fail_beyond
            }
        }
        Tolerance::HigherIsBetter {
            pass_from,
            fail_below,
        } => {
            if best {
                pass_from
            } else {
                fail_below
            }
        }
        Tolerance::Boolean { expected } => f64::from(u8::from(expected == best)),
    }
}

#[test]
fn every_station_file_loads_and_validates() {
    let files = load_station_dir(&stations_dir()).unwrap();
    let ids: Vec<&str> = files.iter().map(|f| f.station.id.as_str()).collect();
    for required in [
        "l4-l5-interlaminar-epidural",
        "l4-left-transforaminal",
        "l4-l5-left-facet",
        "l4-l5-left-facet-ultrasound",
    ] {
        assert!(ids.contains(&required), "{required} missing from {ids:?}");
    }
    for f in &files {
        let s = &f.station;
        assert!(s.revision >= 1 && s.rubric.revision >= 1, "{}", s.id);
        assert!(s.rubric.criteria.iter().all(|c| c.weight > 0.0), "{}", s.id);
        let mut crit_ids: Vec<_> = s.rubric.criteria.iter().map(|c| &c.id).collect();
        crit_ids.sort();
        crit_ids.dedup();
        assert_eq!(
            crit_ids.len(),
            s.rubric.criteria.len(),
            "{}: duplicate criterion id",
            s.id
        );
        assert!(
            !s.modalities.is_empty() && !s.targets.is_empty(),
            "{}",
            s.id
        );
        assert!(
            s.rubric.criteria.iter().any(|c| c.critical),
            "{}: no safety criterion",
            s.id
        );
        // Every station can be met (full credit everywhere) and a full-marks attempt is not
        // mistaken for incomplete, and zero credit everywhere is not met.
        let best: BTreeMap<String, f64> = s
            .rubric
            .criteria
            .iter()
            .map(|c| (c.measurement.clone(), extreme(&c.tolerance, true)))
            .collect();
        let r = s.evaluate(&best);
        assert_eq!((r.outcome, r.score), (Outcome::Met, Some(1.0)), "{}", s.id);
        assert!(r.unused_measurements.is_empty());
        let worst: BTreeMap<String, f64> = s
            .rubric
            .criteria
            .iter()
            .map(|c| (c.measurement.clone(), extreme(&c.tolerance, false)))
            .collect();
        let r = s.evaluate(&worst);
        assert_eq!(
            (r.outcome, r.score),
            (Outcome::NotMet, Some(0.0)),
            "{}",
            s.id
        );
        // Frame convention (assets/stations/README.md): RAS, so left-sided targets lie at x < 0
        // and every target here is posterior to the L4 body centre (y < 0).
        for t in &s.targets {
            assert!(
                t.position_mm[1] < 0.0,
                "{}: {} is not posterior",
                s.id,
                t.name
            );
            if s.id.contains("left") && t.name.starts_with("left") {
                assert!(
                    t.position_mm[0] < 0.0,
                    "{}: {} is not on the left (RAS)",
                    s.id,
                    t.name
                );
            }
        }
        // The same file parses identically through the string entry point.
        assert_eq!(&Station::from_toml_str(&f.text).unwrap(), s);
    }
}

#[test]
fn station_directory_rules_file_name_and_unique_ids() {
    let one = std::fs::read_to_string(stations_dir().join("l4-l5-left-facet.toml")).unwrap();
    // (files to write, expected error fragment)
    let table: &[(&[(&str, &str)], &str)] = &[
        (&[("wrong-name.toml", &one)], "differs from station id"),
        (
            &[("l4-l5-left-facet.toml", "id = ")],
            "cannot parse station",
        ),
        (
            &[(
                "l4-l5-left-facet.toml",
                &one.replace("weight = 1.5", "weight = 0.0"),
            )],
            "weight 0",
        ),
    ];
    for (i, (files, fragment)) in table.iter().enumerate() {
        let dir = tempfile::tempdir().unwrap();
        for (name, text) in *files {
            std::fs::write(dir.path().join(name), text).unwrap();
        }
        let err = load_station_dir(dir.path()).expect_err(&format!("row {i}"));
        assert!(err.to_string().contains(fragment), "row {i}: {err}");
    }
    // And the same file under its own name loads.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("l4-l5-left-facet.toml"), &one).unwrap();
    assert_eq!(load_station_dir(dir.path()).unwrap().len(), 1);
}

#[test]
fn a_target_may_name_a_landmark_with_a_valid_name() {
    let base = station_toml(0.5, &dist("d", 1.0, false));
    let with = |landmark: &str| {
        base.replace(
            "position_mm = [1.0, 2.0, 3.0]",
            &format!("position_mm = [1.0, 2.0, 3.0]\nlandmark = {landmark:?}"),
        )
    };
    let ok = Station::from_toml_str(&with("L4_L5_posterior_epidural_space")).unwrap();
    assert_eq!(
        ok.targets[0].landmark.as_deref(),
        Some("L4_L5_posterior_epidural_space")
    );
    for bad in ["", "no spaces", "dash-ed", &"x".repeat(65)] {
        let e = Station::from_toml_str(&with(bad)).unwrap_err();
        assert!(e.to_string().contains("landmark"), "{bad:?}: {e}");
    }
}
