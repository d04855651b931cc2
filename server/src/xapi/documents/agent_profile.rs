//! The Agent Profile resource (`/xapi/agents/profile`, xAPI 2.0 Communication "Agent Profile
//! Resource"): documents about an Agent, by `profileId`. Without `profileId`, GET lists the
//! Agent's profile ids (`since` keeps those stored after it).
//!
//! The `agent` is an Agent; an identified Group is read as the Agent with the same identifier
//! (the specification's advice for storing a Group's profile), so both reach the same documents.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{RawQuery, State};
use axum::http::HeaderMap;
use axum::response::Response;
use time::OffsetDateTime;
use utoipa::IntoParams;

use super::ops::{Preconditions, Write};
use super::params::{AgentJson, DocumentId, Params, QueryParams};
use super::resource::{self, DocumentResource, NamesDocument, NamesTarget, Target};
use super::store::{DocKey, Kind, Scope};
use crate::error::ApiError;
use crate::xapi::auth::LrsClient;
use crate::xapi::error::XapiError;
use crate::xapi::state::XapiState;
use crate::xapi::version::VersionHeader;

/// The Agent Profile resource, for the generic implementation of [`resource`].
pub struct AgentProfileResource;

impl DocumentResource for AgentProfileResource {
    type Get = AgentProfileQuery;
    type Write = AgentProfileDocument;
    type Delete = AgentProfileDocument;
}

/// Parameters of PUT, POST and DELETE: one document.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct AgentProfileDocument {
    /// The Agent (JSON).
    #[param(inline)]
    agent: AgentJson,
    /// The document's id.
    #[param(inline, rename = "profileId")]
    profile_id: DocumentId,
}

/// Parameters of GET: one document with `profileId`, else the ids of all.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct AgentProfileQuery {
    /// The Agent (JSON).
    #[param(inline)]
    agent: AgentJson,
    /// The document's id; without it, the response is the array of ids.
    #[param(inline, rename = "profileId")]
    profile_id: Option<DocumentId>,
    /// Without `profileId`: only ids of documents stored after this time (exclusive).
    #[param(value_type = Option<String>, format = DateTime)]
    since: Option<OffsetDateTime>,
}

/// The profiles of one Agent.
fn scope(agent: AgentJson) -> Scope {
    Scope {
        kind: Kind::AgentProfile,
        activity_id: String::new(),
        agent_key: agent.into_agent().key,
    }
}

impl QueryParams for AgentProfileDocument {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(AgentProfileDocument {
            agent: p.agent(true)?,
            profile_id: p.document_id("profileId")?,
        })
    }
}

impl NamesDocument for AgentProfileDocument {
    fn key(self) -> DocKey {
        DocKey {
            scope: scope(self.agent),
            registration: None,
            document_id: self.profile_id.into_string(),
        }
    }
}

impl QueryParams for AgentProfileQuery {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(AgentProfileQuery {
            agent: p.agent(true)?,
            since: p.since()?,
            profile_id: p.optional_document_id("profileId")?,
        })
    }
}

impl NamesTarget for AgentProfileQuery {
    fn target(self) -> Target {
        let scope = scope(self.agent);
        Target::of(scope, None, self.profile_id, self.since)
    }
}

/// Fetch one agent profile document, or the Agent's profile ids.
#[utoipa::path(get, path = "/xapi/agents/profile", tag = "xapi",
    params(VersionHeader, AgentProfileQuery),
    responses(
        (status = 200, description = "With `profileId`: the document as stored, with its \
            Content-Type, `ETag` and `Last-Modified`. Without: a JSON array of profile ids, with \
            `Last-Modified` of the newest",
            content((serde_json::Value = "application/json"), (Vec<u8> = "application/octet-stream"))),
        (status = 400, description = "Missing or malformed parameter, or no version header"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not read"),
        (status = 404, description = "No such document")))]
pub async fn get_agent_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
) -> Result<Response, XapiError> {
    resource::get::<AgentProfileResource>(client, &state, query).await
}

/// Store an agent profile document, replacing any (a document that exists needs `If-Match`).
#[utoipa::path(put, path = "/xapi/agents/profile", tag = "xapi",
    params(VersionHeader, Preconditions, AgentProfileDocument),
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
pub async fn put_agent_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, XapiError> {
    resource::write::<AgentProfileResource>(client, &state, query, headers, body, Write::Put).await
}

/// Store an agent profile document, merging a JSON object into a stored JSON object.
#[utoipa::path(post, path = "/xapi/agents/profile", tag = "xapi",
    params(VersionHeader, Preconditions, AgentProfileDocument),
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
pub async fn post_agent_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, XapiError> {
    resource::write::<AgentProfileResource>(client, &state, query, headers, body, Write::Post).await
}

/// Delete one agent profile document.
#[utoipa::path(delete, path = "/xapi/agents/profile", tag = "xapi",
    params(VersionHeader, Preconditions, AgentProfileDocument),
    responses(
        (status = 204, description = "Deleted (or there was nothing to delete)"),
        (status = 400, description = "Missing or malformed parameter"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not write"),
        (status = 412, description = "If-Match or If-None-Match failed; nothing changed")))]
pub async fn delete_agent_profile(
    client: LrsClient,
    State(state): State<XapiState>,
    RawQuery(query): RawQuery,
    headers: HeaderMap,
) -> Result<Response, XapiError> {
    resource::delete::<AgentProfileResource>(client, &state, query, headers).await
}
