//! A target's samples and one triangle's set-up over them (see the module doc of `raster`):
//! its corners snapped to 1/256 of a sample, the edge functions and their tie rule, the plane's
//! depth at each sample, and the samples it covers, row by row.

use std::ops::Range;

use glam::{DMat3, DVec3};
use sim_core::fluoro::nesting::triangle_cross;

/// Sub-sample precision of snapped vertices, bits (GPU rasterisers use 8).
const SUBSAMPLE_BITS: u32 = 8;

/// Snapped coordinates beyond this many samples from the target's origin are refused (the frame
/// falls back to the GPU pass): with 8 fractional bits, edge products then stay below 2^62.
/// Simulator choice: 2^20 samples is a hundred times any detector.
const MAX_SAMPLE_COORDINATE: f64 = (1u64 << 20) as f64;

/// Triangles with a corner nearer than this to the source plane (axial depth, mm) are refused:
/// the GPU clips them, this pass does not. Simulator choice: no anatomy comes within a
/// millimetre of the focal spot.
pub(super) const MIN_AXIAL_DEPTH_MM: f64 = 1.0;

/// Why the CPU pass refused a frame (the GPU pass draws it instead).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Refused;

/// Why a CPU pass drew no sums.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum NotDrawn {
    /// [`Refused`]: the GPU pass draws the frame instead.
    Refused,
    /// Newer input made the frame obsolete before it was drawn (see `crate::interrupt`):
    /// nothing draws it.
    Interrupted,
}

impl From<Refused> for NotDrawn {
    fn from(_: Refused) -> NotDrawn {
        NotDrawn::Refused
    }
}

/// A grid of samples: rows giving `(x w, y w, w)` of a point (sample coordinates `x, y`; `w`
/// its axial depth, mm), and where its samples lie in the full image: sample coordinate `x` is
/// pixel coordinate `origin_px[0] + x / per_px`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SampleProjection {
    pub(crate) rows: [[f64; 4]; 3],
    pub(crate) origin_px: [f64; 2],
    pub(crate) per_px: f64,
}

impl SampleProjection {
    /// The full-image pixel box `(x0, y0, x1, y1)` of the sample centres of `rect`.
    pub(super) fn pixel_box(&self, rect: &SampleRect) -> [f64; 4] {
        let px = |s: usize, a: usize| self.origin_px[a] + (s as f64 + 0.5) / self.per_px;
        [
            px(rect.cols.start, 0),
            px(rect.rows.start, 1),
            px(rect.cols.end.max(rect.cols.start + 1) - 1, 0),
            px(rect.rows.end.max(rect.rows.start + 1) - 1, 1),
        ]
    }
}

/// Columns and rows of a target's samples.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct SampleRect {
    pub(crate) cols: Range<usize>,
    pub(crate) rows: Range<usize>,
}

impl SampleRect {
    pub(super) fn len(&self) -> usize {
        self.cols.len() * self.rows.len()
    }

    /// Index of sample `(i, j)` (one of these) in row-major data over this rectangle.
    #[inline(always)]
    pub(super) fn index(&self, i: usize, j: usize) -> usize {
        (j - self.rows.start) * self.cols.len() + (i - self.cols.start)
    }

    /// Whether every sample of `other` is one of these.
    pub(crate) fn contains(&self, other: &SampleRect) -> bool {
        other.cols.is_empty()
            || other.rows.is_empty()
            || (self.cols.start <= other.cols.start
                && other.cols.end <= self.cols.end
                && self.rows.start <= other.rows.start
                && other.rows.end <= self.rows.end)
    }
}

/// `v` rounded to the nearest integer, halves away from zero (as `f64::round`, which is a libm
/// call on baseline x86-64); `|v|` is at most 2^28 here.
#[inline(always)]
fn snap(v: f64) -> i64 {
    (v + 0.5f64.copysign(v)) as i64
}

#[inline(always)]
pub(super) fn project(rows: &[[f64; 4]; 3], v: &[f64; 3]) -> [f64; 3] {
    rows.map(|r| r[0] * v[0] + r[1] * v[1] + r[2] * v[2] + r[3])
}

/// The samples of a rectangle one triangle can cover (its snapped box there), its edge
/// functions and depth plane, and its facing.
pub(super) struct Span {
    pub(super) rows: std::ops::RangeInclusive<usize>,
    pub(super) cols: std::ops::RangeInclusive<usize>,
    /// Edge values at the box's first sample, and their steps per column and per row.
    pub(super) e_row: [i64; 3],
    pub(super) step_x: [i64; 3],
    pub(super) step_y: [i64; 3],
    /// `w = k / (q.x x + q.y y + q.z)` at sample coordinates `(x, y)`.
    pub(super) q: DVec3,
    pub(super) k: f64,
    /// Whether the triangle enters its mesh here (see the module doc).
    pub(super) entering: bool,
}

impl Span {
    /// `-1` entering, `+1` leaving.
    pub(super) fn sign(&self) -> f64 {
        if self.entering { -1.0 } else { 1.0 }
    }

    /// Calls `visit(i, j, w)` for every sample `(i, j)` the triangle covers, with the axial
    /// depth `w` (mm) of its plane on that sample's ray.
    #[inline(always)]
    pub(super) fn for_each(&self, mut visit: impl FnMut(usize, usize, f64)) {
        self.for_each_row(|j, cols| {
            let qy = self.q.y * (j as f64 + 0.5) + self.q.z;
            for i in cols {
                visit(i, j, self.k / (self.q.x * (i as f64 + 0.5) + qy));
            }
        });
    }

    /// Calls `row(j, cols)` for every row `j` of the span where the triangle covers samples,
    /// with those samples' columns: where all three edge values are non-negative. Each edge
    /// value is linear along the row, so each edge keeps a prefix or a suffix of it; where it
    /// changes sign is estimated in f64 and settled by the exact integer edge values, so the
    /// samples are exactly those of the per-sample test (`(e0 | e1 | e2) >= 0`), without
    /// visiting the box's uncovered samples (two thirds of a C-arm-moved frame's) or
    /// mispredicting a branch at each edge.
    #[inline(always)]
    pub(super) fn for_each_row(&self, mut row: impl FnMut(usize, Range<usize>)) {
        let (i0, i1) = (*self.cols.start(), *self.cols.end());
        let width = (i1 - i0 + 1) as i64;
        if width <= NARROW_SPAN {
            let mut e_row = self.e_row;
            for j in self.rows.clone() {
                let mut ev = e_row;
                // The covered samples of a row are one run (the triangle is convex): its first
                // and one past its last, kept without a branch per sample (coverage is too
                // irregular to predict).
                let (mut first, mut last) = (usize::MAX, 0);
                for i in i0..=i1 {
                    let covered = (ev[0] | ev[1] | ev[2]) >= 0;
                    first = if covered { first.min(i) } else { first };
                    last = if covered { i } else { last };
                    for (v, step) in ev.iter_mut().zip(self.step_x) {
                        *v = v.wrapping_add(step);
                    }
                }
                if first <= last {
                    row(j, first..last + 1);
                }
                for (v, step) in e_row.iter_mut().zip(self.step_y) {
                    *v = v.wrapping_add(step);
                }
            }
            return;
        }
        let inv = self
            .step_x
            .map(|s| if s == 0 { 0.0 } else { 1.0 / s as f64 });
        let mut e_row = self.e_row;
        for j in self.rows.clone() {
            // Covered columns `i0 + lo .. i0 + hi`.
            let (mut lo, mut hi) = (0i64, width);
            for ((&v, &s), &inv) in e_row.iter().zip(&self.step_x).zip(&inv) {
                // The edge value `t` columns on (the box's edge values stay within 2^62, see
                // `MAX_SAMPLE_COORDINATE`; so do those one column beyond it).
                let at = |t: i64| v.wrapping_add(s.wrapping_mul(t));
                if s > 0 {
                    if v < 0 {
                        // The first column where the value is non-negative.
                        // (Truncation, not `ceil`: a libm call on baseline x86-64.)
                        let mut t = ((-v) as f64 * inv).min(width as f64) as i64;
                        while t < width && at(t) < 0 {
                            t += 1;
                        }
                        while t > 0 && at(t - 1) >= 0 {
                            t -= 1;
                        }
                        lo = lo.max(t);
                    }
                } else if s < 0 {
                    if v < 0 {
                        hi = 0;
                    } else {
                        // The last column where the value is non-negative.
                        let mut t = (v as f64 * -inv).min((width - 1) as f64) as i64;
                        while t > 0 && at(t) < 0 {
                            t -= 1;
                        }
                        while t + 1 < width && at(t + 1) >= 0 {
                            t += 1;
                        }
                        hi = hi.min(t + 1);
                    }
                } else if v < 0 {
                    hi = 0;
                }
            }
            if lo < hi {
                row(j, i0 + lo as usize..i0 + hi as usize);
            }
            for (v, step) in e_row.iter_mut().zip(self.step_y) {
                *v = v.wrapping_add(step);
            }
        }
    }
}

/// What every triangle of a target needs.
pub(super) struct Frame {
    pub(super) rows: [[f64; 4]; 3],
    /// `M^-1` of the rows' 3 x 3 part: `M^-1 (x, y, 1)` is the direction of sample `(x, y)`'s
    /// ray with unit axial depth.
    pub(super) inv: DMat3,
    /// `(M^-1)^T`.
    pub(super) inv_t: DMat3,
    /// The focal spot, mm (where the rows give zero).
    pub(super) source: DVec3,
    pub(super) det_positive: bool,
}

impl Frame {
    pub(super) fn new(p: &SampleProjection) -> Result<Frame, Refused> {
        let m = DMat3::from_cols(
            DVec3::new(p.rows[0][0], p.rows[1][0], p.rows[2][0]),
            DVec3::new(p.rows[0][1], p.rows[1][1], p.rows[2][1]),
            DVec3::new(p.rows[0][2], p.rows[1][2], p.rows[2][2]),
        );
        let det = m.determinant();
        if !det.is_finite() || det == 0.0 {
            return Err(Refused);
        }
        let inv = m.inverse();
        Ok(Frame {
            rows: p.rows,
            inv,
            inv_t: inv.transpose(),
            source: -(inv * DVec3::new(p.rows[0][3], p.rows[1][3], p.rows[2][3])),
            det_positive: det > 0.0,
        })
    }

    /// Corner `v` in sample coordinates snapped to 1/256 of a sample, or `Refused` when it
    /// lies within [`MIN_AXIAL_DEPTH_MM`] of the source plane or beyond
    /// [`MAX_SAMPLE_COORDINATE`].
    #[inline(always)]
    pub(super) fn snap(&self, v: &[f64; 3]) -> Result<[i64; 2], Refused> {
        let [xw, yw, w] = project(&self.rows, v);
        if w.is_nan() || w < MIN_AXIAL_DEPTH_MM {
            return Err(Refused);
        }
        let scale = ONE as f64 / w;
        let (x, y) = (xw * scale, yw * scale);
        if !(x.abs() <= MAX_SAMPLE_COORDINATE * ONE as f64
            && y.abs() <= MAX_SAMPLE_COORDINATE * ONE as f64)
        {
            return Err(Refused);
        }
        Ok([snap(x), snap(y)])
    }

    /// Distance from the source per mm of axial depth along sample `(x, y)`'s ray.
    pub(super) fn distance_per_depth(&self, x: f64, y: f64) -> f64 {
        (self.inv * DVec3::new(x, y, 1.0)).length()
    }
}

const ONE: i64 = 1 << SUBSAMPLE_BITS;

/// Spans at most this many samples wide find their covered runs sample by sample, wider ones
/// from their edges' sign changes ([`Span::for_each_row`]). Simulator choice, measured on the
/// default phantom (2 cores): finding every span's runs from its edges made the CPU passes of
/// a C-arm-moved 512^2 frame slower (67-70 -> 87 ms; most rows there are about 6 samples
/// wide), while with this bound they are as before and the needle step's 1024^2 passes drop
/// from 22-23 to 18 ms.
pub(super) const NARROW_SPAN: i64 = 8;
const HALF: i64 = ONE / 2;

/// The span of triangle `t` within `rect`, or `None` when it covers no sample centre there.
pub(super) fn setup(
    f: &Frame,
    t: &[[f64; 3]; 3],
    rect: &SampleRect,
) -> Result<Option<Span>, Refused> {
    let at = [f.snap(&t[0])?, f.snap(&t[1])?, f.snap(&t[2])?];
    Ok(setup_snapped(f, t, at, rect))
}

/// The span within `rect` of triangle `t` whose corners snap to `at` ([`Frame::snap`]), or
/// `None` when it covers no sample centre there.
#[inline(always)]
pub(super) fn setup_snapped(
    f: &Frame,
    t: &[[f64; 3]; 3],
    at: [[i64; 2]; 3],
    rect: &SampleRect,
) -> Option<Span> {
    let mut fx = at.map(|v| v[0]);
    let mut fy = at.map(|v| v[1]);
    // Sample rows and columns of `rect` whose centres lie in the snapped box.
    let first = |lo: i64| (lo - HALF).div_euclid(ONE) + i64::from((lo - HALF).rem_euclid(ONE) != 0);
    let last = |hi: i64| (hi - HALF).div_euclid(ONE);
    let j0 = first(fy[0].min(fy[1]).min(fy[2])).max(rect.rows.start as i64);
    let j1 = last(fy[0].max(fy[1]).max(fy[2])).min(rect.rows.end as i64 - 1);
    if j0 > j1 {
        return None;
    }
    let i0 = first(fx[0].min(fx[1]).min(fx[2])).max(rect.cols.start as i64);
    let i1 = last(fx[0].max(fx[1]).max(fx[2])).min(rect.cols.end as i64 - 1);
    if i0 > i1 {
        return None;
    }
    let area2 = (fx[1] - fx[0]) * (fy[2] - fy[0]) - (fx[2] - fx[0]) * (fy[1] - fy[0]);
    if area2 == 0 {
        return None;
    }
    let entering = (area2 > 0) != f.det_positive;
    if area2 < 0 {
        fx.swap(1, 2);
        fy.swap(1, 2);
    }
    // The plane's 1 / w at sample (x, y): (q . (x, y, 1)) / k.
    let v0 = DVec3::from(t[0]);
    let normal = triangle_cross(*t);
    // Edge functions E(p) = (b - a) x (p - a) at the first sample of the box, their steps,
    // and the tie rule's bias (-1: a sample on the edge is not taken).
    let mut e_row = [0i64; 3];
    let mut step_x = [0i64; 3];
    let mut step_y = [0i64; 3];
    let px0 = i0 * ONE + HALF;
    let py0 = j0 * ONE + HALF;
    for e in 0..3 {
        let (a, b) = (e, (e + 1) % 3);
        let (dx, dy) = (fx[b] - fx[a], fy[b] - fy[a]);
        let takes_ties = dy > 0 || (dy == 0 && dx < 0);
        e_row[e] = dx * (py0 - fy[a]) - dy * (px0 - fx[a]) - i64::from(!takes_ties);
        step_x[e] = -dy * ONE;
        step_y[e] = dx * ONE;
    }
    Some(Span {
        rows: j0 as usize..=j1 as usize,
        cols: i0 as usize..=i1 as usize,
        e_row,
        step_x,
        step_y,
        q: f.inv_t * normal,
        k: normal.dot(v0 - f.source),
        entering,
    })
}
