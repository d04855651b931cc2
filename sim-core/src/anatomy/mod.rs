//! Anatomy assets: the on-disk region format, the meshing and labelling pipeline, real-CT
//! (NIfTI / TotalSegmentator) import and the procedural lumbosacral phantom.
//!
//! Data flow: a CT volume in HU plus one occupancy mask per structure, all on one axis-aligned
//! grid in the region's model frame, go into [`pipeline::build_region`], which returns a
//! [`asset::RegionAsset`] (closed structure meshes, 8-bit CT underlay, label volume, provenance);
//! [`asset::RegionAsset::write_to`] stores it atomically and [`asset::RegionAsset::load`] reads it
//! back, verifying the SHA-256 of every file. The phantom ([`phantom`]) and real-CT import
//! ([`nifti_import`], [`totalseg`]) are the two producers of those inputs.
//! [`lumbar_ct`] adds, for a lumbar CT, landmarks computed from the vertebra masks and the
//! tissues the masks lack (authored canal contents, skin, fat and muscle from HU).
//!
//! The `assets` binary (`sim-core/src/bin/assets.rs`) wraps real-CT import for the command line:
//! `assets build --ct ct.nii.gz --masks segmentations/ --out assets/<region>` (or
//! `--multilabel seg.nii.gz [--label-map map.json]`), and `assets verify assets/<region>`.
//!
//! Architecture invariant: every mesh that leaves the pipeline is closed, consistently wound
//! (outward), free of degenerate triangles and of positive volume; anything else is an error.

pub mod asset;
pub mod decimate;
pub mod error;
mod glb;
pub mod interfaces;
pub mod labels;
pub mod level_set_mesh;
pub mod lumbar_ct;
pub mod mask;
pub mod mesher;
pub mod nifti_import;
pub mod params;
pub mod phantom;
pub mod pipeline;
pub mod smooth;
pub mod solid;
pub mod structure;
pub mod totalseg;

pub use error::AnatomyError;
