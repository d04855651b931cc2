//! The filter keys of a statement (see `migrations/0802_xapi_statements.sql`): what the query
//! parameters `agent` (`a:`; with `related_agents`, `A:`), `verb` (`v:`), `activity` (`o:`; with
//! `related_activities`, `O:`) and `registration` (`r:`) match.

use serde_json::Value;

use crate::xapi::agent::ifi_key;

/// The key of an Agent or identified Group: its objectType and identifier (xAPI 2.0: Agents and
/// identified Groups are equal when they have the same identifier and the same objectType).
/// `None` for an anonymous Group or anything that is no Agent/Group.
pub fn agent_key(v: &Value) -> Option<String> {
    let kind = match v["objectType"].as_str() {
        None | Some("Agent") => "Agent",
        Some("Group") => "Group",
        Some(_) => return None,
    };
    ifi_key(v).ok().map(|k| format!("{kind}|{k}"))
}

fn is_agent(v: &Value) -> bool {
    matches!(v["objectType"].as_str(), Some("Agent") | Some("Group"))
}

fn is_activity(v: &Value) -> bool {
    v.is_object() && matches!(v["objectType"].as_str(), None | Some("Activity"))
}

/// Calls `f` on every element of a value that is one object or a list of them.
fn each<'a>(v: &'a Value, f: &mut dyn FnMut(&'a Value)) {
    match v {
        Value::Array(a) => a.iter().for_each(f),
        Value::Object(_) => f(v),
        _ => {}
    }
}

/// Every Agent/Group a statement (or SubStatement) names beyond its actor and object: the
/// context's instructor and team, 2.0's contextAgents and contextGroups, and `authority`.
fn context_agents<'a>(s: &'a Value, f: &mut dyn FnMut(&'a Value)) {
    let c = &s["context"];
    each(&c["instructor"], f);
    each(&c["team"], f);
    each(&c["contextAgents"], &mut |ca| each(&ca["agent"], f));
    each(&c["contextGroups"], &mut |cg| each(&cg["group"], f));
    each(&s["authority"], f);
}

/// Calls `f` on every activity of a statement: its object, its context activities and those of
/// a SubStatement object.
pub fn for_each_activity<'a>(s: &'a Value, f: &mut dyn FnMut(&'a Value)) {
    let one = |st: &'a Value, f: &mut dyn FnMut(&'a Value)| {
        if is_activity(&st["object"]) {
            f(&st["object"]);
        }
        let ca = &st["context"]["contextActivities"];
        for k in ["parent", "grouping", "category", "other"] {
            each(&ca[k], f);
        }
    };
    one(s, f);
    if s["object"]["objectType"].as_str() == Some("SubStatement") {
        one(&s["object"], f);
    }
}

/// The keys of a statement as stored.
pub fn statement_keys(s: &Value) -> Vec<String> {
    let mut keys = Vec::new();
    let mut related = Vec::new();
    let mut add_agent = |v: &Value, direct: bool, keys: &mut Vec<String>| {
        let mut with_members = vec![v];
        if let Some(m) = v["member"].as_array() {
            with_members.extend(m);
        }
        for (i, a) in with_members.into_iter().enumerate() {
            if let Some(k) = agent_key(a) {
                if direct && i == 0 {
                    keys.push(format!("a:{k}"));
                }
                related.push(format!("A:{k}"));
            }
        }
    };
    add_agent(&s["actor"], true, &mut keys);
    if is_agent(&s["object"]) {
        add_agent(&s["object"], true, &mut keys);
    }
    let mut ctx = Vec::new();
    context_agents(s, &mut |a| ctx.push(a));
    let sub = &s["object"];
    if sub["objectType"].as_str() == Some("SubStatement") {
        ctx.push(&sub["actor"]);
        if is_agent(&sub["object"]) {
            ctx.push(&sub["object"]);
        }
        context_agents(sub, &mut |a| ctx.push(a));
    }
    for a in ctx {
        add_agent(a, false, &mut keys);
    }
    keys.append(&mut related);
    if let Some(v) = s["verb"]["id"].as_str() {
        keys.push(format!("v:{v}"));
    }
    if is_activity(&s["object"])
        && let Some(id) = s["object"]["id"].as_str()
    {
        keys.push(format!("o:{id}"));
    }
    for_each_activity(s, &mut |a| {
        if let Some(id) = a["id"].as_str() {
            keys.push(format!("O:{id}"));
        }
    });
    if let Some(r) = s["context"]["registration"].as_str()
        && let Ok(u) = uuid::Uuid::parse_str(r)
    {
        keys.push(format!("r:{u}"));
    }
    keys.sort();
    keys.dedup();
    keys
}
