//! `sim-core`: the pure, deterministic CPU reference of the simulator.
//!
//! Every modality (fluoroscopy, ultrasound, needle kinematics, contrast transport) and the rubric
//! engine live here as plain functions over plain data, in `f64` where accuracy matters. The GPU
//! renderer in `render-worker` is checked against these functions; the server stores what they
//! compute. This crate does no networking, no async, no database and no GPU work.
//!
//! ```
//! use sim_core::mesh::TriMesh;
//! // A closed, outward-wound unit cube (in millimetres) has volume 1 mm^3 and no boundary edges.
//! let cube = TriMesh::axis_aligned_box([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]);
//! assert!((cube.signed_volume_mm3() - 1.0).abs() < 1e-12);
//! assert!(cube.topology_report().is_closed_and_consistent());
//! ```

pub mod anatomy;
pub mod compare;
pub mod contrast;
pub mod fluoro;
pub mod geom;
pub mod hash;
pub mod material;
pub mod mesh;
pub mod needle;
pub(crate) mod par;
pub mod rng;
pub mod rubric;
pub mod stats;
pub mod ultrasound;
pub mod volume;
