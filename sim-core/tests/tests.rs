//! Integration tests of sim-core, one module per area.
mod rubric;
