//! The one error type of the HTTP boundary, and its JSON body; and the configuration error.
//!
//! Every failure a client sees is `{"error": {"code": "...", "message": "..."}}` with a fitting
//! status. Database and other internal errors are logged with their detail and reach the client
//! only as a generic `internal` error: SQL, table names and driver messages never leave the server.
//!
//! Architecture invariant: this module imports no other module of the crate, so every module
//! (the learning records' configuration included) can use its errors without a cycle.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;

/// A configuration value that could not be used (of the server's or the learning records'
/// configuration).
#[derive(Debug, thiserror::Error)]
#[error("invalid configuration: {variable}={value:?}: {reason}")]
pub struct ConfigError {
    /// The environment variable.
    pub variable: &'static str,
    /// Its value.
    pub value: String,
    /// Why it was rejected.
    pub reason: String,
}

/// Errors returned by HTTP handlers.
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// The request is malformed or a field is invalid (400).
    #[error("{0}")]
    BadRequest(String),
    /// No valid session (401).
    #[error("authentication required")]
    Unauthorized,
    /// Wrong credentials at login (401).
    #[error("{0}")]
    InvalidCredentials(String),
    /// The password was right but the account needs a TOTP code (401).
    #[error("this account needs a TOTP code: send `totp_code` with the login")]
    TotpRequired,
    /// Authenticated but not allowed (403).
    #[error("{0}")]
    Forbidden(String),
    /// The resource does not exist, or the caller may not know that it exists (404).
    #[error("{0} not found")]
    NotFound(String),
    /// The request conflicts with the current state (409).
    #[error("{0}")]
    Conflict(String),
    /// The request body is too large (413).
    #[error("request body too large (limit {0} bytes)")]
    PayloadTooLarge(usize),
    /// Too many requests (429).
    #[error("too many requests; retry after {0} s")]
    TooManyRequests(u64),
    /// A dependency (database, render worker) is not available (503).
    #[error("{0} is unavailable")]
    Unavailable(&'static str),
    /// A database error: logged, shown to the client as `internal`.
    #[error("database error")]
    Database(#[from] sqlx::Error),
    /// Any other internal error: logged, shown to the client as `internal`.
    #[error("internal error")]
    Internal(String),
    /// A failure that one protocol area words itself (an LRS precondition, a refused LTI launch):
    /// the area's error enum converts into this, so that its response is built here like any.
    #[error("{message}")]
    Protocol {
        /// Its status.
        status: StatusCode,
        /// Its stable machine-readable code.
        code: &'static str,
        /// What the client is told.
        message: String,
    },
}

#[derive(Serialize)]
struct ErrorBody<'a> {
    error: ErrorDetail<'a>,
}

#[derive(Serialize)]
struct ErrorDetail<'a> {
    code: &'a str,
    message: String,
}

impl ApiError {
    /// HTTP status and stable machine-readable code.
    pub fn status_and_code(&self) -> (StatusCode, &'static str) {
        match self {
            ApiError::BadRequest(_) => (StatusCode::BAD_REQUEST, "bad_request"),
            ApiError::Unauthorized => (StatusCode::UNAUTHORIZED, "unauthorized"),
            ApiError::InvalidCredentials(_) => (StatusCode::UNAUTHORIZED, "invalid_credentials"),
            ApiError::TotpRequired => (StatusCode::UNAUTHORIZED, "totp_required"),
            ApiError::Forbidden(_) => (StatusCode::FORBIDDEN, "forbidden"),
            ApiError::NotFound(_) => (StatusCode::NOT_FOUND, "not_found"),
            ApiError::Conflict(_) => (StatusCode::CONFLICT, "conflict"),
            ApiError::PayloadTooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large"),
            ApiError::TooManyRequests(_) => (StatusCode::TOO_MANY_REQUESTS, "too_many_requests"),
            ApiError::Unavailable(_) => (StatusCode::SERVICE_UNAVAILABLE, "unavailable"),
            ApiError::Database(_) | ApiError::Internal(_) => (StatusCode::INTERNAL_SERVER_ERROR, "internal"),
            ApiError::Protocol { status, code, .. } => (*status, code),
        }
    }
}

/// Logs an internal failure with its detail and returns what a client may see of it: only
/// "internal error" (every HTTP boundary of the server answers internal failures so).
pub fn logged_internal(what: &str, detail: &dyn std::fmt::Display) -> String {
    tracing::error!(%detail, "{what}");
    "internal error".to_owned()
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let (status, code) = self.status_and_code();
        let message = match &self {
            ApiError::Database(e) => logged_internal("database error", e),
            ApiError::Internal(detail) => logged_internal("internal error", detail),
            other => other.to_string(),
        };
        let retry_after = match &self {
            ApiError::TooManyRequests(s) => Some(*s),
            _ => None,
        };
        let mut resp = (status, Json(ErrorBody { error: ErrorDetail { code, message } })).into_response();
        if let Some(s) = retry_after {
            resp.headers_mut().insert(axum::http::header::RETRY_AFTER, axum::http::HeaderValue::from(s));
        }
        resp
    }
}
