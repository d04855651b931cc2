//! What a learner's browser is told about its own session: what a physician's eyes and hands
//! would have, and in practice mode a few coaching hints; never where the tip really is, which
//! tissue it is in, or how far it is from the target.
//!
//! The render worker's acknowledgements carry the full state its own tests and the scorers
//! need (the tip position, the entry point, the bone contact point, the annotation error, the
//! in-slice flags). The relay passes every acknowledgement through [`ack_for_browser`] before
//! the browser sees it:
//! - [`NEVER`] keys are removed at any depth, in both modes: model-frame positions and
//!   directions of the needle and of what it touched, the tip's own turn and roll (the hand
//!   knows the hub's, not the tip's), and scoring figures. A feed stopped by bone says `hard_stop`
//!   (with `bone_contact`, what the hand feels), not where or at what angle.
//! - [`HINTS`] keys are removed in assessment mode.
//! - Command errors lose any bracketed list of three or more numbers from their message
//!   ([`error_for_browser`]): the worker words errors for the learner, this guards the rest.
//! - The submit's acknowledgement never carries the result; the separate `technical_result`
//!   message does in practice mode, and in assessment mode says only that the attempt was
//!   submitted ([`result_for_browser`]): the debrief is read from the attempt afterwards.
//!
//! The test `disclosure::an_assessment_session_tells_the_browser_nothing_it_could_not_see`
//! records every message of a scripted session with every command kind and checks each key
//! against the list of keys a browser may receive, so a new field of an acknowledgement fails
//! it until someone decides which list it belongs to.

use render_worker::session::Ack;
use render_worker::session::protocol::ServerMessage;
use serde_json::{Value, json};

use crate::records::modes::StationMode;

/// Keys no browser receives, at any depth of an acknowledgement's outcome.
pub const NEVER: &[&str] = &[
    // The tip, the entry and the skin marker in the model frame.
    "tip_mm",
    "entry_mm",
    "marker_mm",
    // The needle's direction in the model frame (the hand knows the hub's tilt, reported as
    // `hub_deviation_deg`).
    "direction",
    // What the tip did inside the body.
    "tip_turn_deg",
    "tip_roll_rad",
    "released_tip_roll_rad",
    "branched",
    // A bone contact's geometry.
    "surface_point_mm",
    "normal",
    "incidence_deg",
    // Scoring: a mark's distance from the structure it names.
    "annotation_error_mm",
    // What aspiration drew back as a category (`csf`, `blood`): the browser gets what the eye
    // sees in the hub (`text`: "clear fluid drips back"), not the model's name for it.
    "aspirate",
];

/// Coaching hints: sent in practice mode only.
pub const HINTS: &[&str] = &["needle_in_slice", "tip_in_slice"];

/// The acknowledgement as the browser gets it (a `ServerMessage::Ack` text).
pub fn ack_for_browser(ack: &Ack, mode: StationMode) -> String {
    let mut v = serde_json::to_value(ServerMessage::Ack(ack.clone())).unwrap_or(Value::Null);
    if let Some(o) = v.as_object_mut() {
        o.remove("result");
        if let Some(outcome) = o.get_mut("outcome") {
            redact(outcome, mode);
        }
    }
    v.to_string()
}

/// The worker's hello as the browser gets it: with the mode the session runs in.
pub fn hello_for_browser(hello: &ServerMessage, mode: StationMode) -> String {
    let mut v = serde_json::to_value(hello).unwrap_or(Value::Null);
    if let Some(session) = v.get_mut("session").and_then(Value::as_object_mut) {
        session.insert("mode".into(), mode.as_str().into());
    }
    v.to_string()
}

/// The stored result's message (`technical_result`, or `technical_result_error`) as the
/// browser gets it: whole in practice mode; in assessment mode only the result's id, that the
/// attempt was submitted, and where its debrief is.
pub fn result_for_browser(message: Value, mode: StationMode, attempt_id: uuid::Uuid) -> Value {
    if mode == StationMode::Practice || message["type"] != "technical_result" {
        return message;
    }
    json!({
        "type": "technical_result",
        "mode": "assessment",
        "result": {
            "id": message["result"]["id"],
            "source": message["result"]["source"],
            "withheld": true,
            "attempt_id": attempt_id,
            "notice": "Submitted. This station runs in assessment mode: the result is in the \
                attempt's debrief (GET /api/attempts/{id}), not in the session.",
        },
    })
}

/// A command error as the browser gets it: its message without any bracketed list of three or
/// more numbers (a coordinate a model put in its wording; a `[lo, hi]` range stays), its field
/// without a [`NEVER`] key. The worker
/// words its errors for the learner already; this is the guard for one that does not.
pub fn error_for_browser(text: String) -> String {
    let Ok(mut v) = serde_json::from_str::<Value>(&text) else {
        return text;
    };
    let Some(error) = v.get_mut("error").and_then(Value::as_object_mut) else {
        return text;
    };
    if let Some(Value::String(m)) = error.get_mut("message") {
        *m = without_number_lists(m);
    }
    if let Some(Value::String(f)) = error.get_mut("field")
        && let Some((head, last)) = f.rsplit_once('.')
        && NEVER.contains(&last)
    {
        *f = head.to_string();
    }
    v.to_string()
}

/// `text` with each `[..]` that holds three or more numbers and nothing else replaced by `[..]`.
fn without_number_lists(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(open) = rest.find('[') {
        out.push_str(&rest[..open]);
        let after = &rest[open + 1..];
        match after.find(']') {
            Some(close)
                if after[..close].matches(',').count() >= 2
                    && after[..close]
                        .chars()
                        .all(|c| c.is_ascii_digit() || " ,.-+eE".contains(c)) =>
            {
                out.push_str("[..]");
                rest = &after[close + 1..];
            }
            _ => {
                out.push('[');
                rest = after;
            }
        }
    }
    out.push_str(rest);
    out
}

/// Removes what the browser must not get from one outcome value, at any depth.
fn redact(v: &mut Value, mode: StationMode) {
    match v {
        Value::Object(o) => {
            let hint_free = mode == StationMode::Assessment;
            o.retain(|k, _| {
                let k = k.as_str();
                let withheld = NEVER.contains(&k) || (hint_free && HINTS.contains(&k));
                !withheld
            });
            // A feed's stop: `Completed`, `HubAtSkin`, or `{"Arrested": {contact}}`, which
            // becomes `hard_stop` (the hand feels one, not where it is).
            if let Some(stop) = o.get_mut("stop")
                && stop.get("Arrested").is_some()
            {
                *stop = Value::from("hard_stop");
            }
            for x in o.values_mut() {
                redact(x, mode);
            }
        }
        Value::Array(a) => a.iter_mut().for_each(|x| redact(x, mode)),
        _ => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ack(outcome: Value) -> Ack {
        Ack {
            seq: 3,
            t_ms: 10,
            duplicate: false,
            outcome,
            engagement: None,
            result: None,
        }
    }

    #[test]
    fn positions_go_in_both_modes_and_hints_in_assessment() {
        let a = ack(json!({
            "tip_mm": [1, 2, 3], "depth_mm": 30.0,
            "outcome": { "stop": { "Arrested": { "surface_point_mm": [1, 2, 3], "normal": [0, 0, 1] } } },
            "ultrasound": { "frozen": false, "needle_in_slice": true, "tip_in_slice": false },
            "nested": [{ "entry_mm": [0, 0, 0], "keep": 1 }],
        }));
        let practice: Value =
            serde_json::from_str(&ack_for_browser(&a, StationMode::Practice)).unwrap();
        assert_eq!(
            practice["outcome"],
            json!({ "depth_mm": 30.0, "outcome": { "stop": "hard_stop" },
                "ultrasound": { "frozen": false, "needle_in_slice": true, "tip_in_slice": false },
                "nested": [{ "keep": 1 }] })
        );
        assert_eq!(practice["type"], "ack");
        assert_eq!(practice["seq"], 3);
        let assessment: Value =
            serde_json::from_str(&ack_for_browser(&a, StationMode::Assessment)).unwrap();
        assert_eq!(
            assessment["outcome"]["ultrasound"],
            json!({ "frozen": false })
        );
    }

    #[test]
    fn error_messages_lose_their_coordinates() {
        let e = json!({ "type": "error", "seq": 4, "error": { "field": "needle.tip_mm",
            "code": "invalid", "message": "tip [1.5, -2e3, 3] is outside [0, 50]; see [notes]" } });
        let out: Value = serde_json::from_str(&error_for_browser(e.to_string())).unwrap();
        assert_eq!(out["error"]["field"], "needle");
        assert_eq!(
            out["error"]["message"],
            "tip [..] is outside [0, 50]; see [notes]"
        );
        assert_eq!(out["seq"], 4);
        assert_eq!(error_for_browser("not json".into()), "not json");
        assert_eq!(without_number_lists("a [1, 2"), "a [1, 2");
    }

    #[test]
    fn an_assessment_result_names_only_its_id() {
        let id = uuid::Uuid::nil();
        let m = json!({ "type": "technical_result", "result": { "id": "r1", "source": "server",
            "measurements": { "tip_to_target_mm": 2.0 } } });
        assert_eq!(
            result_for_browser(m.clone(), StationMode::Practice, id),
            m,
            "practice: whole"
        );
        let a = result_for_browser(m, StationMode::Assessment, id);
        assert_eq!(a["result"]["id"], "r1");
        assert!(!a.to_string().contains("tip_to_target"), "{a}");
        let err = json!({ "type": "technical_result_error", "message": "x" });
        assert_eq!(
            result_for_browser(err.clone(), StationMode::Assessment, id),
            err
        );
    }
}
