//! Agents and Groups of the xAPI 2.0 data model (IEEE 9274.1.1, Data 2.4.2.1-2.4.2.3): their
//! validation, the canonical key of their Inverse Functional Identifier (IFI), and the `agent`
//! query parameter of the LRS resources.
//!
//! An Agent is identified by exactly one IFI: `mbox` (a `mailto:` IRI), `mbox_sha1sum` (the hex
//! SHA-1 of the mbox), `openid` (a URI) or `account` (`homePage` IRL + `name`). Two agents with the
//! same IFI are the same agent whatever else they say (a `name` is not an identifier), so the LRS
//! indexes and compares agents by [`ifi_key`].

use serde_json::{Map, Value};

use super::error::{Invalid, fault};

/// The property names of an IFI.
pub const IFI_PROPERTIES: [&str; 4] = ["mbox", "mbox_sha1sum", "openid", "account"];

/// True for an absolute IRI: a scheme (RFC 3987: a letter, then letters, digits, `+ - .`), a
/// colon and a non-empty rest without whitespace or characters IRIs exclude.
pub fn is_iri(s: &str) -> bool {
    let Some((scheme, rest)) = s.split_once(':') else {
        return false;
    };
    let mut chars = scheme.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
        && !rest.is_empty()
        && !s.chars().any(|c| {
            c.is_whitespace()
                || c.is_control()
                || matches!(c, '<' | '>' | '"' | '{' | '}' | '|' | '\\' | '^' | '`')
        })
}

/// True for a `mailto:` IRI with one `@` between a non-empty local part and domain.
pub fn is_mailto(s: &str) -> bool {
    let Some(addr) = s.strip_prefix("mailto:") else {
        return false;
    };
    let Some((local, domain)) = addr.split_once('@') else {
        return false;
    };
    is_iri(s) && !local.is_empty() && !domain.is_empty() && !domain.contains('@')
}

fn object<'a>(v: &'a Value, path: &str) -> Result<&'a Map<String, Value>, Invalid> {
    v.as_object()
        .ok_or_else(|| fault!("{path}: must be a JSON object"))
}

fn string<'a>(
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

/// Checks the IFI properties of an Agent or identified Group `m`; returns how many it has.
fn check_ifis(m: &Map<String, Value>, path: &str) -> Result<usize, Invalid> {
    let mut count = 0;
    if let Some(mbox) = string(m, "mbox", path)? {
        if !is_mailto(mbox) {
            return Err(fault!(
                "{path}.mbox: must be a mailto: IRI, e.g. mailto:a@example.org"
            ));
        }
        count += 1;
    }
    if let Some(sum) = string(m, "mbox_sha1sum", path)? {
        if sum.len() != 40 || !sum.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(fault!(
                "{path}.mbox_sha1sum: must be 40 hexadecimal digits (SHA-1)"
            ));
        }
        count += 1;
    }
    if let Some(openid) = string(m, "openid", path)? {
        if !is_iri(openid) {
            return Err(fault!("{path}.openid: must be a URI"));
        }
        count += 1;
    }
    if let Some(account) = m.get("account") {
        let a = object(account, &format!("{path}.account"))?;
        for key in a.keys() {
            if key != "homePage" && key != "name" {
                return Err(fault!("{path}.account.{key}: not a property of an Account"));
            }
        }
        match a.get("homePage") {
            Some(Value::String(h)) if is_iri(h) => {}
            _ => return Err(fault!("{path}.account.homePage: required, an IRL")),
        }
        match a.get("name") {
            Some(Value::String(_)) => {}
            _ => return Err(fault!("{path}.account.name: required, a string")),
        }
        count += 1;
    }
    Ok(count)
}

/// Validates an Agent (`objectType` absent or `"Agent"`), at `path` in the statement.
pub fn agent(v: &Value, path: &str) -> Result<(), Invalid> {
    let m = object(v, path)?;
    for key in m.keys() {
        if !matches!(
            key.as_str(),
            "objectType" | "name" | "mbox" | "mbox_sha1sum" | "openid" | "account"
        ) {
            return Err(fault!("{path}.{key}: not a property of an Agent"));
        }
    }
    match m.get("objectType") {
        None => {}
        Some(Value::String(t)) if t == "Agent" => {}
        Some(_) => return Err(fault!("{path}.objectType: must be \"Agent\"")),
    }
    string(m, "name", path)?;
    match check_ifis(m, path)? {
        1 => Ok(()),
        0 => Err(fault!(
            "{path}: an Agent needs exactly one of mbox, mbox_sha1sum, openid, account"
        )),
        _ => Err(fault!(
            "{path}: an Agent must have only one of mbox, mbox_sha1sum, openid, account"
        )),
    }
}

/// Validates a Group (`objectType` `"Group"`): anonymous (members, no IFI) or identified (one IFI,
/// members optional). Members are Agents, never Groups.
pub fn group(v: &Value, path: &str) -> Result<(), Invalid> {
    let m = object(v, path)?;
    for key in m.keys() {
        if !matches!(
            key.as_str(),
            "objectType" | "name" | "member" | "mbox" | "mbox_sha1sum" | "openid" | "account"
        ) {
            return Err(fault!("{path}.{key}: not a property of a Group"));
        }
    }
    if m.get("objectType") != Some(&Value::String("Group".into())) {
        return Err(fault!(
            "{path}.objectType: a Group needs objectType \"Group\""
        ));
    }
    string(m, "name", path)?;
    let ifis = check_ifis(m, path)?;
    if ifis > 1 {
        return Err(fault!(
            "{path}: a Group must have at most one of mbox, mbox_sha1sum, openid, account"
        ));
    }
    match m.get("member") {
        None if ifis == 0 => Err(fault!(
            "{path}.member: an anonymous Group needs its members"
        )),
        None => Ok(()),
        Some(Value::Array(members)) => {
            if ifis == 0 && members.is_empty() {
                return Err(fault!(
                    "{path}.member: an anonymous Group needs at least one member"
                ));
            }
            for (i, member) in members.iter().enumerate() {
                agent(member, &format!("{path}.member[{i}]"))?;
            }
            Ok(())
        }
        Some(_) => Err(fault!("{path}.member: must be an array of Agents")),
    }
}

/// Validates an Agent or a Group, told apart by `objectType`.
pub fn agent_or_group(v: &Value, path: &str) -> Result<(), Invalid> {
    if v.get("objectType").and_then(Value::as_str) == Some("Group") {
        group(v, path)
    } else {
        agent(v, path)
    }
}

/// The canonical key of the IFI of a valid Agent or identified Group: `mbox:<iri>`,
/// `mbox_sha1sum:<lower-case hex>`, `openid:<uri>` or `account:<JSON [homePage, name]>`. Fails for
/// an anonymous Group (it has no identity of its own).
pub fn ifi_key(agent: &Value) -> Result<String, Invalid> {
    if let Some(mbox) = agent.get("mbox").and_then(Value::as_str) {
        return Ok(format!("mbox:{mbox}"));
    }
    if let Some(sum) = agent.get("mbox_sha1sum").and_then(Value::as_str) {
        return Ok(format!("mbox_sha1sum:{}", sum.to_ascii_lowercase()));
    }
    if let Some(openid) = agent.get("openid").and_then(Value::as_str) {
        return Ok(format!("openid:{openid}"));
    }
    if let Some(account) = agent.get("account") {
        let (Some(home), Some(name)) = (
            account.get("homePage").and_then(Value::as_str),
            account.get("name").and_then(Value::as_str),
        ) else {
            return Err("account: needs homePage and name".into());
        };
        return Ok(format!("account:{}", Value::from(vec![home, name])));
    }
    Err(
        "the agent has no inverse functional identifier (mbox, mbox_sha1sum, openid, account)"
            .into(),
    )
}

/// Parses and validates the `agent` query parameter of the LRS resources: the JSON of an Agent or
/// an identified Group.
pub fn parse_agent_param(raw: &str) -> Result<Value, Invalid> {
    let v: Value = serde_json::from_str(raw).map_err(|e| fault!("agent: not valid JSON ({e})"))?;
    agent_or_group(&v, "agent")?;
    ifi_key(&v).map_err(|e| fault!("agent: {e}"))?;
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn agents_need_exactly_one_ifi() {
        assert!(agent(&json!({"mbox": "mailto:a@example.org"}), "actor").is_ok());
        assert!(
            agent(
                &json!({"objectType": "Agent", "name": "A", "openid": "http://id.example.org/a"}),
                "actor"
            )
            .is_ok()
        );
        assert!(
            agent(
                &json!({"account": {"homePage": "http://lms.example.org", "name": "42"}}),
                "actor"
            )
            .is_ok()
        );
        assert!(
            agent(
                &json!({"mbox_sha1sum": "ebd31e95054c018b10727ccffd2ef2ec3a016ee9"}),
                "actor"
            )
            .is_ok()
        );
        for bad in [
            json!({"name": "no ifi"}),
            json!({"mbox": "a@example.org"}),
            json!({"mbox": "mailto:a@example.org", "openid": "http://x.org/a"}),
            json!({"mbox_sha1sum": "xyz"}),
            json!({"account": {"homePage": "lms", "name": "42"}}),
            json!({"account": {"homePage": "http://lms.example.org"}}),
            json!({"account": {"homePage": "http://lms.example.org", "name": "1", "extra": 1}}),
            json!({"mbox": "mailto:a@example.org", "objectType": "agent"}),
            json!({"mbox": "mailto:a@example.org", "Name": "wrong case"}),
            json!({"mbox": "mailto:a@example.org", "member": []}),
            json!({"mbox": null}),
        ] {
            assert!(agent(&bad, "actor").is_err(), "{bad}");
        }
    }

    #[test]
    fn groups_anonymous_or_identified() {
        let member = json!({"mbox": "mailto:m@example.org"});
        assert!(group(&json!({"objectType": "Group", "member": [member]}), "actor").is_ok());
        assert!(
            group(
                &json!({"objectType": "Group", "mbox": "mailto:g@example.org"}),
                "actor"
            )
            .is_ok()
        );
        assert!(group(&json!({"objectType": "Group"}), "actor").is_err());
        assert!(group(&json!({"objectType": "Group", "member": []}), "actor").is_err());
        let nested =
            json!({"objectType": "Group", "member": [{"objectType": "Group", "member": [member]}]});
        assert!(group(&nested, "actor").is_err(), "groups do not nest");
    }

    #[test]
    fn keys_ignore_names_and_sha1_case() {
        let a = ifi_key(&json!({"name": "A", "mbox": "mailto:a@example.org"})).unwrap();
        assert_eq!(
            a,
            ifi_key(&json!({"mbox": "mailto:a@example.org"})).unwrap()
        );
        let s =
            ifi_key(&json!({"mbox_sha1sum": "EBD31E95054C018B10727CCFFD2EF2EC3A016EE9"})).unwrap();
        assert_eq!(s, "mbox_sha1sum:ebd31e95054c018b10727ccffd2ef2ec3a016ee9");
        // Names with the separator cannot collide: the account key is a JSON array.
        let k1 =
            ifi_key(&json!({"account": {"homePage": "http://a.org/ x", "name": "y"}})).unwrap();
        let k2 =
            ifi_key(&json!({"account": {"homePage": "http://a.org/", "name": "x y"}})).unwrap();
        assert_ne!(k1, k2);
        assert!(parse_agent_param("{\"mbox\": \"mailto:a@example.org\"}").is_ok());
        assert!(
            parse_agent_param(
                "{\"objectType\": \"Group\", \"member\": [{\"mbox\": \"mailto:a@example.org\"}]}"
            )
            .is_err()
        );
        assert!(parse_agent_param("mailto:a@example.org").is_err());
    }
}
