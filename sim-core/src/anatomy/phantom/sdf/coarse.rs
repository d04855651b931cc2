//! A solid's values on a coarse lattice over a box: a lower bound of the solid anywhere in that
//! box for the price of one lookup and one distance.
//!
//! A 1-Lipschitz `f` (every [`Sdf`] is one) satisfies `f(p) >= f(c) - |p - c|` for every lattice
//! point `c`; taking the `c` of the cell that holds `p` bounds `f(p)` from below by at most a
//! cell's half-diagonal under its value. A caller that only needs `f(p)` where it is below some
//! threshold (a later solid that can only cut a structure where it is deeper than the structure's
//! own bound, see `level_set`) skips the evaluation wherever the bound already reaches the
//! threshold, with the same result bit for bit.

use glam::DVec3;

use super::{Aabb, MARGIN_MM, Sdf};

/// Smallest lattice spacing, mm (simulator choice: a few times the meshing lattice of the
/// default phantom, 1.5 mm, so that the bound is within about 2.6 mm of the value, far below the
/// distances at which the phantom's solids are skipped, while the lattice costs a few
/// milliseconds per solid).
pub const COARSE_CELL_MM: f64 = 3.0;

/// Most lattice points per solid; a larger box gets a coarser lattice.
const MAX_POINTS: usize = 1 << 18;

/// `f` at the centres of the cells of a lattice over a box.
#[derive(Debug, Clone)]
pub struct CoarseBound {
    /// The lattice's lower corner, mm.
    min: DVec3,
    /// Cell edge, mm.
    cell_mm: f64,
    /// Cells along x, y, z (all zero when the box is empty or unbounded).
    dims: [usize; 3],
    /// `f` at each cell centre, x fastest.
    values: Vec<f64>,
}

impl CoarseBound {
    /// The values of `sdf` on a lattice of cells of at least [`COARSE_CELL_MM`] covering `bbox`
    /// (no lattice, and no bound anywhere, for an empty or unbounded box).
    pub fn new(sdf: &Sdf, bbox: Aabb) -> CoarseBound {
        let size = bbox.max - bbox.min;
        if bbox.is_empty() || !size.is_finite() {
            return CoarseBound {
                min: DVec3::ZERO,
                cell_mm: COARSE_CELL_MM,
                dims: [0; 3],
                values: Vec::new(),
            };
        }
        let mut cell_mm = COARSE_CELL_MM;
        let dims_for = |c: f64| -> [usize; 3] {
            [size.x, size.y, size.z].map(|s| ((s / c).ceil() as usize).max(1))
        };
        while dims_for(cell_mm).iter().product::<usize>() > MAX_POINTS {
            cell_mm *= 1.25;
        }
        let dims = dims_for(cell_mm);
        let mut values = Vec::with_capacity(dims.iter().product());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    values.push(sdf.eval(centre(bbox.min, cell_mm, [i, j, k])));
                }
            }
        }
        CoarseBound {
            min: bbox.min,
            cell_mm,
            dims,
            values,
        }
    }

    /// A lower bound of the solid's value at `p`, mm: `f(c) - |p - c|` for the centre `c` of the
    /// cell holding `p`, less [`MARGIN_MM`] for rounding; minus infinity outside the lattice.
    #[inline]
    pub fn lower(&self, p: DVec3) -> f64 {
        let q = (p - self.min) / self.cell_mm;
        let (i, j, k) = (q.x.floor(), q.y.floor(), q.z.floor());
        // NaN and points outside fail these comparisons.
        if !(i >= 0.0 && j >= 0.0 && k >= 0.0) {
            return f64::NEG_INFINITY;
        }
        let ijk = [i as usize, j as usize, k as usize];
        if (0..3).any(|a| ijk[a] >= self.dims[a]) {
            return f64::NEG_INFINITY;
        }
        let index = ijk[0] + self.dims[0] * (ijk[1] + self.dims[1] * ijk[2]);
        self.values[index] - (p - centre(self.min, self.cell_mm, ijk)).length() - MARGIN_MM
    }

    /// Lattice points evaluated.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    /// Whether the lattice is empty (no bound anywhere).
    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }
}

fn centre(min: DVec3, cell_mm: f64, ijk: [usize; 3]) -> DVec3 {
    min + (DVec3::new(ijk[0] as f64, ijk[1] as f64, ijk[2] as f64) + DVec3::splat(0.5)) * cell_mm
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bound_never_exceeds_the_value_and_is_within_a_half_diagonal() {
        let sdf = Sdf::Union(vec![
            Sdf::Sphere { radius: 9.0 }.at(DVec3::new(3.0, -2.0, 1.0)),
            Sdf::RoundBox {
                half: DVec3::new(12.0, 4.0, 6.0),
                round: 1.5,
            }
            .at(DVec3::new(-10.0, 5.0, 0.0)),
        ]);
        let bbox = sdf.bounds().expand(4.0);
        let bound = CoarseBound::new(&sdf, bbox);
        assert!(!bound.is_empty());
        let reach = 0.5 * bound.cell_mm * 3f64.sqrt() + 2.0 * MARGIN_MM;
        let mut rng = crate::rng::SplitMix64::new(0x9e37_79b9_7f4a_7c15);
        let mut next = move || rng.next_f64();
        for _ in 0..20_000 {
            let t = DVec3::new(next(), next(), next());
            let p = bbox.min + t * (bbox.max - bbox.min);
            let (f, lo) = (sdf.eval(p), bound.lower(p));
            assert!(lo <= f, "{p:?}: bound {lo} above value {f}");
            assert!(
                f - lo <= 2.0 * reach,
                "{p:?}: bound {lo} far below value {f}"
            );
        }
        // Outside the lattice (and at NaN) there is no bound.
        assert_eq!(bound.lower(bbox.max + DVec3::ONE), f64::NEG_INFINITY);
        assert_eq!(bound.lower(bbox.min - DVec3::ONE), f64::NEG_INFINITY);
        assert_eq!(bound.lower(DVec3::NAN), f64::NEG_INFINITY);
    }

    #[test]
    fn an_empty_or_unbounded_box_gives_no_lattice() {
        let half = Sdf::HalfSpace {
            normal: DVec3::X,
            offset: 0.0,
        };
        assert!(CoarseBound::new(&half, half.bounds()).is_empty());
        let ball = Sdf::Sphere { radius: 2.0 };
        let empty = Aabb {
            min: DVec3::ONE,
            max: DVec3::ZERO,
        };
        let bound = CoarseBound::new(&ball, empty);
        assert!(bound.is_empty());
        assert_eq!(bound.lower(DVec3::ZERO), f64::NEG_INFINITY);
    }

    #[test]
    fn a_large_box_gets_a_coarser_lattice_within_the_limit() {
        let ball = Sdf::Sphere { radius: 400.0 };
        let bound = CoarseBound::new(&ball, ball.bounds());
        assert!(bound.len() <= MAX_POINTS);
        assert!(bound.cell_mm > COARSE_CELL_MM);
    }
}
