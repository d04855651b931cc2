//! The LRS router (`/xapi/...`, behind the version-header middleware) and the LMS-integration
//! admin endpoints (`/api/admin/...`), with their OpenAPI document.

use axum::Router;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::auth::LrsClient;
use super::state::XapiState;
use super::{
    about, activities, agents, alternate, credentials, documents, forward, statements, version_gate,
};
use crate::error::ApiError;

#[derive(OpenApi)]
#[openapi(tags(
    (name = "xapi", description = "Learning record store (xAPI 2.0, IEEE 9274.1.1): HTTP Basic \
        with an LMS integration's credential; every request but About sends \
        `X-Experience-API-Version`"),
    (name = "lms", description = "LMS integrations (admin): LRS credentials"),
))]
struct ApiDoc;

/// The LRS and its admin endpoints (with their state applied), and their OpenAPI document.
pub fn router<S: Clone + Send + Sync + 'static>(
    state: XapiState,
) -> (Router<S>, utoipa::openapi::OpenApi) {
    let (lrs, mut doc): (Router<()>, _) = OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(routes!(about::about))
        .routes(routes!(
            statements::put_statement,
            statements::post_statements,
            statements::get_statements
        ))
        .routes(routes!(
            documents::state::get_state,
            documents::state::put_state,
            documents::state::post_state,
            documents::state::delete_state
        ))
        .routes(routes!(
            documents::activity_profile::get_activity_profile,
            documents::activity_profile::put_activity_profile,
            documents::activity_profile::post_activity_profile,
            documents::activity_profile::delete_activity_profile
        ))
        .routes(routes!(
            documents::agent_profile::get_agent_profile,
            documents::agent_profile::put_agent_profile,
            documents::agent_profile::post_agent_profile,
            documents::agent_profile::delete_agent_profile
        ))
        .routes(routes!(agents::get_agents))
        .routes(routes!(activities::get_activities))
        .with_state(state.clone())
        .split_for_parts();
    let unknown = axum::Router::new()
        .route("/xapi/{*rest}", axum::routing::any(unknown_resource))
        .route("/xapi", axum::routing::any(unknown_resource))
        .route("/xapi/", axum::routing::any(unknown_resource))
        .with_state(state.clone());
    let lrs = lrs
        .merge(unknown)
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            version_gate::version_header,
        ));
    // The Alternate Request Syntax changes a request's method and query, so it must run before
    // the routes are matched: it wraps the routed LRS as one service, which the three paths
    // under `/xapi` hand their requests to whole (path included).
    let lrs = tower::Layer::layer(
        &axum::middleware::from_fn_with_state(state.clone(), alternate::alternate_syntax),
        lrs,
    );
    let lrs = Router::new()
        .route_service("/xapi", lrs.clone())
        .route_service("/xapi/", lrs.clone())
        .route_service("/xapi/{*rest}", lrs);
    let (admin, admin_doc) = OpenApiRouter::<XapiState>::new()
        .routes(routes!(
            credentials::create_credential,
            credentials::list_credentials
        ))
        .routes(routes!(credentials::revoke_credential))
        .routes(routes!(
            forward::get_forwarding,
            forward::put_forwarding,
            forward::delete_forwarding
        ))
        .with_state(state)
        .split_for_parts();
    doc.merge(admin_doc);
    (lrs.merge(admin), doc)
}

/// Anything under `/xapi/` that is no resource: 404 for an authenticated client (never the web
/// client's page), 401 for anyone else, so the LRS does not tell strangers what it serves.
async fn unknown_resource(_client: LrsClient) -> ApiError {
    ApiError::NotFound("LRS resource".into())
}
