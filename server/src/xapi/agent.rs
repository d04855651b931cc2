//! TEMP placeholder (the lead's `agent.rs` replaces it at merge): the identity of an Agent or
//! identified Group, and the `agent=` query parameter.

use serde_json::Value;

/// The canonical identity key of an Agent/Group's inverse functional identifier, e.g.
/// `mbox:mailto:a@b`, `mbox_sha1sum:<hex>`, `openid:<uri>`, `account:<homePage> <name>`.
pub fn ifi_key(v: &Value) -> Result<String, String> {
    let obj = v.as_object().ok_or("an Agent must be a JSON object")?;
    let mut keys = Vec::new();
    if let Some(m) = obj.get("mbox") {
        let m = m.as_str().ok_or("mbox: must be a string")?;
        if !m.starts_with("mailto:") || m.len() <= "mailto:".len() {
            return Err("mbox: must be a mailto: IRI".into());
        }
        keys.push(format!("mbox:{m}"));
    }
    if let Some(m) = obj.get("mbox_sha1sum") {
        let m = m.as_str().ok_or("mbox_sha1sum: must be a string")?;
        if m.len() != 40 || !m.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err("mbox_sha1sum: must be 40 hexadecimal digits".into());
        }
        keys.push(format!("mbox_sha1sum:{}", m.to_ascii_lowercase()));
    }
    if let Some(m) = obj.get("openid") {
        let m = m.as_str().ok_or("openid: must be a string")?;
        if !m.contains(':') {
            return Err("openid: must be a URI".into());
        }
        keys.push(format!("openid:{m}"));
    }
    if let Some(a) = obj.get("account") {
        let (Some(h), Some(n)) = (
            a.get("homePage").and_then(Value::as_str),
            a.get("name").and_then(Value::as_str),
        ) else {
            return Err("account: needs homePage and name (strings)".into());
        };
        if !h.contains(':') {
            return Err("account.homePage: must be an IRL".into());
        }
        keys.push(format!("account:{h} {n}"));
    }
    match keys.len() {
        1 => Ok(keys.remove(0)),
        0 => Err("an Agent or identified Group needs an inverse functional identifier".into()),
        _ => Err("an Agent has exactly one inverse functional identifier".into()),
    }
}

/// Parses and validates an `agent=` query parameter (a JSON Agent or identified Group).
pub fn parse_agent_param(raw: &str) -> Result<Value, String> {
    let v: Value = serde_json::from_str(raw).map_err(|e| format!("agent: not JSON: {e}"))?;
    let obj = v.as_object().ok_or("agent: must be a JSON object")?;
    match obj.get("objectType") {
        None => {}
        Some(Value::String(t)) if t == "Agent" || t == "Group" => {}
        Some(_) => return Err("agent: objectType must be Agent or Group".into()),
    }
    if let Some(name) = obj.get("name")
        && !name.is_string()
    {
        return Err("agent: name must be a string".into());
    }
    ifi_key(&v).map_err(|e| format!("agent: {e}"))?;
    Ok(v)
}
