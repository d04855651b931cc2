//! Integration tests of render-worker, one module per area.
mod gpu;
