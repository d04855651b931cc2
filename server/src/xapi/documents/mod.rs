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
//! merge, responses), below [`resource`] (the methods, generic over the resource), below the
//! three resources: their parameter structs and their documented routes.

pub mod activity_profile;
pub mod agent_profile;
pub mod ops;
pub mod params;
pub mod resource;
pub mod state;
pub mod store;
