//! The Activity Profile resource (`/xapi/activities/profile`, xAPI 2.0 Communication "Activity
//! Profile Resource"): documents about an Activity, by `profileId`. Without `profileId`, GET
//! lists the Activity's profile ids (`since` keeps those stored after it).

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{RawQuery, State};
use axum::http::HeaderMap;
use axum::response::Response;
use time::OffsetDateTime;
use utoipa::IntoParams;

use super::ops::{Preconditions, Write};
use super::params::{DocumentId, Iri, Params, QueryParams};
use super::resource::{self, DocumentResource, NamesDocument, NamesTarget, Target};
use super::store::{DocKey, Kind, Scope};
use crate::error::ApiError;
use crate::xapi::auth::LrsClient;
use crate::xapi::error::XapiError;
use crate::xapi::state::XapiState;
use crate::xapi::version::VersionHeader;

/// The Activity Profile resource, for the generic implementation of [`resource`].
pub struct ActivityProfileResource;

impl DocumentResource for ActivityProfileResource {
    type Get = ActivityProfileQuery;
    type Write = ActivityProfileDocument;
    type Delete = ActivityProfileDocument;
}

/// Parameters of PUT, POST and DELETE: one document.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ActivityProfileDocument {
    /// The Activity's IRI.
    #[param(inline, rename = "activityId")]
    activity_id: Iri,
    /// The document's id.
    #[param(inline, rename = "profileId")]
    profile_id: DocumentId,
}

/// Parameters of GET: one document with `profileId`, else the ids of all.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ActivityProfileQuery {
    /// The Activity's IRI.
    #[param(inline, rename = "activityId")]
    activity_id: Iri,
    /// The document's id; without it, the response is the array of ids.
    #[param(inline, rename = "profileId")]
    profile_id: Option<DocumentId>,
    /// Without `profileId`: only ids of documents stored after this time (exclusive).
    #[param(value_type = Option<String>, format = DateTime)]
    since: Option<OffsetDateTime>,
}

/// The profiles of one Activity.
fn scope(activity_id: Iri) -> Scope {
    Scope {
        kind: Kind::ActivityProfile,
        activity_id: activity_id.into_string(),
        agent_key: String::new(),
    }
}

impl QueryParams for ActivityProfileDocument {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(ActivityProfileDocument {
            activity_id: p.activity_id()?,
            profile_id: p.document_id("profileId")?,
        })
    }
}

impl NamesDocument for ActivityProfileDocument {
    fn key(self) -> DocKey {
        DocKey {
            scope: scope(self.activity_id),
            registration: None,
            document_id: self.profile_id.into_string(),
        }
    }
}

impl QueryParams for ActivityProfileQuery {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(ActivityProfileQuery {
            activity_id: p.activity_id()?,
            since: p.since()?,
            profile_id: p.optional_document_id("profileId")?,
        })
    }
}

impl NamesTarget for ActivityProfileQuery {
    fn target(self) -> Target {
        let scope = scope(self.activity_id);
        Target::of(scope, None, self.profile_id, self.since)
    }
}

/// Fetch one activity profile document, or the Activity's profile ids.
#[utoipa::path(get, path = "/xapi/activities/profile", tag = "xapi",
    params(VersionHeader, ActivityProfileQuery),
    responses(
        (status = 200, description = "With `profileId`: the document as stored, with its \
            Content-Type, `ETag` and `Last-Modified`. Without: a JSON array of profile ids, with \
            `Last-Modified` of the newest",
            content((serde_json::Value = "application/json"), (Vec<u8> = "application/octet-stream"))),
        (status = 400, description = "Missing or malformed parameter, or no version header"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not read"),
        (status = 404, description = "No such document")))]
pub async fn get_activity_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
) -> Result<Response, XapiError> {
    resource::get::<ActivityProfileResource>(client, &state, query).await
}

/// Store an activity profile document, replacing any (a document that exists needs `If-Match`).
#[utoipa::path(put, path = "/xapi/activities/profile", tag = "xapi",
    params(VersionHeader, Preconditions, ActivityProfileDocument),
    request_body(description = "The document: any content type, stored as sent",
        content((serde_json::Value = "application/json"), (Vec<u8> = "application/octet-stream"))),
    responses(
        (status = 204, description = "Stored; `ETag` names the new content"),
        (status = 400, description = "Missing or malformed parameter, or an application/json \
            document that is not JSON"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not write"),
        (status = 409, description = "The document exists and neither If-Match nor \
            If-None-Match was sent"),
        (status = 412, description = "If-Match or If-None-Match failed; nothing changed"),
        (status = 413, description = "Body larger than the server's limit")))]
pub async fn put_activity_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, XapiError> {
    resource::write::<ActivityProfileResource>(client, &state, query, headers, body, Write::Put)
        .await
}

/// Store an activity profile document, merging a JSON object into a stored JSON object.
#[utoipa::path(post, path = "/xapi/activities/profile", tag = "xapi",
    params(VersionHeader, Preconditions, ActivityProfileDocument),
    request_body(description = "The document. Merged into a stored one (top-level properties \
        replaced) when both are application/json objects; stored as sent when none exists",
        content((serde_json::Value = "application/json"), (Vec<u8> = "application/octet-stream"))),
    responses(
        (status = 204, description = "Stored or merged; `ETag` names the new content"),
        (status = 400, description = "Missing or malformed parameter, or a merge of documents \
            that are not both JSON objects (nothing changed)"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not write"),
        (status = 412, description = "If-Match or If-None-Match failed; nothing changed"),
        (status = 413, description = "Body larger than the server's limit")))]
pub async fn post_activity_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, XapiError> {
    resource::write::<ActivityProfileResource>(client, &state, query, headers, body, Write::Post)
        .await
}

/// Delete one activity profile document.
#[utoipa::path(delete, path = "/xapi/activities/profile", tag = "xapi",
    params(VersionHeader, Preconditions, ActivityProfileDocument),
    responses(
        (status = 204, description = "Deleted (or there was nothing to delete)"),
        (status = 400, description = "Missing or malformed parameter"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not write"),
        (status = 412, description = "If-Match or If-None-Match failed; nothing changed")))]
pub async fn delete_activity_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
) -> Result<Response, XapiError> {
    resource::delete::<ActivityProfileResource>(client, &state, query, headers).await
}
