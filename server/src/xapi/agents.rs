//! The Agents resource (`GET /xapi/agents?agent=...`, xAPI 2.0 Communication "Agents Resource"):
//! the Person object of an Agent.
//!
//! A Person lists, in arrays, every name and identifier the LRS knows for the person behind an
//! Agent. This LRS merges no identities (no directory service stands behind it), so the Person
//! holds what the requested Agent itself says: its name, if given, and its one identifier. The
//! specification requires exactly that for an Agent the LRS has no more information about,
//! including one it has never seen.

use axum::Json;
use axum::extract::RawQuery;
use serde::Serialize;
use serde_json::Value;
use utoipa::{IntoParams, ToSchema};

use super::auth::LrsClient;
use super::documents::params::{AgentJson, Params, QueryParams};
use super::error::XapiError;
use super::version::VersionHeader;
use crate::error::ApiError;

/// Parameters of the Agents resource.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Query)]
pub struct AgentsQuery {
    /// The Agent (JSON; not a Group).
    #[param(inline)]
    agent: AgentJson,
}

impl QueryParams for AgentsQuery {
    fn read(p: &Params) -> Result<Self, ApiError> {
        Ok(AgentsQuery {
            agent: p.agent(false)?,
        })
    }
}

/// An xAPI Person object: the names and identifiers of one person, each an array.
#[derive(Debug, Default, Serialize, ToSchema)]
pub struct Person {
    /// Always `Person`.
    #[serde(rename = "objectType")]
    pub object_type: String,
    /// Names.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub name: Vec<String>,
    /// `mailto:` IRIs.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub mbox: Vec<String>,
    /// SHA-1 hashes of `mailto:` IRIs, hex.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub mbox_sha1sum: Vec<String>,
    /// OpenIDs.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub openid: Vec<String>,
    /// Accounts (`homePage` and `name`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    #[schema(value_type = Vec<Object>)]
    pub account: Vec<Value>,
}

impl Person {
    /// The Person of one Agent: its name and identifier.
    pub fn of_agent(agent: &Value) -> Person {
        let text = |k: &str| {
            agent
                .get(k)
                .and_then(Value::as_str)
                .map(str::to_owned)
                .into_iter()
                .collect::<Vec<_>>()
        };
        Person {
            object_type: "Person".into(),
            name: text("name"),
            mbox: text("mbox"),
            mbox_sha1sum: text("mbox_sha1sum"),
            openid: text("openid"),
            account: agent.get("account").cloned().into_iter().collect(),
        }
    }
}

/// The Person object of an Agent.
#[utoipa::path(get, path = "/xapi/agents", tag = "xapi",
    params(VersionHeader, AgentsQuery),
    responses(
        (status = 200, body = Person, description = "The Agent's Person object"),
        (status = 400, description = "Missing or malformed agent (or a Group), or no version \
            header"),
        (status = 401, description = "No valid LRS credential"),
        (status = 403, description = "The credential may not read")))]
pub async fn get_agents(
    client: LrsClient,
    RawQuery(query): RawQuery,
) -> Result<Json<Person>, XapiError> {
    client.require_read()?;
    let agent = AgentsQuery::parse(query.as_deref())?.agent.into_agent();
    Ok(Json(Person::of_agent(&agent.json)))
}
