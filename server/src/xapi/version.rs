//! The `X-Experience-API-Version` header (xAPI 2.0, Communication 3.3 "Versioning"): every
//! response carries the version the LRS speaks, and every request but `GET /xapi/about` must name
//! the version the client speaks.
//!
//! We accept `2.0.x` and, like other 2.0 LRSs, `1.0.x` (1.0.3 clients are the majority of
//! deployed LMS content; their statements are valid 2.0 statements but for the few properties 2.0
//! added). Anything else, or no header, is refused with 400 before a handler runs.

use axum::extract::Request;
use axum::http::{HeaderMap, HeaderValue, Method};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use utoipa::IntoParams;

use crate::error::ApiError;

/// Name of the header.
pub const VERSION_HEADER: &str = "x-experience-api-version";
/// The version this LRS speaks (sent on every response).
pub const LRS_VERSION: &str = "2.0.0";
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

/// Middleware of the `/xapi/` router: checks the request's header and sets the response's.
pub async fn version_header(req: Request, next: Next) -> Response {
    let about = req.uri().path().trim_end_matches('/') == "/xapi/about";
    let preflight = req.method() == Method::OPTIONS;
    let mut resp = if about || preflight {
        next.run(req).await
    } else {
        match VersionHeader::read(req.headers()) {
            Ok(_) => next.run(req).await,
            Err(e) => e.into_response(),
        }
    };
    resp.headers_mut()
        .insert(VERSION_HEADER, HeaderValue::from_static(LRS_VERSION));
    resp
}

#[cfg(test)]
mod tests {
    use axum::http::{HeaderMap, HeaderValue};

    use super::{VERSION_HEADER, VersionHeader, accepted};

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
    }
}
