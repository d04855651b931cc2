//! Integration tests of the server against a real PostgreSQL, one module per area.

mod embedded;
mod health;
mod process;
