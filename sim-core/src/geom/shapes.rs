//! Closed meshes of simple solids used by instruments and analytic test scenes.

use glam::DVec3;

use crate::mesh::TriMesh;

/// A closed, capped cylinder (a regular prism) from `base_mm` to `tip_mm`, outward wound.
///
/// The side is a regular `segments`-gon whose vertices lie at `vertex_radius_mm` from the axis;
/// each cap is a fan around its centre. It has `2 * segments + 2` vertices and `4 * segments`
/// triangles. A needle shaft is drawn with this (for a 22 G needle, 0.72 mm outer diameter).
///
/// An inscribed polygon has less cross-section than the circle; pass
/// [`equal_area_vertex_radius`] of the nominal radius to keep the cross-section area (and so the
/// mean chord) of the round shaft.
///
/// # Panics
/// If `segments < 3`, the radius is not positive, or base and tip coincide.
pub fn capped_cylinder(
    base_mm: [f64; 3],
    tip_mm: [f64; 3],
    vertex_radius_mm: f64,
    segments: u32,
) -> TriMesh {
    assert!(segments >= 3, "a prism needs at least 3 sides");
    assert!(vertex_radius_mm > 0.0, "radius must be positive");
    let (base, tip) = (DVec3::from(base_mm), DVec3::from(tip_mm));
    let axis = tip - base;
    let len = axis.length();
    assert!(len > 0.0, "base and tip coincide");
    // Unit vectors here divide by the length (glam's `normalize` multiplies by its reciprocal),
    // which keeps the vertices they had before glam was used here.
    let w = axis / len;
    // A right-handed frame (e1, e2, w): e1 is perpendicular to w, built from the axis least
    // aligned with w.
    let helper = if w.x.abs() <= w.y.abs() && w.x.abs() <= w.z.abs() {
        DVec3::X
    } else if w.y.abs() <= w.z.abs() {
        DVec3::Y
    } else {
        DVec3::Z
    };
    let e1 = helper.cross(w);
    let e1 = e1 / e1.length();
    let e2 = w.cross(e1);
    let n = segments as usize;
    let mut vertices_mm = Vec::with_capacity(2 * n + 2);
    for end in [base, tip] {
        for k in 0..n {
            let th = std::f64::consts::TAU * k as f64 / n as f64;
            let (s, c) = th.sin_cos();
            vertices_mm.push((end + vertex_radius_mm * (c * e1 + s * e2)).to_array());
        }
    }
    vertices_mm.push(base_mm);
    vertices_mm.push(tip_mm);
    let (cb, ct) = ((2 * n) as u32, (2 * n + 1) as u32);
    let mut triangles = Vec::with_capacity(4 * n);
    for k in 0..n {
        let k1 = (k + 1) % n;
        let (b0, b1, t0, t1) = (k as u32, k1 as u32, (n + k) as u32, (n + k1) as u32);
        triangles.push([b0, b1, t1]);
        triangles.push([b0, t1, t0]);
        triangles.push([cb, b1, b0]);
        triangles.push([ct, t0, t1]);
    }
    TriMesh {
        vertices_mm,
        triangles,
    }
}

/// Vertex radius of a regular `segments`-gon with the same area as a circle of `radius_mm`.
pub fn equal_area_vertex_radius(radius_mm: f64, segments: u32) -> f64 {
    let n = segments as f64;
    let polygon_area_per_r2 = 0.5 * n * (std::f64::consts::TAU / n).sin();
    radius_mm * (std::f64::consts::PI / polygon_area_per_r2).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cylinder_is_closed_outward_and_has_the_prism_volume() {
        for (base, tip) in [
            ([0.0; 3], [0.0, 0.0, 50.0]),
            ([1.0, 2.0, 3.0], [-20.0, 35.0, 7.0]),
        ] {
            let m = capped_cylinder(base, tip, 0.36, 24);
            assert!(m.topology_report().is_closed_and_consistent());
            assert_eq!(m.triangle_count(), 96);
            let len = (0..3)
                .map(|a| (tip[a] - base[a]).powi(2))
                .sum::<f64>()
                .sqrt();
            let prism = 0.5 * 24.0 * (std::f64::consts::TAU / 24.0).sin() * 0.36 * 0.36 * len;
            assert!(
                (m.signed_volume_mm3() - prism).abs() < 1e-9 * prism,
                "{}",
                m.signed_volume_mm3()
            );
        }
    }

    #[test]
    fn equal_area_radius_restores_the_circle_area() {
        let r = equal_area_vertex_radius(0.36, 16);
        let m = capped_cylinder([0.0; 3], [0.0, 0.0, 10.0], r, 16);
        let round = std::f64::consts::PI * 0.36 * 0.36 * 10.0;
        assert!((m.signed_volume_mm3() - round).abs() < 1e-9 * round);
    }
}
