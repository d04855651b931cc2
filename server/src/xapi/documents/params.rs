//! The query parameters of the document, Agents and Activities resources.
//!
//! Each route's parameters are one struct: its `IntoParams` derive is what the OpenAPI document
//! shows, and [`QueryParams::parse`] reads a request's query into it in one step, taking the
//! parameter names from that same derive, so the document and the parser cannot drift. Every
//! refusal is a 400 naming the parameter (xAPI 2.0, Communication 3.2 "Error Codes": a parameter
//! the resource does not know, a repeated one, or one with the wrong case, as well as a missing or
//! malformed one).

use std::collections::HashMap;

use serde_json::Value;
use time::OffsetDateTime;
use time::format_description::well_known::Rfc3339;
use utoipa::openapi::path::ParameterIn;
use utoipa::{IntoParams, ToSchema};
use uuid::Uuid;

use crate::error::ApiError;
use crate::xapi::agent;

/// The query parameters of one route, as a typed struct.
pub trait QueryParams: IntoParams + Sized {
    /// Reads the fields from the checked query, in the order whose first fault is reported.
    fn read(p: &Params) -> Result<Self, ApiError>;

    /// The parameters' names as the OpenAPI document shows them, in its order.
    fn names() -> Vec<String> {
        Self::into_params(|| Some(ParameterIn::Query))
            .into_iter()
            .map(|p| p.name)
            .collect()
    }

    /// Parses a raw query string: refuses names the document does not show, repeated names and
    /// NUL characters, then reads the fields.
    fn parse(raw: Option<&str>) -> Result<Self, ApiError> {
        Self::read(&Params::parse(raw, &Self::names())?)
    }
}

/// The query of one request: each documented parameter at most once.
#[derive(Debug)]
pub struct Params {
    values: HashMap<String, String>,
    names: Vec<String>,
}

impl Params {
    /// Parses the raw query string, refusing parameters outside `names`, repeated ones and values
    /// holding NUL (PostgreSQL stores no NUL in text).
    pub fn parse(raw: Option<&str>, names: &[String]) -> Result<Params, ApiError> {
        let mut values = HashMap::new();
        for (name, value) in query_pairs(raw.unwrap_or("")) {
            if !names.contains(&name) {
                return Err(ApiError::BadRequest(format!(
                    "unknown parameter `{}` (this resource takes {})",
                    name.escape_debug(),
                    names.join(", ")
                )));
            }
            if value.contains('\0') {
                return Err(ApiError::BadRequest(format!(
                    "{name}: must not contain NUL characters (U+0000)"
                )));
            }
            if values.insert(name.clone(), value).is_some() {
                return Err(ApiError::BadRequest(format!(
                    "{name}: given more than once"
                )));
            }
        }
        Ok(Params {
            values,
            names: names.to_vec(),
        })
    }

    /// The value of an optional parameter. A name the route does not document is a programming
    /// error (the struct would read a parameter that no request may send).
    pub fn optional(&self, name: &str) -> Option<&str> {
        debug_assert!(
            self.names.iter().any(|n| n == name),
            "{name} is not a documented parameter of this route ({:?})",
            self.names
        );
        self.values.get(name).map(String::as_str)
    }

    /// The value of a required parameter.
    pub fn required(&self, name: &str) -> Result<&str, ApiError> {
        self.optional(name)
            .ok_or_else(|| ApiError::BadRequest(format!("{name}: required")))
    }

    /// The required `activityId`: an absolute IRI.
    pub fn activity_id(&self) -> Result<Iri, ApiError> {
        let v = self.required("activityId")?;
        if !is_iri(v) {
            return Err(ApiError::BadRequest(
                "activityId: must be an absolute IRI (scheme:...)".into(),
            ));
        }
        Ok(Iri(v.to_owned()))
    }

    /// A required document id (`stateId`, `profileId`): any non-empty string.
    pub fn document_id(&self, name: &str) -> Result<DocumentId, ApiError> {
        let v = self.required(name)?;
        if v.is_empty() {
            return Err(ApiError::BadRequest(format!("{name}: must not be empty")));
        }
        Ok(DocumentId(v.to_owned()))
    }

    /// An optional document id: present means one document, absent means all of them.
    pub fn optional_document_id(&self, name: &str) -> Result<Option<DocumentId>, ApiError> {
        match self.optional(name) {
            None => Ok(None),
            Some(_) => self.document_id(name).map(Some),
        }
    }

    /// The required `agent`: a JSON Agent (or, with `allow_group`, an identified Group), with
    /// its identity key. Agents given with different non-identifying properties (a name, say)
    /// have the same key.
    pub fn agent(&self, allow_group: bool) -> Result<AgentJson, ApiError> {
        let raw = self.required("agent")?;
        let agent = agent::parse_agent_param(raw)?;
        if !allow_group && agent.get("objectType").and_then(Value::as_str) == Some("Group") {
            return Err(ApiError::BadRequest(
                "agent: must be an Agent, not a Group".into(),
            ));
        }
        let key =
            agent::ifi_key(&agent).map_err(|e| ApiError::BadRequest(format!("agent: {e}")))?;
        if key.contains('\0') {
            return Err(ApiError::BadRequest(
                "agent: must not contain NUL characters (U+0000)".into(),
            ));
        }
        Ok(AgentJson(Agent { json: agent, key }))
    }

    /// The optional `registration`: a UUID in its hyphenated form.
    pub fn registration(&self) -> Result<Option<Uuid>, ApiError> {
        let Some(v) = self.optional("registration") else {
            return Ok(None);
        };
        let bad = || ApiError::BadRequest("registration: must be a UUID".into());
        if v.len() != 36 {
            return Err(bad());
        }
        Uuid::parse_str(v).map(Some).map_err(|_| bad())
    }

    /// The optional `since`: an ISO 8601 timestamp with a time zone (RFC 3339). A `+` of the
    /// offset that reached us as a space (an unencoded query) is read as the `+` it was.
    pub fn since(&self) -> Result<Option<OffsetDateTime>, ApiError> {
        let Some(v) = self.optional("since") else {
            return Ok(None);
        };
        OffsetDateTime::parse(&v.replace(' ', "+"), &Rfc3339)
            .map(Some)
            .map_err(|_| {
                ApiError::BadRequest(
                    "since: must be a timestamp with a time zone, e.g. 2026-01-31T12:00:00Z".into(),
                )
            })
    }
}

/// An absolute IRI (RFC 3987), as [`is_iri`] accepts it: a scheme, a colon, and no
/// whitespace, control characters or `<>"{}|\^` and backtick.
#[derive(Debug, Clone, ToSchema)]
#[schema(pattern = r#"^[A-Za-z][A-Za-z0-9+.\-]*:[^\s\x00-\x1f\x7f-\x9f<>"{}|\\^`]+$"#)]
pub struct Iri(String);

impl Iri {
    /// The IRI as sent.
    pub fn into_string(self) -> String {
        self.0
    }
}

/// A JSON Agent object (`{"objectType": "Agent", "mbox": "mailto:..."}` or with one other
/// identifier: `mbox_sha1sum`, `openid`, `account`), as text in the query.
#[derive(Debug, Clone, ToSchema)]
#[schema(value_type = String, pattern = r"^\s*\{[^\x00]*\}\s*$")]
pub struct AgentJson(Agent);

impl AgentJson {
    /// The Agent (or identified Group) it names.
    pub fn into_agent(self) -> Agent {
        self.0
    }
}

/// A valid Agent or identified Group, as the `agent` parameter names it.
#[derive(Debug, Clone)]
pub struct Agent {
    /// Its JSON as sent.
    pub json: Value,
    /// Its identity key ([`agent::ifi_key`]).
    pub key: String,
}

/// A document id (`stateId`, `profileId`): any non-empty text.
#[derive(Debug, Clone, ToSchema)]
#[schema(pattern = r"^[^\x00]+$")]
pub struct DocumentId(String);

impl DocumentId {
    /// The id as sent.
    pub fn into_string(self) -> String {
        self.0
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

    fn names(names: &[&str]) -> Vec<String> {
        names.iter().map(|n| n.to_string()).collect()
    }

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
            &names(&["stateId", "since"]),
        )
        .unwrap();
        assert_eq!(p.optional("stateId"), Some("x"));
        assert!(p.since().unwrap().is_some());
        let unencoded_plus =
            Params::parse(Some("since=2026-01-01T00:00:00+01:00"), &names(&["since"])).unwrap();
        assert!(unencoded_plus.since().unwrap().is_some());
        for bad in ["StateId=x", "stateId=x&stateId=y", "stateId=%00", "foo=bar"] {
            assert!(
                Params::parse(Some(bad), &names(&["stateId"])).is_err(),
                "{bad}"
            );
        }
        for bad in [
            "registration=true",
            "registration=6f1c0c5e3b8a4f0e9d2c1b0a99887766",
        ] {
            let p = Params::parse(Some(bad), &names(&["registration"])).unwrap();
            assert!(p.registration().is_err(), "{bad}");
        }
    }
}
