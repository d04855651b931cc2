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
use utoipa::IntoParams;
use uuid::Uuid;

use super::ops::{self, Write};
use super::params::Params;
use super::store::{DocKey, Kind, Scope};
use super::{AgentJson, DocumentId, Iri, Preconditions, VersionHeader};
use crate::xapi::auth::LrsClient;
use crate::xapi::error::XapiError;
use crate::xapi::state::XapiState;

/// Parameters of PUT and POST: one document.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
#[allow(dead_code)]
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
#[allow(dead_code)]
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
    #[param(format = DateTime)]
    since: Option<String>,
}

/// Parameters of DELETE: one document with `stateId`, else all.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
#[allow(dead_code)]
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

const WRITE_PARAMS: [&str; 4] = ["activityId", "agent", "registration", "stateId"];
const GET_PARAMS: [&str; 5] = ["activityId", "agent", "registration", "stateId", "since"];

fn scope(p: &Params) -> Result<Scope, XapiError> {
    let activity_id = p.activity_id()?;
    let (_, agent_key) = p.agent(true)?;
    Ok(Scope {
        kind: Kind::State,
        activity_id,
        agent_key,
    })
}

fn doc_key(p: &Params) -> Result<DocKey, XapiError> {
    Ok(DocKey {
        scope: scope(p)?,
        registration: p.registration()?,
        document_id: p.document_id("stateId")?,
    })
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
    client.require_read()?;
    let p = Params::parse(query.as_deref(), &GET_PARAMS)?;
    let scope = scope(&p)?;
    let registration = p.registration()?;
    let since = p.since()?;
    match p.optional_document_id("stateId")? {
        Some(document_id) => {
            let key = DocKey {
                scope,
                registration,
                document_id,
            };
            ops::get_one(&state.pool, &key).await
        }
        None => ops::get_ids(&state.pool, &scope, registration, since).await,
    }
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
    let req = ops::WriteRequest::new(client, query, &WRITE_PARAMS, headers, body);
    req.run(&state, doc_key, Write::Put).await
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
    let req = ops::WriteRequest::new(client, query, &WRITE_PARAMS, headers, body);
    req.run(&state, doc_key, Write::Post).await
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
    client.require_write()?;
    let p = Params::parse(query.as_deref(), &WRITE_PARAMS)?;
    let scope = scope(&p)?;
    let registration = p.registration()?;
    match p.optional_document_id("stateId")? {
        Some(document_id) => {
            let key = DocKey {
                scope,
                registration,
                document_id,
            };
            ops::delete_one(&state.pool, &key, &headers).await
        }
        None => ops::delete_all(&state.pool, &scope, registration).await,
    }
}
