//! The learning record store (xAPI 2.0, IEEE 9274.1.1) under `/xapi/`, and the LMS integrations'
//! credentials.
//!
//! LMS integrations, the platform's third kind of user, post and read activity records here with
//! per-integration credentials (HTTP Basic; created and revoked by an admin in [`credentials`],
//! checked by the [`auth::LrsClient`] extractor, scoped read and/or write; the credential's agent
//! is the authority of every statement stored through it).
//!
//! Architecture invariant: the modules form layers, and each imports only from layers below it:
//!
//! 1. `error` ([`XapiError`], the failures only the LRS answers, converting into the API's
//!    [`crate::error::ApiError`], and [`error::Invalid`], data that breaks the data model),
//!    `version` (the `X-Experience-API-Version` header on every request and response), `agent`
//!    and `validate` (the data model: Agents and Groups, their identity keys, whole statements);
//! 2. `state` ([`XapiState`]), then `auth` (the credential extractor), `version_gate` (the
//!    middleware that refuses a request without an accepted version, answered in the version
//!    of its credential) and `alternate` (the xAPI 1.0.3 Alternate Request Syntax, rewritten into
//!    ordinary requests);
//! 3. the resources: `about`, `statements`, `documents` (State, Activity Profile, Agent
//!    Profile), `agents`, `activities`, and `credentials` (admin endpoints under `/api/admin/`);
//! 4. the platform's own statements: `platform` (records become statements through a queue the
//!    records' triggers fill) and `forward` (to an institution's LRS, from the durable outbox);
//! 5. `routes`: the router and its OpenAPI document.
//!
//! The LRS builds on the learning records (`crate::records`: the admin's session, the users) and
//! never the reverse: the records know nothing of xAPI.

pub mod about;
pub mod activities;
pub mod agent;
pub mod agents;
pub mod alternate;
pub mod auth;
pub mod credentials;
pub mod documents;
pub mod error;
pub mod forward;
pub mod platform;
pub mod routes;
pub mod state;
pub mod statements;
pub mod validate;
pub mod version;
pub mod version_gate;

pub use error::XapiError;
pub use routes::router;
pub use state::XapiState;
