//! Stations, rubrics and the rubric engine: how simulator measurements become a technical result.
//!
//! A [`Station`] is versioned data authored under `assets/stations/` (one TOML file per station):
//! the anatomical region it runs in, its imaging modalities, the instruments on the tray, named
//! targets in the region's model frame, and a [`Rubric`]. A rubric is a list of [`Criterion`]s,
//! each naming the measurement it reads, a weight, a [`Tolerance`] law, and whether it is
//! critical, plus a pass threshold on the weighted score.
//!
//! [`Station::evaluate`] turns a map of measurements into a [`RubricResult`]:
//!
//! * the score is the weighted mean of per-criterion credit over the criteria that **have** a
//!   usable measurement; a missing (or unusable) measurement is reported as incomplete, never
//!   counted as zero credit;
//! * a **measured** critical failure makes the outcome "not met" whatever the aggregate score;
//! * otherwise any missing measurement makes the outcome "incomplete" (the partial score is still
//!   reported), and with every measurement present the outcome is "met" when the score reaches the
//!   pass threshold.
//!
//! The rules are explicit software and faculty configuration, not a published competency scale:
//! a technical "met" states that simulator measurements fell within authored tolerances, and is
//! never a statement of clinical competency (see [`TECHNICAL_RESULT_NOTICE`]). Faculty approval is
//! a separate record kept by the server.
//!
//! ```
//! use std::collections::BTreeMap;
//! use sim_core::rubric::{Outcome, Station};
//!
//! let station = Station::from_toml_str(r#"
//!     id = "demo-station"
//!     revision = 1
//!     title = "Demo"
//!     region = "lumbar-phantom"
//!     modalities = ["fluoroscopy"]
//!     [rubric]
//!     revision = 1
//!     pass_threshold = 0.7
//!     [[rubric.criteria]]
//!     id = "tip"
//!     description = "Needle tip close to the target"
//!     measurement = "tip_to_target_mm"
//!     unit = "mm"
//!     weight = 1.0
//!     tolerance = { law = "lower_is_better", pass_within = 2.0, fail_beyond = 6.0 }
//! "#).unwrap();
//! let mut measured = BTreeMap::new();
//! measured.insert("tip_to_target_mm".to_string(), 4.0);
//! let result = station.evaluate(&measured);
//! // Halfway between full credit (2 mm) and zero credit (6 mm): credit 0.5, below 0.7.
//! assert!((result.score.unwrap() - 0.5).abs() < 1e-12);
//! assert_eq!(result.outcome, Outcome::NotMet);
//! ```

mod engine;
mod range;
mod station;

pub use engine::{
    CriterionResult, CriterionStatus, Measurements, Outcome, RubricResult, SCORE_TIE_EPSILON,
    TECHNICAL_RESULT_NOTICE,
};
pub use range::{
    MAX_ABS_DEG, MAX_ABS_MM, MAX_COUNT, MAX_SECONDS, RangeError, SIGNED_KEYS, check_measurements,
    check_value, is_magnitude_key, unit_of_key,
};
pub use station::{
    Criterion, Instrument, Modality, ModalityNameError, Rubric, Station, StationError, StationFile,
    Target, Tolerance, Unit, Unscorable, load_station_dir,
};
