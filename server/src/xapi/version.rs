//! The `X-Experience-API-Version` header (xAPI 2.0, Communication 3.3 "Versioning"): every
//! request but `GET /xapi/about` must name the version the client speaks, and every response
//! carries the version the request is answered in: 1.0.3 for a 1.0.x request, 2.0.0 for any
//! other (see [`Spoken`]).
//!
//! Statements are stored once, as sent; a 1.0.x client reads them converted by
//! [`statement_as_1_0`] (the properties 2.0 added dropped, a 2.0 `version` named 1.0.0).
//!
//! We accept `2.0.x` and, like other 2.0 LRSs, `1.0.x` (1.0.3 clients are the majority of
//! deployed LMS content; their statements are valid 2.0 statements but for the few properties 2.0
//! added). Anything else, or no header, is refused with 400 before a handler runs.

use axum::http::HeaderMap;
use serde_json::Value;
use utoipa::IntoParams;

use crate::error::ApiError;

/// Name of the header.
pub const VERSION_HEADER: &str = "x-experience-api-version";
/// The version this LRS speaks (sent on every response).
pub const LRS_VERSION: &str = "2.0.0";
/// The version this LRS answers 1.0.x requests with: the last patch of 1.0 (xAPI 1.0.3,
/// Communication 3.3: "the latest patch version after 1.0.0").
pub const LRS_VERSION_1_0: &str = "1.0.3";
/// Versions listed by the About resource.
pub const SUPPORTED_VERSIONS: [&str; 2] = ["2.0.0", "1.0.3"];

/// True for `1.0`, `1.0.x`, `2.0`, `2.0.x` with `x` a whole number.
pub fn accepted(version: &str) -> bool {
    let mut parts = version.split('.');
    let (Some(major), Some(minor)) = (parts.next(), parts.next()) else {
        return false;
    };
    let patch_ok = match parts.next() {
        None => true,
        Some(p) => !p.is_empty() && p.len() <= 4 && p.bytes().all(|b| b.is_ascii_digit()),
    };
    matches!(major, "1" | "2") && minor == "0" && patch_ok && parts.next().is_none()
}

/// The xAPI line a request speaks, which picks the rules it is answered by: 1.0.x requests get
/// 1.0.3 semantics (SHA-1 ETags, Agent and Activity Profile PUTs that must carry a precondition,
/// State PUTs that overwrite, the 1.0.3 version header), 2.0.x requests and requests without a
/// usable header get 2.0.0's. Stored statements and documents are the same either way.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Spoken {
    /// xAPI 1.0.x (answered as 1.0.3).
    V1_0,
    /// xAPI 2.0.x (answered as 2.0.0).
    #[default]
    V2_0,
}

impl Spoken {
    /// The line of the request's `X-Experience-API-Version` header; 2.0 when it is missing or not
    /// one this LRS accepts (such requests are refused before a handler runs).
    pub fn of(headers: &HeaderMap) -> Spoken {
        headers
            .get(VERSION_HEADER)
            .and_then(|v| v.to_str().ok())
            .map_or(Spoken::V2_0, Spoken::of_version)
    }

    /// The line of a version string (a header's value, or an LRS credential's `xapi_version`):
    /// 1.0 for an accepted 1.0.x, else 2.0.
    pub fn of_version(version: &str) -> Spoken {
        let v = version.trim();
        if accepted(v) && v.starts_with("1.") {
            Spoken::V1_0
        } else {
            Spoken::V2_0
        }
    }

    /// The version the response's header names.
    pub fn answer(self) -> &'static str {
        match self {
            Spoken::V1_0 => LRS_VERSION_1_0,
            Spoken::V2_0 => LRS_VERSION,
        }
    }
}

/// The version header every LRS request but About sends: documented by the routes that take
/// it, and read by the middleware into this struct.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Header)]
pub struct VersionHeader {
    /// The xAPI version the client speaks: 2.0.x (this LRS's) or 1.0.x.
    #[param(
        rename = "X-Experience-API-Version",
        pattern = r"^[12]\.0(\.[0-9]{1,4})?$"
    )]
    version: String,
}

impl VersionHeader {
    /// The request's header, or 400 when it is missing or names a version this LRS does not
    /// accept.
    pub fn read(headers: &HeaderMap) -> Result<VersionHeader, ApiError> {
        match headers.get(VERSION_HEADER).map(|v| v.to_str()) {
            None => Err(ApiError::BadRequest(
                "the X-Experience-API-Version header is required (e.g. 2.0.0)".into(),
            )),
            Some(Ok(v)) if accepted(v.trim()) => Ok(VersionHeader {
                version: v.trim().to_owned(),
            }),
            Some(_) => Err(ApiError::BadRequest(format!(
                "unsupported X-Experience-API-Version; this LRS speaks {} (and accepts 1.0.x)",
                LRS_VERSION
            ))),
        }
    }

    /// The version the client speaks (1.0.x or 2.0.x).
    pub fn version(&self) -> &str {
        &self.version
    }
}

/// A statement as 1.0.3 reads it (a 1.0.x client reading this LRS, or a 1.0.3 LRS this LRS
/// forwards to): without the context properties 2.0 added
/// (`contextAgents`, `contextGroups`), and with a 2.0 `version` property named 1.0.0 (xAPI 1.0.3,
/// Data 2.4.10: an LRS rejects a statement whose version does not start with "1.0.").
pub fn statement_as_1_0(mut statement: Value) -> Value {
    fn strip(statement: &mut Value) {
        if let Some(context) = statement.get_mut("context").and_then(Value::as_object_mut) {
            context.remove("contextAgents");
            context.remove("contextGroups");
        }
        if let Some(v) = statement.get_mut("version")
            && v.as_str().is_some_and(|v| v.starts_with("2."))
        {
            *v = Value::String("1.0.0".into());
        }
    }
    strip(&mut statement);
    if let Some(sub) = statement.get_mut("object")
        && sub["objectType"] == "SubStatement"
    {
        strip(sub);
    }
    statement
}

#[cfg(test)]
mod tests {
    use axum::http::{HeaderMap, HeaderValue};

    use serde_json::json;

    use super::{Spoken, VERSION_HEADER, VersionHeader, accepted, statement_as_1_0};

    #[test]
    fn versions() {
        for ok in ["2.0.0", "2.0", "2.0.1", "1.0.3", "1.0.0", "1.0"] {
            assert!(accepted(ok), "{ok}");
        }
        for bad in [
            "", "2", "0.95", "0.9", "3.0.0", "2.1.0", "2.0.x", "2.0.0.0", "2.0.", "1.0.3-rc",
        ] {
            assert!(!accepted(bad), "{bad}");
        }
    }

    #[test]
    fn the_header_is_read_trimmed_or_refused() {
        let mut headers = HeaderMap::new();
        let missing = VersionHeader::read(&headers).unwrap_err().to_string();
        assert!(missing.contains("is required"), "{missing}");
        headers.insert(VERSION_HEADER, HeaderValue::from_static(" 2.0.1 "));
        assert_eq!(VersionHeader::read(&headers).unwrap().version(), "2.0.1");
        headers.insert(VERSION_HEADER, HeaderValue::from_static("0.95"));
        let old = VersionHeader::read(&headers).unwrap_err().to_string();
        assert!(old.contains("unsupported"), "{old}");
        assert_eq!(Spoken::of(&headers), Spoken::V2_0);
        headers.insert(VERSION_HEADER, HeaderValue::from_static("1.0.1"));
        assert_eq!(Spoken::of(&headers), Spoken::V1_0);
        assert_eq!(Spoken::of(&headers).answer(), "1.0.3");
        headers.remove(VERSION_HEADER);
        assert_eq!(Spoken::of(&headers), Spoken::V2_0);
    }

    #[test]
    fn statements_for_1_0_lose_2_0_context_properties() {
        let s = json!({"version": "2.0.0", "context": {"contextAgents": [], "contextGroups": [],
            "registration": "0f8a7b0e-0a1e-4c5c-9a4c-2f7f8e1b2c3d"},
            "object": {"objectType": "SubStatement", "context": {"contextAgents": []}}});
        let v = statement_as_1_0(s);
        assert_eq!(v["version"], "1.0.0");
        assert!(v["context"].get("contextAgents").is_none());
        assert!(v["context"].get("contextGroups").is_none());
        assert!(v["context"]["registration"].is_string());
        assert!(v["object"]["context"].get("contextAgents").is_none());
    }
}
