//! The recorded tract: the cut channel as a chain of circular arcs, and a cursor for the tip.
//!
//! The channel is kept exactly as it was cut (never re-smoothed). Withdrawal moves the cursor
//! back along it; re-advancing without a tip roll moves the cursor forward along the same arcs,
//! so the tip returns to bit-identical node positions. A tip roll while the cursor is behind the
//! end of the channel truncates it there, and the next advance cuts a new branch.

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::kinematics::{Pose, arc_pose, response_after};

/// How a segment came about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum SegmentKind {
    /// Free cutting through soft tissue along the bevel-driven arc.
    Cut,
    /// Straight sliding along a bone surface after a shallow contact.
    Slide,
    /// A zero-length segment whose start frame carries a hub tilt's turn of the tip.
    Turn,
}

/// One arc of the channel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TractSegment {
    /// Tip pose where the segment starts.
    pub start: Pose,
    /// Bending response at the start (local normal-plane coordinates).
    pub response_start: DVec2,
    /// Bevel direction while this segment was cut (local normal-plane unit vector).
    pub bevel: DVec2,
    /// Constant curvature vector of the arc, 1/mm (local normal-plane coordinates).
    pub curvature_per_mm: DVec2,
    /// Arc length, millimetres (may be zero for a segment that only carries a contact turn).
    pub length_mm: f64,
    /// Buried arc length at the start of the segment, millimetres.
    pub start_arc_mm: f64,
    /// Cutting or sliding.
    pub kind: SegmentKind,
}

impl TractSegment {
    /// Tip pose after `s_mm` along this segment.
    pub fn pose_at(&self, s_mm: f64) -> Pose {
        arc_pose(&self.start, self.curvature_per_mm, s_mm)
    }

    /// Bending response after `s_mm` along this segment (`None` response length: the profile has
    /// no response and it stays constant).
    pub fn response_at(&self, s_mm: f64, response_length_mm: Option<f64>) -> DVec2 {
        match response_length_mm {
            Some(l) => response_after(self.response_start, self.bevel, s_mm, l),
            None => self.response_start,
        }
    }

    /// Pose at the end of the segment.
    pub fn end_pose(&self) -> Pose {
        self.pose_at(self.length_mm)
    }

    /// Buried arc length at the end of the segment.
    pub fn end_arc_mm(&self) -> f64 {
        self.start_arc_mm + self.length_mm
    }
}

/// Where the tip is on the tract: `offset_mm` along segment `segment`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TractCursor {
    /// Index of the segment holding the tip.
    pub segment: usize,
    /// Arc length along that segment, millimetres, in `[0, length]`.
    pub offset_mm: f64,
}

/// The whole recorded channel.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Tract {
    /// Arcs from the skin entry outward.
    pub segments: Vec<TractSegment>,
}

impl Tract {
    /// Total arc length of the recorded channel (which may extend beyond the tip after a
    /// withdrawal), millimetres.
    pub fn length_mm(&self) -> f64 {
        self.segments.last().map_or(0.0, TractSegment::end_arc_mm)
    }

    /// Buried arc length at `cursor`.
    pub fn arc_at(&self, cursor: TractCursor) -> f64 {
        self.segments
            .get(cursor.segment)
            .map_or(0.0, |s| s.start_arc_mm + cursor.offset_mm)
    }

    /// True when `cursor` is at the far end of the channel (or the channel is empty).
    pub fn is_end(&self, cursor: TractCursor) -> bool {
        match self.segments.last() {
            None => true,
            Some(last) => {
                cursor.segment + 1 == self.segments.len() && cursor.offset_mm == last.length_mm
            }
        }
    }

    /// Cut the channel at `cursor`: the segment holding it is shortened to end there and every
    /// later segment is discarded. The segment is kept even if it becomes zero-length, because
    /// its start frame may carry a contact turn.
    pub fn truncate_at(&mut self, cursor: TractCursor) {
        if cursor.segment < self.segments.len() {
            self.segments.truncate(cursor.segment + 1);
            self.segments[cursor.segment].length_mm = cursor.offset_mm;
        }
    }

    /// Points along the channel from the entry up to buried arc length `up_to_arc_mm`, spaced at
    /// most `max_step_mm` apart on each arc (for drawing and for tests).
    pub fn polyline(&self, up_to_arc_mm: f64, max_step_mm: f64) -> Vec<DVec3> {
        let mut out = Vec::new();
        for seg in &self.segments {
            if seg.start_arc_mm > up_to_arc_mm {
                break;
            }
            let len = seg.length_mm.min(up_to_arc_mm - seg.start_arc_mm);
            let n = ((len / max_step_mm).ceil() as usize).max(1);
            if out.is_empty() {
                out.push(seg.start.position_mm);
            }
            for j in 1..=n {
                out.push(seg.pose_at(len * j as f64 / n as f64).position_mm);
            }
        }
        out
    }
}
