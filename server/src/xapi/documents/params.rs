//! The query parameters of the document, Agents and Activities resources, parsed by hand so that
//! every refusal is an [`XapiError`] naming the parameter (xAPI 2.0, Communication 3.2 "Error
//! Codes": a parameter the resource does not know, a repeated one, or one with the wrong case is
//! a 400, as is a missing or malformed one).

use std::collections::HashMap;

use serde_json::Value;
use time::OffsetDateTime;
use time::format_description::well_known::Rfc3339;
use uuid::Uuid;

use crate::xapi::agent;
use crate::xapi::error::XapiError;

/// The query of one request: each allowed parameter at most once.
#[derive(Debug)]
pub struct Params(HashMap<String, String>);

impl Params {
    /// Parses the raw query string, refusing parameters outside `allowed`, repeated ones and
    /// values holding NUL (PostgreSQL stores no NUL in text).
    pub fn parse(raw: Option<&str>, allowed: &[&str]) -> Result<Params, XapiError> {
        let mut map = HashMap::new();
        for (name, value) in query_pairs(raw.unwrap_or("")) {
            if !allowed.contains(&name.as_str()) {
                return Err(XapiError::BadRequest(format!(
                    "unknown parameter `{}` (this resource takes {})",
                    name.escape_debug(),
                    allowed.join(", ")
                )));
            }
            if value.contains('\0') {
                return Err(XapiError::BadRequest(format!(
                    "{name}: must not contain NUL characters (U+0000)"
                )));
            }
            if map.insert(name.clone(), value).is_some() {
                return Err(XapiError::BadRequest(format!(
                    "{name}: given more than once"
                )));
            }
        }
        Ok(Params(map))
    }

    /// The value of an optional parameter.
    pub fn optional(&self, name: &str) -> Option<&str> {
        self.0.get(name).map(String::as_str)
    }

    /// The value of a required parameter.
    pub fn required(&self, name: &str) -> Result<&str, XapiError> {
        self.optional(name)
            .ok_or_else(|| XapiError::BadRequest(format!("{name}: required")))
    }

    /// A required Activity id: an absolute IRI.
    pub fn activity_id(&self) -> Result<String, XapiError> {
        let v = self.required("activityId")?;
        if !is_iri(v) {
            return Err(XapiError::BadRequest(
                "activityId: must be an absolute IRI (scheme:...)".into(),
            ));
        }
        Ok(v.to_owned())
    }

    /// A required document id (`stateId`, `profileId`): any non-empty string.
    pub fn document_id(&self, name: &str) -> Result<String, XapiError> {
        let v = self.required(name)?;
        if v.is_empty() {
            return Err(XapiError::BadRequest(format!("{name}: must not be empty")));
        }
        Ok(v.to_owned())
    }

    /// An optional document id: present means one document, absent means all of them.
    pub fn optional_document_id(&self, name: &str) -> Result<Option<String>, XapiError> {
        match self.optional(name) {
            None => Ok(None),
            Some(_) => self.document_id(name).map(Some),
        }
    }

    /// The required `agent` parameter: a JSON Agent (or, with `allow_group`, an identified
    /// Group), with its identity key. Agents given with different non-identifying properties
    /// (a name, say) have the same key.
    pub fn agent(&self, allow_group: bool) -> Result<(Value, String), XapiError> {
        let raw = self.required("agent")?;
        let agent = agent::parse_agent_param(raw).map_err(XapiError::BadRequest)?;
        if !allow_group && agent.get("objectType").and_then(Value::as_str) == Some("Group") {
            return Err(XapiError::BadRequest(
                "agent: must be an Agent, not a Group".into(),
            ));
        }
        let key =
            agent::ifi_key(&agent).map_err(|e| XapiError::BadRequest(format!("agent: {e}")))?;
        if key.contains('\0') {
            return Err(XapiError::BadRequest(
                "agent: must not contain NUL characters (U+0000)".into(),
            ));
        }
        Ok((agent, key))
    }

    /// The optional `registration`: a UUID in its hyphenated form.
    pub fn registration(&self) -> Result<Option<Uuid>, XapiError> {
        let Some(v) = self.optional("registration") else {
            return Ok(None);
        };
        let bad = || XapiError::BadRequest("registration: must be a UUID".into());
        if v.len() != 36 {
            return Err(bad());
        }
        Uuid::parse_str(v).map(Some).map_err(|_| bad())
    }

    /// The optional `since`: an ISO 8601 timestamp with a time zone (RFC 3339). A `+` of the
    /// offset that reached us as a space (an unencoded query) is read as the `+` it was.
    pub fn since(&self) -> Result<Option<OffsetDateTime>, XapiError> {
        let Some(v) = self.optional("since") else {
            return Ok(None);
        };
        OffsetDateTime::parse(&v.replace(' ', "+"), &Rfc3339)
            .map(Some)
            .map_err(|_| {
                XapiError::BadRequest(
                    "since: must be a timestamp with a time zone, e.g. 2026-01-31T12:00:00Z".into(),
                )
            })
    }
}

/// The name-value pairs of an `application/x-www-form-urlencoded` query, percent-decoded
/// (invalid UTF-8 replaced, as browsers do).
fn query_pairs(raw: &str) -> impl Iterator<Item = (String, String)> + '_ {
    raw.split('&').filter(|p| !p.is_empty()).map(|part| {
        let (name, value) = part.split_once('=').unwrap_or((part, ""));
        (decode(name), decode(value))
    })
}

/// Percent-decoding with `+` as a space.
fn decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        match bytes[i] {
            b'+' => out.push(b' '),
            b'%' if i + 2 < bytes.len() => match (hex_val(bytes[i + 1]), hex_val(bytes[i + 2])) {
                (Some(h), Some(l)) => {
                    out.push(h * 16 + l);
                    i += 2;
                }
                _ => out.push(b'%'),
            },
            b => out.push(b),
        }
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

fn hex_val(b: u8) -> Option<u8> {
    (b as char).to_digit(16).map(|d| d as u8)
}

/// True for an absolute IRI (RFC 3987): a scheme (a letter, then letters, digits, `+`, `-`,
/// `.`), a colon, and at least one more character, with no whitespace, control characters or
/// the characters IRIs exclude (`<>"{}|\^` and the backtick).
pub fn is_iri(s: &str) -> bool {
    let Some((scheme, rest)) = s.split_once(':') else {
        return false;
    };
    let mut chars = scheme.chars();
    let scheme_ok = chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'));
    scheme_ok
        && !rest.is_empty()
        && !s.chars().any(|c| {
            c.is_whitespace()
                || c.is_control()
                || matches!(c, '<' | '>' | '"' | '{' | '}' | '|' | '\\' | '^' | '`')
        })
}

#[cfg(test)]
mod tests {
    use super::{Params, decode, is_iri};

    #[test]
    fn iris() {
        for ok in [
            "http://example.org/a",
            "urn:uuid:6f1c",
            "tag:example.org,2026:x",
            "http://example.org/ü",
        ] {
            assert!(is_iri(ok), "{ok}");
        }
        for bad in [
            "",
            "true",
            "undefined",
            "{\"key\":\"value\"}",
            "1",
            ":x",
            "http:",
            "a b:c",
            "http://a b",
        ] {
            assert!(!is_iri(bad), "{bad}");
        }
    }

    #[test]
    fn query_parsing() {
        assert_eq!(decode("a%20b+c%3A%zz%4"), "a b c:%zz%4");
        let p = Params::parse(
            Some("stateId=x&since=2026-01-01T00:00:00%2B01:00"),
            &["stateId", "since"],
        )
        .unwrap();
        assert_eq!(p.optional("stateId"), Some("x"));
        assert!(p.since().unwrap().is_some());
        let unencoded_plus =
            Params::parse(Some("since=2026-01-01T00:00:00+01:00"), &["since"]).unwrap();
        assert!(unencoded_plus.since().unwrap().is_some());
        for bad in ["StateId=x", "stateId=x&stateId=y", "stateId=%00", "foo=bar"] {
            assert!(Params::parse(Some(bad), &["stateId"]).is_err(), "{bad}");
        }
        for bad in [
            "registration=true",
            "registration=6f1c0c5e3b8a4f0e9d2c1b0a99887766",
        ] {
            let p = Params::parse(Some(bad), &["registration"]).unwrap();
            assert!(p.registration().is_err(), "{bad}");
        }
    }
}
