//! The one error type of the LRS boundary ([`XapiError`]) and its response.
//!
//! The xAPI specification fixes the statuses (400 malformed or invalid, 401 no or bad credentials,
//! 403 not allowed, 404, 409 conflict, 412 precondition failed, 413 too large, 428 precondition
//! required) but not the body; ours is the platform's usual `{"error": {"code", "message"}}`, so
//! clients of both APIs read failures alike. Database and internal errors are logged and reach the
//! client only as `internal`.

use axum::Json;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::json;

use crate::error::logged_internal;

/// Errors of the LRS handlers.
#[derive(Debug, thiserror::Error)]
pub enum XapiError {
    /// Malformed request or a statement/document that breaks the data model (400).
    #[error("{0}")]
    BadRequest(String),
    /// No credentials, unknown ones, or revoked ones (401, with `WWW-Authenticate: Basic`).
    #[error("valid LRS credentials are required (HTTP Basic)")]
    Unauthorized,
    /// Authenticated, but the credential's scope does not allow this (403).
    #[error("{0}")]
    Forbidden(String),
    /// No such statement, document, activity or agent (404).
    #[error("{0} not found")]
    NotFound(String),
    /// The request conflicts with what is stored (409), e.g. a statement id reused with other
    /// content.
    #[error("{0}")]
    Conflict(String),
    /// An `If-Match`/`If-None-Match` precondition failed (412).
    #[error("{0}")]
    PreconditionFailed(String),
    /// A document write that needs a precondition header came without one (428).
    #[error("{0}")]
    PreconditionRequired(String),
    /// The body is over the limit (413).
    #[error("request body too large (limit {0} bytes)")]
    PayloadTooLarge(usize),
    /// A database error: logged, shown as `internal`.
    #[error("database error")]
    Database(#[from] sqlx::Error),
    /// Any other internal failure: logged, shown as `internal`.
    #[error("internal error")]
    Internal(String),
}

impl XapiError {
    /// HTTP status and stable machine-readable code.
    pub fn status_and_code(&self) -> (StatusCode, &'static str) {
        match self {
            XapiError::BadRequest(_) => (StatusCode::BAD_REQUEST, "bad_request"),
            XapiError::Unauthorized => (StatusCode::UNAUTHORIZED, "unauthorized"),
            XapiError::Forbidden(_) => (StatusCode::FORBIDDEN, "forbidden"),
            XapiError::NotFound(_) => (StatusCode::NOT_FOUND, "not_found"),
            XapiError::Conflict(_) => (StatusCode::CONFLICT, "conflict"),
            XapiError::PreconditionFailed(_) => {
                (StatusCode::PRECONDITION_FAILED, "precondition_failed")
            }
            XapiError::PreconditionRequired(_) => {
                (StatusCode::PRECONDITION_REQUIRED, "precondition_required")
            }
            XapiError::PayloadTooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large"),
            XapiError::Database(_) | XapiError::Internal(_) => {
                (StatusCode::INTERNAL_SERVER_ERROR, "internal")
            }
        }
    }
}

impl IntoResponse for XapiError {
    fn into_response(self) -> Response {
        let (status, code) = self.status_and_code();
        let message = match &self {
            XapiError::Database(e) => logged_internal("LRS database error", e),
            XapiError::Internal(detail) => logged_internal("LRS internal error", detail),
            other => other.to_string(),
        };
        let mut resp = (
            status,
            Json(json!({ "error": { "code": code, "message": message } })),
        )
            .into_response();
        if matches!(self, XapiError::Unauthorized) {
            resp.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Basic realm=\"xAPI\", charset=\"UTF-8\""),
            );
        }
        resp
    }
}
