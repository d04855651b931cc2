//! The angle of an in-plane point seen from a curvilinear array's apex, without a libm call:
//! `ScanGeometry::plane_to_line` takes it for every pixel of a new image geometry, every column
//! of the square deposit and every 64th scatterer of an oblique one (`scatter::sector` steps the
//! rest); where glibc's `atan2` took an eighth of a rocked B-mode frame when it was asked once
//! per scatterer.
//!
//! Within 45 degrees of the axis (every point of a sector narrower than 90 degrees) the tangent
//! `t` is split as `c + (t - c)` with `c` the nearest multiple of 1/32, and
//! `atan t = atan c + atan d`, `d = (t - c) / (1 + t c)`, `|d| <= 1/64`: `atan c` comes from a
//! table made once by libm, `atan d` from its odd series to `d^11` (the first term left out is
//! below `(1/64)^13 / 13`, 1e-25). Elsewhere it is libm's `atan2`. Past the table (built once
//! by libm's `atan`, correctly rounded at these knots by glibc), only IEEE additions,
//! multiplications and divisions, so the value is the same on every thread and on every machine
//! whose libm gives the same knots; within 6e-16 of libm's relative to the angle (tested).

use std::sync::OnceLock;

/// Table steps per unit tangent.
const STEPS: f64 = 32.0;
/// Table entries: tangents -1, -1 + 1/32, ..., 1.
const ENTRIES: usize = 65;

fn table() -> &'static [f64; ENTRIES] {
    static T: OnceLock<[f64; ENTRIES]> = OnceLock::new();
    T.get_or_init(|| std::array::from_fn(|i| ((i as f64 - STEPS) / STEPS).atan()))
}

/// `x.atan2(y)`, radians (see the module docs).
#[inline]
pub(crate) fn atan2(x: f64, y: f64) -> f64 {
    // NaN fails the comparison; y > 0 leaves out the signed zeros' half turns, and a finite y
    // the infinite ones (inf / inf is NaN, libm gives a quarter turn).
    if !(x.abs() <= y && y > 0.0 && y.is_finite()) {
        return x.atan2(y);
    }
    let t = x / y;
    // Round half away from zero by truncation (no libm call); |t| <= 1 so |j| <= 32.
    let j = (t * STEPS + 0.5f64.copysign(t)) as i64;
    let c = j as f64 / STEPS;
    let d = (t - c) / (1.0 + t * c);
    let d2 = d * d;
    let series = d - d
        * d2
        * (1.0 / 3.0 - d2 * (1.0 / 5.0 - d2 * (1.0 / 7.0 - d2 * (1.0 / 9.0 - d2 / 11.0))));
    table()[(j + STEPS as i64) as usize] + series
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against libm over random points in every direction and at every scale, at the table's
    /// knots and half-way between them, on the 45-degree diagonals, at zero and for non-finite
    /// input: within 6e-16 of the angle (a few ulp; the worst seen is 4.4e-16), exactly libm's
    /// outside the +-45-degree cone.
    #[test]
    fn the_angle_is_libm_s_within_a_couple_of_ulp() {
        let mut rand = crate::rng::uniform_stream(11);
        let mut points: Vec<(f64, f64)> = Vec::new();
        for _ in 0..400_000 {
            let scale = 10f64.powf(12.0 * rand() - 6.0);
            points.push((scale * (2.0 * rand() - 1.0), scale * (2.0 * rand() - 1.0)));
        }
        for j in -64..=64 {
            let t = j as f64 / 64.0;
            for y in [1.0, 37.5, 1e-3] {
                points.push((t * y, y));
                points.push((f64::from_bits((t * y).to_bits() + 1), y));
            }
        }
        for (x, y) in [
            (1.0, 1.0),
            (-1.0, 1.0),
            (0.0, 1.0),
            (-0.0, 1.0),
            (0.0, 0.0),
            (-0.0, -0.0),
            (f64::NAN, 1.0),
            (1.0, f64::NAN),
            (f64::INFINITY, 1.0),
            (f64::INFINITY, f64::INFINITY),
            (f64::NEG_INFINITY, f64::INFINITY),
            (1.0, f64::INFINITY),
        ] {
            points.push((x, y));
        }
        let mut worst: f64 = 0.0;
        for (x, y) in points {
            let (a, b) = (atan2(x, y), x.atan2(y));
            if !(x.abs() <= y && y > 0.0) {
                assert!(
                    a.to_bits() == b.to_bits(),
                    "({x}, {y}): {a} against libm {b}"
                );
                continue;
            }
            let rel = (a - b).abs() / b.abs().max(f64::MIN_POSITIVE);
            worst = worst.max(rel);
            assert!(
                rel <= 6e-16,
                "({x:e}, {y:e}): {a:e} against libm {b:e} ({rel:e})"
            );
        }
        assert!(
            worst > 0.0,
            "differs from libm somewhere (else it would be libm)"
        );
        eprintln!("largest relative difference from libm: {worst:e}");
    }
}
