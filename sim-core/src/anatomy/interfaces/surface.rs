//! What the extraction hands to the family meshing: one surface per structure with every vertex
//! keyed by its edge of the region's sample lattice, and the weld tolerance along those edges.

use crate::mesh::TriMesh;

/// Largest distance along a lattice edge, as a fraction of the edge, at which the crossings of
/// two structures are taken as the same point. Where two occupancies sum to one, their crossings
/// differ by the `f32` rounding of the mask values divided by the field's change along the edge
/// (about 1e-7 / 0.01 for a surface at 89 degrees to the edge); a genuine gap narrower than a
/// thousandth of an edge (1.5 micrometres on a 1.5 mm grid) is closed by welding, which moves a
/// vertex by at most that much. Simulator choice.
pub const WELD_EDGE_FRACTION: f64 = 1e-3;

/// One extracted structure: its mesh and, per vertex, a key of its lattice edge that is unique in
/// the region (see [`lattice_edge_key`]) and the position along that edge.
#[derive(Debug, Clone)]
pub struct ExtractedSurface {
    /// Structure name (for errors and notes).
    pub name: String,
    /// The closed extracted surface.
    pub mesh: TriMesh,
    /// Per vertex: region-wide lattice edge key and position along the edge (`0..1`).
    pub edges: Vec<(u64, f64)>,
    /// Mask volume, mm^3 (the smoothing guard's reference).
    pub mask_volume_mm3: f64,
    /// For a surface extracted from a level set: per vertex, its position by linear
    /// interpolation of the sampled values, where the family falls back to if the exact
    /// positions make surfaces cross; empty otherwise (the vertices are already there).
    pub interpolated_mm: Vec<[f64; 3]>,
}

/// A region-wide key for a lattice edge: `lower` in the region's fine lattice (non-negative),
/// `extent` the number of fine lattice points per axis that keys may use.
pub fn lattice_edge_key(lower: [u64; 3], axes: u8, extent: [u64; 3]) -> u64 {
    ((lower[2] * extent[1] + lower[1]) * extent[0] + lower[0]) * 8 + u64::from(axes)
}
