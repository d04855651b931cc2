//! Integration tests of sim-core, one module per area.
mod anatomy;
mod cervical;
mod contrast;
mod fluoro;
mod laminar;
mod mesh_volume;
mod lumbar_ct;
mod morphometry;
mod needle;
mod needle_handling;
mod needle_hub;
mod nesting;
mod phantom;
mod rubric;
mod stations;
mod ultrasound;
