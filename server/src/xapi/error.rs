//! The errors of the LRS: [`XapiError`], what only the LRS answers, and [`Invalid`], data that
//! breaks the xAPI data model.
//!
//! The xAPI specification fixes the statuses (400 malformed or invalid, 401 no or bad credentials,
//! 403 not allowed, 404, 409 conflict, 412 precondition failed, 413 too large) but not the body;
//! ours is the platform's usual `{"error": {"code", "message"}}`, so clients of both APIs read
//! failures alike. [`XapiError`] holds only the failures the rest of the API does not have (the
//! HTTP Basic challenge, the document preconditions) and carries every other one as the
//! [`ApiError`] it is; it converts into an [`ApiError`], which builds every response, so database
//! and internal errors are logged there and reach the client only as `internal`. The headers the
//! LRS owns are added around that response: `WWW-Authenticate` here, `X-Experience-API-Version`
//! by the version middleware on every response, `X-Experience-API-Consistent-Through` by the
//! Statement resource on every answer to a GET.

use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};

use crate::error::ApiError;

/// Errors of the LRS handlers.
#[derive(Debug, thiserror::Error)]
pub enum XapiError {
    /// No credentials, unknown ones, or revoked ones (401, with `WWW-Authenticate: Basic`).
    #[error("valid LRS credentials are required (HTTP Basic)")]
    Unauthorized,
    /// An `If-Match`/`If-None-Match` precondition failed (412).
    #[error("{0}")]
    PreconditionFailed(String),
    /// Any failure the API answers alike: malformed or invalid requests (400), a credential's
    /// scope (403), 404, 409, 413, and database or internal errors (logged, never sent).
    #[error(transparent)]
    Api(#[from] ApiError),
}

impl From<sqlx::Error> for XapiError {
    fn from(e: sqlx::Error) -> Self {
        XapiError::Api(ApiError::Database(e))
    }
}

impl From<Invalid> for XapiError {
    fn from(e: Invalid) -> Self {
        XapiError::Api(e.into())
    }
}

impl XapiError {
    /// HTTP status and stable machine-readable code.
    pub fn status_and_code(&self) -> (StatusCode, &'static str) {
        match self {
            XapiError::Unauthorized => (StatusCode::UNAUTHORIZED, "unauthorized"),
            XapiError::PreconditionFailed(_) => {
                (StatusCode::PRECONDITION_FAILED, "precondition_failed")
            }
            XapiError::Api(e) => e.status_and_code(),
        }
    }
}

impl From<XapiError> for ApiError {
    fn from(e: XapiError) -> Self {
        match e {
            XapiError::Api(e) => e,
            other => {
                let (status, code) = other.status_and_code();
                ApiError::Protocol {
                    status,
                    code,
                    message: other.to_string(),
                }
            }
        }
    }
}

impl IntoResponse for XapiError {
    fn into_response(self) -> Response {
        let challenge = matches!(self, XapiError::Unauthorized);
        let mut resp = ApiError::from(self).into_response();
        if challenge {
            resp.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Basic realm=\"xAPI\", charset=\"UTF-8\""),
            );
        }
        resp
    }
}

/// A value that breaks the xAPI data model (Data, IEEE 9274.1.1): an Agent, a statement or a
/// query parameter. Its message names the property path and the rule, e.g.
/// `actor.mbox: must be a mailto: IRI`; at the HTTP boundary it is a 400.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct Invalid(pub String);

/// An [`Invalid`] naming the fault, with a `format!` message.
macro_rules! fault {
    ($($arg:tt)*) => {
        $crate::xapi::error::Invalid(format!($($arg)*))
    };
}
pub(crate) use fault;

impl From<&str> for Invalid {
    fn from(message: &str) -> Self {
        Invalid(message.to_owned())
    }
}

impl From<Invalid> for ApiError {
    fn from(e: Invalid) -> Self {
        ApiError::BadRequest(e.0)
    }
}
