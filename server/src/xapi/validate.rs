//! Validation of one statement against the xAPI 2.0 data model (IEEE 9274.1.1, Data part 2.4).
//!
//! [`statement`] checks a statement as a client sends it: every property known and of its type,
//! no `null` where a value is required, identifiers in their formats (UUIDs, IRIs, language tags,
//! ISO 8601 timestamps and durations), the rules that tie properties together (an Agent has one
//! IFI; `revision` and `platform` only with an Activity object; a SubStatement holds no
//! SubStatement, id, stored, version or authority; interaction components only for their
//! interaction types; a score's scaled in [-1, 1] and raw within [min, max]; a voiding statement's
//! object is a StatementRef). Messages name the property path, e.g. `result.score.scaled`.
//!
//! Properties the LRS sets (`stored`, `authority`, `version`) are accepted when well-formed; the
//! statements resource decides what to keep.

use serde_json::{Map, Value};

use super::agent::{agent, agent_or_group, group, is_iri};
use super::error::{Invalid, fault};

/// The verb IRI of voiding (Data 2.4.3.1, "Voided").
pub const VOIDED_VERB: &str = "http://adlnet.gov/expapi/verbs/voided";

/// Interaction types of an Activity definition (Data 2.4.4.1.1.2).
const INTERACTION_TYPES: [&str; 10] = [
    "true-false",
    "choice",
    "fill-in",
    "long-fill-in",
    "matching",
    "performance",
    "sequencing",
    "likert",
    "numeric",
    "other",
];

type R = Result<(), Invalid>;

fn obj<'a>(v: &'a Value, path: &str) -> Result<&'a Map<String, Value>, Invalid> {
    v.as_object()
        .ok_or_else(|| fault!("{path}: must be a JSON object"))
}

fn only(m: &Map<String, Value>, allowed: &[&str], path: &str, what: &str) -> R {
    for (key, value) in m {
        if !allowed.contains(&key.as_str()) {
            return Err(fault!("{path}.{key}: not a property of {what}"));
        }
        if value.is_null() {
            return Err(fault!("{path}.{key}: must not be null"));
        }
    }
    Ok(())
}

fn str_at<'a>(
    m: &'a Map<String, Value>,
    key: &str,
    path: &str,
) -> Result<Option<&'a str>, Invalid> {
    match m.get(key) {
        None => Ok(None),
        Some(Value::String(s)) => Ok(Some(s)),
        Some(_) => Err(fault!("{path}.{key}: must be a string")),
    }
}

fn iri_at(m: &Map<String, Value>, key: &str, path: &str, required: bool) -> R {
    match str_at(m, key, path)? {
        Some(s) if is_iri(s) => Ok(()),
        Some(_) => Err(fault!("{path}.{key}: must be an absolute IRI")),
        None if required => Err(fault!("{path}.{key}: required")),
        None => Ok(()),
    }
}

fn bool_at(m: &Map<String, Value>, key: &str, path: &str) -> R {
    match m.get(key) {
        None | Some(Value::Bool(_)) => Ok(()),
        Some(_) => Err(fault!("{path}.{key}: must be true or false")),
    }
}

/// True for a UUID in its 36-character hyphenated form (RFC 4122, any version).
pub fn is_uuid(s: &str) -> bool {
    s.len() == 36 && uuid::Uuid::try_parse(s).is_ok()
}

/// True for an RFC 5646 language tag in the shape xAPI uses: a 2-8 letter primary subtag and
/// 1-8 character alphanumeric subtags (e.g. `en`, `en-US`, `zh-Hant-TW`, `x-klingon`).
pub fn is_language_tag(s: &str) -> bool {
    let mut parts = s.split('-');
    let first = parts.next().unwrap_or_default();
    let first_ok =
        (first.len() >= 2 && first.len() <= 8 && first.bytes().all(|b| b.is_ascii_alphabetic()))
            || first.eq_ignore_ascii_case("x")
            || first.eq_ignore_ascii_case("i");
    first_ok
        && parts
            .all(|p| !p.is_empty() && p.len() <= 8 && p.bytes().all(|b| b.is_ascii_alphanumeric()))
}

fn language_map(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    for (tag, text) in m {
        if !is_language_tag(tag) {
            return Err(fault!("{path}: \"{tag}\" is not an RFC 5646 language tag"));
        }
        if !text.is_string() {
            return Err(fault!("{path}.{tag}: must be a string"));
        }
    }
    Ok(())
}

fn extensions(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    for key in m.keys() {
        if !is_iri(key) {
            return Err(fault!(
                "{path}: extension key \"{key}\" is not an absolute IRI"
            ));
        }
    }
    Ok(())
}

fn digits(s: &str) -> bool {
    !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit())
}

/// True for an ISO 8601 timestamp with date and time (`2026-11-27T05:32:34.804Z`,
/// `...+01:00`, `...+0100`, `...+01`, or no zone), with month, day, hour, minute and second in
/// range. The offset `-00:00` ("unknown local offset", RFC 3339) is refused, as xAPI 2.0 requires.
pub fn is_timestamp(s: &str) -> bool {
    let Some((date, time)) = s.split_once('T') else {
        return false;
    };
    let d: Vec<&str> = date.split('-').collect();
    if d.len() != 3
        || d[0].len() != 4
        || d[1].len() != 2
        || d[2].len() != 2
        || !d.iter().all(|p| digits(p))
    {
        return false;
    }
    let (month, day): (u32, u32) = (d[1].parse().unwrap_or(0), d[2].parse().unwrap_or(0));
    if !(1..=12).contains(&month) || !(1..=31).contains(&day) {
        return false;
    }
    let (clock, zone) = if let Some(c) = time.strip_suffix('Z') {
        (c, Some("Z"))
    } else if let Some(i) = time.rfind(['+', '-']) {
        (&time[..i], Some(&time[i..]))
    } else {
        (time, None)
    };
    if let Some(z) = zone.filter(|z| *z != "Z") {
        let body = z[1..].replace(':', "");
        if !(body.len() == 2 || body.len() == 4) || !digits(&body) {
            return false;
        }
        if z.starts_with('-') && body.bytes().all(|b| b == b'0') {
            return false;
        }
        let (h, m): (u32, u32) = (
            body[..2].parse().unwrap_or(99),
            body.get(2..).map_or(0, |m| m.parse().unwrap_or(99)),
        );
        if h > 14 || m > 59 {
            return false;
        }
    }
    let (hms, fraction) = match clock.split_once('.') {
        Some((hms, f)) => (hms, Some(f)),
        None => (clock, None),
    };
    if fraction.is_some_and(|f| !digits(f)) {
        return false;
    }
    let t: Vec<&str> = hms.split(':').collect();
    if !(t.len() == 2 || t.len() == 3) || !t.iter().all(|p| p.len() == 2 && digits(p)) {
        return false;
    }
    let parse = |i: usize| t.get(i).map_or(0, |p| p.parse::<u32>().unwrap_or(99));
    parse(0) <= 23 && parse(1) <= 59 && parse(2) <= 60 && (fraction.is_none() || t.len() == 3)
}

/// True for an ISO 8601 duration as xAPI uses them (`PT1H30M`, `P1DT2.5S`, `P3W`): components in
/// order, at least one, a `T` only before time components, a decimal fraction only on the seconds.
pub fn is_duration(s: &str) -> bool {
    let Some(rest) = s.strip_prefix('P') else {
        return false;
    };
    let (date, time) = match rest.split_once('T') {
        Some((d, t)) => {
            if t.is_empty() {
                return false;
            }
            (d, Some(t))
        }
        None => (rest, None),
    };
    fn components(part: &str, designators: &[char], fraction_on: Option<char>) -> Option<usize> {
        let mut count = 0;
        let mut next = 0;
        let mut number = String::new();
        for c in part.chars() {
            if c.is_ascii_digit() || c == '.' {
                number.push(c);
                continue;
            }
            let i = designators[next..].iter().position(|d| *d == c)? + next;
            let ok_number = match number.split_once('.') {
                None => digits(&number),
                Some((a, b)) => fraction_on == Some(c) && digits(a) && digits(b),
            };
            if !ok_number {
                return None;
            }
            number.clear();
            next = i + 1;
            count += 1;
        }
        number.is_empty().then_some(count)
    }
    let Some(date_count) = components(date, &['Y', 'M', 'W', 'D'], None) else {
        return false;
    };
    let time_count = match time {
        Some(t) => match components(t, &['H', 'M', 'S'], Some('S')) {
            Some(n) if n > 0 => n,
            _ => return false,
        },
        None => 0,
    };
    // Weeks stand alone (ISO 8601:2004 4.4.3.2: PnW is its own format, never mixed with others).
    if date.contains('W') && (date_count != 1 || time_count != 0) {
        return false;
    }
    date_count + time_count > 0
}

fn interaction_components(v: &Value, path: &str) -> R {
    let list = v
        .as_array()
        .ok_or_else(|| fault!("{path}: must be an array of interaction components"))?;
    let mut seen = std::collections::HashSet::new();
    for (i, c) in list.iter().enumerate() {
        let p = format!("{path}[{i}]");
        let m = obj(c, &p)?;
        only(m, &["id", "description"], &p, "an interaction component")?;
        match str_at(m, "id", &p)? {
            Some(id) if !id.is_empty() => {
                if !seen.insert(id.to_owned()) {
                    return Err(fault!("{p}.id: \"{id}\" is used twice"));
                }
            }
            _ => return Err(fault!("{p}.id: required, a non-empty string")),
        }
        if let Some(d) = m.get("description") {
            language_map(d, &format!("{p}.description"))?;
        }
    }
    Ok(())
}

fn activity_definition(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    only(
        m,
        &[
            "name",
            "description",
            "type",
            "moreInfo",
            "extensions",
            "interactionType",
            "correctResponsesPattern",
            "choices",
            "scale",
            "source",
            "target",
            "steps",
        ],
        path,
        "an Activity Definition",
    )?;
    for key in ["name", "description"] {
        if let Some(x) = m.get(key) {
            language_map(x, &format!("{path}.{key}"))?;
        }
    }
    iri_at(m, "type", path, false)?;
    iri_at(m, "moreInfo", path, false)?;
    if let Some(x) = m.get("extensions") {
        extensions(x, &format!("{path}.extensions"))?;
    }
    let interaction = str_at(m, "interactionType", path)?;
    if let Some(t) = interaction {
        if !INTERACTION_TYPES.contains(&t) {
            return Err(fault!(
                "{path}.interactionType: \"{t}\" is not an interaction type"
            ));
        }
    }
    if let Some(p) = m.get("correctResponsesPattern") {
        if interaction.is_none() {
            return Err(fault!(
                "{path}.correctResponsesPattern: needs an interactionType"
            ));
        }
        let list = p
            .as_array()
            .ok_or_else(|| fault!("{path}.correctResponsesPattern: must be an array of strings"))?;
        if list.iter().any(|x| !x.is_string()) {
            return Err(fault!(
                "{path}.correctResponsesPattern: must be an array of strings"
            ));
        }
    }
    let allowed: &[&str] = match interaction {
        Some("choice" | "sequencing") => &["choices"],
        Some("likert") => &["scale"],
        Some("matching") => &["source", "target"],
        Some("performance") => &["steps"],
        _ => &[],
    };
    for key in ["choices", "scale", "source", "target", "steps"] {
        if let Some(x) = m.get(key) {
            if !allowed.contains(&key) {
                return Err(fault!(
                    "{path}.{key}: not allowed for interactionType {}",
                    interaction.unwrap_or("(none)")
                ));
            }
            interaction_components(x, &format!("{path}.{key}"))?;
        }
    }
    Ok(())
}

fn activity(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    only(m, &["objectType", "id", "definition"], path, "an Activity")?;
    match str_at(m, "objectType", path)? {
        None | Some("Activity") => {}
        Some(_) => return Err(fault!("{path}.objectType: must be \"Activity\"")),
    }
    iri_at(m, "id", path, true)?;
    if let Some(d) = m.get("definition") {
        activity_definition(d, &format!("{path}.definition"))?;
    }
    Ok(())
}

fn statement_ref(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    only(m, &["objectType", "id"], path, "a StatementRef")?;
    if str_at(m, "objectType", path)? != Some("StatementRef") {
        return Err(fault!("{path}.objectType: must be \"StatementRef\""));
    }
    match str_at(m, "id", path)? {
        Some(id) if is_uuid(id) => Ok(()),
        _ => Err(fault!("{path}.id: required, a UUID")),
    }
}

fn verb(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    only(m, &["id", "display"], path, "a Verb")?;
    iri_at(m, "id", path, true)?;
    if let Some(d) = m.get("display") {
        language_map(d, &format!("{path}.display"))?;
    }
    Ok(())
}

fn number(m: &Map<String, Value>, key: &str, path: &str) -> Result<Option<f64>, Invalid> {
    match m.get(key) {
        None => Ok(None),
        Some(Value::Number(n)) => Ok(n.as_f64()),
        Some(_) => Err(fault!("{path}.{key}: must be a number")),
    }
}

fn result(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    only(
        m,
        &[
            "score",
            "success",
            "completion",
            "response",
            "duration",
            "extensions",
        ],
        path,
        "a Result",
    )?;
    if let Some(s) = m.get("score") {
        let p = format!("{path}.score");
        let sm = obj(s, &p)?;
        only(sm, &["scaled", "raw", "min", "max"], &p, "a Score")?;
        if let Some(scaled) = number(sm, "scaled", &p)? {
            if !(-1.0..=1.0).contains(&scaled) {
                return Err(fault!("{p}.scaled: must be between -1 and 1"));
            }
        }
        let (raw, min, max) = (
            number(sm, "raw", &p)?,
            number(sm, "min", &p)?,
            number(sm, "max", &p)?,
        );
        if let (Some(lo), Some(hi)) = (min, max) {
            if lo >= hi {
                return Err(fault!("{p}.min: must be less than max"));
            }
        }
        if let Some(r) = raw {
            if min.is_some_and(|lo| r < lo) {
                return Err(fault!("{p}.raw: must not be less than min"));
            }
            if max.is_some_and(|hi| r > hi) {
                return Err(fault!("{p}.raw: must not be more than max"));
            }
        }
    }
    bool_at(m, "success", path)?;
    bool_at(m, "completion", path)?;
    str_at(m, "response", path)?;
    if let Some(d) = str_at(m, "duration", path)? {
        if !is_duration(d) {
            return Err(fault!(
                "{path}.duration: must be an ISO 8601 duration, e.g. PT1H30M"
            ));
        }
    }
    if let Some(x) = m.get("extensions") {
        extensions(x, &format!("{path}.extensions"))?;
    }
    Ok(())
}

fn activities(v: &Value, path: &str) -> R {
    match v {
        Value::Array(list) => {
            for (i, a) in list.iter().enumerate() {
                activity(a, &format!("{path}[{i}]"))?;
            }
            Ok(())
        }
        other => activity(other, path),
    }
}

fn relevant_types(m: &Map<String, Value>, path: &str) -> R {
    match m.get("relevantTypes") {
        None => Ok(()),
        Some(Value::Array(list)) if !list.is_empty() => {
            for (i, t) in list.iter().enumerate() {
                if !t.as_str().is_some_and(is_iri) {
                    return Err(fault!("{path}.relevantTypes[{i}]: must be an IRI"));
                }
            }
            Ok(())
        }
        Some(_) => Err(fault!(
            "{path}.relevantTypes: must be a non-empty array of IRIs"
        )),
    }
}

/// `contextAgents` or `contextGroups` (xAPI 2.0): objects of `object_type` holding an Agent (or
/// a Group) under `inner` and optional `relevantTypes`.
fn context_members(
    m: &Map<String, Value>,
    key: &str,
    object_type: &str,
    inner: &str,
    check: fn(&Value, &str) -> R,
    path: &str,
) -> R {
    let Some(list) = m.get(key) else {
        return Ok(());
    };
    let list = list
        .as_array()
        .ok_or_else(|| fault!("{path}.{key}: must be an array"))?;
    for (i, member) in list.iter().enumerate() {
        let p = format!("{path}.{key}[{i}]");
        let cm = obj(member, &p)?;
        only(cm, &["objectType", inner, "relevantTypes"], &p, object_type)?;
        if str_at(cm, "objectType", &p)? != Some(object_type) {
            return Err(fault!("{p}.objectType: must be \"{object_type}\""));
        }
        let value = cm
            .get(inner)
            .ok_or_else(|| fault!("{p}.{inner}: required"))?;
        check(value, &format!("{p}.{inner}"))?;
        relevant_types(cm, &p)?;
    }
    Ok(())
}

fn context(v: &Value, path: &str, object_is_activity: bool) -> R {
    let m = obj(v, path)?;
    only(
        m,
        &[
            "registration",
            "instructor",
            "team",
            "contextActivities",
            "contextAgents",
            "contextGroups",
            "revision",
            "platform",
            "language",
            "statement",
            "extensions",
        ],
        path,
        "a Context",
    )?;
    if let Some(r) = str_at(m, "registration", path)? {
        if !is_uuid(r) {
            return Err(fault!("{path}.registration: must be a UUID"));
        }
    }
    if let Some(i) = m.get("instructor") {
        agent_or_group(i, &format!("{path}.instructor"))?;
    }
    if let Some(t) = m.get("team") {
        group(t, &format!("{path}.team"))?;
    }
    if let Some(ca) = m.get("contextActivities") {
        let p = format!("{path}.contextActivities");
        let cm = obj(ca, &p)?;
        only(
            cm,
            &["parent", "grouping", "category", "other"],
            &p,
            "contextActivities",
        )?;
        for (key, list) in cm {
            activities(list, &format!("{p}.{key}"))?;
        }
    }
    context_members(m, "contextAgents", "contextAgent", "agent", agent, path)?;
    context_members(m, "contextGroups", "contextGroup", "group", group, path)?;
    for key in ["revision", "platform"] {
        if str_at(m, key, path)?.is_some() && !object_is_activity {
            return Err(fault!(
                "{path}.{key}: only allowed when the object is an Activity"
            ));
        }
    }
    if let Some(lang) = str_at(m, "language", path)? {
        if !is_language_tag(lang) {
            return Err(fault!("{path}.language: must be an RFC 5646 language tag"));
        }
    }
    if let Some(s) = m.get("statement") {
        statement_ref(s, &format!("{path}.statement"))?;
    }
    if let Some(x) = m.get("extensions") {
        extensions(x, &format!("{path}.extensions"))?;
    }
    Ok(())
}

fn attachments(v: &Value, path: &str) -> R {
    let list = v
        .as_array()
        .ok_or_else(|| fault!("{path}: must be an array of Attachments"))?;
    for (i, a) in list.iter().enumerate() {
        let p = format!("{path}[{i}]");
        let m = obj(a, &p)?;
        only(
            m,
            &[
                "usageType",
                "display",
                "description",
                "contentType",
                "length",
                "sha2",
                "fileUrl",
            ],
            &p,
            "an Attachment",
        )?;
        iri_at(m, "usageType", &p, true)?;
        language_map(
            m.get("display")
                .ok_or_else(|| fault!("{p}.display: required"))?,
            &format!("{p}.display"),
        )?;
        if let Some(d) = m.get("description") {
            language_map(d, &format!("{p}.description"))?;
        }
        match str_at(m, "contentType", &p)? {
            Some(ct)
                if ct.contains('/') && (ct.contains(';') || !ct.contains(char::is_whitespace)) => {}
            _ => {
                return Err(fault!("{p}.contentType: required, an Internet media type"));
            }
        }
        match m.get("length") {
            Some(Value::Number(n)) if n.as_u64().is_some() => {}
            _ => return Err(fault!("{p}.length: required, a whole number of octets")),
        }
        match str_at(m, "sha2", &p)? {
            Some(h)
                if (h.len() == 64 || h.len() == 96 || h.len() == 128 || h.len() == 56)
                    && h.bytes().all(|b| b.is_ascii_hexdigit()) => {}
            _ => return Err(fault!("{p}.sha2: required, the hex SHA-2 of the content")),
        }
        iri_at(m, "fileUrl", &p, false)?;
    }
    Ok(())
}

/// Validates the object of a statement (`sub`: of a SubStatement, which may not nest another).
fn object(v: &Value, path: &str, sub: bool) -> R {
    obj(v, path)?;
    match v.get("objectType").map(|t| t.as_str()) {
        None | Some(Some("Activity")) => activity(v, path),
        Some(Some("Agent")) => agent(v, path),
        Some(Some("Group")) => group(v, path),
        Some(Some("StatementRef")) => statement_ref(v, path),
        Some(Some("SubStatement")) if sub => {
            Err(fault!("{path}: a SubStatement cannot hold a SubStatement"))
        }
        Some(Some("SubStatement")) => sub_statement(v, path),
        _ => Err(fault!(
            "{path}.objectType: one of Activity, Agent, Group, StatementRef, SubStatement"
        )),
    }
}

fn sub_statement(v: &Value, path: &str) -> R {
    let m = obj(v, path)?;
    only(
        m,
        &[
            "objectType",
            "actor",
            "verb",
            "object",
            "result",
            "context",
            "timestamp",
            "attachments",
        ],
        path,
        "a SubStatement",
    )?;
    core(m, path, true)
}

/// The properties statements and SubStatements share.
fn core(m: &Map<String, Value>, path: &str, sub: bool) -> R {
    let p = |k: &str| {
        if path.is_empty() {
            k.to_owned()
        } else {
            format!("{path}.{k}")
        }
    };
    agent_or_group(
        m.get("actor")
            .ok_or_else(|| fault!("{}: required", p("actor")))?,
        &p("actor"),
    )?;
    verb(
        m.get("verb")
            .ok_or_else(|| fault!("{}: required", p("verb")))?,
        &p("verb"),
    )?;
    let o = m
        .get("object")
        .ok_or_else(|| fault!("{}: required", p("object")))?;
    object(o, &p("object"), sub)?;
    let is_activity = matches!(
        o.get("objectType").and_then(Value::as_str),
        None | Some("Activity")
    );
    if let Some(r) = m.get("result") {
        result(r, &p("result"))?;
    }
    if let Some(c) = m.get("context") {
        context(c, &p("context"), is_activity)?;
    }
    if let Some(t) = str_at(m, "timestamp", path)? {
        if !is_timestamp(t) {
            return Err(fault!(
                "{}: must be an ISO 8601 timestamp with date and time",
                p("timestamp")
            ));
        }
    } else if m.contains_key("timestamp") {
        return Err(fault!("{}: must be a string", p("timestamp")));
    }
    if let Some(a) = m.get("attachments") {
        attachments(a, &p("attachments"))?;
    }
    if m.get("verb")
        .and_then(|v| v.get("id"))
        .and_then(Value::as_str)
        == Some(VOIDED_VERB)
        && o.get("objectType").and_then(Value::as_str) != Some("StatementRef")
    {
        return Err(fault!(
            "{}: a voiding statement's object must be a StatementRef",
            p("object")
        ));
    }
    Ok(())
}

/// Validates one statement as a client sends it.
pub fn statement(v: &Value) -> Result<(), Invalid> {
    let m = v.as_object().ok_or("a statement must be a JSON object")?;
    for (key, value) in m {
        if !matches!(
            key.as_str(),
            "id" | "actor"
                | "verb"
                | "object"
                | "result"
                | "context"
                | "timestamp"
                | "stored"
                | "authority"
                | "version"
                | "attachments"
        ) {
            return Err(fault!("{key}: not a property of a Statement"));
        }
        if value.is_null() {
            return Err(fault!("{key}: must not be null"));
        }
    }
    if let Some(id) = m.get("id") {
        if !id.as_str().is_some_and(is_uuid) {
            return Err("id: must be a UUID".into());
        }
    }
    core(m, "", false)?;
    if let Some(s) = m.get("stored") {
        if !s.as_str().is_some_and(is_timestamp) {
            return Err("stored: must be an ISO 8601 timestamp".into());
        }
    }
    if let Some(a) = m.get("authority") {
        agent_or_group(a, "authority")?;
        if a.get("objectType").and_then(Value::as_str) == Some("Group") {
            // Data 2.4.9: a Group authority is the anonymous pair of an OAuth consumer and a user.
            let members = a
                .get("member")
                .and_then(Value::as_array)
                .map_or(0, Vec::len);
            let identified = super::agent::IFI_PROPERTIES
                .iter()
                .any(|k| a.get(*k).is_some());
            if members != 2 || identified {
                return Err(
                    "authority: a Group authority is anonymous with exactly two Agents \
                    (OAuth consumer and user)"
                        .into(),
                );
            }
        }
    }
    if let Some(version) = m.get("version") {
        let ok = version.as_str().is_some_and(|s| {
            let parts: Vec<&str> = s.split('.').collect();
            (parts.len() == 2 || parts.len() == 3 && digits(parts[2]))
                && matches!(parts[0], "1" | "2")
                && parts[1] == "0"
        });
        if !ok {
            return Err("version: must be 1.0, 1.0.x, 2.0 or 2.0.x".into());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The message of a statement's first fault.
    fn fault_of(s: &Value) -> String {
        statement(s).unwrap_err().0
    }
    use serde_json::json;

    fn base() -> Value {
        json!({
            "actor": {"mbox": "mailto:learner@example.org", "name": "L"},
            "verb": {"id": "http://adlnet.gov/expapi/verbs/experienced", "display": {"en-US": "experienced"}},
            "object": {"id": "http://example.org/activities/station/l4", "definition": {"name": {"en": "L4"}}},
        })
    }

    fn with(path: &[&str], value: Value) -> Value {
        let mut s = base();
        let mut cur = &mut s;
        for key in &path[..path.len() - 1] {
            cur = cur
                .as_object_mut()
                .unwrap()
                .entry(key.to_string())
                .or_insert(json!({}));
        }
        cur.as_object_mut()
            .unwrap()
            .insert(path[path.len() - 1].to_string(), value);
        s
    }

    #[test]
    fn a_minimal_statement_and_full_one_pass() {
        assert_eq!(statement(&base()), Ok(()));
        let full = json!({
            "id": "fd41c918-b88b-4b20-a0a5-a4c32391aaa0",
            "actor": {"objectType": "Group", "name": "team", "member": [{"openid": "http://openid.example.org/a"}]},
            "verb": {"id": "http://adlnet.gov/expapi/verbs/scored"},
            "object": {"objectType": "SubStatement",
                "actor": {"account": {"homePage": "http://lms.example.org", "name": "7"}},
                "verb": {"id": "http://adlnet.gov/expapi/verbs/answered"},
                "object": {"id": "http://example.org/q1", "definition": {
                    "interactionType": "choice", "correctResponsesPattern": ["a[,]b"],
                    "choices": [{"id": "a", "description": {"en": "A"}}, {"id": "b"}]}},
                "timestamp": "2026-11-27T05:00:00Z"},
            "result": {"score": {"scaled": 0.5, "raw": 5, "min": 0, "max": 10}, "success": true,
                "completion": true, "duration": "PT1M30.5S", "extensions": {"http://example.org/x": null}},
            "context": {"registration": "ec531277-b57b-4c15-8d91-d292c5b2b8f7",
                "contextActivities": {"parent": {"id": "http://example.org/p"}, "category": [{"id": "http://example.org/c"}]},
                "contextAgents": [{"objectType": "contextAgent", "agent": {"mbox": "mailto:f@example.org"}, "relevantTypes": ["http://example.org/faculty"]}],
                "language": "en-GB", "statement": {"objectType": "StatementRef", "id": "fd41c918-b88b-4b20-a0a5-a4c32391aaa1"}},
            "timestamp": "2026-11-27T05:32:34.804+01:00",
            "version": "2.0.0",
            "attachments": [{"usageType": "http://adlnet.gov/expapi/attachments/signature",
                "display": {"en": "sig"}, "contentType": "application/octet-stream", "length": 10,
                "sha2": "672fa5fa658017f1b72d65036f13379c6ab05d4ab3b6664908d8acf0b6a0c634"}]
        });
        assert_eq!(statement(&full), Ok(()));
    }

    #[test]
    fn each_broken_rule_is_refused_naming_the_property() {
        let cases = [
            (with(&["id"], json!("not-a-uuid")), "id"),
            (with(&["actor"], json!({"name": "no ifi"})), "actor"),
            (with(&["verb"], json!({"id": "experienced"})), "verb.id"),
            (
                with(&["verb", "display"], json!({"en_US": "x"})),
                "verb.display",
            ),
            (with(&["object", "id"], json!("station")), "object.id"),
            (
                with(&["object", "objectType"], json!("activity")),
                "object.objectType",
            ),
            (
                with(&["result", "score"], json!({"scaled": 1.5})),
                "result.score.scaled",
            ),
            (
                with(
                    &["result", "score"],
                    json!({"raw": 11, "min": 0, "max": 10}),
                ),
                "result.score.raw",
            ),
            (
                with(&["result", "score"], json!({"min": 5, "max": 5})),
                "result.score.min",
            ),
            (
                with(&["result", "duration"], json!("1 hour")),
                "result.duration",
            ),
            (with(&["result", "success"], json!("yes")), "result.success"),
            (
                with(&["context", "registration"], json!("x")),
                "context.registration",
            ),
            (
                with(&["context", "language"], json!("english!")),
                "context.language",
            ),
            (
                with(&["context", "contextActivities"], json!({"parents": []})),
                "context.contextActivities.parents",
            ),
            (
                with(&["context", "extensions"], json!({"color": "red"})),
                "context.extensions",
            ),
            (
                with(&["timestamp"], json!("2026-13-01T00:00:00Z")),
                "timestamp",
            ),
            (
                with(&["timestamp"], json!("2026-11-27T05:32:34-00:00")),
                "timestamp",
            ),
            (with(&["timestamp"], json!("2026-11-27")), "timestamp"),
            (with(&["version"], json!("3.0.0")), "version"),
            (with(&["version"], json!("1.0.")), "version"),
            (with(&["Actor"], json!({})), "Actor"),
            (with(&["result"], json!(null)), "result"),
            (with(&["verb", "id"], json!(VOIDED_VERB)), "object"),
            (
                with(
                    &["attachments"],
                    json!([{"usageType": "http://x.org/u", "display": {"en": "a"}, "contentType": "text/plain", "length": -1, "sha2": "00"}]),
                ),
                "attachments[0].length",
            ),
        ];
        for (s, path) in cases {
            let e = statement(&s).expect_err(&s.to_string());
            assert!(e.0.starts_with(path), "{path}: {e}");
        }
        let mut s = base();
        s["object"] = json!({"objectType": "Agent", "mbox": "mailto:a@example.org"});
        s["context"] = json!({"platform": "web"});
        assert!(fault_of(&s).starts_with("context.platform"));
        let mut sub = base();
        sub["object"] = json!({"objectType": "SubStatement", "actor": base()["actor"], "verb": base()["verb"],
            "object": {"objectType": "SubStatement"}});
        assert!(fault_of(&sub).contains("cannot hold a SubStatement"));
        let mut sub_id = base();
        sub_id["object"] = json!({"objectType": "SubStatement", "id": "fd41c918-b88b-4b20-a0a5-a4c32391aaa0",
            "actor": base()["actor"], "verb": base()["verb"], "object": base()["object"]});
        assert!(fault_of(&sub_id).starts_with("object.id"));
        let mut likert = base();
        likert["object"]["definition"] =
            json!({"interactionType": "likert", "choices": [{"id": "a"}]});
        assert!(fault_of(&likert).contains("not allowed for interactionType likert"));
        let pair =
            json!([{"mbox": "mailto:consumer@example.org"}, {"mbox": "mailto:user@example.org"}]);
        let mut authority = base();
        authority["authority"] = json!({"objectType": "Group", "member": pair});
        assert_eq!(statement(&authority), Ok(()));
        authority["authority"]["mbox"] = json!("mailto:group@example.org");
        assert!(fault_of(&authority).starts_with("authority"));
        let mut version = base();
        version["version"] = json!("1.0");
        assert_eq!(statement(&version), Ok(()));
    }

    #[test]
    fn timestamps_and_durations() {
        for ok in [
            "2026-11-27T05:32:34Z",
            "2026-11-27T05:32:34.123456+05:30",
            "2026-11-27T05:32Z",
            "2026-11-27T05:32:34+0100",
            "2026-11-27T05:32:34",
        ] {
            assert!(is_timestamp(ok), "{ok}");
        }
        for bad in [
            "2026-11-27",
            "2026-11-27T25:00:00Z",
            "27/11/2026T05:00:00Z",
            "2026-11-27T05:32:34+1",
            "2026-11-27T05:32:34-00:00",
            "2026-11-27T05:32.5Z",
        ] {
            assert!(!is_timestamp(bad), "{bad}");
        }
        for ok in ["PT1H30M", "P1DT2.5S", "P3W", "P1Y2M3DT4H5M6S", "PT0S"] {
            assert!(is_duration(ok), "{ok}");
        }
        for bad in [
            "P", "PT", "1H", "PT1.5M", "P1DT", "PT1S2M", "P1H", "P4W1D", "P1WT1H",
        ] {
            assert!(!is_duration(bad), "{bad}");
        }
    }
}
