//! Learning records: accounts, roles and sessions; courses; stations; attempts with append-only
//! engagement activity; technical results from the rubric engine; faculty review and audit.
//!
//! Three records are kept apart on purpose (see ARCHITECTURE.md and the reference system's
//! "Learning activity & technical assessment" rules):
//!
//! * **engagement** (`activity_events`): what the learner did, recorded by the server, append-only;
//!   reading a page is engagement, never self-certified completion;
//! * **technical results** (`technical_results`): rubric-engine output on measurements, with the
//!   station and rubric revisions and a reproducibility record; "met" is a technical statement,
//!   never a certification of clinical competency;
//! * **faculty approval** (`reviews`): a person's decision, by faculty of the learner's course,
//!   never by the learner themselves, with a comment, in the audit trail.
//!
//! Architecture invariant: every query that reads or changes an attempt carries the caller's
//! identity and role in its `WHERE` clause ([`authz`]); handlers never fetch first and filter in
//! Rust.
//!
//! The module is mounted by [`router`], which returns the axum router and the OpenAPI document
//! generated from the handlers' annotations (served at `/api/openapi.json`).

pub mod attempts;
pub mod auth;
pub mod authz;
pub mod cli;
pub mod config;
pub mod courses;
pub mod demo;
pub mod extract;
pub mod password;
pub mod ratelimit;
pub mod reviews;
pub mod stations;
pub mod totp;
pub mod users;

use std::sync::Arc;

use axum::Router;
use axum::routing::get;
use sqlx::PgPool;
use utoipa::OpenApi;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

pub use config::RecordsConfig;
pub use stations::StationCatalog;

/// State shared by the learning-records handlers. Cheap to clone.
#[derive(Clone)]
pub struct RecordsState {
    /// Database pool (the same one as the rest of the server).
    pub pool: PgPool,
    /// Settings.
    pub config: Arc<RecordsConfig>,
    /// Stations loaded from `assets/stations/` and registered in the database.
    pub stations: Arc<StationCatalog>,
    /// Per-client limiter of the authentication endpoints.
    pub auth_limiter: Arc<ratelimit::RateLimiter>,
    /// Hash verified against when a login names an unknown e-mail (made once, on first need, so
    /// that unknown and known e-mails cost the same single verification).
    pub decoy_hash: Arc<std::sync::OnceLock<String>>,
}

impl RecordsState {
    /// Builds the state for [`crate::app`]: loads the stations synchronously. A station directory
    /// that fails to load is logged and leaves the catalog empty; [`prepare`], which start-up
    /// runs first, turns the same failure into a start-up error.
    pub fn from_parts(pool: PgPool, config: RecordsConfig) -> RecordsState {
        let stations = StationCatalog::load(&config.stations_dir).unwrap_or_else(|e| {
            tracing::error!(error = %format!("{e:#}"), "no stations available");
            StationCatalog::default()
        });
        let auth_limiter =
            ratelimit::RateLimiter::new(config.auth_rate_per_minute, config.auth_burst);
        RecordsState {
            pool,
            config: Arc::new(config),
            stations: Arc::new(stations),
            auth_limiter: Arc::new(auth_limiter),
            decoy_hash: Arc::default(),
        }
    }
}

/// Start-up work of the learning records, run before serving: loads the stations and registers
/// their revisions (failing if a published revision was edited in place), and with the embedded
/// database creates the demo accounts and returns the notice to print.
pub async fn prepare(
    pool: &PgPool,
    config: &RecordsConfig,
    embedded_db: bool,
) -> anyhow::Result<Option<String>> {
    let stations = StationCatalog::load(&config.stations_dir)?;
    stations.register(pool).await?;
    tracing::info!(stations = stations.stations.len(), "stations registered");
    if !embedded_db {
        return Ok(None);
    }
    let accounts = demo::ensure_demo_accounts(pool, config.argon2).await?;
    Ok(Some(demo::startup_notice(&accounts)))
}

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

/// The learning-records API router (with its state applied) and its OpenAPI document.
pub fn router<S: Clone + Send + Sync + 'static>(
    state: RecordsState,
) -> (Router<S>, utoipa::openapi::OpenApi) {
    let (router, doc) = OpenApiRouter::with_openapi(ApiDoc::openapi())
        .routes(routes!(auth::login))
        .routes(routes!(auth::logout))
        .routes(routes!(auth::me))
        .routes(routes!(auth::totp_enroll))
        .routes(routes!(auth::totp_confirm))
        .routes(routes!(users::create_user_handler, users::list_users))
        .routes(routes!(courses::create_course, courses::list_courses))
        .routes(routes!(courses::get_course))
        .routes(routes!(courses::put_member))
        .routes(routes!(stations::list_stations))
        .routes(routes!(stations::get_station))
        .routes(routes!(attempts::create_attempt, attempts::list_attempts))
        .routes(routes!(attempts::get_attempt))
        .routes(routes!(attempts::post_activity, attempts::list_activity))
        .routes(routes!(attempts::submit_result))
        .routes(routes!(reviews::review_attempt))
        .routes(routes!(reviews::review_queue))
        .routes(routes!(reviews::export_csv))
        .routes(routes!(reviews::bulk_approve))
        .routes(routes!(reviews::audit_trail))
        .with_state(state)
        .split_for_parts();
    let served = Arc::new(doc.clone());
    let router = router.route(
        "/api/openapi.json",
        get(move || {
            let doc = served.clone();
            async move { axum::Json(doc.as_ref().clone()) }
        }),
    );
    (router, doc)
}
