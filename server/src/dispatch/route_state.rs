//! The state of the dispatch routes and the caller they authenticate, shared by the browser's
//! routes (`routes`) and the render workers' (`worker_routes`).

use axum::extract::FromRequestParts;
use axum::http::request::Parts;

use super::Dispatcher;
use crate::error::ApiError;
use crate::records::RecordsState;
use crate::records::auth::CurrentUser;

/// State of the dispatch routes.
#[derive(Clone)]
pub struct DispatchState {
    pub(super) records: RecordsState,
    pub(super) dispatcher: Dispatcher,
}

impl axum::extract::FromRef<DispatchState> for RecordsState {
    fn from_ref(s: &DispatchState) -> RecordsState {
        s.records.clone()
    }
}

/// The authenticated caller (the learning records' session cookie and CSRF rules).
pub(super) struct Caller(pub(super) CurrentUser);

impl FromRequestParts<DispatchState> for Caller {
    type Rejection = ApiError;

    async fn from_request_parts(
        parts: &mut Parts,
        state: &DispatchState,
    ) -> Result<Self, ApiError> {
        CurrentUser::from_request_parts(parts, &state.records)
            .await
            .map(Caller)
    }
}
