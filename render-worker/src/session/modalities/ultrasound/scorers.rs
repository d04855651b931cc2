//! Scorers of ultrasound-guided needling: where the scan plane lies against the target joint,
//! how much of the needle's advance was watched in plane, whether the tip itself was on screen
//! at the end, how many passes the needle took, and the needle's angle to the scan plane.
//!
//! | measurement | meaning |
//! |---|---|
//! | `scan_plane_to_joint_deg` | angle between the facet joint line seen in a transverse view (the joint plane's trace in the axial plane) and the scan plane, at the end |
//! | `needle_in_plane_fraction` | share of the millimetres of needle advance made with the shaft in the scan plane (tip in the slice and at least [`IN_PLANE_MIN_SHAFT_MM`] of shaft in the slice) |
//! | `tip_visible_bool` | the displayed image shows the tip itself (in the slice and field of view) at its current position; a shaft crossing the slice does not count |
//! | `needle_redirections_count` | advances begun after a withdrawal of at least [`REDIRECT_MIN_WITHDRAW_MM`] (a new pass), including after a new placement |
//! | `needle_plane_angle_deg` | angle between the needle shaft and the scan plane (0 in plane, 90 straight across), at the end |

use glam::DVec3;
use serde::{Deserialize, Serialize};
use sim_core::rubric::Measurements;
use sim_core::ultrasound::{NeedleView, ProbePose};

use super::scene::{ScanScene, needle_shaft, scene_needle_view};
use crate::session::anatomy::{facet_joint_normal, primary_target};
use crate::session::world::World;

/// Shortest shaft in the slice for an advance to count as in plane, mm (or 80 % of the buried
/// length while less than this is buried). Simulator choice: 5 mm of shaft is a line on a 4 to
/// 10 cm image, not a dot.
pub const IN_PLANE_MIN_SHAFT_MM: f64 = 5.0;
/// Withdrawal after which the next advance counts as a new pass, mm. Simulator choice: smaller
/// back-and-forth movements are adjustments of the same pass.
pub const REDIRECT_MIN_WITHDRAW_MM: f64 = 2.0;

/// The needle's history as the scorers need it (part of the modality's state).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct History {
    /// Buried length after the last needle change, mm.
    pub last_depth_mm: f64,
    /// Total advance, mm.
    pub advanced_mm: f64,
    /// Advance made in plane, mm.
    pub in_plane_mm: f64,
    /// Withdrawn since the last advance, mm.
    pub withdrawn_mm: f64,
    /// New passes after the first.
    pub redirections: u32,
}

impl History {
    /// The needle changed to `depth_mm` buried, with `view` what the live scan plane shows of it.
    pub fn needle_moved(&mut self, depth_mm: f64, view: Option<NeedleView>) {
        let d = depth_mm - self.last_depth_mm;
        if d > 0.0 {
            if self.advanced_mm > 0.0 && self.withdrawn_mm >= REDIRECT_MIN_WITHDRAW_MM {
                self.redirections += 1;
            }
            self.withdrawn_mm = 0.0;
            self.advanced_mm += d;
            if view.is_some_and(|v| in_plane(&v, depth_mm)) {
                self.in_plane_mm += d;
            }
        } else if d < 0.0 {
            self.withdrawn_mm -= d;
        }
        self.last_depth_mm = depth_mm;
    }
}

/// Whether a needle view is the shaft in plane (see the module table).
pub fn in_plane(v: &NeedleView, buried_mm: f64) -> bool {
    let Some((a, b)) = v.in_slice else {
        return false;
    };
    let len = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    v.tip_in_slice && len >= IN_PLANE_MIN_SHAFT_MM.min(0.8 * buried_mm)
}

/// Angle between a line and a plane given by its normal, degrees.
fn line_to_plane_deg(line: DVec3, normal: DVec3) -> f64 {
    line.normalize_or_zero()
        .dot(normal.normalize_or_zero())
        .abs()
        .min(1.0)
        .asin()
        .to_degrees()
}

/// Adds the measurements of the module table.
pub fn measure(
    pose: &ProbePose,
    history: &History,
    displayed: &ScanScene,
    world: &World,
    out: &mut Measurements,
) {
    let Ok(frame) = pose.frame() else {
        return;
    };
    if let Some(n) = primary_target(&world.station)
        .and_then(|t| facet_joint_normal(&world.region, t))
        .map(|n| n.cross(DVec3::Z))
        .filter(|l| l.length() > 1e-6)
    {
        out.insert(
            "scan_plane_to_joint_deg".into(),
            line_to_plane_deg(n, frame.elevation),
        );
    }
    let Some(needle) = &world.needle else {
        return;
    };
    out.insert(
        "needle_redirections_count".into(),
        f64::from(history.redirections),
    );
    if history.advanced_mm > 0.0 {
        out.insert(
            "needle_in_plane_fraction".into(),
            history.in_plane_mm / history.advanced_mm,
        );
    }
    let tip = needle.state.tip_mm();
    let visible = scene_needle_view(displayed).is_some_and(|v| v.tip_in_slice)
        && displayed.needle.is_some_and(|n| n.tip_mm == tip);
    out.insert("tip_visible_bool".into(), if visible { 1.0 } else { 0.0 });
    if let Some(shaft) = needle_shaft(world) {
        out.insert(
            "needle_plane_angle_deg".into(),
            line_to_plane_deg(shaft.tip_mm - shaft.hub_mm, frame.elevation),
        );
    }
}
