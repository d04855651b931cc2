//! The version gate of the `/xapi/` router: every request but About and preflights must name an
//! accepted version (see [`super::version`]), and every response names the version it is answered
//! in.

use axum::extract::{Request, State};
use axum::http::{HeaderValue, Method};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::auth::authenticate;
use super::state::XapiState;
use super::version::{Spoken, VERSION_HEADER, VersionHeader};

/// Middleware of the `/xapi/` router: checks the request's header and sets the response's.
///
/// A request without a usable header is refused with 400 before any handler runs; that answer
/// names the version the request's credential is registered as speaking (an LMS integration set
/// up as 1.0.3 gets 1.0.3, as its own specification requires), 2.0.0 without a valid credential.
pub async fn version_header(State(state): State<XapiState>, req: Request, next: Next) -> Response {
    let about = req.uri().path().trim_end_matches('/') == "/xapi/about";
    let preflight = req.method() == Method::OPTIONS;
    let mut spoken = Spoken::of(req.headers());
    let mut resp = if about || preflight {
        next.run(req).await
    } else {
        match VersionHeader::read(req.headers()) {
            Ok(_) => next.run(req).await,
            Err(e) => {
                if let Ok(credential) = authenticate(&state, req.headers()).await {
                    spoken = credential.speaks;
                }
                e.into_response()
            }
        }
    };
    resp.headers_mut()
        .insert(VERSION_HEADER, HeaderValue::from_static(spoken.answer()));
    resp
}
