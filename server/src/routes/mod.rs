//! HTTP routes, one module per area.

pub mod headers;
pub mod health;
pub mod web;
