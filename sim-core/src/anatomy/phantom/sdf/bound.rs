//! The lower bound of a solid's value away from its box, which lets a union skip a child (see
//! [`super::Sdf::prepared`] and `cull.rs` for the derivations).

use glam::DVec3;

use super::aabb::Aabb;

/// How much further than the exact condition a lower bound must reach before a child is
/// skipped, mm. Values are at most about 1e3 mm, whose double-precision rounding is 1e-13 mm:
/// four orders of magnitude below this.
pub const MARGIN_MM: f64 = 1e-9;

/// A lower bound of a solid's bound away from its box (derived in `cull.rs`): for every
/// point `p` outside `bbox`, `eval(p) >= lambda * distance(p, bbox) - c`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cull {
    /// The box, mm.
    pub bbox: Aabb,
    /// The slope of the bound, in (0, 1].
    pub lambda: f64,
    /// The offset of the bound, mm (not negative).
    pub c: f64,
}

impl Cull {
    /// A bound that never lets a child be skipped.
    pub(super) const NONE: Cull = Cull {
        bbox: Aabb {
            min: DVec3::NEG_INFINITY,
            max: DVec3::INFINITY,
        },
        lambda: 1.0,
        c: 0.0,
    };

    /// The lower bound at `p`, mm: minus infinity inside the box (no bound there).
    #[inline]
    pub fn lower(&self, p: DVec3) -> f64 {
        let d = self.bbox.signed_distance_mm(p);
        if d > 0.0 {
            self.lambda * d - self.c
        } else {
            f64::NEG_INFINITY
        }
    }

    pub(super) fn exact(bbox: Aabb) -> Cull {
        Cull {
            bbox,
            lambda: 1.0,
            c: 0.0,
        }
    }

    /// Whether a child with this bound can ever be skipped.
    pub(super) fn useful(&self) -> bool {
        self.bbox.is_finite() && !self.bbox.is_empty() && self.lambda > 0.0 && self.c.is_finite()
    }
}

/// The ratio of the smallest to the largest of `r` (positive semi-axes), or 0 when they are not
/// positive and finite (no bound).
pub(super) fn axis_ratio(r: &[f64]) -> f64 {
    let lo = r.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = r.iter().copied().fold(0.0, f64::max);
    if lo > 0.0 && hi.is_finite() {
        lo / hi
    } else {
        0.0
    }
}
