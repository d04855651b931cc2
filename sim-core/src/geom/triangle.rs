//! The watertight ray/triangle test (Woop, Benthin and Wald 2013), in `f64`.

/// A ray prepared for many triangle tests: the permutation and shear that map it onto +z.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RayPrecomp {
    /// Ray origin, millimetres.
    pub origin_mm: [f64; 3],
    /// Ray direction (any non-zero length; `t` is measured in units of this vector).
    pub dir: [f64; 3],
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f64,
    sy: f64,
    sz: f64,
}

impl RayPrecomp {
    /// Prepares a ray. `dir` must be finite and non-zero.
    pub fn new(origin_mm: [f64; 3], dir: [f64; 3]) -> RayPrecomp {
        let ad = dir.map(f64::abs);
        let kz = if ad[0] >= ad[1] && ad[0] >= ad[2] {
            0
        } else if ad[1] >= ad[2] {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Swapping x and y for a ray along -z keeps the winding (and so the entering/leaving
        // classification) the same as for a ray along +z.
        if dir[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        RayPrecomp {
            origin_mm,
            dir,
            kx,
            ky,
            kz,
            sx: dir[kx] / dir[kz],
            sy: dir[ky] / dir[kz],
            sz: 1.0 / dir[kz],
        }
    }

    /// A vertex in the sheared ray frame: the ray is the +z axis through (0, 0).
    #[inline]
    fn shear(&self, v: [f64; 3]) -> [f64; 3] {
        let a = [
            v[0] - self.origin_mm[0],
            v[1] - self.origin_mm[1],
            v[2] - self.origin_mm[2],
        ];
        [
            a[self.kx] - self.sx * a[self.kz],
            a[self.ky] - self.sy * a[self.kz],
            self.sz * a[self.kz],
        ]
    }
}

/// Edge function of the directed 2-D edge `p -> q` at the origin. Swapping `p` and `q` negates it
/// exactly (floating-point products commute and `x - y == -(y - x)`), which is what makes two
/// triangles sharing the edge agree.
#[inline]
fn edge(p: [f64; 3], q: [f64; 3]) -> f64 {
    q[0] * p[1] - q[1] * p[0]
}

/// Tie-break for an edge function that is exactly zero (the ray passes through the edge's line).
///
/// Equivalent to moving the ray by the fixed infinitesimal offset `(-eps^2, eps)` in the sheared
/// frame: the edge owns the ray if that offset lies on the triangle's interior side. `ccw` says
/// whether the triangle's interior is to the left of `p -> q` in the sheared frame.
#[inline]
fn tie_accepts(p: [f64; 3], q: [f64; 3], ccw: bool) -> bool {
    let (dx, dy) = if ccw {
        (q[0] - p[0], q[1] - p[1])
    } else {
        (p[0] - q[0], p[1] - q[1])
    };
    dx > 0.0 || (dx == 0.0 && dy > 0.0)
}

/// Intersects a prepared ray with triangle `tri` (corners in mm, counter-clockwise from outside).
///
/// Returns `(t, entering)` for a crossing with `t_min <= t <= t_max`, where the hit point is
/// `origin + t * dir` and `entering` is true when the ray goes from outside to inside (it meets
/// the triangle's front, outward-facing side). A ray in the plane of the triangle never hits it.
#[inline]
pub fn intersect_triangle(
    ray: &RayPrecomp,
    tri: &[[f64; 3]; 3],
    t_min: f64,
    t_max: f64,
) -> Option<(f64, bool)> {
    let a = ray.shear(tri[0]);
    let b = ray.shear(tri[1]);
    let c = ray.shear(tri[2]);
    let u = edge(b, c);
    let v = edge(c, a);
    let w = edge(a, b);
    let det = u + v + w;
    if det == 0.0 {
        return None;
    }
    // det < 0: the triangle is counter-clockwise in the sheared frame (interior to the left of
    // each edge), its outward normal points along the ray, and the ray is leaving the solid.
    let ccw = det < 0.0;
    let ok = |e: f64, p: [f64; 3], q: [f64; 3]| {
        if e == 0.0 {
            tie_accepts(p, q, ccw)
        } else {
            (e < 0.0) == ccw
        }
    };
    if !(ok(u, b, c) && ok(v, c, a) && ok(w, a, b)) {
        return None;
    }
    let t = (u * a[2] + v * b[2] + w * c[2]) / det;
    if t >= t_min && t <= t_max {
        Some((t, !ccw))
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn normal(t: &[[f64; 3]; 3]) -> [f64; 3] {
        let e1 = [t[1][0] - t[0][0], t[1][1] - t[0][1], t[1][2] - t[0][2]];
        let e2 = [t[2][0] - t[0][0], t[2][1] - t[0][1], t[2][2] - t[0][2]];
        [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ]
    }

    #[test]
    fn entering_flag_matches_the_normal_for_every_dominant_axis_and_sign() {
        // A triangle facing +z (CCW seen from +z) and rays along all six dominant directions.
        let tri = [[-1.0, -1.0, 0.0], [2.0, -1.0, 0.0], [-1.0, 2.0, 0.0]];
        let rots: [fn([f64; 3]) -> [f64; 3]; 3] =
            [|v| v, |v| [v[2], v[0], v[1]], |v| [v[1], v[2], v[0]]];
        for rot in rots {
            let t = [rot(tri[0]), rot(tri[1]), rot(tri[2])];
            let n = normal(&t);
            for sign in [1.0, -1.0] {
                // Slightly oblique, so the dominant axis is the triangle's normal axis.
                let d = rot([0.05 * sign, 0.03, sign]);
                let o = rot([0.0, 0.0, -5.0 * sign]);
                let ray = RayPrecomp::new(o, d);
                let (t_hit, entering) = intersect_triangle(&ray, &t, 0.0, f64::INFINITY).unwrap();
                let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
                assert_eq!(entering, dn < 0.0, "rot/sign {sign}");
                // The hit lies in the triangle's plane.
                let p = [
                    o[0] + t_hit * d[0],
                    o[1] + t_hit * d[1],
                    o[2] + t_hit * d[2],
                ];
                let off =
                    (p[0] - t[0][0]) * n[0] + (p[1] - t[0][1]) * n[1] + (p[2] - t[0][2]) * n[2];
                assert!(off.abs() < 1e-12, "{off}");
            }
        }
    }

    #[test]
    fn shared_edge_is_owned_by_exactly_one_triangle() {
        // Two triangles of a square split along its diagonal; rays exactly through the diagonal.
        let p = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let t1 = [p[0], p[1], p[2]];
        let t2 = [p[0], p[2], p[3]];
        for k in 1..10 {
            let s = k as f64 / 10.0;
            for d in [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]] {
                let ray = RayPrecomp::new([s, s, -d[2] * 3.0], d);
                let n1 = intersect_triangle(&ray, &t1, 0.0, 10.0).is_some() as u32;
                let n2 = intersect_triangle(&ray, &t2, 0.0, 10.0).is_some() as u32;
                assert_eq!(n1 + n2, 1, "s = {s}, d = {d:?}");
            }
        }
    }
}
