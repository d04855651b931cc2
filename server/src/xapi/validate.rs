//! TEMP placeholder (the lead's `validate.rs` replaces it at merge): the data model of one
//! statement. Only the shape the Statement resource relies on is checked here.

use serde_json::Value;

/// Checks one statement as a client sends it; the message names the property path.
pub fn statement(v: &Value) -> Result<(), String> {
    let Some(o) = v.as_object() else {
        return Err("statement: must be an object".into());
    };
    const KNOWN: [&str; 12] = [
        "id",
        "actor",
        "verb",
        "object",
        "result",
        "context",
        "timestamp",
        "stored",
        "authority",
        "version",
        "attachments",
        "objectType",
    ];
    if let Some(k) = o.keys().find(|k| !KNOWN.contains(&k.as_str())) {
        return Err(format!("{k}: not a statement property"));
    }
    for key in ["actor", "verb", "object"] {
        if !o.get(key).is_some_and(Value::is_object) {
            return Err(format!("{key}: required object"));
        }
    }
    if !v["verb"]["id"].is_string() {
        return Err("verb.id: required IRI".into());
    }
    if let Some(id) = o.get("id")
        && !id
            .as_str()
            .is_some_and(|s| uuid::Uuid::parse_str(s).is_ok())
    {
        return Err("id: must be a UUID".into());
    }
    Ok(())
}
