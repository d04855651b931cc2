//! The debrief of a submitted attempt, shared by the learner's screen and the faculty review:
//! each criterion with its measured value, its tolerance and one line that explains the
//! verdict, the events of the session in order (images, punctures, losses of resistance,
//! injections, bone contacts, safety violations) as ticks for the replay bar, and the reveal
//! (where the needle really went, outlined over the last image).
//!
//! The events come from replaying the recorded log on the replay host one command at a time,
//! so they are exactly what happened (the log carries the clock). A safety violation is the
//! command after which a critical criterion of the station's rubric, measured on the session
//! so far, first scores zero credit.

use axum::extract::State;
use render_worker::session::{Command, Envelope, LogEntry, Session};
use serde::Serialize;
use sim_core::rubric::{Criterion, Station, Tolerance, Unit};
use utoipa::ToSchema;
use uuid::Uuid;

use super::recorded::{parse_recorded, recorded_session};
use super::route_state::{Caller, DispatchState};
use super::verify::{on_replay_host, restore};
use crate::error::ApiError;
use crate::records::extract::ApiPath;

/// One criterion as the debrief shows it.
#[derive(Debug, Clone, Serialize, ToSchema, PartialEq)]
pub struct DebriefCriterion {
    /// Criterion id.
    pub id: String,
    /// What it checks.
    pub description: String,
    /// The measurement it reads.
    pub measurement: String,
    /// Unit of the value (`mm`, `deg`, `count`, `s`, `fraction`, `bool`, `mgy`, `gycm2`).
    pub unit: String,
    /// The measured value (absent: not measured).
    pub value: Option<f64>,
    /// `met`, `not_met` or `missing`.
    pub status: String,
    /// Credit in 0..=1 (absent: not measured).
    pub credit: Option<f64>,
    /// Weight in the score.
    pub weight: f64,
    /// A safety criterion: its failure fails the attempt whatever the score.
    pub critical: bool,
    /// The station's tolerance, as its file states it.
    #[schema(value_type = Object)]
    pub tolerance: serde_json::Value,
    /// One line: the value against the tolerance, in words.
    pub explanation: String,
}

/// One event of the session, a tick on the replay bar.
#[derive(Debug, Clone, Serialize, ToSchema, PartialEq)]
pub struct DebriefEvent {
    /// Steps of the log up to and including this command (the replay bar's position).
    pub step: u32,
    /// The command's sequence number.
    pub seq: u64,
    /// Session time, ms.
    pub t_ms: u64,
    /// `image`, `puncture`, `loss_of_resistance`, `injection`, `bone_contact`, `violation`
    /// or `submit`.
    pub kind: String,
    /// In words.
    pub label: String,
}

/// The debrief of one attempt.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct Debrief {
    /// Attempt.
    pub attempt_id: Uuid,
    /// Station.
    pub station_id: String,
    /// Technical outcome of the result.
    pub outcome: Option<String>,
    /// Weighted score.
    pub score: Option<f64>,
    /// Score needed (besides every critical criterion).
    pub pass_threshold: f64,
    /// Every criterion, in the rubric's order.
    pub criteria: Vec<DebriefCriterion>,
    /// Commands in the log (the replay bar's length).
    pub steps: u32,
    /// Events, in order.
    pub events: Vec<DebriefEvent>,
    /// "Met" is a technical statement, not a certification.
    pub notice: String,
}

/// A value in a unit, as a person reads it.
fn shown(value: f64, unit: Unit) -> String {
    match unit {
        Unit::Bool => (if value >= 0.5 { "yes" } else { "no" }).into(),
        Unit::Count => format!("{value:.0}"),
        Unit::Fraction => format!("{:.0} %", value * 100.0),
        Unit::Mm => format!("{value:.1} mm"),
        Unit::Deg => format!("{value:.1}°"),
        Unit::S => format!("{value:.1} s"),
        Unit::Mgy => format!("{value:.2} mGy"),
        Unit::Gycm2 => format!("{value:.3} Gy·cm²"),
    }
}

/// One line that explains a criterion's verdict from its tolerance.
pub fn explain(c: &Criterion, value: Option<f64>) -> String {
    let Some(v) = value else {
        return "Not measured: the attempt never did what this criterion measures.".into();
    };
    let u = c.unit;
    let credit = c.tolerance.credit(v).unwrap_or(0.0);
    let verdict = if credit >= 1.0 {
        "full credit"
    } else if credit <= 0.0 {
        "no credit"
    } else {
        "partial credit"
    };
    let rule = match c.tolerance {
        Tolerance::LowerIsBetter {
            pass_within,
            fail_beyond,
        } => format!(
            "full credit at or below {}, none from {}",
            shown(pass_within, u),
            shown(fail_beyond, u)
        ),
        Tolerance::NearValue {
            value,
            pass_within,
            fail_beyond,
        } => format!(
            "{} from the ideal {}; full credit within {}, none from {}",
            shown((v - value).abs(), u),
            shown(value, u),
            shown(pass_within, u),
            shown(fail_beyond, u)
        ),
        Tolerance::HigherIsBetter {
            pass_from,
            fail_below,
        } => format!(
            "full credit from {}, none at or below {}",
            shown(pass_from, u),
            shown(fail_below, u)
        ),
        Tolerance::Boolean { expected } => format!(
            "expected {}",
            shown(if expected { 1.0 } else { 0.0 }, Unit::Bool)
        ),
    };
    let safety = if c.critical && Criterion::is_failure(credit) {
        " A safety criterion: this alone fails the attempt, whatever the score."
    } else {
        ""
    };
    format!("Measured {}: {rule}, so {verdict}.{safety}", shown(v, u))
}

/// The events of a log, replayed on `session` (restored at its initial state) one command at a
/// time; `critical` are the rubric's safety criteria.
fn events_of(session: &mut Session, log: &[LogEntry], critical: &[Criterion]) -> Vec<DebriefEvent> {
    let mut out = Vec::new();
    let mut violated = vec![false; critical.len()];
    for (i, e) in log.iter().enumerate() {
        let step = i as u32 + 1;
        let ack = session.apply(
            Envelope {
                seq: e.seq,
                command: e.command.clone(),
            },
            e.t_ms,
        );
        let mut push = |kind: &str, label: String| {
            out.push(DebriefEvent {
                step,
                seq: e.seq,
                t_ms: e.t_ms,
                kind: kind.into(),
                label,
            })
        };
        let Ok(ack) = ack else { continue };
        let o = &ack.outcome;
        match &e.command {
            Command::Shot => push("image", "Shot".into()),
            Command::Live { on: true } => push("image", "Live fluoroscopy".into()),
            Command::NeedlePuncture { instrument, .. }
            | Command::NeedlePlace { instrument, .. } => {
                push("puncture", format!("Skin puncture ({instrument})"))
            }
            Command::Inject {
                agent, volume_ml, ..
            } => push(
                "injection",
                format!("Injection: {volume_ml} ml of {agent:?}"),
            ),
            Command::Plunger { ml } => push("injection", format!("Plunger: {ml} ml")),
            Command::Submit => push("submit", "Submitted".into()),
            _ => {}
        }
        if o["lor"]["gave_way"] == true {
            push("loss_of_resistance", "Loss of resistance".into());
        }
        if o["bone_contact"] == true {
            push("bone_contact", "Bone contact".into());
        }
        // Safety: measured only after commands that can change a critical measurement.
        let may_violate = matches!(
            e.command,
            Command::NeedleFeed { .. }
                | Command::NeedleTilt { .. }
                | Command::NeedleWithdraw { .. }
                | Command::NeedlePuncture { .. }
                | Command::NeedlePlace { .. }
                | Command::Inject { .. }
                | Command::Plunger { .. }
                | Command::Tick
        );
        if may_violate && !critical.is_empty() && violated.iter().any(|v| !v) {
            let m = session.measurements();
            for (k, c) in critical.iter().enumerate() {
                let failed = m
                    .get(&c.measurement)
                    .and_then(|v| c.tolerance.credit(*v).ok())
                    .is_some_and(Criterion::is_failure);
                if failed && !violated[k] {
                    violated[k] = true;
                    push("violation", c.description.clone());
                }
            }
        }
    }
    out
}

/// `GET /api/attempts/{attempt_id}/debrief`: the submitted attempt's criteria explained and its
/// session's events. The learner once submitted; faculty of the course and admins.
#[utoipa::path(get, path = "/api/attempts/{attempt_id}/debrief", tag = "sessions",
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 200, body = Debrief), (status = 400, description = "Malformed attempt id"), (status = 401),
        (status = 404, description = "No such attempt visible to the caller, or no recorded session"),
        (status = 409, description = "Not submitted yet"),
        (status = 503, description = "The anatomy is being prepared")))]
pub(super) async fn debrief(
    State(state): State<DispatchState>,
    Caller(user): Caller,
    ApiPath(attempt_id): ApiPath<Uuid>,
) -> Result<axum::Json<Debrief>, ApiError> {
    let (session_id, station_id, initial, result_id, _, _, score, outcome) =
        recorded_session(&state, &user, attempt_id).await?;
    let Some(result_id) = result_id else {
        return Err(ApiError::Conflict(
            "the debrief opens once the attempt is submitted".into(),
        ));
    };
    let (definition, detail): (serde_json::Value, serde_json::Value) = sqlx::query_as(
        "SELECT s.definition, r.detail FROM technical_results r
         JOIN station_revisions s ON s.station_id = r.station_id AND s.revision = r.station_revision
              AND s.rubric_revision = r.rubric_revision
         WHERE r.id = $1",
    )
    .bind(result_id)
    .fetch_one(&state.records.pool)
    .await?;
    let station: Station = serde_json::from_value(definition)
        .map_err(|e| ApiError::Internal(format!("stored station: {e}")))?;
    let scored = detail["criteria"].as_array().cloned().unwrap_or_default();
    let criteria = station
        .rubric
        .criteria
        .iter()
        .map(|c| {
            let s = scored.iter().find(|s| s["id"] == c.id.as_str());
            let value = s.and_then(|s| s["value"].as_f64());
            DebriefCriterion {
                id: c.id.clone(),
                description: c.description.clone(),
                measurement: c.measurement.clone(),
                unit: c.unit.name().into(),
                value,
                status: s
                    .and_then(|s| s["status"].as_str())
                    .unwrap_or("missing")
                    .into(),
                credit: s.and_then(|s| s["credit"].as_f64()),
                weight: c.weight,
                critical: c.critical,
                tolerance: serde_json::to_value(c.tolerance).unwrap_or_default(),
                explanation: explain(c, value),
            }
        })
        .collect();
    let critical: Vec<Criterion> = station
        .rubric
        .criteria
        .iter()
        .filter(|c| c.critical)
        .cloned()
        .collect();
    let (initial, log) = parse_recorded(&state, session_id, initial).await?;
    let steps = log.len() as u32;
    let host = state.dispatcher.inner.replay.clone();
    let events = on_replay_host(host, station_id.clone(), move |env| {
        let mut s = restore(env, &initial, &[])?;
        Ok(events_of(&mut s, &log, &critical))
    })
    .await?;
    Ok(axum::Json(Debrief {
        attempt_id,
        station_id,
        outcome,
        score,
        pass_threshold: station.rubric.pass_threshold,
        criteria,
        steps,
        events,
        notice: sim_core::rubric::TECHNICAL_RESULT_NOTICE.into(),
    }))
}

/// Where the needle went, over the last image of the attempt's session.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct RevealView {
    /// Attempt.
    pub attempt_id: Uuid,
    /// The replay step whose image the outlines belong to (the whole log:
    /// `GET /api/attempts/{id}/replay/frame?step={step}`).
    pub step: u32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Structures the final needle's tract passed through, in the order the tip entered them.
    pub touched: Vec<String>,
    /// Outlines of the touched structures (envelopes such as the skin left out): runs
    /// `[row, first column, last column]` of outline pixels.
    #[schema(value_type = Vec<Object>)]
    pub outlines: Vec<render_worker::session::reveal::Outline>,
}

/// `GET /api/attempts/{attempt_id}/reveal`: the structures the needle passed through, outlined
/// over the last image of the session (none when the session had no needle). The learner once
/// submitted; faculty and admins.
#[utoipa::path(get, path = "/api/attempts/{attempt_id}/reveal", tag = "sessions",
    params(("attempt_id" = Uuid, Path, description = "Attempt id")),
    responses((status = 200, body = RevealView), (status = 400, description = "Malformed attempt id"), (status = 401),
        (status = 404, description = "No such attempt visible to the caller, no recorded session, or no fluoroscopy image in it"),
        (status = 409, description = "Not submitted yet"),
        (status = 503, description = "The anatomy is being prepared")))]
pub(super) async fn reveal(
    State(state): State<DispatchState>,
    Caller(user): Caller,
    ApiPath(attempt_id): ApiPath<Uuid>,
) -> Result<axum::Json<RevealView>, ApiError> {
    let (session_id, station_id, initial, result_id, ..) =
        recorded_session(&state, &user, attempt_id).await?;
    if result_id.is_none() {
        return Err(ApiError::Conflict(
            "the reveal opens once the attempt is submitted".into(),
        ));
    }
    let (initial, log) = parse_recorded(&state, session_id, initial).await?;
    let step = log.len() as u32;
    let host = state.dispatcher.inner.replay.clone();
    let r = on_replay_host(host, station_id, move |env| {
        let s = restore(env, &initial, &log)?;
        Ok(render_worker::session::reveal::reveal(&s))
    })
    .await?
    .ok_or_else(|| ApiError::NotFound("a fluoroscopy image in the session".into()))?;
    Ok(axum::Json(RevealView {
        attempt_id,
        step,
        width: r.width,
        height: r.height,
        touched: r.touched,
        outlines: r.outlines,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn criterion(unit: Unit, tolerance: Tolerance, critical: bool) -> Criterion {
        Criterion {
            id: "c".into(),
            description: "d".into(),
            measurement: format!("x_{}", unit.name()),
            unit,
            weight: 1.0,
            critical,
            target: None,
            tolerance,
        }
    }

    #[test]
    fn each_tolerance_is_explained_in_one_line() {
        let lower = Tolerance::LowerIsBetter {
            pass_within: 2.0,
            fail_beyond: 8.0,
        };
        let c = criterion(Unit::Mm, lower, false);
        assert_eq!(
            explain(&c, Some(5.0)),
            "Measured 5.0 mm: full credit at or below 2.0 mm, none from 8.0 mm, so partial credit."
        );
        assert_eq!(
            explain(&c, None),
            "Not measured: the attempt never did what this criterion measures."
        );
        let near = Tolerance::NearValue {
            value: 20.0,
            pass_within: 5.0,
            fail_beyond: 15.0,
        };
        assert_eq!(
            explain(&criterion(Unit::Deg, near, false), Some(24.0)),
            "Measured 24.0°: 4.0° from the ideal 20.0°; full credit within 5.0°, none from 15.0°, \
             so full credit."
        );
        let higher = Tolerance::HigherIsBetter {
            pass_from: 0.9,
            fail_below: 0.5,
        };
        assert_eq!(
            explain(&criterion(Unit::Fraction, higher, false), Some(0.2)),
            "Measured 20 %: full credit from 90 %, none at or below 50 %, so no credit."
        );
        let boolean = Tolerance::Boolean { expected: false };
        assert_eq!(
            explain(&criterion(Unit::Bool, boolean, true), Some(1.0)),
            "Measured yes: expected no, so no credit. A safety criterion: this alone fails the \
             attempt, whatever the score."
        );
    }
}
