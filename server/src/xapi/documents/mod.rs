//! The document resources of the LRS (xAPI 2.0, IEEE 9274.1.1, Communication "Document
//! Resources"): State (`/xapi/activities/state`), Activity Profile (`/xapi/activities/profile`)
//! and Agent Profile (`/xapi/agents/profile`).
//!
//! Each keeps arbitrary documents (any bytes, any Content-Type) under an id in a context: State
//! under an Activity, an Agent and optionally a registration; Activity Profile under an Activity;
//! Agent Profile under an Agent. Agents are keyed by their identity ([`crate::xapi::agent::ifi_key`]):
//! an Agent given with a name and an mbox and one given with the mbox alone have the same
//! documents. The LRS needs no prior knowledge of the Activity or Agent.
//!
//! Layers: [`params`] (query parameters) and [`store`] (the table) below [`ops`] (concurrency,
//! merge, responses), below the three resources' handlers.

pub mod activity_profile;
pub mod agent_profile;
pub mod ops;
pub mod params;
pub mod state;
pub mod store;

use utoipa::{IntoParams, ToSchema};

/// The version header every LRS request but About sends (documented here so that the OpenAPI
/// document states it: the version middleware refuses requests without it).
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Header)]
#[allow(dead_code)]
pub struct VersionHeader {
    /// The xAPI version the client speaks: 2.0.x (this LRS's) or 1.0.x.
    #[param(
        rename = "X-Experience-API-Version",
        pattern = r"^[12]\.0(\.[0-9]{1,4})?$"
    )]
    version: String,
}

/// The concurrency headers of document writes.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Header)]
#[allow(dead_code)]
pub struct Preconditions {
    /// Write only if the document's ETag is one of these (or `*`: if it exists); else 412.
    #[param(rename = "If-Match")]
    if_match: Option<String>,
    /// Write only if the document's ETag is none of these (or `*`: if it does not exist); else
    /// 412.
    #[param(rename = "If-None-Match")]
    if_none_match: Option<String>,
}

/// An absolute IRI (RFC 3987), as [`params::is_iri`] accepts it: a scheme, a colon, and no
/// whitespace, control characters or `<>"{}|\^` and backtick.
#[derive(Debug, ToSchema)]
#[schema(pattern = r#"^[A-Za-z][A-Za-z0-9+.\-]*:[^\s\x00-\x1f\x7f-\x9f<>"{}|\\^`]+$"#)]
#[allow(dead_code)]
pub struct Iri(String);

/// A JSON Agent object (`{"objectType": "Agent", "mbox": "mailto:..."}` or with one other
/// identifier: `mbox_sha1sum`, `openid`, `account`), as text in the query.
#[derive(Debug, ToSchema)]
#[schema(pattern = r"^\s*\{[^\x00]*\}\s*$")]
#[allow(dead_code)]
pub struct AgentJson(String);

/// A document id (`stateId`, `profileId`): any non-empty text.
#[derive(Debug, ToSchema)]
#[schema(pattern = r"^[^\x00]+$")]
#[allow(dead_code)]
pub struct DocumentId(String);
