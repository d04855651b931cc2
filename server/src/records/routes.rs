//! The learning-records router and its OpenAPI document: the one module that imports every
//! handler (nothing imports it but the server's `app`, through the re-export `records::router`).

use axum::Router;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::state::RecordsState;
use super::{accounts, activity, attempts, catalogue, detail, history, login, reviews, users};

#[derive(OpenApi)]
#[openapi(
    info(
        title = "pain-sim learning records API",
        description = "Accounts, courses, stations, attempts, engagement activity, technical \
            results and faculty review. Cookie-authenticated writes need the `X-CSRF-Token` \
            header. A technical \"met\" is not a certification of clinical competency."
    ),
    tags(
        (name = "auth", description = "Login, logout, sessions and TOTP"),
        (name = "users", description = "Accounts (admin)"),
        (name = "courses", description = "Courses and memberships"),
        (name = "stations", description = "Versioned stations and rubrics"),
        (name = "attempts", description = "Attempts, activity and technical results"),
        (name = "reviews", description = "Faculty review queue, approval and audit"),
    )
)]
struct ApiDoc;

/// The learning-records API router (with its state applied) and its OpenAPI document (served,
/// merged with the other parts of the API, by the server's `app` at `/api/openapi.json`).
pub fn router<S: Clone + Send + Sync + 'static>(
    state: RecordsState,
) -> (Router<S>, utoipa::openapi::OpenApi) {
    let (router, doc) = OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(routes!(login::login))
        .routes(routes!(login::logout))
        .routes(routes!(login::me))
        .routes(routes!(login::totp_enroll))
        .routes(routes!(login::totp_confirm))
        .routes(routes!(accounts::change_password))
        .routes(routes!(accounts::complete_password_reset))
        .routes(routes!(users::create_user_handler, users::list_users))
        .routes(routes!(accounts::disable_user))
        .routes(routes!(accounts::enable_user))
        .routes(routes!(accounts::start_password_reset))
        .routes(routes!(catalogue::create_course, catalogue::list_courses))
        .routes(routes!(catalogue::get_course))
        .routes(routes!(catalogue::put_member))
        .routes(routes!(catalogue::list_stations))
        .routes(routes!(catalogue::get_station))
        .routes(routes!(attempts::create_attempt, attempts::list_attempts))
        .routes(routes!(detail::get_attempt))
        .routes(routes!(activity::post_activity, activity::list_activity))
        .routes(routes!(reviews::review_attempt))
        .routes(routes!(reviews::review_queue))
        .routes(routes!(reviews::export_csv))
        .routes(routes!(reviews::bulk_approve))
        .routes(routes!(history::audit_trail))
        .with_state(state)
        .split_for_parts();
    (router, doc)
}
