//! Cohort analytics for a course's faculty, per station: pass rate per criterion, each
//! learner's attempts in order (score, dose, fluoroscopy time) against the cohort's band, and
//! a competency judgement on the last three scored attempts in which a failed safety
//! (critical) criterion cannot be offset by a good score elsewhere. JSON for the dashboard, CSV
//! for a spreadsheet.
//!
//! Every figure comes from each attempt's latest technical result (the server's scoring of the
//! session), so the dashboard and the attempt's own page never disagree.

use std::collections::BTreeMap;

use axum::extract::State;
use axum::http::header::{CONTENT_DISPOSITION, CONTENT_TYPE};
use axum::response::IntoResponse;
use serde::{Deserialize, Serialize};
use serde_json::Value;
use time::OffsetDateTime;
use utoipa::{IntoParams, ToSchema};
use uuid::Uuid;

use super::auth::CurrentUser;
use super::extract::{ApiPath, ApiQuery};
use super::modes::course_access;
use super::reviews::csv_field;
use super::state::RecordsState;
use crate::error::ApiError;

/// Scored attempts the competency judgement reads (the most recent ones). Simulator choice:
/// three consecutive acceptable attempts, the window of the consecutive-successes rules common
/// in procedural skills assessment; faculty judge what the figures cannot.
pub const COMPETENCY_WINDOW: usize = 3;

/// Which attempts the dashboard covers.
#[derive(Debug, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct CohortFilter {
    /// The station (required: criteria differ between stations).
    #[param(pattern = "^[^\\u0000]*$")]
    pub station_id: String,
    /// Only this learner.
    pub learner_id: Option<Uuid>,
    /// Only attempts run in this mode (`practice` or `assessment`).
    pub mode: Option<super::modes::StationMode>,
}

/// One criterion across the cohort.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct CriterionRate {
    /// Criterion id.
    pub id: String,
    /// What it checks.
    pub description: String,
    /// A safety criterion: its failure fails the attempt whatever the score.
    pub critical: bool,
    /// Scored attempts in which it was measured and met.
    pub met: u32,
    /// ... measured and not met.
    pub not_met: u32,
    /// ... not measured (the learner never did what it measures).
    pub missing: u32,
    /// `met / (met + not_met)`, absent when never measured.
    pub pass_rate: Option<f64>,
}

/// One attempt on a learner's curve.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct CurvePoint {
    /// Attempt id.
    pub attempt_id: Uuid,
    /// 1 for the learner's first attempt at the station, and so on (scored or not).
    pub n: u32,
    /// Opened.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub created_at: OffsetDateTime,
    /// The attempt's state.
    pub state: String,
    /// `practice` or `assessment`.
    pub mode: String,
    /// Weighted score of its latest result (absent: not scored yet).
    pub score: Option<f64>,
    /// `met`, `not_met` or `incomplete` (absent: not scored yet).
    pub outcome: Option<String>,
    /// Reference air kerma, mGy.
    pub air_kerma_mgy: Option<f64>,
    /// Kerma-area product, Gy cm^2.
    pub kerma_area_product_gycm2: Option<f64>,
    /// Fluoroscopy time, s.
    pub fluoro_time_s: Option<f64>,
    /// Safety (critical) criteria it failed.
    pub critical_failures: Vec<String>,
    /// Each criterion's status in its latest result (`met`, `not_met`, `missing`).
    pub criteria: BTreeMap<String, String>,
}

/// The competency judgement of one learner.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct Competency {
    /// `competent`, `not_yet` or `too_few_attempts`.
    pub status: String,
    /// Why, in words.
    pub reason: String,
    /// The attempts judged (the last [`COMPETENCY_WINDOW`] scored ones).
    pub judged: Vec<Uuid>,
}

/// One learner of the cohort.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct LearnerCurve {
    /// User id.
    pub learner_id: Uuid,
    /// E-mail.
    pub email: String,
    /// Name.
    pub name: String,
    /// Attempts, oldest first.
    pub attempts: Vec<CurvePoint>,
    /// Judgement on the last scored attempts.
    pub competency: Competency,
}

/// The cohort's scores at one attempt number: the reference band of the learning curves.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct BandPoint {
    /// Attempt number (1 = first scored attempt of each learner).
    pub n: u32,
    /// Learners with a scored attempt of that number.
    pub learners: u32,
    /// Lower quartile of their scores.
    pub p25: f64,
    /// Median.
    pub median: f64,
    /// Upper quartile.
    pub p75: f64,
}

/// A course's cohort at one station.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema, PartialEq)]
pub struct Cohort {
    /// Course id.
    pub course_id: Uuid,
    /// Station id.
    pub station_id: String,
    /// Station title.
    pub station_title: String,
    /// Score a result needs to be met (besides every critical criterion).
    pub pass_threshold: f64,
    /// Attempts counted (scored or not).
    pub attempts: u32,
    /// Attempts with a result.
    pub scored_attempts: u32,
    /// Per criterion, in the rubric's order.
    pub criteria: Vec<CriterionRate>,
    /// Per learner, by e-mail.
    pub learners: Vec<LearnerCurve>,
    /// Quartiles of the whole cohort's scores by scored-attempt number (the reference band:
    /// the learner filter does not narrow it; the mode filter does).
    pub band: Vec<BandPoint>,
    /// "Met" is a technical statement; competency is a faculty judgement the figures inform.
    pub notice: String,
}

/// One attempt with its latest result, as the query reads it.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct AttemptRow {
    /// Attempt.
    pub id: Uuid,
    /// Learner.
    pub learner_id: Uuid,
    /// Learner e-mail.
    pub email: String,
    /// Learner name.
    pub display_name: String,
    /// State.
    pub state: String,
    /// Mode.
    pub mode: String,
    /// Opened.
    pub created_at: OffsetDateTime,
    /// Latest result's outcome.
    pub outcome: Option<String>,
    /// ... score.
    pub score: Option<f64>,
    /// ... measurements.
    pub measurements: Option<Value>,
    /// ... detail (criteria with their status).
    pub detail: Option<Value>,
}

/// The p-quantile of sorted values by linear interpolation between order statistics (the
/// "type 7" definition of Hyndman and Fan 1996, R's and NumPy's default).
fn quantile(sorted: &[f64], p: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * p;
    let lo = h.floor() as usize;
    let hi = h.ceil() as usize;
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

fn judge(points: &[CurvePoint]) -> Competency {
    let scored: Vec<&CurvePoint> = points.iter().filter(|p| p.outcome.is_some()).collect();
    let last = &scored[scored.len().saturating_sub(COMPETENCY_WINDOW)..];
    let judged = last.iter().map(|p| p.attempt_id).collect();
    if last.len() < COMPETENCY_WINDOW {
        return Competency {
            status: "too_few_attempts".into(),
            reason: format!(
                "{} scored attempt(s); the judgement needs the last {COMPETENCY_WINDOW}",
                last.len()
            ),
            judged,
        };
    }
    if let Some(p) = last.iter().find(|p| !p.critical_failures.is_empty()) {
        return Competency {
            status: "not_yet".into(),
            reason: format!(
                "attempt {} failed the safety criterion {}: no score elsewhere offsets it",
                p.n,
                p.critical_failures.join(", ")
            ),
            judged,
        };
    }
    if let Some(p) = last.iter().find(|p| p.outcome.as_deref() != Some("met")) {
        return Competency {
            status: "not_yet".into(),
            reason: format!(
                "attempt {} was {}",
                p.n,
                p.outcome.as_deref().unwrap_or("not scored")
            ),
            judged,
        };
    }
    Competency {
        status: "competent".into(),
        reason: format!(
            "the last {COMPETENCY_WINDOW} scored attempts met every criterion set, safety ones included"
        ),
        judged,
    }
}

fn number(v: &Option<Value>, key: &str) -> Option<f64> {
    v.as_ref().and_then(|m| m.get(key)).and_then(Value::as_f64)
}

/// The cohort from its attempts (ordered by learner, then opening time).
pub fn analyse(
    course_id: Uuid,
    station: &sim_core::rubric::Station,
    rows: &[AttemptRow],
) -> Cohort {
    let mut criteria: Vec<CriterionRate> = station
        .rubric
        .criteria
        .iter()
        .map(|c| CriterionRate {
            id: c.id.clone(),
            description: c.description.clone(),
            critical: c.critical,
            met: 0,
            not_met: 0,
            missing: 0,
            pass_rate: None,
        })
        .collect();
    let mut by_learner: BTreeMap<Uuid, LearnerCurve> = BTreeMap::new();
    let mut scored_attempts = 0;
    for r in rows {
        let statuses: Vec<(String, String, bool)> = r
            .detail
            .as_ref()
            .and_then(|d| d.get("criteria"))
            .and_then(Value::as_array)
            .map(|cs| {
                cs.iter()
                    .map(|c| {
                        (
                            c["id"].as_str().unwrap_or_default().to_string(),
                            c["status"].as_str().unwrap_or_default().to_string(),
                            c["critical_failure"].as_bool().unwrap_or(false),
                        )
                    })
                    .collect()
            })
            .unwrap_or_default();
        if r.outcome.is_some() {
            scored_attempts += 1;
            for c in &mut criteria {
                match statuses.iter().find(|s| s.0 == c.id).map(|s| s.1.as_str()) {
                    Some("met") => c.met += 1,
                    Some("not_met") => c.not_met += 1,
                    _ => c.missing += 1,
                }
            }
        }
        let learner = by_learner
            .entry(r.learner_id)
            .or_insert_with(|| LearnerCurve {
                learner_id: r.learner_id,
                email: r.email.clone(),
                name: r.display_name.clone(),
                attempts: Vec::new(),
                competency: judge(&[]),
            });
        learner.attempts.push(CurvePoint {
            attempt_id: r.id,
            n: learner.attempts.len() as u32 + 1,
            created_at: r.created_at,
            state: r.state.clone(),
            mode: r.mode.clone(),
            score: r.score,
            outcome: r.outcome.clone(),
            air_kerma_mgy: number(&r.measurements, "air_kerma_mgy"),
            kerma_area_product_gycm2: number(&r.measurements, "kerma_area_product_gycm2"),
            fluoro_time_s: number(&r.measurements, "fluoro_time_s"),
            critical_failures: statuses
                .iter()
                .filter(|s| s.2)
                .map(|s| s.0.clone())
                .collect(),
            criteria: statuses
                .iter()
                .map(|s| (s.0.clone(), s.1.clone()))
                .collect(),
        });
    }
    for c in &mut criteria {
        let measured = c.met + c.not_met;
        c.pass_rate = (measured > 0).then(|| f64::from(c.met) / f64::from(measured));
    }
    let mut learners: Vec<LearnerCurve> = by_learner.into_values().collect();
    for l in &mut learners {
        l.competency = judge(&l.attempts);
    }
    learners.sort_by(|a, b| a.email.cmp(&b.email));
    // Scores by scored-attempt number across learners.
    let mut at: BTreeMap<u32, Vec<f64>> = BTreeMap::new();
    for l in &learners {
        for (k, s) in l.attempts.iter().filter_map(|p| p.score).enumerate() {
            at.entry(k as u32 + 1).or_default().push(s);
        }
    }
    let band = at
        .into_iter()
        .map(|(n, mut s)| {
            s.sort_by(f64::total_cmp);
            BandPoint {
                n,
                learners: s.len() as u32,
                p25: quantile(&s, 0.25),
                median: quantile(&s, 0.5),
                p75: quantile(&s, 0.75),
            }
        })
        .collect();
    Cohort {
        course_id,
        station_id: station.id.clone(),
        station_title: station.title.clone(),
        pass_threshold: station.rubric.pass_threshold,
        attempts: rows.len() as u32,
        scored_attempts,
        criteria,
        learners,
        band,
        notice: "Technical results: simulator measurements against the station's tolerances. \
            \"Competent\" here means three scored attempts in a row met every criterion set; \
            competency itself is a faculty judgement these figures inform."
            .into(),
    }
}

async fn cohort_of(
    state: &RecordsState,
    user: &CurrentUser,
    course_id: Uuid,
    f: &CohortFilter,
) -> Result<Cohort, ApiError> {
    if !course_access(state, user, course_id).await? {
        return Err(ApiError::Forbidden(
            "the cohort dashboard is for the course's faculty (or an admin)".into(),
        ));
    }
    let station = state
        .stations
        .get(&f.station_id)
        .ok_or_else(|| ApiError::NotFound(format!("station {:?}", f.station_id)))?;
    let rows: Vec<AttemptRow> = sqlx::query_as(
        "SELECT a.id, a.learner_id, u.email, u.display_name, a.state, a.mode, a.created_at,
                r.outcome, r.score, r.measurements, r.detail
         FROM attempts a JOIN users u ON u.id = a.learner_id
         LEFT JOIN LATERAL (SELECT outcome, score, measurements, detail FROM technical_results t
                            WHERE t.attempt_id = a.id ORDER BY t.seq DESC LIMIT 1) r ON true
         WHERE a.course_id = $1 AND a.station_id = $2 AND ($3::text IS NULL OR a.mode = $3)
         ORDER BY a.learner_id, a.created_at, a.id
         LIMIT 20000",
    )
    .bind(course_id)
    .bind(&f.station_id)
    .bind(f.mode.map(|m| m.as_str()))
    .fetch_all(&state.pool)
    .await?;
    let whole = analyse(course_id, &station.station, &rows);
    let Some(learner) = f.learner_id else {
        return Ok(whole);
    };
    // One learner against the whole cohort's band (a band of their own scores is no reference).
    let theirs: Vec<AttemptRow> = rows
        .into_iter()
        .filter(|r| r.learner_id == learner)
        .collect();
    Ok(Cohort {
        band: whole.band,
        ..analyse(course_id, &station.station, &theirs)
    })
}

/// A course's cohort at one station (its faculty, or an admin).
#[utoipa::path(get, path = "/api/courses/{course_id}/cohort", tag = "courses",
    params(("course_id" = Uuid, Path, description = "Course id"), CohortFilter),
    responses((status = 200, body = Cohort), (status = 400), (status = 401),
        (status = 403, description = "Not faculty of the course"), (status = 404, description = "Unknown course or station")))]
pub async fn get_cohort(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(course_id): ApiPath<Uuid>,
    ApiQuery(f): ApiQuery<CohortFilter>,
) -> Result<axum::Json<Cohort>, ApiError> {
    Ok(axum::Json(cohort_of(&state, &user, course_id, &f).await?))
}

/// The cohort as CSV: one row per attempt, with each criterion's status.
#[utoipa::path(get, path = "/api/courses/{course_id}/cohort.csv", tag = "courses",
    params(("course_id" = Uuid, Path, description = "Course id"), CohortFilter),
    responses((status = 200, description = "CSV, one row per attempt", content_type = "text/csv"), (status = 400), (status = 401),
        (status = 403, description = "Not faculty of the course"), (status = 404, description = "Unknown course or station")))]
pub async fn get_cohort_csv(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(course_id): ApiPath<Uuid>,
    ApiQuery(f): ApiQuery<CohortFilter>,
) -> Result<axum::response::Response, ApiError> {
    let c = cohort_of(&state, &user, course_id, &f).await?;
    Ok((
        [
            (CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                CONTENT_DISPOSITION,
                "attachment; filename=\"cohort.csv\"".to_string(),
            ),
        ],
        cohort_csv(&c),
    )
        .into_response())
}

/// One header row and one row per attempt.
pub fn cohort_csv(c: &Cohort) -> String {
    let mut head = vec![
        "learner_email",
        "learner_name",
        "attempt_id",
        "attempt_n",
        "created_at",
        "state",
        "mode",
        "outcome",
        "score",
        "air_kerma_mgy",
        "kerma_area_product_gycm2",
        "fluoro_time_s",
        "critical_failures",
        "competency",
    ]
    .into_iter()
    .map(String::from)
    .collect::<Vec<_>>();
    head.extend(c.criteria.iter().map(|k| format!("criterion:{}", k.id)));
    let mut out = head
        .iter()
        .map(|h| csv_field(h))
        .collect::<Vec<_>>()
        .join(",");
    out.push_str("\r\n");
    let num = |v: Option<f64>| v.map(|x| x.to_string()).unwrap_or_default();
    for l in &c.learners {
        for p in &l.attempts {
            let mut cells = vec![
                l.email.clone(),
                l.name.clone(),
                p.attempt_id.to_string(),
                p.n.to_string(),
                p.created_at
                    .format(&time::format_description::well_known::Rfc3339)
                    .unwrap_or_default(),
                p.state.clone(),
                p.mode.clone(),
                p.outcome.clone().unwrap_or_default(),
                num(p.score),
                num(p.air_kerma_mgy),
                num(p.kerma_area_product_gycm2),
                num(p.fluoro_time_s),
                p.critical_failures.join(" "),
                l.competency.status.clone(),
            ];
            cells.extend(
                c.criteria
                    .iter()
                    .map(|k| p.criteria.get(&k.id).cloned().unwrap_or_default()),
            );
            out.push_str(
                &cells
                    .iter()
                    .map(|x| csv_field(x))
                    .collect::<Vec<_>>()
                    .join(","),
            );
            out.push_str("\r\n");
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quartiles_follow_the_type_7_definition() {
        // R: quantile(c(1, 2, 3, 4), c(.25, .5, .75)) = 1.75 2.50 3.25.
        let s = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(
            [quantile(&s, 0.25), quantile(&s, 0.5), quantile(&s, 0.75)],
            [1.75, 2.5, 3.25]
        );
        assert_eq!(quantile(&[0.4], 0.25), 0.4);
    }

    fn point(n: u32, outcome: &str, critical: &[&str]) -> CurvePoint {
        CurvePoint {
            attempt_id: Uuid::from_u128(u128::from(n)),
            n,
            created_at: OffsetDateTime::UNIX_EPOCH,
            state: "submitted".into(),
            mode: "practice".into(),
            score: Some(0.9),
            outcome: Some(outcome.into()),
            air_kerma_mgy: None,
            kerma_area_product_gycm2: None,
            fluoro_time_s: None,
            critical_failures: critical.iter().map(|s| s.to_string()).collect(),
            criteria: BTreeMap::new(),
        }
    }

    #[test]
    fn a_safety_failure_in_the_window_is_not_offset_and_older_ones_age_out() {
        let unsafe_then_good = [
            point(1, "not_met", &["no_dural_puncture"]),
            point(2, "met", &[]),
            point(3, "met", &[]),
            point(4, "met", &[]),
        ];
        assert_eq!(judge(&unsafe_then_good).status, "competent");
        let unsafe_in_window = [
            point(1, "met", &[]),
            point(2, "met", &["no_dural_puncture"]),
            point(3, "met", &[]),
        ];
        let j = judge(&unsafe_in_window);
        assert_eq!(j.status, "not_yet");
        assert!(j.reason.contains("no_dural_puncture"), "{}", j.reason);
        assert_eq!(judge(&unsafe_then_good[..2]).status, "too_few_attempts");
    }
}
