//! The learning-records router and its OpenAPI document: the one module that imports every
//! handler (nothing imports it but the server's `app`, through the re-export `records::router`).

use axum::Router;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::state::RecordsState;
use super::{
    accounts, activity, attempts, catalogue, cohort, detail, history, login, modes, reviews, users,
};

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
        .routes(routes!(modes::list_station_modes))
        .routes(routes!(modes::put_station_mode))
        .routes(routes!(cohort::get_cohort))
        .routes(routes!(cohort::get_cohort_csv))
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

/// The writes that need no session (the others pass [`super::auth::CurrentUser`]); the worker
/// registration of `dispatch` authenticates with the cluster token instead.
const UNAUTHENTICATED_WRITES: [&str; 3] = ["login", "complete_password_reset", "register_worker"];

/// Adds the refusals every handler shares through its extractors, so each operation lists them
/// without repeating them in its annotation: a body ([`super::extract::ApiJson`]) can be
/// malformed (400) or too large (413); a path or query parameter can be malformed (400); an
/// authenticated write ([`super::auth::CurrentUser`] on POST, PUT, PATCH or DELETE) can lack its
/// CSRF token (403) or exceed the account's write rate (429 with `Retry-After`).
pub fn document_shared_refusals(doc: &mut utoipa::openapi::OpenApi) {
    use utoipa::openapi::{HttpMethod, RefOr, ResponseBuilder};
    let add = |op: &mut utoipa::openapi::path::Operation, status: &str, description: &str| {
        op.responses
            .responses
            .entry(status.to_string())
            .or_insert_with(|| RefOr::T(ResponseBuilder::new().description(description).build()));
    };
    for item in doc.paths.paths.values_mut() {
        for (method, op) in [
            (HttpMethod::Get, item.get.as_mut()),
            (HttpMethod::Post, item.post.as_mut()),
            (HttpMethod::Put, item.put.as_mut()),
            (HttpMethod::Patch, item.patch.as_mut()),
            (HttpMethod::Delete, item.delete.as_mut()),
        ] {
            let Some(op) = op else { continue };
            if op.request_body.is_some() {
                add(
                    op,
                    "400",
                    "Malformed body, or a value outside its documented range",
                );
                add(op, "413", "Body larger than the server's limit");
            }
            if op.parameters.as_ref().is_some_and(|p| !p.is_empty()) {
                add(op, "400", "Malformed path or query parameter");
            }
            let id = op.operation_id.as_deref().unwrap_or_default();
            let write = !matches!(method, HttpMethod::Get);
            if write && !UNAUTHENTICATED_WRITES.contains(&id) {
                add(op, "401", "No valid session");
                add(op, "403", "Missing or wrong CSRF token, or not allowed");
                add(
                    op,
                    "429",
                    "Too many writes from this account; `Retry-After` says when to retry",
                );
            }
            describe_error_bodies(op);
        }
    }
    doc.components
        .get_or_insert_with(Default::default)
        .schemas
        .insert("Error".into(), super::schema::error_body().into());
}

/// Every 4xx of the records API is an [`crate::error::ApiError`]: a JSON body `{"error": {"code",
/// "message"}}`, and on 429 a `Retry-After` header in seconds.
fn describe_error_bodies(op: &mut utoipa::openapi::path::Operation) {
    use utoipa::openapi::{ContentBuilder, Ref, RefOr, header::HeaderBuilder};
    for (status, response) in op.responses.responses.iter_mut() {
        let RefOr::T(response) = response else {
            continue;
        };
        if !status.starts_with('4') || !response.content.is_empty() {
            continue;
        }
        response.content.insert(
            "application/json".into(),
            ContentBuilder::new()
                .schema(Some(Ref::from_schema_name("Error")))
                .build(),
        );
        if status == "429" {
            response.headers.insert(
                "Retry-After".into(),
                HeaderBuilder::new()
                    .schema(
                        utoipa::openapi::ObjectBuilder::new()
                            .schema_type(utoipa::openapi::schema::Type::Integer)
                            .minimum(Some(0)),
                    )
                    .description(Some("Seconds to wait before retrying"))
                    .build(),
            );
        }
    }
}
