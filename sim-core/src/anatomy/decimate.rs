//! Quadric-error decimation through meshoptimizer (`meshopt` crate), with checks and back-off.
//!
//! meshoptimizer's `simplify` collapses edges by quadric error (Garland & Heckbert, SIGGRAPH
//! 1997) onto existing vertices and never moves a vertex, so its output only references input
//! positions. It is topology-preserving in practice but not by contract, so every result is
//! checked: closed (see [`Closure`]), no degenerate triangles, positive signed volume, and a
//! volume within `max_volume_change` of the input mesh's. A result that fails is rejected and the
//! reduction retried with locks around the defect or a smaller error (see [`decimate`]); if all
//! attempts fail the input mesh is kept and the report says so.

use serde::{Deserialize, Serialize};

use super::smooth::{grow_rings, vertex_neighbours};
use crate::mesh::{TriMesh, directed_edge_uses, is_degenerate};

/// Parameters of [`decimate`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DecimationParams {
    /// Target triangle count as a fraction of the input's (0.25 keeps a quarter).
    pub target_fraction: f64,
    /// Largest geometric deviation meshoptimizer may introduce, mm (absolute).
    pub max_error_mm: f64,
    /// Largest relative volume change versus the input mesh that is accepted.
    pub max_volume_change: f64,
}

impl Default for DecimationParams {
    fn default() -> Self {
        // A quarter of the marching-tetrahedra triangles and 0.3 mm (a tenth of a 3 mm voxel)
        // deviation: simulator choices that keep meshes small without visible faceting.
        DecimationParams {
            target_fraction: 0.25,
            max_error_mm: 0.3,
            max_volume_change: 0.01,
        }
    }
}

/// Drops unreferenced vertices and renumbers the rest (order of first use).
pub(crate) fn compact(vertices: &[[f64; 3]], triangles: &[[u32; 3]]) -> TriMesh {
    let mut map = vec![u32::MAX; vertices.len()];
    let mut out = TriMesh::default();
    for t in triangles {
        let mut nt = [0u32; 3];
        for (slot, &v) in t.iter().enumerate() {
            if map[v as usize] == u32::MAX {
                map[v as usize] = out.vertices_mm.len() as u32;
                out.vertices_mm.push(vertices[v as usize]);
            }
            nt[slot] = map[v as usize];
        }
        out.triangles.push(nt);
    }
    out
}

pub(crate) fn acceptable(
    before_volume: f64,
    m: &TriMesh,
    max_volume_change: f64,
    closure: Closure,
) -> Result<(), String> {
    let t = m.topology_report();
    let closed = match closure {
        Closure::Manifold => t.is_closed_and_consistent(),
        Closure::Oriented => {
            t.degenerate_triangles == 0 && defective_vertices(&m.triangles, closure).is_empty()
        }
    };
    if !closed {
        return Err(format!("topology {t:?}"));
    }
    let v = m.signed_volume_mm3();
    if v.is_nan() || v <= 0.0 {
        return Err(format!("signed volume {v}"));
    }
    let rel = (v - before_volume).abs() / before_volume;
    if rel > max_volume_change {
        return Err(format!("volume change {:.2}%", 100.0 * rel));
    }
    Ok(())
}

/// How closed a decimated surface must be.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Closure {
    /// Every edge shared by exactly two oppositely wound triangles: the physics meshes (their
    /// solid checks, and ray casts that pair each entry with an exit, need it).
    Manifold,
    /// Every edge traversed as often in one direction as in the other: an edge shared by four
    /// triangles, two each way (two sheets of the surface touching along it, as where the
    /// layers of the marching-tetrahedra meshes meet), passes. Enough for what sums signed
    /// quantities over a closed oriented surface (signed volume; the renderer's signed depth
    /// sums, which is all a draft scene is drawn with). Demanding a manifold there made the
    /// reduction back off entirely on the largest meshes of the default phantom, whose own
    /// welded triangles are not manifold.
    Oriented,
}

/// Vertices (input ids) of degenerate triangles and of edges that break `closure`.
pub(crate) fn defective_vertices(tris: &[[u32; 3]], closure: Closure) -> Vec<u32> {
    let mut bad: Vec<u32> = tris
        .iter()
        .filter(|t| is_degenerate(t))
        .flatten()
        .copied()
        .collect();
    for &((a, b), (f, r)) in &directed_edge_uses(tris) {
        let broken = match closure {
            Closure::Manifold => f != 1 || r != 1,
            Closure::Oriented => f != r,
        };
        if broken {
            bad.push(a);
            bad.push(b);
        }
    }
    bad
}

/// Decimates a closed mesh into a closed oriented one ([`Closure::Oriented`]: the draft scenes'
/// rule; the physics meshes are decimated by `interfaces`, to [`Closure::Manifold`]); returns the
/// result (or the input, if no attempt passed the checks) and a one-line report.
///
/// Back-off, up to eight attempts: where a result has topological defects (typically two
/// nearly touching sheets of the surface collapsed onto one edge), the input vertices around the
/// defect (two rings) are locked and the reduction is retried; where the volume changed too much,
/// the allowed error is halved.
pub fn decimate(mesh: &TriMesh, params: &DecimationParams) -> (TriMesh, String) {
    let before_volume = mesh.signed_volume_mm3();
    let positions: Vec<f32> = mesh
        .vertices_mm
        .iter()
        .flat_map(|v| v.map(|x| x as f32))
        .collect();
    let bytes: Vec<u8> = positions.iter().flat_map(|x| x.to_le_bytes()).collect();
    let Ok(adapter) = meshopt::VertexDataAdapter::new(&bytes, 12, 0) else {
        return (
            mesh.clone(),
            "decimation skipped: vertex buffer rejected".into(),
        );
    };
    let indices: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let neighbours = vertex_neighbours(mesh);
    let fraction = params.target_fraction.clamp(0.0, 1.0);
    if fraction >= 1.0 {
        return (mesh.clone(), "decimation skipped: target fraction 1".into());
    }
    let target = (((indices.len() / 3) as f64 * fraction).round() as usize * 3).max(12);
    let mut locks = vec![false; mesh.vertices_mm.len()];
    let mut max_error = params.max_error_mm;
    let mut rejections = Vec::new();
    for attempt in 0..8 {
        let mut err = 0.0f32;
        let out = meshopt::simplify_with_locks(
            &indices,
            &adapter,
            &locks,
            target,
            max_error as f32,
            meshopt::SimplifyOptions::ErrorAbsolute,
            Some(&mut err),
        );
        let tris: Vec<[u32; 3]> = out.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let candidate = compact(&mesh.vertices_mm, &tris);
        match acceptable(
            before_volume,
            &candidate,
            params.max_volume_change,
            Closure::Oriented,
        ) {
            Ok(()) => {
                let locked = locks.iter().filter(|&&l| l).count();
                let report = format!(
                    "decimated {} -> {} triangles (max error {err:.3} mm, volume change {:.3}%, attempt {}, {locked} vertices locked)",
                    mesh.triangles.len(),
                    candidate.triangles.len(),
                    100.0 * (candidate.signed_volume_mm3() - before_volume) / before_volume,
                    attempt + 1,
                );
                return (candidate, report);
            }
            Err(why) => {
                let defects = defective_vertices(&tris, Closure::Oriented);
                if defects.is_empty() {
                    max_error *= 0.5;
                } else {
                    // Lock the defect's vertices and two rings around them in the input mesh.
                    for v in grow_rings(defects, &neighbours, 2) {
                        locks[v as usize] = true;
                    }
                }
                rejections.push(why);
            }
        }
    }
    (
        mesh.clone(),
        format!(
            "decimation backed off, mesh kept at {} triangles ({})",
            mesh.triangles.len(),
            rejections.join("; ")
        ),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two tetrahedra sharing one edge (four triangles on it, two each way) are closed and
    /// oriented: accepted. With a face removed (a hole), or a face flipped, they are not, and
    /// the defect's vertices are named.
    #[test]
    fn an_edge_shared_by_two_solids_passes_and_holes_do_not() {
        // Tetrahedron (0, 1, 2, 3) and its mirror (0, 1, 4, 5) through the edge 0-1.
        let vertices_mm = vec![
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 10.0],
            [10.0, 0.0, 5.0],
            [5.0, 10.0, 5.0],
            [-10.0, 0.0, 5.0],
            [-5.0, -10.0, 5.0],
        ];
        let tetra = |[a, b, c, d]: [u32; 4]| [[a, c, b], [a, b, d], [b, c, d], [a, d, c]];
        let mut triangles: Vec<[u32; 3]> = tetra([0, 1, 2, 3]).to_vec();
        triangles.extend(tetra([0, 1, 4, 5]));
        let mut both = TriMesh {
            vertices_mm,
            triangles,
        };
        if both.signed_volume_mm3() < 0.0 {
            for t in &mut both.triangles {
                t.swap(1, 2);
            }
        }
        let volume = both.signed_volume_mm3();
        assert!(volume > 0.0, "{volume}");
        let report = both.topology_report();
        assert_eq!(report.non_manifold_edges, 1, "{report:?}");
        assert_eq!(acceptable(volume, &both, 0.0, Closure::Oriented), Ok(()));
        assert!(defective_vertices(&both.triangles, Closure::Oriented).is_empty());
        // The physics meshes' rule refuses it.
        assert!(acceptable(volume, &both, 0.0, Closure::Manifold).is_err());
        assert_eq!(
            defective_vertices(&both.triangles, Closure::Manifold),
            vec![0, 1]
        );
        let mut holed = both.clone();
        holed.triangles.remove(2);
        assert!(acceptable(volume, &holed, 1.0, Closure::Oriented).is_err());
        let mut bad = defective_vertices(&holed.triangles, Closure::Oriented);
        bad.sort_unstable();
        bad.dedup();
        assert_eq!(bad, vec![1, 2, 3]);
        let mut flipped = both.clone();
        flipped.triangles[5].swap(1, 2);
        assert!(acceptable(volume, &flipped, 1.0, Closure::Oriented).is_err());
    }

    #[test]
    fn decimated_sphere_stays_closed_and_close() {
        let m = TriMesh::icosphere([5.0, 6.0, 7.0], 20.0, 5);
        let p = DecimationParams {
            target_fraction: 0.1,
            max_error_mm: 0.2,
            max_volume_change: 0.01,
        };
        let (d, report) = decimate(&m, &p);
        assert!(d.triangles.len() < m.triangles.len() / 4, "{report}");
        assert!(d.topology_report().is_closed_and_consistent(), "{report}");
        let rel = (d.signed_volume_mm3() - m.signed_volume_mm3()).abs() / m.signed_volume_mm3();
        assert!(rel < 0.01, "{report}");
    }
}
