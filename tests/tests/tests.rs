//! Whole-system tests: one binary, one module per area.

mod architecture;
mod sbom;
