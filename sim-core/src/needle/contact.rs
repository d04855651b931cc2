//! Bone contact: the needle centre-line is ray-cast against bone surfaces.
//!
//! The needle only needs "where does this segment first cross bone, and what is the outward
//! normal there", so bone is anything implementing [`BoneSurface`]: analytic surfaces for tests,
//! and triangle meshes through a bounding-volume hierarchy for anatomy.
//!
//! Both contact thresholds are simulator safeguards, not measured needle-bone laws (the reference
//! simulator says the same of its own values):
//! - [`ARREST_INCIDENCE_DEG`]: a tip meeting bone at 30 degrees or more from the tangent plane
//!   stops (it would engage the cortex rather than glance off).
//! - [`TURNING_BUDGET_DEG`]: a shallow contact redirects the tip along the surface, but the
//!   accumulated redirection over one continuous contact is limited to 45 degrees; beyond it the
//!   tip stops, so a concave bony gutter cannot steer the needle round a corner.

use glam::DVec3;

/// Incidence (angle between travel direction and the surface's tangent plane) at or above which
/// the tip is arrested, degrees. Simulator choice.
pub const ARREST_INCIDENCE_DEG: f64 = 30.0;

/// Largest accumulated redirection over one continuous contact, degrees. Simulator choice.
pub const TURNING_BUDGET_DEG: f64 = 45.0;

/// Gap kept between a stopped or sliding tip and the bone surface, measured normal to the
/// surface, millimetres. Simulator choice: 1 micrometre keeps every ray origin strictly outside
/// bone under round-off, and is far below the 0.01 mm contact tolerance and the 1.5 mm CT voxel.
pub const CONTACT_GAP_MM: f64 = 1e-3;

/// How far beyond the end of a move the bone ray looks for a surface whose gap the move would
/// violate, millimetres. Simulator choice: 1 mm (a move approaching at less than
/// `CONTACT_GAP_MM / LOOKAHEAD_MM` = 1 mrad may end closer than the gap, but never inside).
pub const LOOKAHEAD_MM: f64 = 1.0;

/// A ray hit: distance along the (unit) ray and the outward unit normal of the surface there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayHit {
    /// Distance from the ray origin, millimetres.
    pub t_mm: f64,
    /// Outward unit normal of the bone surface at the hit.
    pub normal: DVec3,
}

/// Bone geometry as seen by the needle.
pub trait BoneSurface {
    /// The first crossing of the surface (entering or leaving) by `origin + t dir` with
    /// `0 <= t <= max_t_mm`; `dir` is a unit vector.
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit>;

    /// True when `p` lies inside bone (for checks and for validating an entry point).
    fn contains(&self, p: DVec3) -> bool;
}

/// No bone at all.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoBone;

impl BoneSurface for NoBone {
    fn first_hit(&self, _: DVec3, _: DVec3, _: f64) -> Option<RayHit> {
        None
    }
    fn contains(&self, _: DVec3) -> bool {
        false
    }
}

/// A bony half-space: bone is every point `x` with `(x - point) . normal < 0`.
#[derive(Debug, Clone, Copy)]
pub struct HalfSpaceBone {
    /// A point on the bone surface, millimetres.
    pub point_mm: DVec3,
    /// Outward unit normal (pointing away from bone).
    pub normal: DVec3,
}

impl HalfSpaceBone {
    /// Signed distance from the surface, positive outside bone, millimetres.
    pub fn signed_distance_mm(&self, p: DVec3) -> f64 {
        (p - self.point_mm).dot(self.normal)
    }
}

impl BoneSurface for HalfSpaceBone {
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit> {
        let denom = dir.dot(self.normal);
        if denom == 0.0 {
            return None;
        }
        let t = (self.point_mm - origin).dot(self.normal) / denom;
        (t >= 0.0 && t <= max_t_mm).then_some(RayHit {
            t_mm: t,
            normal: self.normal,
        })
    }
    fn contains(&self, p: DVec3) -> bool {
        self.signed_distance_mm(p) < 0.0
    }
}

/// A bony ball.
#[derive(Debug, Clone, Copy)]
pub struct SphereBone {
    /// Centre, millimetres.
    pub centre_mm: DVec3,
    /// Radius, millimetres.
    pub radius_mm: f64,
}

impl SphereBone {
    /// Signed distance from the surface, positive outside bone, millimetres.
    pub fn signed_distance_mm(&self, p: DVec3) -> f64 {
        p.distance(self.centre_mm) - self.radius_mm
    }
}

impl BoneSurface for SphereBone {
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit> {
        let oc = origin - self.centre_mm;
        let b = dir.dot(oc);
        let c = oc.length_squared() - self.radius_mm * self.radius_mm;
        let disc = b * b - c;
        if disc < 0.0 {
            return None;
        }
        let root = disc.sqrt();
        // Stable ordering of the two roots.
        let (t0, t1) = (-b - root, -b + root);
        let t = if t0 >= 0.0 { t0 } else { t1 };
        if t < 0.0 || t > max_t_mm {
            return None;
        }
        let normal = (origin + dir * t - self.centre_mm).normalize();
        Some(RayHit { t_mm: t, normal })
    }
    fn contains(&self, p: DVec3) -> bool {
        self.signed_distance_mm(p) < 0.0
    }
}

impl<T: BoneSurface + ?Sized> BoneSurface for &T {
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit> {
        (**self).first_hit(origin, dir, max_t_mm)
    }
    fn contains(&self, p: DVec3) -> bool {
        (**self).contains(p)
    }
}

impl<T: BoneSurface> BoneSurface for [T] {
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit> {
        let mut best: Option<RayHit> = None;
        for bone in self {
            let limit = best.map_or(max_t_mm, |h| h.t_mm);
            if let Some(hit) = bone.first_hit(origin, dir, limit) {
                if best.is_none_or(|b| hit.t_mm < b.t_mm) {
                    best = Some(hit);
                }
            }
        }
        best
    }
    fn contains(&self, p: DVec3) -> bool {
        self.iter().any(|b| b.contains(p))
    }
}

impl<T: BoneSurface> BoneSurface for Vec<T> {
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit> {
        BoneSurface::first_hit(self.as_slice(), origin, dir, max_t_mm)
    }
    fn contains(&self, p: DVec3) -> bool {
        BoneSurface::contains(self.as_slice(), p)
    }
}

/// The first crossing *into* bone along the segment from `origin` in unit direction `dir` over
/// `len_mm`. Crossings out of bone are stepped over: they only occur for a
/// ray starting on or inside a surface, and moving outward is not a contact.
pub fn first_entry(
    bone: &dyn BoneSurface,
    origin: DVec3,
    dir: DVec3,
    len_mm: f64,
) -> Option<RayHit> {
    let max_t = len_mm;
    let mut skipped = 0.0;
    // A handful of exits in a row means nested or overlapping surfaces; eight is ample.
    for _ in 0..8 {
        let from = origin + dir * skipped;
        let hit = bone.first_hit(from, dir, max_t - skipped)?;
        let t = skipped + hit.t_mm;
        if hit.normal.dot(dir) < 0.0 {
            return Some(RayHit {
                t_mm: t,
                normal: hit.normal,
            });
        }
        // Step just past the exit (1e-9 mm, far below any geometric scale here).
        skipped = t + 1e-9;
        if skipped > max_t {
            return None;
        }
    }
    None
}

/// Bone given as a closed triangle mesh, queried through its bounding-volume hierarchy.
impl BoneSurface for crate::geom::Bvh {
    fn first_hit(&self, origin: DVec3, dir: DVec3, max_t_mm: f64) -> Option<RayHit> {
        crate::geom::Bvh::first_hit(self, origin.to_array(), dir.to_array(), 0.0, max_t_mm).map(
            |h| RayHit {
                t_mm: h.hit.t_mm,
                normal: DVec3::from_array(h.normal),
            },
        )
    }
    fn contains(&self, p: DVec3) -> bool {
        crate::geom::Bvh::contains(self, p.to_array())
    }
}
