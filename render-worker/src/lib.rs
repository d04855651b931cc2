//! `render-worker`: owns simulation sessions and renders their frames on the GPU with wgpu.
//!
//! Every GPU result has a CPU reference in `sim-core` and is compared with it under a stated
//! tolerance. On machines without a hardware GPU, Mesa's lavapipe (software Vulkan) is used.

pub mod alloc;
pub mod cluster;
pub mod exit;
pub mod fluoro;
pub mod gallery;
pub mod gpu;
pub mod interrupt;
pub mod priority;
pub mod session;
pub mod ultrasound;
