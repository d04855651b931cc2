//! Skipping the children of a union or a subtraction that cannot change its value at a point,
//! without changing any value.
//!
//! A bone is a smooth union of a dozen parts, each a placed primitive, and most of them are far
//! from any one point. [`Sdf::prepared`] wraps every child of a union, a smooth union and the
//! subtracted side of a subtraction in [`Sdf::Bounded`] with a [`Cull`]: a box and two constants
//! such that the child's bound is at least `lambda * distance(p, box) - c` at every point `p`
//! outside the box. Where that lower bound shows the child's value would not change the
//! combination, `eval` skips it:
//!
//! - `min(d, e)` is `d` when `e > d`;
//! - the polynomial smooth minimum `smin(d, e, k)` is exactly `d` when `e >= d + k` (its blend
//!   weight is zero there, see [`super::smin`]);
//! - `max(a, -b)` is `a` when `b > -a`, and the smooth subtraction `-smin(-a, b, k)` is exactly
//!   `a` when `b >= -a + k`.
//!
//! Every skip asks for `bound::MARGIN_MM` more than the exact condition, which covers the
//! rounding of both the bound and the child's value, so prepared and plain solids evaluate bit
//! for bit the same (tested on the phantoms' solids).
//!
//! The lower bounds, for `p` outside the node's box `B` (`D = distance(p, B)`):
//! - sphere, rounded box, tube (exact distances whose solid lies in `B`): `f >= D`;
//! - ellipsoid with semi-axes `r`: `f = min(r) (|p / r| - 1)`, and `D <= max(r) dist(p / r,
//!   unit cube) <= max(r) (|p / r| - 1)` because the unit ball lies in the unit cube, so
//!   `f >= (min r / max r) D`;
//! - elliptic cylinder: the same ratio for the section's bound, which the rounded profile keeps
//!   (`|(a + r, b + r)| - r >= |(a, b)|` for `a, b >= 0`);
//! - union: outside the union of the children's boxes every child's bound holds, so the
//!   smallest `lambda` and the largest `c`; a smooth union lowers a minimum by at most `k / 4` at
//!   each of its `n - 1` blends, so `c` grows by `(n - 1) k / 4`;
//! - intersection, subtraction: at least the bound of one finite child (the smallest box);
//! - offset by `r >= 0`: the box grows by `r` and `c` by `r` (a shrink only raises the bound);
//! - rigid placement: the box of the placed box's corners (a point outside it is outside the
//!   placed box and no nearer to it);
//! - scaling by `s`: `lambda min(s) / max(s)` and `c min(s)`.

use glam::DVec3;

use super::Sdf;
use super::aabb::Aabb;
use super::bound::{Cull, axis_ratio};

impl Sdf {
    /// The same solid with every child of a union, a smooth union and every subtracted solid
    /// wrapped in [`Sdf::Bounded`], so that `eval` skips those that cannot change its value (see
    /// the module documentation). Values are unchanged bit for bit.
    pub fn prepared(self) -> Sdf {
        let boxed = |s: Box<Sdf>| Box::new(s.prepared());
        let bounded = |s: Box<Sdf>| Box::new(s.prepared().bounded());
        match self {
            Sdf::Union(c) => Sdf::Union(c.into_iter().map(|s| s.prepared().bounded()).collect()),
            Sdf::SmoothUnion(c, k) => {
                Sdf::SmoothUnion(c.into_iter().map(|s| s.prepared().bounded()).collect(), k)
            }
            Sdf::Intersect(c) => Sdf::Intersect(c.into_iter().map(Sdf::prepared).collect()),
            Sdf::Subtract(a, b) => Sdf::Subtract(boxed(a), bounded(b)),
            Sdf::SmoothSubtract(a, b, k) => Sdf::SmoothSubtract(boxed(a), bounded(b), k),
            Sdf::Offset(a, r) => Sdf::Offset(boxed(a), r),
            Sdf::Placed(a, rigid) => Sdf::Placed(boxed(a), rigid),
            Sdf::Scaled(a, s) => Sdf::Scaled(boxed(a), s),
            Sdf::Bounded(a, cull) => Sdf::Bounded(boxed(a), cull),
            leaf => leaf,
        }
    }

    /// This solid wrapped with its [`Cull`] where that can ever skip it.
    fn bounded(self) -> Sdf {
        if matches!(self, Sdf::Bounded(..)) {
            return self;
        }
        let cull = self.cull();
        if cull.useful() {
            Sdf::Bounded(Box::new(self), cull)
        } else {
            self
        }
    }

    /// The lower bound of this solid away from a box (see the module documentation).
    pub fn cull(&self) -> Cull {
        match self {
            Sdf::Sphere { .. } | Sdf::RoundBox { .. } | Sdf::Tube { .. } => {
                Cull::exact(self.bounds())
            }
            Sdf::Ellipsoid { radii } => Cull {
                lambda: axis_ratio(&radii.to_array()),
                ..Cull::exact(self.bounds())
            },
            Sdf::EllipticCylinder { rx, ry, .. } => Cull {
                lambda: axis_ratio(&[*rx, *ry]),
                ..Cull::exact(self.bounds())
            },
            Sdf::HalfSpace { .. } => Cull::NONE,
            Sdf::Union(c) => union_cull(c, 0.0),
            Sdf::SmoothUnion(c, k) => union_cull(c, 0.25 * k.max(0.0)),
            Sdf::Intersect(c) => c
                .iter()
                .map(Sdf::cull)
                .filter(Cull::useful)
                .min_by(|a, b| volume(&a.bbox).total_cmp(&volume(&b.bbox)))
                .unwrap_or(Cull::NONE),
            Sdf::Subtract(a, _) | Sdf::SmoothSubtract(a, _, _) => a.cull(),
            Sdf::Offset(a, r) => {
                let inner = a.cull();
                if *r >= 0.0 {
                    Cull {
                        bbox: inner.bbox.expand(*r),
                        lambda: inner.lambda,
                        c: inner.c + r,
                    }
                } else {
                    inner
                }
            }
            Sdf::Placed(a, rigid) => {
                let inner = a.cull();
                Cull {
                    bbox: inner.bbox.map_corners(|q| rigid.to_world(q)),
                    ..inner
                }
            }
            Sdf::Scaled(a, s) => {
                let inner = a.cull();
                let ratio = axis_ratio(&s.to_array());
                if ratio == 0.0 {
                    return Cull::NONE;
                }
                Cull {
                    bbox: inner.bbox.map_corners(|q| q * *s),
                    lambda: inner.lambda * ratio,
                    c: inner.c * s.min_element(),
                }
            }
            Sdf::Bounded(_, cull) => *cull,
        }
    }

    /// The lower bound of a child at `p` (minus infinity for a child that is not
    /// [`Sdf::Bounded`]).
    #[inline]
    pub(super) fn lower_bound(&self, p: DVec3) -> f64 {
        match self {
            Sdf::Bounded(_, cull) => cull.lower(p),
            _ => f64::NEG_INFINITY,
        }
    }
}

/// A union's bound: its children's boxes joined, the smallest slope, the largest offset, plus
/// `blend_mm` for each blend of a smooth union.
fn union_cull(children: &[Sdf], blend_mm: f64) -> Cull {
    let culls: Vec<Cull> = children.iter().map(Sdf::cull).collect();
    let Some(first) = culls.first() else {
        return Cull::NONE;
    };
    let mut out = *first;
    for c in &culls[1..] {
        out.bbox = out.bbox.union(c.bbox);
        out.lambda = out.lambda.min(c.lambda);
        out.c = out.c.max(c.c);
    }
    out.c += blend_mm * (culls.len() - 1) as f64;
    out
}

fn volume(b: &Aabb) -> f64 {
    let e = b.max - b.min;
    e.x * e.y * e.z
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::anatomy::phantom::sdf::Rigid;

    fn points(seed: u64, n: usize, span: f64) -> Vec<DVec3> {
        let mut state = seed;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        (0..n)
            .map(|_| DVec3::new(next(), next(), next()) * span)
            .collect()
    }

    fn shapes() -> Vec<Sdf> {
        let ell = Sdf::Ellipsoid {
            radii: DVec3::new(14.0, 3.0, 6.0),
        };
        let cyl = Sdf::EllipticCylinder {
            rx: 9.0,
            ry: 2.5,
            half_h: 7.0,
            round: 1.5,
        };
        let slab = Sdf::slab_between(
            DVec3::new(-10.0, 4.0, 2.0),
            DVec3::new(12.0, -3.0, 5.0),
            DVec3::Z,
            2.0,
            4.0,
            1.0,
        );
        let tube = Sdf::Tube {
            points: vec![
                DVec3::new(-20.0, 0.0, 0.0),
                DVec3::new(0.0, 8.0, 3.0),
                DVec3::new(15.0, 2.0, -6.0),
            ],
            radii: vec![2.0, 4.0, 1.0],
        };
        let rot = Rigid::from_axes(
            DVec3::new(3.0, -2.0, 1.0),
            DVec3::new(1.0, 2.0, 0.5),
            DVec3::new(0.2, -0.3, 1.0),
        );
        vec![
            ell.clone().placed(rot),
            cyl.clone().placed(rot),
            Sdf::Scaled(Box::new(ell.clone()), DVec3::new(1.5, 0.7, 2.0)),
            Sdf::SmoothUnion(
                vec![
                    ell.clone(),
                    cyl.clone().at(DVec3::new(15.0, 0.0, 0.0)),
                    tube.clone(),
                ],
                4.0,
            ),
            Sdf::Union(vec![
                slab.clone(),
                tube.clone(),
                Sdf::Sphere { radius: 3.0 },
            ])
            .minus(cyl.clone().offset(2.0))
            .offset(1.5),
            Sdf::Intersect(vec![
                Sdf::SmoothUnion(vec![slab.clone(), ell.clone()], 3.0),
                Sdf::HalfSpace {
                    normal: DVec3::Z,
                    offset: 2.0,
                },
            ])
            .smooth_minus(tube.clone(), 2.5),
            Sdf::SmoothUnion(vec![slab, tube.offset(-0.5)], 6.0).placed(rot),
        ]
    }

    /// The same solid without its [`Sdf::Bounded`] wrappers: what `eval` computed before
    /// [`Sdf::prepared`].
    fn plain(s: Sdf) -> Sdf {
        let b = |s: Box<Sdf>| Box::new(plain(*s));
        match s {
            Sdf::Union(c) => Sdf::Union(c.into_iter().map(plain).collect()),
            Sdf::SmoothUnion(c, k) => Sdf::SmoothUnion(c.into_iter().map(plain).collect(), k),
            Sdf::Intersect(c) => Sdf::Intersect(c.into_iter().map(plain).collect()),
            Sdf::Subtract(a, c) => Sdf::Subtract(b(a), b(c)),
            Sdf::SmoothSubtract(a, c, k) => Sdf::SmoothSubtract(b(a), b(c), k),
            Sdf::Offset(a, r) => Sdf::Offset(b(a), r),
            Sdf::Placed(a, rigid) => Sdf::Placed(b(a), rigid),
            Sdf::Scaled(a, s) => Sdf::Scaled(b(a), s),
            Sdf::Bounded(a, _) => plain(*a),
            leaf => leaf,
        }
    }

    /// Every bounded child inside `s` with its bound (for the checks below).
    fn bounded_children<'a>(s: &'a Sdf, out: &mut Vec<(&'a Sdf, Cull)>) {
        match s {
            Sdf::Union(c) | Sdf::SmoothUnion(c, _) | Sdf::Intersect(c) => {
                c.iter().for_each(|s| bounded_children(s, out));
            }
            Sdf::Subtract(a, b) | Sdf::SmoothSubtract(a, b, _) => {
                bounded_children(a, out);
                bounded_children(b, out);
            }
            Sdf::Offset(a, _) | Sdf::Placed(a, _) | Sdf::Scaled(a, _) => bounded_children(a, out),
            Sdf::Bounded(a, cull) => {
                out.push((a, *cull));
                bounded_children(a, out);
            }
            _ => {}
        }
    }

    /// Both phantoms as built (their parts are prepared when pushed): every part gives its plain
    /// solid's values bit for bit around its box, and every top-level child's bound holds.
    /// (Children inside a placement or a scaling are checked in their own frame by the shapes
    /// test above; here only those evaluated in the model frame are.)
    #[test]
    fn the_phantoms_prepared_solids_evaluate_as_the_plain_ones() {
        use crate::anatomy::phantom::{self, PhantomParams, cervical};
        let lumbar = phantom::anatomy(&PhantomParams::default());
        let neck = cervical::anatomy(&cervical::default_params());
        let mut skipped_somewhere = false;
        for (n, part) in lumbar.parts.iter().chain(&neck.parts).enumerate() {
            let reference = plain(part.sdf.clone());
            let b = reference.bounds().expand(20.0);
            let b = if b.is_finite() {
                b
            } else {
                Aabb::centered(DVec3::ZERO, DVec3::splat(200.0))
            };
            let top: Vec<(&Sdf, Cull)> = match &part.sdf {
                Sdf::Union(c) | Sdf::SmoothUnion(c, _) => c
                    .iter()
                    .filter_map(|s| match s {
                        Sdf::Bounded(a, cull) => Some((&**a, *cull)),
                        _ => None,
                    })
                    .collect(),
                _ => Vec::new(),
            };
            let mut all = Vec::new();
            bounded_children(&part.sdf, &mut all);
            skipped_somewhere |= !all.is_empty();
            for q in points(0xabc + n as u64, 3_000, 1.0) {
                let p = b.min + (q * 0.5 + DVec3::splat(0.5)) * (b.max - b.min);
                assert_eq!(
                    part.sdf.eval(p).to_bits(),
                    reference.eval(p).to_bits(),
                    "{} at {p}",
                    part.name
                );
                for (child, cull) in &top {
                    let lower = cull.lower(p);
                    assert!(child.eval(p) >= lower - 1e-12, "{} at {p}", part.name);
                }
            }
        }
        assert!(skipped_somewhere, "some part has bounded children");
    }

    /// The lower bound holds outside the box for every shape and combination (the skips rest on
    /// it), and prepared solids give the plain solids' values bit for bit.
    #[test]
    fn lower_bounds_hold_and_prepared_solids_evaluate_the_same() {
        for (n, s) in shapes().into_iter().enumerate() {
            let cull = s.cull();
            let prepared = s.clone().prepared();
            let mut outside = 0;
            for p in points(0x5eed + n as u64, 20_000, 45.0) {
                let f = s.eval(p);
                let lower = cull.lower(p);
                if lower > f64::NEG_INFINITY {
                    outside += 1;
                    assert!(f >= lower - 1e-12, "shape {n}: {f} < {lower} at {p}");
                }
                assert_eq!(prepared.eval(p).to_bits(), f.to_bits(), "shape {n} at {p}");
            }
            assert!(
                outside > 1000,
                "shape {n}: {outside} points outside the box"
            );
        }
    }
}
