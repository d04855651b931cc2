//! The one error type of the ultrasound reference: every refusal names the offending field.

/// Why a scan request was refused. `field` is the dotted name of the input that is wrong
/// (`pose.position_mm`, `settings.depth_mm`, ...), so a session can report it to the learner.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UltrasoundError {
    /// A number is NaN or infinite.
    #[error("{field} is not a finite number")]
    NonFinite {
        /// The offending input.
        field: &'static str,
    },
    /// A number lies outside its allowed range.
    #[error("{field} = {value} is outside {min} ..= {max}")]
    OutOfRange {
        /// The offending input.
        field: &'static str,
        /// The value given.
        value: f64,
        /// Smallest allowed value.
        min: f64,
        /// Largest allowed value.
        max: f64,
    },
    /// A direction is zero or parallel to another one it must be independent of.
    #[error("{field} is degenerate (zero length or parallel to the beam)")]
    Degenerate {
        /// The offending input.
        field: &'static str,
    },
}

/// `Ok(v)` when `v` is finite and in `min ..= max`, else the error naming `field`.
pub(crate) fn check_range(
    field: &'static str,
    value: f64,
    min: f64,
    max: f64,
) -> Result<f64, UltrasoundError> {
    if !value.is_finite() {
        return Err(UltrasoundError::NonFinite { field });
    }
    if value < min || value > max {
        return Err(UltrasoundError::OutOfRange {
            field,
            value,
            min,
            max,
        });
    }
    Ok(value)
}

/// `Ok(v)` when all three components are finite.
pub(crate) fn check_finite3(
    field: &'static str,
    v: glam::DVec3,
) -> Result<glam::DVec3, UltrasoundError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(UltrasoundError::NonFinite { field })
    }
}
