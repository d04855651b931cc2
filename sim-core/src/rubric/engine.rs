//! The rubric engine: measurements in, a technical result with per-criterion detail out.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::station::{Criterion, Station, Unit};

/// Measurements of one attempt, keyed by measurement key (for example `tip_to_target_mm`).
pub type Measurements = BTreeMap<String, f64>;

/// Shown with every technical result, so that "met" is never read as a clinical judgement.
pub const TECHNICAL_RESULT_NOTICE: &str = "Technical result: simulator measurements compared with \
the station's authored tolerances. \"Met\" is not a certification of clinical competency; faculty \
approval is a separate record.";

/// Slack when comparing the score with the pass threshold. A weighted mean that equals the
/// threshold in exact arithmetic can come out a few ulps low in floating point (e.g. 0.1 + 0.2);
/// 1e-9 is far below any meaningful difference in a rubric score and far above that rounding.
pub const SCORE_TIE_EPSILON: f64 = 1e-9;

/// The overall technical outcome. Deliberately "met"/"not met"/"incomplete": never "competent".
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Every measurement present, no critical failure, score at or above the pass threshold.
    Met,
    /// A measured critical failure, or every measurement present and the score below threshold.
    NotMet,
    /// At least one criterion has no usable measurement and nothing measured is a critical failure.
    Incomplete,
}

impl Outcome {
    /// Wording for people: "met", "not met" or "incomplete".
    pub fn label(self) -> &'static str {
        match self {
            Outcome::Met => "met",
            Outcome::NotMet => "not met",
            Outcome::Incomplete => "incomplete",
        }
    }

    /// Stable machine name, as serialized: "met", "not_met", "incomplete".
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Met => "met",
            Outcome::NotMet => "not_met",
            Outcome::Incomplete => "incomplete",
        }
    }
}

/// What happened to one criterion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CriterionStatus {
    /// Full credit.
    Met,
    /// Some credit, less than full (inside the linear band of the tolerance).
    Partial,
    /// Zero credit.
    NotMet,
    /// No measurement was supplied.
    Missing,
    /// A measurement was supplied but cannot be scored (not finite, outside its physical range
    /// as `range::check_value` states it, or a yes/no value that is neither 1 nor 0). Treated
    /// like a missing one: reported, never counted as zero.
    Invalid,
}

/// Per-criterion detail of a result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CriterionResult {
    /// Criterion id.
    pub id: String,
    /// Criterion description.
    pub description: String,
    /// Measurement key read.
    pub measurement: String,
    /// Unit of the measurement.
    pub unit: Unit,
    /// Weight in the aggregate.
    pub weight: f64,
    /// Whether the criterion is critical.
    pub critical: bool,
    /// The measured value, when one was supplied (also when it was unusable).
    pub value: Option<f64>,
    /// Credit in 0..=1, when the value could be scored.
    pub credit: Option<f64>,
    /// Outcome of this criterion.
    pub status: CriterionStatus,
    /// True for a critical criterion with a measured zero credit.
    pub critical_failure: bool,
    /// Why the measurement could not be scored, for [`CriterionStatus::Invalid`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The technical result of evaluating one attempt's measurements against a station's rubric.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RubricResult {
    /// Station id.
    pub station_id: String,
    /// Station revision used.
    pub station_revision: u32,
    /// Rubric revision used.
    pub rubric_revision: u32,
    /// The overall outcome.
    pub outcome: Outcome,
    /// Weighted mean credit over the criteria with a usable measurement (`None` when there are
    /// none). With missing measurements this is a partial score, not a final one.
    pub score: Option<f64>,
    /// Share of the total weight that was measured, 0..=1.
    pub measured_weight_fraction: f64,
    /// The rubric's pass threshold.
    pub pass_threshold: f64,
    /// Ids of critical criteria that failed on a measured value.
    pub critical_failures: Vec<String>,
    /// Ids of criteria without a usable measurement (missing or invalid).
    pub incomplete_criteria: Vec<String>,
    /// Supplied measurement keys that no criterion reads (often a typo in a key).
    pub unused_measurements: Vec<String>,
    /// Per-criterion detail, in rubric order.
    pub criteria: Vec<CriterionResult>,
    /// See [`TECHNICAL_RESULT_NOTICE`].
    pub notice: String,
}

impl Station {
    /// Evaluate measurements against this station's rubric.
    ///
    /// Precedence of the outcome: a measured critical failure ("not met") beats missing
    /// measurements ("incomplete"), because no further measurement can undo it; missing
    /// measurements beat the threshold test, because a partial score is not a final one.
    pub fn evaluate(&self, measurements: &Measurements) -> RubricResult {
        let rubric = &self.rubric;
        let mut criteria = Vec::with_capacity(rubric.criteria.len());
        let (mut weighted_credit, mut measured_weight, mut total_weight) = (0.0, 0.0, 0.0);
        let mut critical_failures = Vec::new();
        let mut incomplete = Vec::new();
        for c in &rubric.criteria {
            total_weight += c.weight;
            let value = measurements.get(&c.measurement).copied();
            // A physically impossible value is refused before the tolerance sees it.
            let scored = value.map(|v| {
                super::range::check_value(&c.measurement, c.unit, v)
                    .map_err(|e| e.to_string())
                    .and_then(|()| c.tolerance.credit(v).map_err(|e| e.to_string()))
            });
            let (credit, status, note) = match scored {
                None => (None, CriterionStatus::Missing, None),
                Some(Err(why)) => (None, CriterionStatus::Invalid, Some(why)),
                Some(Ok(credit)) => {
                    let status = if credit >= 1.0 {
                        CriterionStatus::Met
                    } else if credit <= 0.0 {
                        CriterionStatus::NotMet
                    } else {
                        CriterionStatus::Partial
                    };
                    (Some(credit), status, None)
                }
            };
            let critical_failure = c.critical && credit.is_some_and(Criterion::is_failure);
            match credit {
                Some(credit) => {
                    weighted_credit += c.weight * credit;
                    measured_weight += c.weight;
                }
                None => incomplete.push(c.id.clone()),
            }
            if critical_failure {
                critical_failures.push(c.id.clone());
            }
            criteria.push(CriterionResult {
                id: c.id.clone(),
                description: c.description.clone(),
                measurement: c.measurement.clone(),
                unit: c.unit,
                weight: c.weight,
                critical: c.critical,
                value,
                credit,
                status,
                critical_failure,
                note,
            });
        }
        let score = (measured_weight > 0.0).then(|| weighted_credit / measured_weight);
        let outcome = if !critical_failures.is_empty() {
            Outcome::NotMet
        } else if !incomplete.is_empty() {
            Outcome::Incomplete
        } else if score.is_some_and(|s| s + SCORE_TIE_EPSILON >= rubric.pass_threshold) {
            Outcome::Met
        } else {
            Outcome::NotMet
        };
        let unused_measurements = measurements
            .keys()
            .filter(|k| !rubric.criteria.iter().any(|c| &c.measurement == *k))
            .cloned()
            .collect();
        RubricResult {
            station_id: self.id.clone(),
            station_revision: self.revision,
            rubric_revision: rubric.revision,
            outcome,
            score,
            measured_weight_fraction: if total_weight > 0.0 {
                measured_weight / total_weight
            } else {
                0.0
            },
            pass_threshold: rubric.pass_threshold,
            critical_failures,
            incomplete_criteria: incomplete,
            unused_measurements,
            criteria,
            notice: TECHNICAL_RESULT_NOTICE.to_string(),
        }
    }
}
