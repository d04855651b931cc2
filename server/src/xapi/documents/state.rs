//! The State resource (`/xapi/activities/state`, xAPI 2.0 Communication "State Resource"): a
//! scratch area of documents per Activity, Agent (or identified Group) and optional registration.
//!
//! With `stateId`, each method acts on that one document; the registration is part of its key
//! (a document stored without one is not the one stored with one). Without `stateId`, GET lists
//! the ids of the Activity's and Agent's documents (of one registration if given, else of all;
//! `since` keeps those stored after it) and DELETE deletes them.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{RawQuery, State};
use axum::http::HeaderMap;
use axum::response::Response;
use time::OffsetDateTime;
use utoipa::IntoParams;
use uuid::Uuid;

use super::ops::{Preconditions, Write};
use super::params::{AgentJson, DocumentId, Iri, Params, QueryParams};
use super::resource::{self, DocumentResource, NamesDocument, NamesTarget, Target};
use super::store::{DocKey, Kind, Scope};
use crate::error::ApiError;
use crate::xapi::auth::LrsClient;
use crate::xapi::error::XapiError;
use crate::xapi::state::XapiState;
use crate::xapi::version::VersionHeader;

/// The State resource, for the generic implementation of [`resource`].
pub struct StateResource;

impl DocumentResource for StateResource {
    type Get = StateQuery;
    type Write = StateDocument;
    type Delete = StateDelete;
}

/// Parameters of PUT and POST: one document.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct StateDocument {
    /// The Activity's IRI.
    #[param(inline, rename = "activityId")]
    activity_id: Iri,
    /// The Agent or identified Group (JSON).
    #[param(inline)]
    agent: AgentJson,
    /// The registration (a UUID), if the state belongs to one.
    registration: Option<Uuid>,
    /// The document's id.
    #[param(inline, rename = "stateId")]
    state_id: DocumentId,
}

/// Parameters of GET: one document with `stateId`, else the ids of all.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct StateQuery {
    /// The Activity's IRI.
    #[param(inline, rename = "activityId")]
    activity_id: Iri,
    /// The Agent or identified Group (JSON).
    #[param(inline)]
    agent: AgentJson,
    /// The registration (a UUID): part of a document's key; without `stateId`, keeps only that
    /// registration's ids.
    registration: Option<Uuid>,
    /// The document's id; without it, the response is the array of ids.
    #[param(inline, rename = "stateId")]
    state_id: Option<DocumentId>,
    /// Without `stateId`: only ids of documents stored after this time (exclusive).
    #[param(value_type = Option<String>, format = DateTime)]
    since: Option<OffsetDateTime>,
}

/// Parameters of DELETE: one document with `stateId`, else all.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct StateDelete {
    /// The Activity's IRI.
    #[param(inline, rename = "activityId")]
    activity_id: Iri,
    /// The Agent or identified Group (JSON).
    #[param(inline)]
    agent: AgentJson,
    /// The registration (a UUID): part of a document's key; without `stateId`, deletes only
    /// that registration's documents.
    registration: Option<Uuid>,
    /// The document's id; without it, every matching document is deleted.
    #[param(inline, rename = "stateId")]
    state_id: Option<DocumentId>,
}

/// The states of one Activity and Agent.
fn scope(activity_id: Iri, agent: AgentJson) -> Scope {
    Scope {
        kind: Kind::State,
        activity_id: activity_id.into_string(),
        agent_key: agent.into_agent().key,
    }
}

impl QueryParams for StateDocument {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(StateDocument {
            activity_id: p.activity_id()?,
            agent: p.agent(true)?,
            registration: p.registration()?,
            state_id: p.document_id("stateId")?,
        })
    }
}

impl NamesDocument for StateDocument {
    fn key(self) -> DocKey {
        DocKey {
            scope: scope(self.activity_id, self.agent),
            registration: self.registration,
            document_id: self.state_id.into_string(),
        }
    }
}

impl QueryParams for StateQuery {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(StateQuery {
            activity_id: p.activity_id()?,
            agent: p.agent(true)?,
            registration: p.registration()?,
            since: p.since()?,
            state_id: p.optional_document_id("stateId")?,
        })
    }
}

impl NamesTarget for StateQuery {
    fn target(self) -> Target {
        let scope = scope(self.activity_id, self.agent);
        Target::of(scope, self.registration, self.state_id, self.since)
    }
}

impl QueryParams for StateDelete {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(StateDelete {
            activity_id: p.activity_id()?,
            agent: p.agent(true)?,
            registration: p.registration()?,
            state_id: p.optional_document_id("stateId")?,
        })
    }
}

impl NamesTarget for StateDelete {
    fn target(self) -> Target {
        let scope = scope(self.activity_id, self.agent);
        Target::of(scope, self.registration, self.state_id, None)
    }
}

/// Fetch one state document, or the ids of the matching ones.
#[utoipa::path(get, path = "/xapi/activities/state", tag = "xapi",
    params(VersionHeader, StateQuery),
    responses(
        (status = 200, description = "With `stateId`: the document as stored, with its \
            Content-Type, `ETag` and `Last-Modified`. Without: a JSON array of state ids, with \
            `Last-Modified` of the newest",
            content((serde_json::Value = "application/json"), (Vec<u8> = "application/octet-stream"))),
        (status = 400, description = "Missing or malformed parameter, or no version header"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not read"),
        (status = 404, description = "No such document")))]
pub async fn get_state(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
) -> Result<Response, XapiError> {
    resource::get::<StateResource>(client, &state, query).await
}

/// Store a state document, replacing any (a document that exists needs `If-Match`).
#[utoipa::path(put, path = "/xapi/activities/state", tag = "xapi",
    params(VersionHeader, Preconditions, StateDocument),
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
pub async fn put_state(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, XapiError> {
    resource::write::<StateResource>(client, &state, query, headers, body, Write::Put).await
}

/// Store a state document, merging a JSON object into a stored JSON object.
#[utoipa::path(post, path = "/xapi/activities/state", tag = "xapi",
    params(VersionHeader, Preconditions, StateDocument),
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
pub async fn post_state(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, XapiError> {
    resource::write::<StateResource>(client, &state, query, headers, body, Write::Post).await
}

/// Delete one state document, or all the matching ones.
#[utoipa::path(delete, path = "/xapi/activities/state", tag = "xapi",
    params(VersionHeader, Preconditions, StateDelete),
    responses(
        (status = 204, description = "Deleted (or there was nothing to delete)"),
        (status = 400, description = "Missing or malformed parameter"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not write"),
        (status = 412, description = "With `stateId`: If-Match or If-None-Match failed; \
            nothing changed")))]
pub async fn delete_state(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
) -> Result<Response, XapiError> {
    resource::delete::<StateResource>(client, &state, query, headers).await
}
