//! Axis-aligned boxes of the phantom's solids.

use glam::DVec3;

/// An axis-aligned box `(min, max)` in millimetres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// Lower corner.
    pub min: DVec3,
    /// Upper corner.
    pub max: DVec3,
}

impl Aabb {
    /// The box `centre +- half`.
    pub fn centered(centre: DVec3, half: DVec3) -> Aabb {
        Aabb {
            min: centre - half,
            max: centre + half,
        }
    }

    /// An infinite box (for unbounded shapes such as half-spaces).
    pub fn everything() -> Aabb {
        Aabb {
            min: DVec3::splat(f64::NEG_INFINITY),
            max: DVec3::splat(f64::INFINITY),
        }
    }

    /// Smallest box holding both.
    pub fn union(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// Overlap of both (may be empty: some `min > max`).
    pub fn intersect(self, o: Aabb) -> Aabb {
        Aabb {
            min: self.min.max(o.min),
            max: self.max.min(o.max),
        }
    }

    /// Grown by `r` on every side.
    pub fn expand(self, r: f64) -> Aabb {
        Aabb {
            min: self.min - DVec3::splat(r),
            max: self.max + DVec3::splat(r),
        }
    }

    /// True when the box holds no point.
    pub fn is_empty(&self) -> bool {
        self.min.x > self.max.x || self.min.y > self.max.y || self.min.z > self.max.z
    }

    /// Exact signed distance from `p` to the box, mm (negative inside).
    pub fn signed_distance_mm(&self, p: DVec3) -> f64 {
        let c = 0.5 * (self.min + self.max);
        let half = 0.5 * (self.max - self.min);
        let q = (p - c).abs() - half;
        q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
    }

    /// Whether the box is finite on every side.
    pub fn is_finite(&self) -> bool {
        self.min.is_finite() && self.max.is_finite()
    }

    /// Box of this box's corners mapped by `f` (exact for affine maps).
    pub(crate) fn map_corners(self, f: impl Fn(DVec3) -> DVec3) -> Aabb {
        if !self.is_finite() {
            return Aabb::everything();
        }
        let mut out = Aabb {
            min: DVec3::splat(f64::INFINITY),
            max: DVec3::splat(f64::NEG_INFINITY),
        };
        for c in 0..8 {
            let p = DVec3::new(
                if c & 1 == 0 { self.min.x } else { self.max.x },
                if c & 2 == 0 { self.min.y } else { self.max.y },
                if c & 4 == 0 { self.min.z } else { self.max.z },
            );
            let q = f(p);
            out.min = out.min.min(q);
            out.max = out.max.max(q);
        }
        out
    }
}
