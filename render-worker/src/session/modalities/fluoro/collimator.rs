//! The learner's collimator: a pair of shutter blades on each axis, closing symmetrically about
//! the central ray (as on a mobile C-arm), and a round iris, all given in the detector plane.
//!
//! What it changes, through the [`sim_core::fluoro::Projection`] every image records:
//! - the image: pixels outside the opening get no primary beam and show the shutter grey;
//! - the kerma-area product: the field area shrinks (the skin air kerma does not: the beam's
//!   centre is as intense as before);
//! - the brightness control: only the metering rays inside the opening count.
//!
//! - scatter ([`super::scatter`]): fewer irradiated cells scatter, so a tighter field shows
//!   less fog, and the brightness control's estimate of the scatter it meters falls with the
//!   field's area.
//!
//! Command: `{"type": "collimation", "width_mm": 200, "height_mm": 150, "iris_diameter_mm":
//! 250}` (the iris may be omitted or `null` for none). Sessions recorded before the collimator
//! have no collimation in their state: the field is fully open.

use serde::{Deserialize, Serialize};
use sim_core::fluoro::Collimation;

use crate::session::command::{CommandError, ErrorCode, ModalityCommand};

/// The command kind that sets the collimator.
pub const COLLIMATION_KIND: &str = "collimation";

/// Narrowest opening a blade pair or the iris may make, mm in the detector plane. Simulator
/// choice: 20 mm (about 10 mm at the isocentre), narrower than any useful spine field.
pub const MIN_OPENING_MM: f64 = 20.0;

/// The collimator's setting (part of the fluoroscopy state once set).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollimatorSetting {
    /// Distance between the left and right blades, detector plane, mm.
    pub width_mm: f64,
    /// Distance between the top and bottom blades, detector plane, mm.
    pub height_mm: f64,
    /// Iris diameter, detector plane, mm, or `None` for no iris.
    #[serde(default)]
    pub iris_diameter_mm: Option<f64>,
}

impl CollimatorSetting {
    /// The blades and iris as a [`Collimation`] about the detector centre.
    pub fn collimation(&self) -> Collimation {
        Collimation {
            x_min_mm: -0.5 * self.width_mm,
            x_max_mm: 0.5 * self.width_mm,
            y_min_mm: -0.5 * self.height_mm,
            y_max_mm: 0.5 * self.height_mm,
            iris_radius_mm: self.iris_diameter_mm.map(|d| 0.5 * d),
        }
    }
}

/// The setting a `collimation` command asks for on a detector `detector_mm` wide, or its
/// field-named error: blades from [`MIN_OPENING_MM`] to the detector's side, the iris from
/// [`MIN_OPENING_MM`] to its diagonal.
pub fn parse(
    command: &ModalityCommand,
    detector_mm: f64,
) -> Result<CollimatorSetting, CommandError> {
    let s: CollimatorSetting = command.parse()?;
    let check = |field: &str, v: f64, max: f64| {
        if v.is_finite() && (MIN_OPENING_MM..=max).contains(&v) {
            Ok(())
        } else {
            Err(CommandError::field(
                &format!("command.{field}"),
                ErrorCode::OutOfRange,
                format!("{v} mm: give {MIN_OPENING_MM} to {max:.0} mm in the detector plane"),
            ))
        }
    };
    check("width_mm", s.width_mm, detector_mm)?;
    check("height_mm", s.height_mm, detector_mm)?;
    if let Some(d) = s.iris_diameter_mm {
        check(
            "iris_diameter_mm",
            d,
            detector_mm * std::f64::consts::SQRT_2,
        )?;
    }
    Ok(s)
}

/// Area of the rectangle `[x0, x1] x [y0, y1]` inside the disc of radius `r` about the origin,
/// mm^2 (exact: the integral over x of the clipped chord, in closed form).
pub fn rectangle_in_disc_mm2(x0: f64, x1: f64, y0: f64, y1: f64, r: f64) -> f64 {
    if !(x1 > x0 && y1 > y0 && r > 0.0) {
        return 0.0;
    }
    // Area of {(x, y): x0 <= x <= x1, 0 <= y <= min(h, sqrt(r^2 - x^2))} for h >= 0, by the
    // antiderivative of min(h, sqrt(r^2 - x^2)).
    let upper = |h: f64| -> f64 {
        let f = |x: f64| -> f64 {
            // Integral from 0 to x of sqrt(r^2 - t^2) dt, x within [-r, r].
            let x = x.clamp(-r, r);
            0.5 * (x * (r * r - x * x).max(0.0).sqrt() + r * r * (x / r).asin())
        };
        let (a, b) = (x0.clamp(-r, r), x1.clamp(-r, r));
        if a >= b {
            return 0.0;
        }
        if h >= r {
            return f(b) - f(a);
        }
        // |x| <= c: the chord is above h, the strip is h tall.
        let c = (r * r - h * h).sqrt();
        let flat = (b.min(c) - a.max(-c)).max(0.0) * h;
        let left = if a < -c { f(b.min(-c)) - f(a) } else { 0.0 };
        let right = if b > c { f(b) - f(a.max(c)) } else { 0.0 };
        flat + left + right
    };
    // The rectangle's part above and below y = 0, each against the disc's upper half.
    let part = |lo: f64, hi: f64| -> f64 {
        if hi <= 0.0 {
            return 0.0;
        }
        upper(hi) - upper(lo.max(0.0))
    };
    part(y0, y1) + part(-y1, -y0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rectangle_in_disc_is_exact_against_counting() {
        // Independent: a 4,000^2 grid of cell centres over the rectangle (area error of the
        // count about the circumference times a cell, below 0.1 % here).
        let count = |x0: f64, x1: f64, y0: f64, y1: f64, r: f64| {
            let n = 4000;
            let (dx, dy) = ((x1 - x0) / n as f64, (y1 - y0) / n as f64);
            let mut k = 0usize;
            for j in 0..n {
                let y = y0 + (j as f64 + 0.5) * dy;
                for i in 0..n {
                    let x = x0 + (i as f64 + 0.5) * dx;
                    if x * x + y * y <= r * r {
                        k += 1;
                    }
                }
            }
            k as f64 * dx * dy
        };
        for (x0, x1, y0, y1, r) in [
            (-150.0, 150.0, -150.0, 150.0, 150.0),
            (-150.0, 150.0, -150.0, 150.0, 200.0),
            (-100.0, 100.0, -60.0, 60.0, 90.0),
            (-150.0, 150.0, -150.0, 150.0, 250.0),
            (-50.0, 120.0, -140.0, 10.0, 110.0),
        ] {
            let exact = rectangle_in_disc_mm2(x0, x1, y0, y1, r);
            let counted = count(x0, x1, y0, y1, r);
            assert!(
                (exact / counted - 1.0).abs() < 1e-3,
                "{x0} {x1} {y0} {y1} {r}: {exact} vs {counted}"
            );
        }
        // The disc inside the rectangle, the rectangle inside the disc.
        let pi = std::f64::consts::PI;
        assert!((rectangle_in_disc_mm2(-9.0, 9.0, -9.0, 9.0, 5.0) - pi * 25.0).abs() < 1e-9);
        assert!((rectangle_in_disc_mm2(-3.0, 3.0, -2.0, 2.0, 10.0) - 24.0).abs() < 1e-9);
        assert_eq!(rectangle_in_disc_mm2(1.0, 0.0, -1.0, 1.0, 5.0), 0.0);
        assert_eq!(rectangle_in_disc_mm2(-1.0, 1.0, -1.0, 1.0, f64::NAN), 0.0);
    }
}
