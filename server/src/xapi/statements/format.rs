//! The `format` parameter of GET statements (xAPI 2.0, Communication 2.1.3): `exact` returns the
//! statement as stored; `ids` keeps only what identifies Agents, Groups, Activities and Verbs;
//! `canonical` replaces each activity's definition with the LRS's latest one and keeps one
//! language of every language map, chosen by the request's `Accept-Language`.

use std::collections::HashMap;

use serde_json::{Map, Value};

/// The three formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// As stored.
    Exact,
    /// Identifiers only.
    Ids,
    /// Canonical definitions, one language.
    Canonical,
}

impl Format {
    /// Parses the parameter.
    pub fn parse(s: &str) -> Option<Format> {
        match s {
            "exact" => Some(Format::Exact),
            "ids" => Some(Format::Ids),
            "canonical" => Some(Format::Canonical),
            _ => None,
        }
    }
}

const IFIS: [&str; 4] = ["mbox", "mbox_sha1sum", "openid", "account"];

fn agent_ids(a: &Value) -> Value {
    let Some(o) = a.as_object() else {
        return a.clone();
    };
    let mut out = Map::new();
    if let Some(t) = o.get("objectType") {
        out.insert("objectType".into(), t.clone());
    }
    let mut identified = false;
    for k in IFIS {
        if let Some(v) = o.get(k) {
            out.insert(k.into(), v.clone());
            identified = true;
        }
    }
    if !identified && let Some(Value::Array(m)) = o.get("member") {
        out.insert(
            "member".into(),
            Value::Array(m.iter().map(agent_ids).collect()),
        );
    }
    Value::Object(out)
}

/// An Activity (or a Verb) as its identifier alone: `objectType` "Activity" is the default and
/// says nothing more (the conformance suite expects `{id}` only).
fn activity_ids(a: &Value) -> Value {
    let mut out = Map::new();
    for k in ["id"] {
        if let Some(v) = a.get(k) {
            out.insert(k.into(), v.clone());
        }
    }
    Value::Object(out)
}

fn map_list(v: &mut Value, f: &dyn Fn(&Value) -> Value) {
    match v {
        Value::Array(a) => a.iter_mut().for_each(|x| *x = f(x)),
        Value::Object(_) => *v = f(v),
        _ => {}
    }
}

/// The `ids` form of a statement (or SubStatement).
pub fn ids(s: &mut Value) {
    let Some(o) = s.as_object_mut() else { return };
    for k in ["actor", "authority"] {
        if let Some(a) = o.get_mut(k) {
            *a = agent_ids(a);
        }
    }
    if let Some(v) = o.get_mut("verb") {
        *v = activity_ids(v);
    }
    if let Some(obj) = o.get_mut("object") {
        match obj["objectType"].as_str() {
            None | Some("Activity") => *obj = activity_ids(obj),
            Some("Agent") | Some("Group") => *obj = agent_ids(obj),
            Some("SubStatement") => ids(obj),
            _ => {}
        }
    }
    if let Some(c) = o.get_mut("context").and_then(Value::as_object_mut) {
        for k in ["instructor", "team"] {
            if let Some(a) = c.get_mut(k) {
                *a = agent_ids(a);
            }
        }
        for (list, key) in [("contextAgents", "agent"), ("contextGroups", "group")] {
            if let Some(Value::Array(items)) = c.get_mut(list) {
                for it in items {
                    if let Some(a) = it.get_mut(key) {
                        *a = agent_ids(a);
                    }
                }
            }
        }
        if let Some(ca) = c
            .get_mut("contextActivities")
            .and_then(Value::as_object_mut)
        {
            for (_, v) in ca.iter_mut() {
                map_list(v, &activity_ids);
            }
        }
    }
}

/// Language ranges of an `Accept-Language` header, best first.
pub fn accept_languages(header: &str) -> Vec<String> {
    let mut ranges: Vec<(f32, usize, String)> = header
        .split(',')
        .enumerate()
        .filter_map(|(i, r)| {
            let mut it = r.split(';');
            let tag = it.next()?.trim().to_ascii_lowercase();
            let q = it
                .find_map(|p| p.trim().strip_prefix("q="))
                .and_then(|q| q.trim().parse::<f32>().ok())
                .unwrap_or(1.0);
            (!tag.is_empty() && q > 0.0).then_some((q, i, tag))
        })
        .collect();
    ranges.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    ranges.into_iter().map(|(_, _, t)| t).collect()
}

/// Keeps one entry of a language map: the first accepted language (exact, then by prefix), else
/// `und`, else the first entry.
fn pick(map: &mut Value, langs: &[String]) {
    let Some(m) = map.as_object() else { return };
    if m.len() <= 1 {
        return;
    }
    let lower: Vec<(String, &String)> = m.keys().map(|k| (k.to_ascii_lowercase(), k)).collect();
    let chosen = langs
        .iter()
        .find_map(|l| {
            lower.iter().find(|(k, _)| k == l).or_else(|| {
                lower.iter().find(|(k, _)| {
                    l == "*" || k.starts_with(&format!("{l}-")) || l.starts_with(&format!("{k}-"))
                })
            })
        })
        .or_else(|| lower.iter().find(|(k, _)| k == "und"))
        .or_else(|| lower.first())
        .map(|(_, k)| (*k).clone());
    if let Some(k) = chosen {
        let v = m[&k].clone();
        let mut one = Map::new();
        one.insert(k, v);
        *map = Value::Object(one);
    }
}

fn definition_languages(d: &mut Value, langs: &[String]) {
    for k in ["name", "description"] {
        if let Some(m) = d.get_mut(k) {
            pick(m, langs);
        }
    }
    for k in ["choices", "scale", "source", "target", "steps"] {
        if let Some(Value::Array(items)) = d.get_mut(k) {
            for it in items {
                if let Some(m) = it.get_mut("description") {
                    pick(m, langs);
                }
            }
        }
    }
}

/// The `canonical` form: `definitions` holds the LRS's definition of each activity id.
pub fn canonical(s: &mut Value, langs: &[String], definitions: &HashMap<String, Value>) {
    let mut fix = |a: &mut Value| {
        let id = a["id"].as_str().map(str::to_owned);
        if let Some(d) = id.and_then(|id| definitions.get(&id))
            && let Some(o) = a.as_object_mut()
        {
            o.insert("definition".into(), d.clone());
        }
        if let Some(d) = a.get_mut("definition") {
            definition_languages(d, langs);
        }
    };
    for_each_activity_mut(s, &mut fix);
    if let Some(d) = s.get_mut("verb").and_then(|v| v.get_mut("display")) {
        pick(d, langs);
    }
    if let Some(Value::Array(atts)) = s.get_mut("attachments") {
        for a in atts {
            for k in ["display", "description"] {
                if let Some(m) = a.get_mut(k) {
                    pick(m, langs);
                }
            }
        }
    }
    if s["object"]["objectType"].as_str() == Some("SubStatement")
        && let Some(d) = s["object"]
            .get_mut("verb")
            .and_then(|v| v.get_mut("display"))
    {
        pick(d, langs);
    }
}

fn for_each_activity_mut(s: &mut Value, f: &mut dyn FnMut(&mut Value)) {
    fn one(st: &mut Value, f: &mut dyn FnMut(&mut Value)) {
        if let Some(obj) = st.get_mut("object") {
            if matches!(obj["objectType"].as_str(), None | Some("Activity")) && obj.is_object() {
                f(obj);
            }
        }
        if let Some(ca) = st
            .get_mut("context")
            .and_then(|c| c.get_mut("contextActivities"))
            .and_then(Value::as_object_mut)
        {
            for (_, v) in ca.iter_mut() {
                match v {
                    Value::Array(a) => a.iter_mut().for_each(&mut *f),
                    Value::Object(_) => f(v),
                    _ => {}
                }
            }
        }
    }
    one(s, f);
    if s["object"]["objectType"].as_str() == Some("SubStatement")
        && let Some(sub) = s.get_mut("object")
    {
        one(sub, f);
    }
}

/// Every activity id of a statement (to load their canonical definitions).
pub fn activity_ids_of(s: &Value, out: &mut Vec<String>) {
    super::keys::for_each_activity(s, &mut |a| {
        if let Some(id) = a["id"].as_str() {
            out.push(id.to_owned());
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn languages() {
        let l = accept_languages("fr;q=0.5, en-GB, de;q=0.9");
        assert_eq!(l, ["en-gb", "de", "fr"]);
        let mut m = json!({ "en-US": "a", "fr-FR": "b" });
        pick(&mut m, &["fr".into()]);
        assert_eq!(m, json!({ "fr-FR": "b" }));
    }

    #[test]
    fn ids_form() {
        let mut s = json!({
            "actor": { "name": "A", "mbox": "mailto:a@example.org" },
            "verb": { "id": "http://example.org/v", "display": { "en": "v" } },
            "object": { "id": "http://example.org/x", "definition": { "name": { "en": "x" } } }
        });
        ids(&mut s);
        assert_eq!(s["actor"], json!({ "mbox": "mailto:a@example.org" }));
        assert_eq!(s["verb"], json!({ "id": "http://example.org/v" }));
        assert_eq!(s["object"], json!({ "id": "http://example.org/x" }));
    }
}
