//! The deposit of a lattice column that crosses the slice obliquely (a tilted or rotated probe):
//! every scatterer has its own in-plane point, so each is deposited on its own. Two things keep
//! this loop short: the column is first clipped to the part whose points can be within reach
//! (a convex region of the plane, so one interval of cells), and on a linear array the line
//! index, depth and carrier phase of consecutive scatterers follow by constant steps.

use super::super::probe::{ProbeKind, ScanGeometry};
use super::super::tissue::{ScatterProps, Texture};
use super::column::{Column, EchoCache, Reach, ScatterContext};
use super::fascicle::fascicle_factor;
use super::grid::{CellSum, IqGrid};
use super::lookup::{cis, exp_neg_in};
use super::sector::SectorSteps;

/// A convex region of the plane (image coordinates, mm) that holds every point within the
/// reach: half-planes `a . p <= b` and, for a sector, a disc. Its clip of a column is one
/// interval; the points of that interval are still checked one by one against the reach.
pub(super) struct ConvexReach {
    /// `(a_x, a_y, b)` per half-plane.
    planes: Vec<(f64, f64, f64)>,
    /// `(centre_x, centre_y, radius)` of the disc, if any.
    disc: Option<(f64, f64, f64)>,
}

impl ConvexReach {
    /// The region of `geo`'s reach: the padded lines' rectangle (linear) or the wedge of the
    /// padded sector cut by the outer radius (curvilinear; no clip where the wedge is not
    /// convex, more than a half turn).
    pub(super) fn new(geo: &ScanGeometry, reach: &Reach) -> ConvexReach {
        let at = |u: f64| geo.line_coordinate(u);
        match geo.spec.kind {
            ProbeKind::Linear => {
                let (x0, x1) = (at(reach.u.0), at(reach.u.1));
                ConvexReach {
                    planes: vec![
                        (-1.0, 0.0, -x0),
                        (1.0, 0.0, x1),
                        (0.0, -1.0, -reach.z.0),
                        (0.0, 1.0, reach.z.1),
                    ],
                    disc: None,
                }
            }
            ProbeKind::Curvilinear => {
                let r0 = geo.spec.radius_mm;
                let (t0, t1) = (at(reach.u.0), at(reach.u.1));
                let r_hi = (r0 + reach.z.1).max(0.0);
                let disc = Some((0.0, -r0, r_hi));
                if t1 - t0 >= std::f64::consts::PI || t0 < -std::f64::consts::PI {
                    return ConvexReach {
                        planes: Vec::new(),
                        disc,
                    };
                }
                // A point at angle theta from the apex (0, -r0) (theta = atan2(x, y + r0)) is
                // right of the ray at t0: cos t0 x - sin t0 (y + r0) >= 0, left of t1's.
                let (s0, c0) = t0.sin_cos();
                let (s1, c1) = t1.sin_cos();
                ConvexReach {
                    planes: vec![(-c0, s0, -s0 * r0), (c1, -s1, s1 * r0)],
                    disc,
                }
            }
        }
    }

    /// The cells `lo..=hi` of a column whose cell `k` is at `p + (k - k0) d` (in plane) that
    /// can lie in the region, with a cell of slack each side (empty: `lo > hi`).
    pub(super) fn clip(
        &self,
        p: (f64, f64),
        d: (f64, f64),
        k0: i64,
        (lo, hi): (i64, i64),
    ) -> (i64, i64) {
        let (mut a, mut b) = ((lo - k0) as f64, (hi - k0) as f64);
        for &(ax, ay, bound) in &self.planes {
            // ax (px + t dx) + ay (py + t dy) <= bound.
            let slope = ax * d.0 + ay * d.1;
            let rest = bound - (ax * p.0 + ay * p.1);
            if slope.abs() < 1e-15 {
                if rest < 0.0 {
                    return (1, 0);
                }
            } else if slope > 0.0 {
                b = b.min(rest / slope);
            } else {
                a = a.max(rest / slope);
            }
        }
        if let Some((cx, cy, r)) = self.disc {
            // |c + t d|^2 <= r^2 with c = p - centre.
            let (ux, uy) = (p.0 - cx, p.1 - cy);
            let qa = d.0 * d.0 + d.1 * d.1;
            let qb = ux * d.0 + uy * d.1;
            let qc = ux * ux + uy * uy - r * r;
            if qa > 0.0 {
                let disc = qb * qb - qa * qc;
                if disc < 0.0 {
                    return (1, 0);
                }
                let root = disc.sqrt();
                a = a.max((-qb - root) / qa);
                b = b.min((-qb + root) / qa);
            } else if qc > 0.0 {
                return (1, 0);
            }
        }
        // Empty, or NaN from a degenerate frame.
        if a.partial_cmp(&b)
            .is_none_or(|o| o == std::cmp::Ordering::Greater)
        {
            return (1, 0);
        }
        (
            (k0 + a.floor() as i64 - 1).max(lo),
            (k0 + b.ceil() as i64 + 1).min(hi),
        )
    }
}

/// Deposits the scatterers of an oblique column (along region axis `AM`) one by one.
#[inline(always)]
pub(super) fn column_oblique<const AM: usize>(
    cx: &ScatterContext<'_>,
    col: &Column<'_>,
    region: &ConvexReach,
    grid: &mut IqGrid,
    cells: &mut CellSum,
    (echo, tissues): (&mut EchoCache, &mut Vec<ScatterProps>),
) {
    let geo = cx.geo;
    let k_first = col.k.start;
    let (k_lo, k_hi) = region.clip(
        (col.q.x, col.q.y),
        (col.step.x, col.step.y),
        k_first,
        (col.k.start, col.k.end - 1),
    );
    if k_lo > k_hi {
        return;
    }
    let lines_max = (geo.lines - 1) as f64;
    let t0 = (k_lo - k_first) as f64;
    let q0 = col.q + col.step * t0;
    let linear = geo.spec.kind == ProbeKind::Linear;
    // Linear array: the line index is affine in x and the depth is y, so the carrier phase
    // 2 k z advances by a constant turn from one cell of the column to the next.
    let n = (geo.lines.max(2) - 1) as f64;
    let lines_per_mm = n / geo.spec.footprint_mm;
    let (mut carrier, turn) = if linear {
        (
            cos_sin(2.0 * cx.k0 * q0.y),
            cos_sin(2.0 * cx.k0 * col.step.y),
        )
    } else {
        ((1.0, 0.0), (1.0, 0.0))
    };
    let mut pos = col.pos;
    // Curvilinear array: each point's angle from the previous one's (see `sector`).
    let mut sector = SectorSteps::new(geo);
    col.tissue::<AM>(cx, k_lo..k_hi + 1, tissues);
    for (i, k) in (k_lo..=k_hi).enumerate() {
        let here = q0 + col.step * (k - k_lo) as f64;
        let (u, z, (cs, sn)) = if linear {
            let c = carrier;
            carrier = (c.0 * turn.0 - c.1 * turn.1, c.0 * turn.1 + c.1 * turn.0);
            (here.x * lines_per_mm + 0.5 * n, here.y, c)
        } else {
            let (u, z) = sector.next(here.x, here.y);
            (u, z, (f64::NAN, f64::NAN))
        };
        if !cx.reach.contains(u, z) {
            continue;
        }
        let tissue = &col.tissue_at::<AM>(cx, (i, k), tissues);
        let Some(hsh) = col.scatterer::<AM>(cx, k, tissue, &mut pos, echo) else {
            continue;
        };
        let s = z / cx.tables.dz;
        let i = cx.tables.sample_at(s);
        let elev_arg = here.z * here.z * cx.tables.elev_inv2s2[i];
        let mut w = echo.amp * (exp_neg_in(cx.exp_tab, elev_arg) * cx.tables.elev_energy[i]);
        if tissue.texture == Texture::Fascicular {
            let ([_, _], [dx, dy]) = geo.line_in_plane(u.clamp(0.0, lines_max));
            let dir = geo.frame.lateral * dx + geo.frame.beam * dy;
            w *= fascicle_factor(pos, cx.medium.fibre_axis(pos), dir, cx.seed);
        }
        let (cs, sn) = if linear {
            (cs, sn)
        } else {
            cis(2.0 * cx.k0 * z)
        };
        let (ci, cq) = super::amplitude::iq_of_hash(hsh);
        let (a, b) = (ci * w, cq * w);
        cells.deposit(grid, u, s, a * cs - b * sn, a * sn + b * cs);
    }
}

/// `(cos x, sin x)`.
fn cos_sin(x: f64) -> (f64, f64) {
    let (s, c) = x.sin_cos();
    (c, s)
}

#[cfg(test)]
mod tests {
    use super::super::column::test_frames;
    use super::*;
    use crate::ultrasound::probe::{ProbeKind, ProbePose};
    use glam::DVec3;

    /// Every cell of a column that the clip leaves out is out of reach, for both probes, random
    /// poses and random column traces (steep, shallow, crossing the apex side of the sector);
    /// and the clip does leave cells out.
    #[test]
    fn the_cells_a_column_clip_leaves_out_are_all_out_of_reach() {
        let mut rand = test_frames::uniform(0x9e37_79b9_7f4a_7c15);
        let mut left_out = 0;
        for kind in [ProbeKind::Linear, ProbeKind::Curvilinear] {
            for trial in 0..40 {
                let pose = ProbePose::from_rotation(
                    DVec3::ZERO,
                    DVec3::new(rand() - 0.5, rand() - 0.5, 1.0),
                    180.0 * rand() - 90.0,
                );
                let (geo, reach) = test_frames::scan_at(kind, pose);
                let region = ConvexReach::new(&geo, &reach);
                for _ in 0..50 {
                    let p = (160.0 * rand() - 80.0, 100.0 * rand() - 30.0);
                    let d = (0.4 * rand() - 0.2, 0.4 * rand() - 0.2);
                    let (k0, bounds) = (-40i64, (-40i64, 60i64));
                    let (lo, hi) = region.clip(p, d, k0, bounds);
                    for k in (bounds.0..=bounds.1).filter(|k| !(lo..=hi).contains(k)) {
                        let t = (k - k0) as f64;
                        assert!(
                            !test_frames::in_reach(&geo, &reach, p.0 + t * d.0, p.1 + t * d.1),
                            "{kind:?} trial {trial}: cell {k} left out but in reach"
                        );
                        left_out += 1;
                    }
                }
            }
        }
        assert!(left_out > 1000, "the clip leaves cells out ({left_out})");
    }
}
