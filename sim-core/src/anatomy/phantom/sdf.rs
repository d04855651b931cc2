//! Implicit solids for the phantom: signed distance bounds with smooth blends, in millimetres.
//!
//! Every shape here evaluates a function `f(p)` that is negative inside, positive outside and
//! zero on the surface, and that is **1-Lipschitz** (`|f(p) - f(q)| <= |p - q|`). Exact signed
//! distances have this property; so do the bounds we use for ellipses and anisotropic scaling,
//! and it survives `min`, `max`, rigid motion, offsets and the polynomial smooth minimum
//! (whose gradient is a convex combination of its arguments' gradients). The voxelizer relies on
//! it: when `|f|` at the centre of a block of voxels exceeds the block's half-diagonal, the whole
//! block lies on one side of the surface and needs no further evaluation.
//!
//! Shapes also report a conservative axis-aligned bounding box so that each structure is only
//! evaluated near where it can be.

use glam::{DMat3, DVec2, DVec3};

mod aabb;
mod bound;
mod coarse;
mod cull;

pub use aabb::Aabb;
pub use bound::Cull;
use bound::MARGIN_MM;
pub use coarse::{COARSE_CELL_MM, CoarseBound};

/// A rigid placement: `world = rotation * local + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    /// Columns are the local axes expressed in the world frame (orthonormal).
    pub rotation: DMat3,
    /// The local origin in the world frame, mm.
    pub translation: DVec3,
}

impl Rigid {
    /// The identity placement.
    pub const IDENTITY: Rigid = Rigid {
        rotation: DMat3::IDENTITY,
        translation: DVec3::ZERO,
    };

    /// A translation only.
    pub fn at(translation: DVec3) -> Rigid {
        Rigid {
            rotation: DMat3::IDENTITY,
            translation,
        }
    }

    /// A placement whose local axes are `x`, `y`, `z` (orthonormalised from `x` and `z`).
    pub fn from_axes(translation: DVec3, x: DVec3, z: DVec3) -> Rigid {
        let z = z.normalize();
        let x = (x - z * x.dot(z)).normalize();
        let y = z.cross(x);
        Rigid {
            rotation: DMat3::from_cols(x, y, z),
            translation,
        }
    }

    /// Local point to world.
    pub fn to_world(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    /// Local direction to world.
    pub fn dir_to_world(&self, d: DVec3) -> DVec3 {
        self.rotation * d
    }

    /// World point to local.
    pub fn to_local(&self, p: DVec3) -> DVec3 {
        self.rotation.transpose() * (p - self.translation)
    }

    /// `self` applied after `inner` (inner's world is self's local).
    pub fn compose(&self, inner: &Rigid) -> Rigid {
        Rigid {
            rotation: self.rotation * inner.rotation,
            translation: self.to_world(inner.translation),
        }
    }
}

/// A 1-Lipschitz implicit solid (negative inside).
#[derive(Debug, Clone, PartialEq)]
pub enum Sdf {
    /// Sphere of `radius` about the origin.
    Sphere {
        /// Radius, mm.
        radius: f64,
    },
    /// Ellipsoid with semi-axes `radii` about the origin (distance bound).
    Ellipsoid {
        /// Semi-axes along x, y, z, mm.
        radii: DVec3,
    },
    /// Box of half-extents `half` with edges rounded by `round` (inside the half-extents).
    RoundBox {
        /// Half-extents along x, y, z, mm (including the rounding).
        half: DVec3,
        /// Edge radius, mm.
        round: f64,
    },
    /// Cylinder along z with elliptic section (semi-axes `rx`, `ry`), half-height `half_h`, and
    /// rim rounded by `round`.
    EllipticCylinder {
        /// Semi-axis along x, mm.
        rx: f64,
        /// Semi-axis along y, mm.
        ry: f64,
        /// Half-height along z, mm.
        half_h: f64,
        /// Rim rounding radius, mm.
        round: f64,
    },
    /// A chain of round cones through `points` with per-point `radii` (a tapered tube).
    Tube {
        /// Centre-line nodes, mm.
        points: Vec<DVec3>,
        /// Radius at each node, mm.
        radii: Vec<f64>,
    },
    /// Half-space `n . p <= offset` (`n` unit).
    HalfSpace {
        /// Outward unit normal.
        normal: DVec3,
        /// Signed offset of the plane along `normal`, mm.
        offset: f64,
    },
    /// Union of all children.
    Union(Vec<Sdf>),
    /// Polynomial smooth union with blend radius `k` (mm).
    SmoothUnion(Vec<Sdf>, f64),
    /// Intersection of all children.
    Intersect(Vec<Sdf>),
    /// `a` minus `b`.
    Subtract(Box<Sdf>, Box<Sdf>),
    /// `a` minus `b` with a smooth blend of radius `k` (mm).
    SmoothSubtract(Box<Sdf>, Box<Sdf>, f64),
    /// The child grown by `r` mm (negative `r` shrinks it).
    Offset(Box<Sdf>, f64),
    /// The child placed by a rigid motion (the child is defined in the placement's local frame).
    Placed(Box<Sdf>, Rigid),
    /// The child stretched by `scale` along the local axes (a distance bound, not exact).
    Scaled(Box<Sdf>, DVec3),
    /// The child unchanged, with a lower bound of its value away from its box that lets a
    /// union or a subtraction skip it where it cannot change their value (see
    /// [`Sdf::prepared`]).
    Bounded(Box<Sdf>, Cull),
}

/// Polynomial smooth minimum (Quilez): equal to `min(a, b)` when `|a - b| >= k`, rounded within.
pub fn smin(a: f64, b: f64, k: f64) -> f64 {
    if k <= 0.0 {
        return a.min(b);
    }
    let h = (k - (a - b).abs()).max(0.0) / k;
    a.min(b) - h * h * k * 0.25
}

fn round_cone(p: DVec3, a: DVec3, b: DVec3, r1: f64, r2: f64) -> f64 {
    // Exact distance to a round cone (Quilez, "distance functions", round cone with two points).
    let ba = b - a;
    let l2 = ba.dot(ba);
    if l2 < 1e-18 {
        return (p - a).length() - r1.max(r2);
    }
    let rr = r1 - r2;
    let a2 = l2 - rr * rr;
    let il2 = 1.0 / l2;
    let pa = p - a;
    let y = pa.dot(ba);
    let z = y - l2;
    let xv = pa * l2 - ba * y;
    let x2 = xv.dot(xv);
    let y2 = y * y * l2;
    let z2 = z * z * l2;
    let k = rr.signum() * rr * rr * x2;
    if z.signum() * a2 * z2 > k {
        return (x2 + z2).sqrt() * il2 - r2;
    }
    if y.signum() * a2 * y2 < k {
        return (x2 + y2).sqrt() * il2 - r1;
    }
    ((x2 * a2 * il2).sqrt() + y * rr) * il2 - r1
}

impl Sdf {
    /// Evaluates the bound at `p` (mm); negative inside.
    pub fn eval(&self, p: DVec3) -> f64 {
        match self {
            Sdf::Sphere { radius } => p.length() - radius,
            Sdf::Ellipsoid { radii } => {
                // |p / r| - 1 has gradient at most 1 / min(r); scaling by min(r) keeps it
                // 1-Lipschitz, with the exact zero set.
                let m = radii.min_element();
                ((p / *radii).length() - 1.0) * m
            }
            Sdf::RoundBox { half, round } => {
                let q = p.abs() - (*half - DVec3::splat(*round));
                q.max(DVec3::ZERO).length() + q.max_element().min(0.0) - round
            }
            Sdf::EllipticCylinder {
                rx,
                ry,
                half_h,
                round,
            } => {
                // The ellipse bound is exact on the axes; the rim is rounded by offsetting the
                // 2-D profile inwards and back out.
                let d2 = (DVec2::new(p.x / rx, p.y / ry).length() - 1.0) * rx.min(*ry);
                let w = DVec2::new(d2 + round, p.z.abs() - (half_h - round));
                w.max(DVec2::ZERO).length() + w.max_element().min(0.0) - round
            }
            Sdf::Tube { points, radii } => {
                let mut d = f64::INFINITY;
                for i in 0..points.len().saturating_sub(1) {
                    d = d.min(round_cone(
                        p,
                        points[i],
                        points[i + 1],
                        radii[i],
                        radii[i + 1],
                    ));
                }
                if points.len() == 1 {
                    d = (p - points[0]).length() - radii[0];
                }
                d
            }
            Sdf::HalfSpace { normal, offset } => normal.dot(p) - offset,
            // A child skipped here (its lower bound shows it cannot lower the minimum, or lies
            // beyond the blend) would leave the value unchanged bit for bit (see `cull`).
            Sdf::Union(c) => c.iter().fold(f64::INFINITY, |d, s| {
                if s.lower_bound(p) > d + MARGIN_MM {
                    d
                } else {
                    d.min(s.eval(p))
                }
            }),
            Sdf::SmoothUnion(c, k) => {
                let mut it = c.iter();
                let first = it.next().map_or(f64::INFINITY, |s| s.eval(p));
                let beyond = k.max(0.0) + MARGIN_MM;
                it.fold(first, |d, s| {
                    if s.lower_bound(p) > d + beyond {
                        d
                    } else {
                        smin(d, s.eval(p), *k)
                    }
                })
            }
            Sdf::Intersect(c) => c.iter().fold(f64::NEG_INFINITY, |d, s| d.max(s.eval(p))),
            Sdf::Subtract(a, b) => {
                let fa = a.eval(p);
                if b.lower_bound(p) > -fa + MARGIN_MM {
                    fa
                } else {
                    fa.max(-b.eval(p))
                }
            }
            Sdf::SmoothSubtract(a, b, k) => {
                let fa = a.eval(p);
                if b.lower_bound(p) > -fa + k.max(0.0) + MARGIN_MM {
                    fa
                } else {
                    -smin(-fa, b.eval(p), *k)
                }
            }
            Sdf::Offset(a, r) => a.eval(p) - r,
            Sdf::Placed(a, rigid) => a.eval(rigid.to_local(p)),
            Sdf::Scaled(a, s) => a.eval(p / *s) * s.min_element(),
            Sdf::Bounded(a, _) => a.eval(p),
        }
    }

    /// A conservative bounding box of the solid (the set where `eval <= 0`).
    pub fn bounds(&self) -> Aabb {
        match self {
            Sdf::Sphere { radius } => Aabb::centered(DVec3::ZERO, DVec3::splat(*radius)),
            Sdf::Ellipsoid { radii } => Aabb::centered(DVec3::ZERO, *radii),
            Sdf::RoundBox { half, .. } => Aabb::centered(DVec3::ZERO, *half),
            Sdf::EllipticCylinder { rx, ry, half_h, .. } => {
                Aabb::centered(DVec3::ZERO, DVec3::new(*rx, *ry, *half_h))
            }
            Sdf::Tube { points, radii } => points
                .iter()
                .zip(radii)
                .map(|(p, r)| Aabb::centered(*p, DVec3::splat(*r)))
                .reduce(Aabb::union)
                .unwrap_or(Aabb {
                    min: DVec3::ZERO,
                    max: DVec3::ZERO,
                }),
            Sdf::HalfSpace { .. } => Aabb::everything(),
            Sdf::Union(c) => c
                .iter()
                .map(Sdf::bounds)
                .reduce(Aabb::union)
                .unwrap_or(Aabb::everything()),
            // A smooth union only bulges within the blend radius of the children.
            Sdf::SmoothUnion(c, k) => c
                .iter()
                .map(Sdf::bounds)
                .reduce(Aabb::union)
                .unwrap_or(Aabb::everything())
                .expand(0.25 * k),
            Sdf::Intersect(c) => c
                .iter()
                .map(Sdf::bounds)
                .reduce(Aabb::intersect)
                .unwrap_or(Aabb::everything()),
            Sdf::Subtract(a, _) | Sdf::SmoothSubtract(a, _, _) => a.bounds(),
            Sdf::Offset(a, r) => a.bounds().expand(r.max(0.0)),
            Sdf::Placed(a, rigid) => a.bounds().map_corners(|q| rigid.to_world(q)),
            Sdf::Scaled(a, s) => a.bounds().map_corners(|q| q * *s),
            Sdf::Bounded(a, _) => a.bounds(),
        }
    }

    /// Places this shape (defined in a local frame) by `rigid`.
    pub fn placed(self, rigid: Rigid) -> Sdf {
        Sdf::Placed(Box::new(self), rigid)
    }

    /// Translates this shape.
    pub fn at(self, centre: DVec3) -> Sdf {
        self.placed(Rigid::at(centre))
    }

    /// Grows (positive `r`) or shrinks the shape.
    pub fn offset(self, r: f64) -> Sdf {
        Sdf::Offset(Box::new(self), r)
    }

    /// This shape minus `other`.
    pub fn minus(self, other: Sdf) -> Sdf {
        Sdf::Subtract(Box::new(self), Box::new(other))
    }

    /// This shape minus `other`, blended over `k` mm.
    pub fn smooth_minus(self, other: Sdf, k: f64) -> Sdf {
        Sdf::SmoothSubtract(Box::new(self), Box::new(other), k)
    }

    /// A straight capsule from `a` to `b` of radius `r`.
    pub fn capsule(a: DVec3, b: DVec3, r: f64) -> Sdf {
        Sdf::Tube {
            points: vec![a, b],
            radii: vec![r, r],
        }
    }

    /// A round cone from `a` (radius `ra`) to `b` (radius `rb`).
    pub fn cone(a: DVec3, ra: f64, b: DVec3, rb: f64) -> Sdf {
        Sdf::Tube {
            points: vec![a, b],
            radii: vec![ra, rb],
        }
    }

    /// A rounded box whose local x axis runs from `a` to `b` (centred between them, reaching
    /// `round` beyond each end), with half-thickness `half_y`, half-height `half_z`, and local z
    /// axis as close to `up` as possible.
    pub fn slab_between(
        a: DVec3,
        b: DVec3,
        up: DVec3,
        half_y: f64,
        half_z: f64,
        round: f64,
    ) -> Sdf {
        let axis = b - a;
        let half_x = 0.5 * axis.length() + round;
        let x = axis.normalize();
        let z = up - x * up.dot(x);
        let z = if z.length() < 1e-9 {
            x.any_orthonormal_vector()
        } else {
            z.normalize()
        };
        let y = z.cross(x);
        let rigid = Rigid {
            rotation: DMat3::from_cols(x, y, z),
            translation: 0.5 * (a + b),
        };
        Sdf::RoundBox {
            half: DVec3::new(half_x, half_y, half_z),
            round,
        }
        .placed(rigid)
    }

    /// An intervertebral disc: an elliptic cylinder of radii `radii` and half-height `half_h`,
    /// turned by `rotation` about the midpoint of the two endplates, cut between the upper
    /// body's inferior endplate (`upper`: a point on it and that body's cranial axis) and the
    /// lower body's superior endplate (`lower`), overlapping each by 0.5 mm (bone is painted over
    /// the overlap).
    pub fn disc_between(
        radii: [f64; 2],
        half_h: f64,
        rotation: DMat3,
        upper: (DVec3, DVec3),
        lower: (DVec3, DVec3),
    ) -> Sdf {
        let ((top, up_axis), (bottom, lo_axis)) = (upper, lower);
        Sdf::Intersect(vec![
            Sdf::EllipticCylinder {
                rx: radii[0],
                ry: radii[1],
                half_h,
                round: 0.0,
            }
            .placed(Rigid {
                rotation,
                translation: 0.5 * (top + bottom),
            }),
            Sdf::HalfSpace {
                normal: up_axis,
                offset: up_axis.dot(top) + 0.5,
            },
            Sdf::HalfSpace {
                normal: -lo_axis,
                offset: -lo_axis.dot(bottom) + 0.5,
            },
        ])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Finite-difference Lipschitz check over a set of random-ish points.
    fn max_slope(s: &Sdf, centre: DVec3, span: f64) -> f64 {
        let mut worst: f64 = 0.0;
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for _ in 0..4000 {
            let p = centre + DVec3::new(next(), next(), next()) * span;
            let q = p + DVec3::new(next(), next(), next()) * 0.5;
            let d = (q - p).length();
            if d > 1e-6 {
                worst = worst.max((s.eval(p) - s.eval(q)).abs() / d);
            }
        }
        worst
    }

    #[test]
    fn primitives_have_the_right_zero_sets() {
        let s = Sdf::Sphere { radius: 5.0 }.at(DVec3::new(1.0, 2.0, 3.0));
        assert!((s.eval(DVec3::new(6.0, 2.0, 3.0))).abs() < 1e-12);
        assert!((s.eval(DVec3::new(1.0, 2.0, 3.0)) + 5.0).abs() < 1e-12);
        let e = Sdf::Ellipsoid {
            radii: DVec3::new(10.0, 5.0, 2.0),
        };
        for p in [
            DVec3::new(10.0, 0.0, 0.0),
            DVec3::new(0.0, -5.0, 0.0),
            DVec3::new(0.0, 0.0, 2.0),
        ] {
            assert!(e.eval(p).abs() < 1e-12);
        }
        let c = Sdf::EllipticCylinder {
            rx: 20.0,
            ry: 15.0,
            half_h: 10.0,
            round: 2.0,
        };
        assert!(c.eval(DVec3::new(20.0, 0.0, 0.0)).abs() < 1e-12);
        assert!(c.eval(DVec3::new(0.0, 0.0, 10.0)).abs() < 1e-12);
        assert!(c.eval(DVec3::new(0.0, 15.0, 0.0)).abs() < 1e-12);
        let t = Sdf::cone(DVec3::ZERO, 3.0, DVec3::new(0.0, 0.0, 10.0), 1.0);
        assert!((t.eval(DVec3::new(3.0, 0.0, 0.0))).abs() < 1e-9);
        assert!((t.eval(DVec3::new(0.0, 0.0, 11.0))).abs() < 1e-9);
        assert!((t.eval(DVec3::new(0.0, 0.0, -3.0))).abs() < 1e-9);
    }

    #[test]
    fn blends_and_bounds_stay_one_lipschitz() {
        let a = Sdf::Ellipsoid {
            radii: DVec3::new(12.0, 6.0, 4.0),
        };
        let b = Sdf::RoundBox {
            half: DVec3::new(3.0, 15.0, 3.0),
            round: 1.0,
        }
        .placed(Rigid::from_axes(
            DVec3::new(4.0, 2.0, 1.0),
            DVec3::new(1.0, 1.0, 0.0),
            DVec3::Z,
        ));
        let u = Sdf::SmoothUnion(vec![a.clone(), b.clone()], 4.0);
        let sub = Sdf::Scaled(
            Box::new(u.clone().smooth_minus(Sdf::Sphere { radius: 3.0 }, 2.0)),
            DVec3::new(1.0, 0.5, 2.0),
        );
        for s in [&a, &b, &u, &sub] {
            // 1.0 is the property the voxelizer's block culling needs; 1e-6 absorbs round-off.
            let slope = max_slope(s, DVec3::ZERO, 25.0);
            assert!(slope <= 1.0 + 1e-6, "slope {slope} for {s:?}");
            // Bounds contain every inside point.
            let bb = s.bounds();
            let mut state = 12345u64;
            for _ in 0..20000 {
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let f = |sh: u32| ((state >> sh) & 0xffff) as f64 / 65535.0 * 80.0 - 40.0;
                let p = DVec3::new(f(0), f(16), f(32));
                if s.eval(p) <= 0.0 {
                    assert!(
                        p.cmpge(bb.min).all() && p.cmple(bb.max).all(),
                        "{p} outside {bb:?}"
                    );
                }
            }
        }
    }
}
