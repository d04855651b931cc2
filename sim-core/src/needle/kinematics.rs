//! The exact geometry of one substep: a circular arc from a tip pose, and the exponential bending
//! response integrated analytically over the substep.
//!
//! Frame convention: a [`Pose`] maps the local frame to the world. Local `z` is the tangent
//! (direction of travel); local `x` and `y` span the normal plane and are parallel-transported
//! along the path, so they carry no axial twist of their own. Curvature, bending response and
//! bevel direction are 2-vectors in that normal plane.

use glam::{DQuat, DVec2, DVec3};
use serde::{Deserialize, Serialize};

/// Position and transported frame of the needle tip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Tip position, millimetres.
    pub position_mm: DVec3,
    /// Rotation from the local frame (z = tangent) to the world.
    pub orientation: DQuat,
}

impl Pose {
    /// A pose at `position_mm` travelling along `direction`, with local `x` as close as possible
    /// to `reference_normal` (typically the initial bevel direction).
    ///
    /// Returns `None` when the direction is degenerate or parallel to the reference.
    pub fn looking_along(
        position_mm: DVec3,
        direction: DVec3,
        reference_normal: DVec3,
    ) -> Option<Self> {
        let t = direction.try_normalize()?;
        let x = (reference_normal - t * reference_normal.dot(t)).try_normalize()?;
        let y = t.cross(x);
        let orientation = DQuat::from_mat3(&glam::DMat3::from_cols(x, y, t)).normalize();
        Some(Self {
            position_mm,
            orientation,
        })
    }

    /// Unit tangent (direction of travel) in world coordinates.
    pub fn tangent(&self) -> DVec3 {
        self.orientation * DVec3::Z
    }

    /// World direction of a normal-plane vector given in local coordinates.
    pub fn normal_to_world(&self, v: DVec2) -> DVec3 {
        self.orientation * DVec3::new(v.x, v.y, 0.0)
    }

    /// Local normal-plane coordinates of a world vector (its tangential part is dropped).
    pub fn world_to_normal(&self, w: DVec3) -> DVec2 {
        let l = self.orientation.inverse() * w;
        DVec2::new(l.x, l.y)
    }
}

/// Bending response after travelling `s_mm` toward the fixed bevel direction `bevel`:
/// `b(s) = bevel + (b0 - bevel) exp(-s / L)`, the exact solution of `db/ds = (bevel - b) / L`.
pub fn response_after(b0: DVec2, bevel: DVec2, s_mm: f64, response_length_mm: f64) -> DVec2 {
    bevel + (b0 - bevel) * (-s_mm / response_length_mm).exp()
}

/// Mean of the bending response over a substep of length `h_mm`, integrated analytically:
/// `bevel + (b0 - bevel) (L / h) (1 - exp(-h / L))`.
///
/// Using this mean (rather than the start-of-step value) makes the heading change of every
/// substep exact in the planar case, and the arc integrator second order in general.
pub fn mean_response(b0: DVec2, bevel: DVec2, h_mm: f64, response_length_mm: f64) -> DVec2 {
    if h_mm <= 0.0 {
        return b0;
    }
    let x = h_mm / response_length_mm;
    // (1 - e^-x) / x, written with expm1 so that it stays accurate for tiny substeps.
    let factor = -(-x).exp_m1() / x;
    bevel + (b0 - bevel) * factor
}

/// The pose reached by travelling `s_mm` along the circular arc that leaves `start` with the
/// constant curvature vector `curvature_per_mm` (local normal-plane coordinates, 1/mm).
///
/// The position moves along the exact chord of the arc and the frame rotates exactly about the
/// binormal, which is parallel transport along a circle: no spurious axial roll. For a constant
/// curvature this reproduces the analytic arc for any step length.
pub fn arc_pose(start: &Pose, curvature_per_mm: DVec2, s_mm: f64) -> Pose {
    let kappa = curvature_per_mm.length();
    if kappa == 0.0 || s_mm == 0.0 {
        return Pose {
            position_mm: start.position_mm + start.tangent() * s_mm,
            orientation: start.orientation,
        };
    }
    let dir = curvature_per_mm / kappa;
    let phi = kappa * s_mm;
    let sin_phi = phi.sin();
    let half_sin = (0.5 * phi).sin();
    // Chord in local coordinates: sin(phi)/k along the tangent, (1 - cos phi)/k toward the
    // centre of curvature; the second term is written as 2 sin^2(phi/2)/k to avoid cancellation.
    let along = sin_phi / kappa;
    let across = 2.0 * half_sin * half_sin / kappa;
    let chord_local = DVec3::new(dir.x * across, dir.y * across, along);
    // Rotation about the local binormal z x dir = (-dir.y, dir.x, 0) turns z toward dir.
    let axis_local = DVec3::new(-dir.y, dir.x, 0.0);
    let turn = DQuat::from_axis_angle(axis_local, phi);
    Pose {
        position_mm: start.position_mm + start.orientation * chord_local,
        orientation: (start.orientation * turn).normalize(),
    }
}

/// Arc length of a circular arc with curvature `kappa_per_mm` whose chord is `chord_mm` long
/// (used by the tract checks to measure length from geometry alone).
pub fn arc_length_from_chord(chord_mm: f64, kappa_per_mm: f64) -> f64 {
    if kappa_per_mm == 0.0 {
        return chord_mm;
    }
    let x = (0.5 * chord_mm * kappa_per_mm).clamp(-1.0, 1.0);
    2.0 * x.asin() / kappa_per_mm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_response_matches_quadrature() {
        let b0 = DVec2::new(-1.0, 0.3);
        let v = DVec2::new(1.0, 0.0);
        let (h, l) = (7.0, 25.0);
        let n = 20_000;
        let mut acc = DVec2::ZERO;
        for i in 0..n {
            let s = (i as f64 + 0.5) * h / n as f64;
            acc += response_after(b0, v, s, l);
        }
        acc /= n as f64;
        // Midpoint quadrature error ~ h^2/(24 n^2) |b''| ~ 1e-13; 1e-10 leaves margin.
        assert!((acc - mean_response(b0, v, h, l)).length() < 1e-10);
    }

    #[test]
    fn arc_pose_stays_on_circle_and_frame_is_orthonormal() {
        let start = Pose::looking_along(DVec3::ZERO, DVec3::Z, DVec3::X).unwrap();
        let k = DVec2::new(0.0, 1.0 / 50.0);
        let p = arc_pose(&start, k, 40.0);
        // Centre of curvature at (0, 50, 0): distance must stay 50.
        assert!((p.position_mm.distance(DVec3::new(0.0, 50.0, 0.0)) - 50.0).abs() < 1e-12);
        // Tangent perpendicular to the radius.
        assert!(
            p.tangent()
                .dot(p.position_mm - DVec3::new(0.0, 50.0, 0.0))
                .abs()
                < 1e-12
        );
        // Local x stays the world x (binormal of this planar arc): no axial roll.
        assert!((p.orientation * DVec3::X - DVec3::X).length() < 1e-14);
    }
}
