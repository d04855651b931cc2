//! The physical range of a measurement: what a simulator can produce at all. A value outside it
//! is not a poor performance but an impossible one (a negative distance, a fraction above one, a
//! non-finite number), so the engine refuses it instead of scoring it: `tip_to_target_mm =
//! -1e308` must never earn the credit of a perfect placement.
//!
//! The unit comes from the key's suffix (`_mm`, `_deg`, `_count`, `_s`, `_fraction`, `_bool`,
//! `_mgy`, `_gycm2`, the
//! convention station validation enforces for criteria). A key of the form `<a>_to_<b>_<unit>`
//! names the distance or the smallest angle between two things: a magnitude, never negative.
//! Other millimetre and degree keys may be signed; the few signed offsets whose key also contains
//! `_to_` (`tip_medial_to_pedicle_mm`, negative when the tip lies lateral of the pedicle) are
//! listed in [`SIGNED_KEYS`].

use super::station::Unit;

/// Largest magnitude of a length in mm. Our choice: every region is well under a metre across,
/// so no distance between two points of one region can exceed 1000 mm.
pub const MAX_ABS_MM: f64 = 1000.0;

/// Largest magnitude of an angle in degrees: angles are reported in (-180, 180].
pub const MAX_ABS_DEG: f64 = 180.0;

/// Largest count. Our choice: a million acquisitions or passes is beyond any attempt (the
/// session's own command limit is far lower).
pub const MAX_COUNT: f64 = 1.0e6;

/// Longest duration in seconds. Our choice: one day, beyond any attempt.
pub const MAX_SECONDS: f64 = 86_400.0;

/// Largest air kerma, mGy. Our choice: 10^5 mGy (100 Gy) is far beyond any fluoroscopic
/// procedure (skin injury thresholds begin at a few gray; ICRP Publication 85, 2000).
pub const MAX_MGY: f64 = 1.0e5;

/// Largest kerma-area product, Gy cm^2. Our choice: 10^4 Gy cm^2 is far beyond any procedure
/// (complex interventional procedures reach a few hundred; ICRP Publication 85, 2000).
pub const MAX_GYCM2: f64 = 1.0e4;

/// Keys containing `_to_` that are signed offsets rather than magnitudes.
pub const SIGNED_KEYS: &[&str] = &["tip_medial_to_pedicle_mm"];

/// The unit named by a measurement key's suffix, if it has one.
pub fn unit_of_key(key: &str) -> Option<Unit> {
    let suffix = key.rsplit('_').next()?;
    if suffix.len() == key.len() {
        return None;
    }
    Some(match suffix {
        "mm" => Unit::Mm,
        "deg" => Unit::Deg,
        "count" => Unit::Count,
        "s" => Unit::S,
        "fraction" => Unit::Fraction,
        "bool" => Unit::Bool,
        "mgy" => Unit::Mgy,
        "gycm2" => Unit::Gycm2,
        _ => return None,
    })
}

/// True for keys that name a magnitude (see the module documentation).
pub fn is_magnitude_key(key: &str) -> bool {
    key.contains("_to_") && !SIGNED_KEYS.contains(&key)
}

/// Why a measurement cannot be scored: it names the key and the value, and says why in words for
/// people (the message is what a technical result's note and the server's refusal show).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RangeError {
    /// The value is NaN or infinite.
    #[error("{key}: {value} is not a finite number")]
    NonFinite {
        /// The measurement key.
        key: String,
        /// The value given.
        value: f64,
    },
    /// The value is finite but outside the physical range of the unit its key names.
    #[error("{key}: {value} is outside the physical range {range}")]
    OutOfRange {
        /// The measurement key.
        key: String,
        /// The value given.
        value: f64,
        /// The range, in words with its unit (`0 to 1000 mm`).
        range: &'static str,
    },
}

/// Checks that `value` of measurement `key` in `unit` is physically possible; the error says why
/// not.
pub fn check_value(key: &str, unit: Unit, value: f64) -> Result<(), RangeError> {
    if !value.is_finite() {
        return Err(RangeError::NonFinite {
            key: key.to_owned(),
            value,
        });
    }
    let out = |range: &'static str| {
        Err(RangeError::OutOfRange {
            key: key.to_owned(),
            value,
            range,
        })
    };
    let magnitude = is_magnitude_key(key);
    match unit {
        Unit::Mm if magnitude && !(0.0..=MAX_ABS_MM).contains(&value) => out("0 to 1000 mm"),
        Unit::Mm if value.abs() > MAX_ABS_MM => out("-1000 to 1000 mm"),
        Unit::Deg if magnitude && !(0.0..=MAX_ABS_DEG).contains(&value) => out("0 to 180 degrees"),
        Unit::Deg if value.abs() > MAX_ABS_DEG => out("-180 to 180 degrees"),
        Unit::Count if !(0.0..=MAX_COUNT).contains(&value) || value.fract() != 0.0 => {
            out("a whole number from 0 to 1e6")
        }
        Unit::S if !(0.0..=MAX_SECONDS).contains(&value) => out("0 to 86400 s"),
        Unit::Fraction if !(0.0..=1.0).contains(&value) => out("0 to 1"),
        Unit::Bool if value != 0.0 && value != 1.0 => out("1 or 0 (yes or no)"),
        Unit::Mgy if !(0.0..=MAX_MGY).contains(&value) => out("0 to 1e5 mGy"),
        Unit::Gycm2 if !(0.0..=MAX_GYCM2).contains(&value) => out("0 to 1e4 Gy cm^2"),
        _ => Ok(()),
    }
}

/// Checks every measurement: finite, and within the physical range of the unit its key names.
pub fn check_measurements<'a>(
    measurements: impl IntoIterator<Item = (&'a String, &'a f64)>,
) -> Result<(), RangeError> {
    for (key, &value) in measurements {
        match unit_of_key(key) {
            Some(unit) => check_value(key, unit, value)?,
            None if !value.is_finite() => {
                return Err(RangeError::NonFinite {
                    key: key.clone(),
                    value,
                });
            }
            None => {}
        }
    }
    Ok(())
}
