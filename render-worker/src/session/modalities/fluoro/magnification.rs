//! Magnification modes: the detector reads out a smaller central field over the same pixels, so
//! the image shows the anatomy larger (the X-ray field shrinks with it, as a C-arm collimates to
//! the active field).
//!
//! What a mode changes, through the [`sim_core::fluoro::Projection`] every image records and
//! the brightness control:
//! - the image: pixel pitch `field / pixels`, the central part of the full field;
//! - the kerma-area product: the field's area (the blades are clipped to it);
//! - the noise: a pixel covers a smaller area of the detector, so it counts fewer quanta; the
//!   brightness control raises its target by `full / field`
//!   ([`sim_core::fluoro::brightness::magnification_target_factor`]), so the skin dose rises and
//!   the image is noisier than in normal mode, but not by the area ratio.
//!
//! Command: `{"type": "magnification", "field_mm": 150}`, a field of [`FIELD_FRACTIONS`] of the
//! detector's side (300, 225 and 150 mm on the default 300 mm panel). Sessions recorded before
//! the modes have no field in their state: the full detector.

use sim_core::fluoro::Collimation;

use crate::session::command::{CommandError, ErrorCode, ModalityCommand};

/// The command kind that selects a mode.
pub const MAGNIFICATION_KIND: &str = "magnification";

/// The active fields as fractions of the detector's side: normal, mag 1 and mag 2. Simulator
/// choice: a mobile C-arm's flat panel offers the full field and two or three smaller ones
/// (a 30 cm panel: 30, 22.5 and 15 cm here).
pub const FIELD_FRACTIONS: [f64; 3] = [1.0, 0.75, 0.5];

/// The fields of a `magnification` command.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Magnification {
    /// Side of the active field, mm.
    field_mm: f64,
}

/// The field a `magnification` command asks for on a detector `detector_mm` wide, or its
/// field-named error naming the fields there are.
pub fn parse(command: &ModalityCommand, detector_mm: f64) -> Result<f64, CommandError> {
    let Magnification { field_mm } = command.parse()?;
    let fields = FIELD_FRACTIONS.map(|f| f * detector_mm);
    fields
        .iter()
        .copied()
        .find(|f| (f - field_mm).abs() <= 1e-6)
        .ok_or_else(|| {
            let names: Vec<String> = fields.iter().map(|f| format!("{f}")).collect();
            CommandError::field(
                "command.field_mm",
                ErrorCode::OutOfRange,
                format!("{field_mm} mm: the fields are {} mm", names.join(", ")),
            )
        })
}

/// `collimation` clipped to the central field of side `field_mm`.
pub fn clip_to_field(collimation: Collimation, field_mm: f64) -> Collimation {
    let h = 0.5 * field_mm;
    Collimation {
        x_min_mm: collimation.x_min_mm.max(-h),
        x_max_mm: collimation.x_max_mm.min(h),
        y_min_mm: collimation.y_min_mm.max(-h),
        y_max_mm: collimation.y_max_mm.min(h),
        iris_radius_mm: collimation.iris_radius_mm,
    }
}
