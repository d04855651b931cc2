//! Hub roll versus tip roll: a depth-dependent play (backlash) operator.
//!
//! Torsional friction along the buried shaft makes the tip lag the hub (Reed et al. 2009); we
//! model the lag as a deadband on the stored hub-minus-tip twist, following the deadband
//! precedent of Ertop et al. (2020), not the distributed torsional dynamics of Swensen et al.
//! (2014). The twist may wander freely inside a window of total width `w(depth)`; the tip turns
//! only when the hub pushes the twist against an edge of the window. A reversal therefore has to
//! cross the whole window before the bevel moves again (hysteresis).
//!
//! Simulator choice: the window grows linearly with buried depth, `w = w_100 * depth / 100 mm`,
//! because friction torque accumulates along the buried length; the twist is centred, so it lies
//! in `[-w/2, +w/2]`. When the window narrows (withdrawal) the excess twist is released into the
//! tip.

use serde::{Deserialize, Serialize};

/// Twist state of the shaft.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TorsionalPlay {
    /// Accumulated hub roll commanded so far, radians.
    pub hub_roll_rad: f64,
    /// Stored hub-minus-tip twist, radians; always inside the current window.
    pub twist_rad: f64,
}

/// Total window width in radians at `depth_mm` for a profile's width at 100 mm (degrees).
pub fn window_rad(play_deg_at_100mm: f64, depth_mm: f64) -> f64 {
    (play_deg_at_100mm * depth_mm.max(0.0) / 100.0).to_radians()
}

impl TorsionalPlay {
    /// Apply a hub roll of `hub_delta_rad` with the window `window_rad` (total width); returns the
    /// resulting tip roll in radians.
    pub fn roll(&mut self, hub_delta_rad: f64, window_rad: f64) -> f64 {
        let half = 0.5 * window_rad;
        self.hub_roll_rad += hub_delta_rad;
        let free = self.twist_rad + hub_delta_rad;
        let clamped = free.clamp(-half, half);
        self.twist_rad = clamped;
        // Whatever the window could not absorb turns the tip.
        free - clamped
    }

    /// Narrow (or widen) the window to `window_rad`; twist outside it is released into the tip.
    /// Returns the tip roll caused by the release, radians.
    pub fn set_window(&mut self, window_rad: f64) -> f64 {
        let half = 0.5 * window_rad;
        let clamped = self.twist_rad.clamp(-half, half);
        let released = self.twist_rad - clamped;
        self.twist_rad = clamped;
        released
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_window_is_one_to_one() {
        let mut p = TorsionalPlay::default();
        assert_eq!(p.roll(0.3, 0.0), 0.3);
        assert_eq!(p.roll(-0.5, 0.0), -0.5);
        assert_eq!(p.twist_rad, 0.0);
    }

    #[test]
    fn reversal_crosses_whole_window() {
        let w = 30f64.to_radians();
        let mut p = TorsionalPlay::default();
        // First 15 degrees fill half the window.
        let tip = p.roll(40f64.to_radians(), w);
        assert!((tip - 25f64.to_radians()).abs() < 1e-15);
        // Reversal of 29 degrees is absorbed entirely (window is 30 wide).
        assert_eq!(p.roll(-29f64.to_radians(), w), 0.0);
        // The next 2 degrees cross the far edge by 1 degree.
        assert!((p.roll(-2f64.to_radians(), w) + 1f64.to_radians()).abs() < 1e-15);
    }
}
