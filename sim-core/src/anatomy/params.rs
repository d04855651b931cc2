//! The knobs of the meshing and labelling pipeline (recorded in every region's provenance).

use serde::{Deserialize, Serialize};

use super::decimate::DecimationParams;
use super::smooth::TaubinParams;

/// Knobs of the pipeline; all are recorded in the provenance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PipelineParams {
    /// Up-sampling factor before extraction (1 = none). Trilinear, voxel-centre exact.
    pub upsample: u32,
    /// Occupancy level of the surface. 0.5 puts the surface of a binary mask half-way between
    /// inside and outside voxel centres, i.e. on the voxel faces.
    pub iso_level: f32,
    /// Optional Taubin smoothing.
    pub smoothing: Option<TaubinParams>,
    /// Optional quadric-error decimation.
    pub decimation: Option<DecimationParams>,
    /// Nominal cortical shell thickness used to split a bone mask into cortical and cancellous
    /// labels, mm. 1.8 mm is the nominal shell of the methods page of the system that inspired us;
    /// real vertebral cortex is thinner (0.2-0.5 mm, Silva et al. 1994, Spine 19:1445), but a
    /// shell thinner than a voxel cannot be represented in the label volume.
    pub cortical_shell_mm: f64,
    /// For structures meshed from level sets (the procedural phantoms): after decimation, edges
    /// whose midpoint lies farther than this from the surface are split there (up to three
    /// rounds), mm; `None` leaves the meshes as decimated. Absent in regions built before it
    /// existed.
    #[serde(default)]
    pub surface_tolerance_mm: Option<f64>,
}

impl Default for PipelineParams {
    fn default() -> Self {
        PipelineParams {
            upsample: 1,
            iso_level: 0.5,
            smoothing: None,
            decimation: None,
            cortical_shell_mm: 1.8,
            surface_tolerance_mm: None,
        }
    }
}
