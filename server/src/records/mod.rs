//! Learning records: accounts, roles and sessions; courses; stations; attempts with append-only
//! engagement activity; technical results from the rubric engine; faculty review and audit.
//!
//! Three records are kept apart on purpose (see ARCHITECTURE.md and the reference system's
//! "Learning activity & technical assessment" rules):
//!
//! * **engagement** (`activity_events`): what the learner did, recorded by the server, append-only;
//!   reading a page is engagement, never self-certified completion;
//! * **technical results** (`technical_results`): rubric-engine output on measurements, with the
//!   station and rubric revisions and a reproducibility record; "met" is a technical statement,
//!   never a certification of clinical competency;
//! * **faculty approval** (`reviews`): a person's decision, by faculty of the learner's course,
//!   never by the learner themselves, with a comment, in the audit trail.
//!
//! Architecture invariant: every query that reads or changes an attempt carries the caller's
//! identity and role in its `WHERE` clause ([`authz`]); handlers never fetch first and filter in
//! Rust.
//!
//! The module is mounted by [`router`], which returns the axum router and the OpenAPI document
//! generated from the handlers' annotations (served at `/api/openapi.json`).
//!
//! Architecture invariant: the modules form layers, and each imports only from layers below it:
//!
//! 1. `config`, `authz`, `password`, `totp`, `ratelimit`, `stations` (the catalog as loaded),
//!    `schema` (building blocks of the OpenAPI document): no handler state;
//! 2. `state` ([`RecordsState`]), then the shared extractors `extract` and `auth`
//!    ([`auth::CurrentUser`]);
//! 3. `history` (the audit writer and its readers) and `summary` (the attempt as listed);
//! 4. the handlers: `login`, `accounts`, `users`, `catalogue`, `attempts`, `activity`, `results`,
//!    `reviews`, and `detail` (one attempt with everything recorded about it); `demo` and
//!    `startup` (start-up work);
//! 5. `routes`: the router and OpenAPI document.
//!
//! This file only declares the modules and re-exports. The learning records import nothing of
//! the rest of the server but its error types (`crate::error`): dispatch, start-up and future
//! integrations (LTI, xAPI) build on them, never the reverse.

pub mod accounts;
pub mod activity;
pub mod attempts;
pub mod auth;
pub mod authz;
pub mod catalogue;
pub mod cohort;
pub mod config;
pub mod demo;
pub mod detail;
pub mod extract;
pub mod history;
pub mod login;
pub mod modes;
pub mod password;
pub mod ratelimit;
pub mod results;
pub mod reviews;
pub mod routes;
pub mod schema;
pub mod startup;
pub mod state;
pub mod stations;
pub mod summary;
pub mod totp;
pub mod users;

pub use config::RecordsConfig;
pub use routes::router;
pub use startup::prepare;
pub use state::RecordsState;
pub use stations::StationCatalog;
