//! Scattered radiation in a session: the anti-scatter grid the learner puts in or takes out,
//! what each image records of it, and the brightness control's view of it.
//!
//! - New sessions start with the grid in (as a C-arm's flat panel carries one); `{"type":
//!   "grid", "grid": "out"}` removes it and `"in"` puts it back. With it out, the image shows
//!   more fog and the primary is not cut by the grid's 0.73, so the control lowers the dose.
//! - Each image records the grid and the air gap of its view (patient exit surface to detector
//!   along the central ray, from the scene alone), so it renders and replays the same on any
//!   renderer: `sim_core::fluoro::scatter` adds the superposed scatter to its primary.
//! - The brightness control meters the total signal behind the grid: the metered primary times
//!   [`Metering::scatter_factor`] (the grid's primary transmission times `1 + SPR` of the
//!   disc's water-equivalent thickness over the irradiated field).
//! - Sessions recorded before scatter have no `scatter` in their state: their images carry
//!   none and render as they always did.

use serde::{Deserialize, Serialize};
use sim_core::fluoro::Projection;
use sim_core::fluoro::brightness::Metering;

use crate::session::command::{CommandError, ModalityCommand};

/// The command kind that puts the grid in or takes it out.
pub const GRID_KIND: &str = "grid";

/// Whether the anti-scatter grid is in (part of the fluoroscopy state once scatter exists).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScatterState {
    /// The grid is in front of the detector.
    pub grid: bool,
}

/// What an image records of scatter: the grid and its view's air gap.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageScatter {
    /// The grid was in.
    pub grid: bool,
    /// Exit surface to detector along the central ray, mm.
    pub air_gap_mm: f64,
}

/// The fields of a `grid` command.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct GridCommand {
    /// `in` or `out`.
    grid: String,
}

/// Whether a `grid` command puts the grid in, or its field-named error.
pub fn parse(command: &ModalityCommand) -> Result<bool, CommandError> {
    let GridCommand { grid } = command.parse()?;
    crate::session::command::named_choice(
        "grid",
        &grid,
        |g| match g {
            "in" => Some(true),
            "out" => Some(false),
            _ => None,
        },
        "in or out",
    )
}

/// Half-sides of the irradiated field at the detector, mm: the blades clipped to the active
/// detector field, scaled to the area of their overlap with the iris (same aspect) when there
/// is one.
pub fn field_half_sizes_mm(projection: &Projection) -> (f64, f64) {
    let [w, h] = projection.detector_size_mm();
    let c = &projection.collimation;
    let x = (c.x_max_mm.min(0.5 * w) - c.x_min_mm.max(-0.5 * w)).max(0.0);
    let y = (c.y_max_mm.min(0.5 * h) - c.y_min_mm.max(-0.5 * h)).max(0.0);
    let area = super::dose::field_area_at_detector_mm2(projection);
    let scale = if x * y > 0.0 {
        (area / (x * y)).clamp(0.0, 1.0).sqrt()
    } else {
        0.0
    };
    (0.5 * x * scale, 0.5 * y * scale)
}

/// The factor from the metered primary to the metered total signal of a view (1 when the
/// session has no scatter, or the factor is not finite: nothing to meter).
pub fn metering_factor(
    state: Option<ScatterState>,
    metering: &Metering,
    kvp: u32,
    projection: &Projection,
) -> f64 {
    let Some(s) = state else {
        return 1.0;
    };
    let (hx, hy) = field_half_sizes_mm(projection);
    let f = metering.scatter_factor(kvp, hx, hy, s.grid);
    if f.is_finite() { f } else { 1.0 }
}

/// The record of an image acquired with `state` on a view metered as `metering`.
pub fn image_scatter(state: Option<ScatterState>, metering: &Metering) -> Option<ImageScatter> {
    state.map(|s| ImageScatter {
        grid: s.grid,
        air_gap_mm: metering.air_gap_mm,
    })
}
