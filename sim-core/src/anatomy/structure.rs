//! One structure of a region asset: its closed surface and tissue class (written to and read from
//! the region's glTF file by [`super::asset`]).

use crate::material::MaterialClass;
use crate::mesh::TriMesh;

/// One anatomical structure: a closed, outward-wound surface tagged with its tissue class.
#[derive(Debug, Clone, PartialEq)]
pub struct StructureAsset {
    /// Unique name within the region (e.g. `vertebrae_L3`, `aorta`).
    pub name: String,
    /// Tissue class of the solid the mesh bounds.
    pub material: MaterialClass,
    /// Surface in millimetres in the region's model frame (CCW seen from outside).
    pub mesh: TriMesh,
    /// Volume of the source mask (sum of occupancies times voxel volume), mm^3: the reference the
    /// mesh volume is checked against.
    pub mask_volume_mm3: f64,
}
