//! TEMP placeholder (the lead's `agent.rs` replaces it at merge): the identity of an Agent or
//! Group.

use serde_json::Value;

/// The canonical identity key of an Agent/Group's inverse functional identifier.
pub fn ifi_key(v: &Value) -> Result<String, String> {
    if let Some(m) = v.get("mbox").and_then(Value::as_str) {
        return Ok(format!("mbox:{m}"));
    }
    if let Some(m) = v.get("mbox_sha1sum").and_then(Value::as_str) {
        return Ok(format!("mbox_sha1sum:{m}"));
    }
    if let Some(m) = v.get("openid").and_then(Value::as_str) {
        return Ok(format!("openid:{m}"));
    }
    if let Some(a) = v.get("account") {
        let (Some(h), Some(n)) = (a["homePage"].as_str(), a["name"].as_str()) else {
            return Err("account: needs homePage and name".into());
        };
        return Ok(format!("account:{h} {n}"));
    }
    Err("an Agent or identified Group needs an inverse functional identifier".into())
}

/// Parses an `agent=` query parameter (a JSON Agent or Group).
pub fn parse_agent_param(s: &str) -> Result<Value, String> {
    let v: Value = serde_json::from_str(s).map_err(|e| format!("agent: not JSON: {e}"))?;
    if !v.is_object() {
        return Err("agent: must be a JSON object".into());
    }
    ifi_key(&v)?;
    Ok(v)
}
