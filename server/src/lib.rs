//! `server`: the platform's HTTP service.
//!
//! It owns the database (an existing PostgreSQL via `DATABASE_URL`, or by default a private
//! cluster it starts itself, see [`embedded_pg`]), runs the migrations, serves the JSON API and
//! the web client, and dispatches simulation sessions to render workers (in-process by default).
//!
//! The router is built by a function, [`app`], from an [`AppState`], so tests drive exactly the
//! router production uses.

pub mod cli;
pub mod config;
pub mod db;
pub mod dispatch;
pub mod embedded_pg;
pub mod error;
pub mod lti;
pub mod outbox;
pub mod records;
pub mod routes;
pub mod startup;
pub mod state;
pub mod telemetry;
#[cfg(feature = "test-support")]
pub mod test_support;
pub mod workers;
pub mod xapi;

use axum::Router;
use axum::routing::{any, get};
use tower_http::trace::TraceLayer;

pub use config::Config;
pub use error::ApiError;

pub use state::AppState;

/// The complete HTTP application.
pub fn app(state: AppState) -> Router {
    let web_dir = state.config.web_dir.clone();
    let records_state =
        records::RecordsState::from_parts(state.pool.clone(), state.config.records.clone());
    let tls = routes::headers::Tls(state.config.records.cookie_secure);
    let (records_router, mut doc) = records::router(records_state.clone());
    doc.merge(dispatch::openapi());
    let xapi_state = xapi::XapiState {
        pool: state.pool.clone(),
        records: records_state.clone(),
        public_url: state.config.public_url.as_str().into(),
        max_body_bytes: state.config.max_body_bytes,
    };
    let (xapi_router, xapi_doc) = xapi::router(xapi_state);
    doc.merge(xapi_doc);
    let lti_state = lti::LtiState::new(
        state.pool.clone(),
        records_state.clone(),
        state.config.public_url.as_str(),
    );
    let (lti_router, lti_doc) = lti::router(lti_state);
    doc.merge(lti_doc);
    doc.info.title = "pain-sim API".into();
    records::routes::document_shared_refusals(&mut doc);
    let doc = std::sync::Arc::new(doc);
    Router::new()
        .route("/healthz", get(routes::health::healthz))
        .route(
            "/api/openapi.json",
            get(move || async move { axum::Json(doc.as_ref().clone()) }),
        )
        .merge(records_router)
        .merge(xapi_router)
        .merge(lti_router)
        .merge(dispatch::router(records_state, dispatcher_for(&state)))
        .route("/api/{*rest}", any(routes::headers::api_not_found))
        .route("/api", any(routes::headers::api_not_found))
        .route("/api/", any(routes::headers::api_not_found))
        .fallback(move |req| routes::web::serve(web_dir.clone(), req))
        .layer(axum::extract::DefaultBodyLimit::max(
            state.config.max_body_bytes,
        ))
        .layer(axum::middleware::from_fn_with_state(
            tls,
            routes::headers::security_headers,
        ))
        .layer(TraceLayer::new_for_http())
        .with_state(state)
}

/// The dispatcher attached to `state`, else the default from its configuration.
fn dispatcher_for(state: &AppState) -> dispatch::Dispatcher {
    dispatch::Dispatcher::for_app(
        state.dispatcher.as_ref(),
        &state.workers,
        &state.config.dispatch,
        &state.config.records.stations_dir,
    )
}
