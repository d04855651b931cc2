//! Integration tests of render-worker, one module per area.
mod fluoro;
mod gpu;
mod sessions;
