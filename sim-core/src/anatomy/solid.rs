//! The checks every mesh passes before it leaves the pipeline (see the architecture invariant in
//! [`super`]).

use super::error::AnatomyError;
use crate::mesh::TriMesh;

/// The checks every stored mesh passes: closed, consistently wound, no degenerate triangles,
/// positive signed volume.
pub fn check_solid(name: &str, mesh: &TriMesh, after: &str) -> Result<(), AnatomyError> {
    let t = mesh.topology_report();
    if mesh.triangles.is_empty() {
        return Err(AnatomyError::Mesh {
            structure: name.into(),
            message: format!("no triangles after {after}"),
        });
    }
    if !t.is_closed_and_consistent() {
        return Err(AnatomyError::Mesh {
            structure: name.into(),
            message: format!("not a closed consistent surface after {after}: {t:?}"),
        });
    }
    let v = mesh.signed_volume_mm3();
    if v.is_nan() || v <= 0.0 {
        return Err(AnatomyError::Mesh {
            structure: name.into(),
            message: format!("signed volume {v} mm^3 after {after}"),
        });
    }
    Ok(())
}
