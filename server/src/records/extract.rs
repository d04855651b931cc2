//! Extractors whose rejections are [`ApiError`]s, so malformed JSON, wrong types, oversized
//! bodies and bad path or query parameters get the same JSON error body as every other failure
//! (axum's own rejections answer in plain text).

use std::net::SocketAddr;

use axum::extract::FromRequest;
use axum::extract::FromRequestParts;
use axum::extract::ConnectInfo;
use axum::http::request::Parts;
use axum::extract::rejection::{JsonRejection, PathRejection, QueryRejection};
use axum::http::StatusCode;

use super::state::RecordsState;
use crate::error::ApiError;

/// `axum::Json` with [`ApiError`] rejections (naming the body limit when it is exceeded).
#[derive(Debug, Clone, Copy, Default)]
pub struct ApiJson<T>(pub T);

impl<T, S> FromRequest<S> for ApiJson<T>
where
    T: serde::de::DeserializeOwned,
    S: Send + Sync,
    RecordsState: axum::extract::FromRef<S>,
{
    type Rejection = ApiError;

    async fn from_request(req: axum::extract::Request, state: &S) -> Result<Self, ApiError> {
        let state = &<RecordsState as axum::extract::FromRef<S>>::from_ref(state);
        // PostgreSQL stores no NUL in text or jsonb: a body with one is refused here, naming
        // the field, instead of failing at the database (a 500 before). JSON can only carry a
        // NUL as the escape `\u0000`, so bodies without that sequence skip the search.
        let (parts, body) = req.into_parts();
        let headers = parts.headers.clone();
        let bytes =
            axum::body::Bytes::from_request(axum::extract::Request::from_parts(parts, body), state)
                .await
                .map_err(|r| match r.status() {
                    StatusCode::PAYLOAD_TOO_LARGE => {
                        ApiError::PayloadTooLarge(state.config.max_body_bytes)
                    }
                    _ => ApiError::BadRequest(format!("invalid body: {}", r.body_text())),
                })?;
        if let Some(field) = nul_field(&bytes) {
            return Err(ApiError::BadRequest(format!(
                "{field}: must not contain NUL characters (U+0000)"
            )));
        }
        let mut req = axum::extract::Request::new(axum::body::Body::from(bytes));
        *req.headers_mut() = headers;
        match axum::Json::<T>::from_request(req, state).await {
            Ok(axum::Json(v)) => Ok(ApiJson(v)),
            Err(r) if r.status() == StatusCode::PAYLOAD_TOO_LARGE => {
                Err(ApiError::PayloadTooLarge(state.config.max_body_bytes))
            }
            Err(r) => Err(r.into()),
        }
    }
}

/// The path of the first string (key or value) holding a NUL in a JSON body, `None` when there
/// is none (or the body is not JSON: the JSON extractor reports that).
pub fn nul_field(body: &[u8]) -> Option<String> {
    if !body.windows(6).any(|w| w.eq_ignore_ascii_case(b"\\u0000")) {
        return None;
    }
    let value: serde_json::Value = serde_json::from_slice(body).ok()?;
    fn walk(v: &serde_json::Value, path: &str) -> Option<String> {
        let here = || {
            if path.is_empty() {
                "body".to_string()
            } else {
                path.to_string()
            }
        };
        match v {
            serde_json::Value::String(s) => s.contains('\0').then(here),
            serde_json::Value::Array(items) => items
                .iter()
                .enumerate()
                .find_map(|(i, x)| walk(x, &format!("{}[{i}]", here()))),
            serde_json::Value::Object(map) => map.iter().find_map(|(k, x)| {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                if k.contains('\0') {
                    return Some(format!("{} (a key)", p.replace('\0', "\\u0000")));
                }
                walk(x, &p)
            }),
            _ => None,
        }
    }
    walk(&value, "")
}

impl<T: serde::Serialize> axum::response::IntoResponse for ApiJson<T> {
    fn into_response(self) -> axum::response::Response {
        axum::Json(self.0).into_response()
    }
}

/// `axum::extract::Path` with [`ApiError`] rejections.
#[derive(Debug, FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(ApiError))]
pub struct ApiPath<T>(pub T);

/// `axum::extract::Query` with [`ApiError`] rejections; a NUL in a parameter is refused naming
/// it, as in bodies (a filter holding one failed at the database, a 500 before).
#[derive(Debug)]
pub struct ApiQuery<T>(pub T);

impl<T: serde::de::DeserializeOwned, S: Send + Sync> FromRequestParts<S> for ApiQuery<T> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, ApiError> {
        use axum::extract::Query;
        // A URI cannot hold a raw NUL, only the escape `%00`.
        let raw = parts.uri.query().unwrap_or_default();
        if raw
            .as_bytes()
            .windows(3)
            .any(|w| w.eq_ignore_ascii_case(b"%00"))
        {
            let Query(pairs) = Query::<Vec<(String, String)>>::try_from_uri(&parts.uri)?;
            if let Some((k, _)) = pairs
                .iter()
                .find(|(k, v)| k.contains('\0') || v.contains('\0'))
            {
                return Err(ApiError::BadRequest(format!(
                    "{}: must not contain NUL characters (U+0000)",
                    k.replace('\0', "\\u0000")
                )));
            }
        }
        let Query(v) = Query::<T>::try_from_uri(&parts.uri)?;
        Ok(ApiQuery(v))
    }
}

impl From<JsonRejection> for ApiError {
    fn from(r: JsonRejection) -> ApiError {
        match r.status() {
            StatusCode::PAYLOAD_TOO_LARGE => ApiError::BadRequest("request body too large".into()),
            StatusCode::UNSUPPORTED_MEDIA_TYPE => ApiError::BadRequest(
                "expected a JSON body with `Content-Type: application/json`".into(),
            ),
            _ => ApiError::BadRequest(format!("invalid JSON body: {}", r.body_text())),
        }
    }
}

impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> ApiError {
        ApiError::BadRequest(format!("invalid path parameter: {}", r.body_text()))
    }
}

impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> ApiError {
        ApiError::BadRequest(format!("invalid query parameter: {}", r.body_text()))
    }
}

/// The client key for rate limiting: the peer address when the server was started with connect
/// info, else one shared key (the limiter then bounds all clients together).
pub struct ClientKey(pub String);

impl<S: Send + Sync> FromRequestParts<S> for ClientKey {
    type Rejection = std::convert::Infallible;

    async fn from_request_parts(parts: &mut Parts, _: &S) -> Result<Self, Self::Rejection> {
        let ip = parts
            .extensions
            .get::<ConnectInfo<SocketAddr>>()
            .map(|c| c.0.ip().to_string());
        Ok(ClientKey(ip.unwrap_or_else(|| "unknown-peer".into())))
    }
}

/// Passes the authentication endpoints' per-client token bucket, or 429.
pub fn limit(state: &RecordsState, key: &ClientKey) -> Result<(), ApiError> {
    state
        .auth_limiter
        .check(&key.0)
        .map_err(ApiError::TooManyRequests)
}

#[cfg(test)]
mod tests {
    use super::nul_field;

    #[test]
    fn nul_is_found_in_values_keys_and_arrays_and_only_there() {
        assert_eq!(
            nul_field(br#"{"email": "a\u0000b"}"#).as_deref(),
            Some("email")
        );
        assert_eq!(
            nul_field(br#"{"detail": {"notes": ["ok", "x\u0000"]}}"#).as_deref(),
            Some("detail.notes[1]")
        );
        assert_eq!(
            nul_field(br#"{"detail": {"k\u0000": 1}}"#).as_deref(),
            Some("detail.k\\u0000 (a key)")
        );
        assert_eq!(nul_field(br#""\u0000""#).as_deref(), Some("body"));
        // An escaped backslash followed by "u0000" is six ordinary characters, not a NUL.
        assert_eq!(nul_field(br#"{"text": "\\u0000"}"#), None);
        assert_eq!(nul_field(br#"{"text": "plain"}"#), None);
        assert_eq!(nul_field(b"not json \\u0000"), None);
    }
}
