//! The error of the LTI protocol endpoints: a refused login or launch says why, as
//! `{"error": {"code", "message"}}` like every other endpoint, and opens no session.
//!
//! [`LtiError`] holds only the failures of the LTI protocol itself and carries every other one as
//! the [`ApiError`] it is; it converts into an [`ApiError`], which builds the response (and logs
//! database and internal errors, which the client sees only as `internal`).

use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};

use crate::error::ApiError;

/// Errors of the LTI endpoints.
#[derive(Debug, thiserror::Error)]
pub enum LtiError {
    /// The launch or login is refused: bad signature, replay, expiry, audience, deployment (401).
    #[error("LTI launch refused: {0}")]
    Refused(String),
    /// A platform did not answer as it should (502).
    #[error("the LTI platform failed: {0}")]
    Platform(String),
    /// Anything else, as the API reports it: a malformed request (400), a missing course (404),
    /// database and internal errors.
    #[error(transparent)]
    Api(#[from] ApiError),
}

impl From<sqlx::Error> for LtiError {
    fn from(e: sqlx::Error) -> Self {
        LtiError::Api(ApiError::from(e))
    }
}

impl From<LtiError> for ApiError {
    fn from(e: LtiError) -> Self {
        let (status, code) = match e {
            LtiError::Api(e) => return e,
            LtiError::Refused(_) => (StatusCode::UNAUTHORIZED, "lti_launch_refused"),
            LtiError::Platform(_) => (StatusCode::BAD_GATEWAY, "lti_platform_failed"),
        };
        ApiError::Protocol {
            status,
            code,
            message: e.to_string(),
        }
    }
}

impl IntoResponse for LtiError {
    fn into_response(self) -> Response {
        if matches!(self, LtiError::Refused(_)) {
            tracing::info!(reason = %self, "LTI launch refused");
        }
        ApiError::from(self).into_response()
    }
}
