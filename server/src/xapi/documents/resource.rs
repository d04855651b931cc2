//! The one implementation of the three document resources' methods, generic over the resource.
//!
//! A resource is what its parameter structs name: the key columns of its documents in
//! `xapi_documents` (State: Activity, Agent, registration and `stateId`; Activity Profile:
//! Activity and `profileId`; Agent Profile: Agent and `profileId`) and whether a request names one
//! document or all of a scope's. Everything else is shared: the credential's scope first (403),
//! then the parameters (400), then the document (413, 400), then the concurrency rules and the
//! store ([`super::ops`]).

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::http::HeaderMap;
use axum::response::Response;
use time::OffsetDateTime;
use uuid::Uuid;

use super::ops::{self, Incoming, Write};
use super::params::{DocumentId, QueryParams};
use super::store::{DocKey, Scope};
use crate::xapi::auth::LrsClient;
use crate::xapi::error::XapiError;
use crate::xapi::state::XapiState;

/// What a GET or DELETE names: one document, or all of a scope's.
#[derive(Debug, Clone)]
pub enum Target {
    /// The document with this key.
    One(DocKey),
    /// The scope's documents: of one registration if given (State only), and for GET only those
    /// stored after `since` (exclusive) if given.
    All {
        /// Resource, Activity, Agent.
        scope: Scope,
        /// The registration.
        registration: Option<Uuid>,
        /// Stored after this time.
        since: Option<OffsetDateTime>,
    },
}

impl Target {
    /// The document `document_id` of `scope` (and `registration`) when the request names one,
    /// else all of them (stored after `since`, for GET).
    pub fn of(
        scope: Scope,
        registration: Option<Uuid>,
        document_id: Option<DocumentId>,
        since: Option<OffsetDateTime>,
    ) -> Target {
        match document_id {
            Some(id) => Target::One(DocKey {
                scope,
                registration,
                document_id: id.into_string(),
            }),
            None => Target::All {
                scope,
                registration,
                since,
            },
        }
    }
}

/// The parameters of a write (PUT, POST): exactly one document.
pub trait NamesDocument: QueryParams {
    /// The document's key.
    fn key(self) -> DocKey;
}

/// The parameters of a GET or DELETE: one document, or all of a scope's.
pub trait NamesTarget: QueryParams {
    /// The document or documents named.
    fn target(self) -> Target;
}

/// Every parameter struct that names exactly one document names a target too (the profile
/// resources delete one document at a time).
impl<T: NamesDocument> NamesTarget for T {
    fn target(self) -> Target {
        Target::One(self.key())
    }
}

/// A document resource: the parameter structs of its methods, each as its OpenAPI document
/// shows it.
pub trait DocumentResource {
    /// GET: one document, or the ids of all.
    type Get: NamesTarget;
    /// PUT and POST: one document.
    type Write: NamesDocument;
    /// DELETE: one document, or (State) all.
    type Delete: NamesTarget;
}

/// GET: the document (200 with its Content-Type, ETag and Last-Modified; 404 when there is none),
/// or the JSON array of the scope's ids.
pub async fn get<R: DocumentResource>(
    client: LrsClient,
    state: &XapiState,
    query: Option<String>,
) -> Result<Response, XapiError> {
    client.require_read()?;
    Ok(match R::Get::parse(query.as_deref())?.target() {
        Target::One(key) => ops::get_one(&state.pool, &key, client.spoken).await?,
        Target::All {
            scope,
            registration,
            since,
        } => ops::get_ids(&state.pool, &scope, registration, since).await?,
    })
}

/// PUT (store, replacing) or POST (store, merging JSON objects): 204 with the new ETag.
pub async fn write<R: DocumentResource>(
    client: LrsClient,
    state: &XapiState,
    query: Option<String>,
    headers: HeaderMap,
    body: Result<Bytes, BytesRejection>,
    write: Write,
) -> Result<Response, XapiError> {
    client.require_write()?;
    let key = R::Write::parse(query.as_deref())?.key();
    let doc = Incoming::read(&headers, body, state.max_body_bytes)?;
    ops::store(&state.pool, &key, &headers, write, doc, client.spoken).await
}

/// DELETE: of one document (its preconditions honoured), or of all the scope's; 204.
pub async fn delete<R: DocumentResource>(
    client: LrsClient,
    state: &XapiState,
    query: Option<String>,
    headers: HeaderMap,
) -> Result<Response, XapiError> {
    client.require_write()?;
    match R::Delete::parse(query.as_deref())?.target() {
        Target::One(key) => ops::delete_one(&state.pool, &key, &headers, client.spoken).await,
        Target::All {
            scope,
            registration,
            ..
        } => Ok(ops::delete_all(&state.pool, &scope, registration).await?),
    }
}
