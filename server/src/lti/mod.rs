//! LTI 1.3 (tool side) and LTI Advantage: learners arrive from their LMS course.
//!
//! * [`platforms`]: an admin registers each platform (issuer, client id, deployments, URLs).
//! * [`keys`]: the tool's own RSA keys, JWKS at `GET /lti/jwks`, rotation.
//! * [`launch`]: OIDC login (`GET`/`POST /lti/login`), the launch (`POST /lti/launch`) mapped to
//!   an account, a course, a membership and a session, and Deep Linking (`POST /lti/deep-link`).
//! * [`services`]: OAuth 2 tokens, AGS score publication through the outbox, NRPS course fill.
//!
//! Architecture invariant: `jws` and `error` at the bottom, then `state`, `keys`, `platforms`,
//! `launch`, `services`, and `router` on top. The learning records never import this module:
//! scores reach it through database triggers and a queue (migration 0805).

pub mod error;
pub mod jws;
pub mod keys;
pub mod launch;
pub mod platforms;
pub mod services;
pub mod state;

use axum::Router;
use axum::routing::{get, post};
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

pub use error::LtiError;
pub use state::LtiState;

/// The LTI endpoints (with their state applied) and the OpenAPI document of the admin ones. The
/// protocol endpoints under `/lti/` follow the LTI 1.3 specification and are not in the document.
pub fn router<S: Clone + Send + Sync + 'static>(
    state: LtiState,
) -> (Router<S>, utoipa::openapi::OpenApi) {
    let (admin, doc) = OpenApiRouter::new()
        .routes(routes!(
            platforms::create_platform,
            platforms::list_platforms
        ))
        .routes(routes!(
            platforms::update_platform,
            platforms::delete_platform
        ))
        .routes(routes!(keys::rotate))
        .routes(routes!(services::sync_memberships))
        .with_state(state.clone())
        .split_for_parts();
    let protocol = Router::new()
        .route(
            "/lti/login",
            get(launch::login_get).post(launch::login_post),
        )
        .route("/lti/launch", post(launch::launch))
        .route("/lti/deep-link", post(launch::deep_link_choose))
        .route("/lti/jwks", get(keys::jwks))
        .route("/lti/autosubmit.js", get(launch::autosubmit))
        .with_state(state);
    (admin.merge(protocol), doc)
}

/// Starts the LTI background work of a running server: the AGS score pump, delivering through
/// `outbox` (which the caller runs). Runs until the process ends.
pub fn start(
    pool: sqlx::PgPool,
    records: crate::records::RecordsState,
    public_url: &str,
    outbox: crate::outbox::Outbox,
) {
    let state = LtiState::new(pool, records, public_url);
    services::spawn_score_pump(state, outbox, std::future::pending());
}
