//! The error of the LTI protocol endpoints: a refused login or launch says why, as
//! `{"error": {"code", "message"}}` like every other endpoint, and opens no session.

use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;

use crate::error::ApiError;

/// Errors of the LTI endpoints.
#[derive(Debug, thiserror::Error)]
pub enum LtiError {
    /// The request is malformed (400).
    #[error("{0}")]
    BadRequest(String),
    /// The launch or login is refused: bad signature, replay, expiry, audience, deployment (401).
    #[error("LTI launch refused: {0}")]
    Refused(String),
    /// A platform did not answer as it should (502).
    #[error("the LTI platform failed: {0}")]
    Platform(String),
    /// Anything else, as the API reports it.
    #[error(transparent)]
    Api(#[from] ApiError),
}

impl From<sqlx::Error> for LtiError {
    fn from(e: sqlx::Error) -> Self {
        LtiError::Api(ApiError::from(e))
    }
}

impl IntoResponse for LtiError {
    fn into_response(self) -> Response {
        let (status, code) = match &self {
            // Answered below, as the API answers it.
            LtiError::Api(_) => (StatusCode::INTERNAL_SERVER_ERROR, "internal"),
            LtiError::BadRequest(_) => (StatusCode::BAD_REQUEST, "bad_request"),
            LtiError::Refused(_) => (StatusCode::UNAUTHORIZED, "lti_launch_refused"),
            LtiError::Platform(_) => (StatusCode::BAD_GATEWAY, "lti_platform_failed"),
        };
        if let LtiError::Api(e) = self {
            return e.into_response();
        }
        if status == StatusCode::UNAUTHORIZED {
            tracing::info!(reason = %self, "LTI launch refused");
        }
        (
            status,
            Json(json!({ "error": { "code": code, "message": self.to_string() } })),
        )
            .into_response()
    }
}
