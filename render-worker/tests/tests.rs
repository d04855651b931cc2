//! Integration tests of render-worker, one module per area.
mod calibration;
mod cervical;
mod contrast;
mod driver;
mod fluoro;
mod fluoro_cache;
mod gallery;
mod gpu;
mod habitus;
mod lumbar_ct;
mod modality_seam;
mod needle_handling;
mod session_host;
mod sessions;
mod ultrasound;
mod ultrasound_gpu;
mod worker_process;
