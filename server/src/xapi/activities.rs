//! The Activities resource (`GET /xapi/activities?activityId=...`, xAPI 2.0 Communication
//! "Activities Resource"): the Activity object with the canonical definition the LRS holds.
//!
//! The Statement resource keeps that definition in `xapi_activities` from the statements it
//! stores. An Activity the LRS has no definition of (never seen, or seen without one) is still
//! an Activity: the answer is `{"objectType": "Activity", "id": ...}` with 200, as the
//! specification asks.

use axum::Json;
use axum::extract::{RawQuery, State};
use serde_json::{Value, json};
use utoipa::IntoParams;

use super::auth::LrsClient;
use super::documents::params::{Iri, Params, QueryParams};
use super::error::XapiError;
use super::state::XapiState;
use super::version::VersionHeader;
use crate::error::ApiError;

/// Parameters of the Activities resource.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ActivitiesQuery {
    /// The Activity's IRI.
    #[param(inline, rename = "activityId")]
    activity_id: Iri,
}

impl QueryParams for ActivitiesQuery {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(ActivitiesQuery {
            activity_id: p.activity_id()?,
        })
    }
}

/// The Activity object: `objectType`, `id` and, when the LRS holds one, `definition`.
pub async fn activity(pool: &sqlx::PgPool, activity_id: &str) -> Result<Value, sqlx::Error> {
    let definition: Option<Value> =
        sqlx::query_scalar("SELECT definition FROM xapi_activities WHERE activity_id = $1")
            .bind(activity_id)
            .fetch_optional(pool)
            .await?;
    let mut activity = json!({ "objectType": "Activity", "id": activity_id });
    if let Some(def) = definition.filter(|d| d.as_object().is_some_and(|m| !m.is_empty())) {
        activity["definition"] = def;
    }
    Ok(activity)
}

/// The Activity object with its canonical definition.
#[utoipa::path(get, path = "/xapi/activities", tag = "xapi",
    params(VersionHeader, ActivitiesQuery),
    responses(
        (status = 200, body = serde_json::Value, description = "The Activity object (`objectType`, `id`, \
            and `definition` when the LRS holds one)"),
        (status = 400, description = "Missing or malformed activityId, or no version header"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not read")))]
pub async fn get_activities(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
) -> Result<Json<Value>, XapiError> {
    client.require_read()?;
    let activity_id = ActivitiesQuery::parse(query.as_deref())?.activity_id;
    Ok(Json(
        activity(&state.pool, &activity_id.into_string()).await?,
    ))
}
