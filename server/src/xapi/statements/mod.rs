//! TEMP placeholder (outbox branch): the statements helper's module replaces this file.
pub mod store;
