//! The steel a fluoroscopy image shows (the needle's shaft and the skin marker's rods) as
//! closed meshes, for the CPU reference's overlay scene and the GPU renderers' needle pass.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use sim_core::geom::{capped_cylinder, equal_area_vertex_radius};

/// Facets of the needle prism. Simulator choice: with the equal-area radius, 8 facets keep the
/// mean chord of the round shaft exactly and its silhouette within 4% of the radius.
pub const NEEDLE_FACETS: u32 = 8;

/// Makes `renderer`'s needle mesh `needle`'s, if it differs from `current` (which it becomes).
pub(super) fn set_needle(
    renderer: &mut crate::fluoro::GpuFluoroRenderer,
    current: &mut Option<NeedleShaft>,
    needle: Option<&NeedleShaft>,
) {
    if current.as_ref() != needle {
        match needle {
            // One mesh of all segments: exact for a straight shaft (one convex prism); a bent
            // shaft's segments overlap at the joints by a fraction of its radius.
            Some(n) => {
                let mut mesh = sim_core::mesh::TriMesh {
                    vertices_mm: Vec::new(),
                    triangles: Vec::new(),
                };
                for m in needle_meshes(n) {
                    mesh.append(&m);
                }
                renderer.update_needle(&mesh);
            }
            None => renderer.clear_needle(),
        }
        *current = needle.cloned();
    }
}

/// The needle's closed prisms, one per polyline segment (equal-area radius, [`NEEDLE_FACETS`]).
pub fn needle_meshes(needle: &NeedleShaft) -> Vec<sim_core::mesh::TriMesh> {
    let r = equal_area_vertex_radius(needle.radius_mm, NEEDLE_FACETS);
    let rods = needle.rods.iter().map(|([a, b], radius)| {
        capped_cylinder(
            *a,
            *b,
            equal_area_vertex_radius(*radius, NEEDLE_FACETS),
            NEEDLE_FACETS,
        )
    });
    needle
        .points_mm
        .windows(2)
        .filter(|w| (0..3).map(|a| (w[1][a] - w[0][a]).powi(2)).sum::<f64>() > 1e-12)
        .map(|w| capped_cylinder(w[0], w[1], r, NEEDLE_FACETS))
        .chain(rods)
        .collect()
}

/// The steel instruments as imaged: the needle shaft, a polyline (hub first; empty without a
/// needle) with its radius, and straight rods lying on the skin (the skin marker).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NeedleShaft {
    /// Points, mm.
    pub points_mm: Vec<[f64; 3]>,
    /// Outer radius, mm.
    pub radius_mm: f64,
    /// Straight steel rods: ends (mm) and radius (mm).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rods: Vec<([[f64; 3]; 2], f64)>,
}

/// Drops polyline points that lie on the line of their neighbours (within 1e-6 rad), so a
/// straight needle is one prism instead of dozens.
pub(super) fn simplify_polyline(points: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut out: Vec<[f64; 3]> = Vec::new();
    for &p in points {
        if let Some(&last) = out.last() {
            if (0..3).all(|a| (p[a] - last[a]).abs() < 1e-9) {
                continue;
            }
        }
        if out.len() >= 2 {
            let a = DVec3::from_array(out[out.len() - 2]);
            let b = DVec3::from_array(out[out.len() - 1]);
            let c = DVec3::from_array(p);
            let (u, v) = ((b - a).normalize_or_zero(), (c - b).normalize_or_zero());
            if u.cross(v).length() < 1e-6 && u.dot(v) > 0.0 {
                out.pop();
            }
        }
        out.push(p);
    }
    out
}
