//! Integration tests of sim-core, one module per area.
mod anatomy;
mod fluoro;
mod rubric;
mod phantom;
mod laminar;
mod needle;
mod nesting;
