//! The needle state, its three commands (feed, roll, withdraw) and the replayable command log.

use glam::{DQuat, DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::contact::{
    ARREST_INCIDENCE_DEG, BoneSurface, CONTACT_GAP_MM, LOOKAHEAD_MM, NoBone, TURNING_BUDGET_DEG,
    first_entry,
};
use super::hub::{MAX_HUB_DEVIATION_DEG, REDIRECT_MIN_DISCARD_MM, tip_turn_fraction};
use super::kinematics::{Pose, arc_pose, mean_response};
use super::play::{TorsionalPlay, window_rad};
use super::profile::{InstrumentProfile, PathModel, ProfileError};
use super::tract::{SegmentKind, Tract, TractCursor, TractSegment};

/// Largest number of contact events resolved inside one substep before the tip is arrested.
/// Simulator choice: sliding along a concave surface takes several contacts per millimetre, and
/// a tip wedged between surfaces should stop rather than loop.
const MAX_CONTACTS_PER_SUBSTEP: usize = 256;

/// Feed remainders this small at the end of a retraced channel are absorbed by the channel's end
/// instead of cutting a sliver of new channel, millimetres. Simulator choice: the round-off of
/// withdraw-then-feed arithmetic is ~1e-14 mm; 1e-9 mm is far below any physical scale.
const RETRACE_SNAP_MM: f64 = 1e-9;

/// Bisection tolerance on the arc length of a contact-truncated substep, millimetres.
/// Simulator choice, far below [`CONTACT_GAP_MM`].
const CONTACT_BISECTION_TOL_MM: f64 = 1e-10;

/// Errors of the needle API.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NeedleError {
    /// A command carried a non-finite or negative distance, or a non-finite angle.
    #[error("invalid command {0:?}: distances must be finite and >= 0, angles finite")]
    InvalidCommand(NeedleCommand),
    /// The profile failed validation.
    #[error("invalid instrument profile: {0}")]
    InvalidProfile(ProfileError),
    /// The substep is not a finite positive length.
    #[error("substep must be finite and > 0 mm, got {0}")]
    InvalidSubstep(f64),
    /// The entry direction or bevel reference is degenerate.
    #[error("degenerate entry pose (zero direction, or bevel parallel to it)")]
    DegenerateEntry,
    /// A hub tilt would take the hub further than [`MAX_HUB_DEVIATION_DEG`] from the puncture
    /// direction.
    #[error(
        "hub tilt refused: the hub would be {deviation_deg:.1} degrees from the puncture direction (at most {MAX_HUB_DEVIATION_DEG})"
    )]
    TiltLimit {
        /// Deviation the tilt would have reached, degrees.
        deviation_deg: f64,
    },
    /// A tilt direction with no component across the hub's direction.
    #[error("hub tilt direction is parallel to the needle")]
    DegenerateTilt,
}

/// Bending response when the needle enters the skin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum InitialResponse {
    /// No bending load yet (our default assumption for a needle entering the skin).
    Relaxed,
    /// Fully settled toward the bevel, as after a long insertion without roll.
    Settled,
}

/// One operator command. Feed and withdraw are millimetres of hub travel; roll is degrees of hub
/// rotation about the shaft (positive: right-handed about the direction of travel).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum NeedleCommand {
    /// Advance the needle.
    Feed {
        /// Hub travel, millimetres (>= 0).
        mm: f64,
    },
    /// Roll the hub.
    Roll {
        /// Hub rotation, degrees.
        deg: f64,
    },
    /// Pull the needle back along its tract.
    Withdraw {
        /// Hub travel, millimetres (>= 0).
        mm: f64,
    },
    /// Tilt the hub: the aim turns by `deg` degrees towards `toward` (its component across the
    /// hub's direction); the tip follows by the fraction of [`super::hub`].
    Tilt {
        /// World direction the aim turns towards (need not be unit length).
        toward: DVec3,
        /// Tilt angle, degrees (>= 0).
        deg: f64,
    },
}

impl NeedleCommand {
    fn is_valid(&self) -> bool {
        match *self {
            NeedleCommand::Feed { mm } | NeedleCommand::Withdraw { mm } => {
                mm.is_finite() && mm >= 0.0
            }
            NeedleCommand::Roll { deg } => deg.is_finite(),
            NeedleCommand::Tilt { toward, deg } => {
                toward.is_finite() && toward.length_squared() > 0.0 && deg.is_finite() && deg >= 0.0
            }
        }
    }
}

/// Why a contact stopped the tip.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ArrestReason {
    /// Incidence at or above [`ARREST_INCIDENCE_DEG`].
    SteepIncidence,
    /// The accumulated redirection would exceed [`TURNING_BUDGET_DEG`].
    TurningBudget,
    /// More than a fixed number of contacts inside one substep (wedged between surfaces).
    Wedged,
}

/// A contact that stopped the feed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactArrest {
    /// Why the tip stopped.
    pub reason: ArrestReason,
    /// Where the centre-line met bone, millimetres.
    pub surface_point_mm: DVec3,
    /// Outward bone normal there.
    pub normal: DVec3,
    /// Angle between the tip tangent and the surface's tangent plane, degrees.
    pub incidence_deg: f64,
}

/// How a feed ended.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum FeedStop {
    /// All requested travel was used.
    Completed,
    /// The hub reached the skin (the shaft is fully buried).
    HubAtSkin,
    /// Bone stopped the tip.
    Arrested(ContactArrest),
}

/// Result of a feed command.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FeedOutcome {
    /// Arc length the tip actually advanced, millimetres.
    pub advanced_mm: f64,
    /// Of which retraced along an existing channel, millimetres.
    pub retraced_mm: f64,
    /// Number of shallow contacts that redirected the tip.
    pub slides: usize,
    /// How it ended.
    pub stop: FeedStop,
}

/// Result of a roll command.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RollOutcome {
    /// Rotation that reached the bevel, radians.
    pub tip_roll_rad: f64,
    /// True when the roll cut the channel ahead of the tip (the next advance branches).
    pub branched: bool,
}

/// Result of a withdraw command.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WithdrawOutcome {
    /// Arc length the tip moved back, millimetres.
    pub withdrawn_mm: f64,
    /// Tip roll caused by the play window narrowing, radians.
    pub released_tip_roll_rad: f64,
    /// True when that release cut the channel ahead of the tip.
    pub branched: bool,
}

/// Result of any command.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum CommandOutcome {
    /// See [`FeedOutcome`].
    Feed(FeedOutcome),
    /// See [`RollOutcome`].
    Roll(RollOutcome),
    /// See [`WithdrawOutcome`].
    Withdraw(WithdrawOutcome),
    /// See [`TiltOutcome`].
    Tilt(TiltOutcome),
}

/// Result of a hub tilt.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TiltOutcome {
    /// Angle between the hub's new direction and the puncture direction, degrees.
    pub hub_deviation_deg: f64,
    /// How far the tip heading turned, degrees.
    pub tip_turn_deg: f64,
    /// True when the turn cut the channel ahead of the tip (the next advance branches).
    pub branched: bool,
}

/// The contrast outlet in world coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutletFootprint {
    /// Centre of the opening on the shaft axis, millimetres.
    pub centre_mm: DVec3,
    /// Shaft axis at the tip (unit).
    pub axis: DVec3,
    /// Direction the opening faces (the bevel direction, unit).
    pub facing: DVec3,
    /// Axial length of the opening, millimetres.
    pub length_mm: f64,
    /// Shaft outer diameter, millimetres.
    pub diameter_mm: f64,
}

/// Everything that determines the needle's future: serializable, and bit-identical after a
/// replay of the same commands.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NeedleState {
    /// The instrument.
    pub profile: InstrumentProfile,
    /// Largest feed substep, millimetres. A feed of `d` mm is cut in `ceil(d / substep)` equal
    /// substeps.
    pub substep_mm: f64,
    /// Skin entry pose (local x is the bevel direction at zero tip roll).
    pub entry: Pose,
    /// Bending response at the skin.
    pub entry_response: DVec2,
    /// The recorded channel.
    pub tract: Tract,
    /// Where the tip is on the channel.
    pub cursor: TractCursor,
    /// Tip position and transported frame.
    pub pose: Pose,
    /// Bending response (local normal-plane coordinates).
    pub response: DVec2,
    /// Bevel angle about the tangent, measured from the transported local x, radians.
    pub tip_roll_rad: f64,
    /// Hub-minus-tip twist.
    pub play: TorsionalPlay,
    /// Redirection accumulated over the current continuous bone contact, radians.
    pub contact_turn_rad: f64,
    /// Direction of the external shaft from the skin entry towards the tip (`None`: the entry
    /// direction, never tilted).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hub_dir: Option<DVec3>,
    /// Direction the needle punctured the skin with, the reference of
    /// [`MAX_HUB_DEVIATION_DEG`] (`None`: the entry direction).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub puncture_dir: Option<DVec3>,
    /// Redirections so far: advances into new tissue on a branch that left at least
    /// [`REDIRECT_MIN_DISCARD_MM`] of channel behind (see [`super::hub`]).
    #[serde(default, skip_serializing_if = "is_zero_u32")]
    pub redirections: u32,
    /// Channel discarded by the latest branch not yet followed by new cutting, mm.
    #[serde(default, skip_serializing_if = "is_zero_f64")]
    pub pending_branch_mm: f64,
}

fn is_zero_u32(v: &u32) -> bool {
    *v == 0
}

fn is_zero_f64(v: &f64) -> bool {
    *v == 0.0
}

impl NeedleState {
    /// A needle whose tip rests at the skin entry `entry_mm`, pointing along `direction`, with
    /// its bevel facing `bevel_reference` (projected onto the normal plane).
    pub fn new(
        profile: InstrumentProfile,
        entry_mm: DVec3,
        direction: DVec3,
        bevel_reference: DVec3,
        substep_mm: f64,
        initial: InitialResponse,
    ) -> Result<Self, NeedleError> {
        profile.validate().map_err(NeedleError::InvalidProfile)?;
        if !(substep_mm.is_finite() && substep_mm > 0.0) {
            return Err(NeedleError::InvalidSubstep(substep_mm));
        }
        let entry = Pose::looking_along(entry_mm, direction, bevel_reference)
            .ok_or(NeedleError::DegenerateEntry)?;
        let entry_response = match (initial, profile.path) {
            (_, PathModel::Straight) | (InitialResponse::Relaxed, _) => DVec2::ZERO,
            (InitialResponse::Settled, _) => DVec2::X,
        };
        Ok(Self {
            profile,
            substep_mm,
            entry,
            entry_response,
            tract: Tract::default(),
            cursor: TractCursor::default(),
            pose: entry,
            response: entry_response,
            tip_roll_rad: 0.0,
            play: TorsionalPlay::default(),
            contact_turn_rad: 0.0,
            hub_dir: None,
            puncture_dir: None,
            redirections: 0,
            pending_branch_mm: 0.0,
        })
    }

    /// Buried arc length of the shaft (skin to tip), millimetres.
    pub fn buried_mm(&self) -> f64 {
        self.tract.arc_at(self.cursor)
    }

    /// Bevel direction in local normal-plane coordinates.
    pub fn bevel_local(&self) -> DVec2 {
        let (s, c) = self.tip_roll_rad.sin_cos();
        DVec2::new(c, s)
    }

    /// Bevel direction in the world.
    pub fn bevel_world(&self) -> DVec3 {
        self.pose.normal_to_world(self.bevel_local())
    }

    /// Tip position, millimetres.
    pub fn tip_mm(&self) -> DVec3 {
        self.pose.position_mm
    }

    /// The physical tip frame: position, and orientation whose local x is the bevel direction and
    /// local z the tangent.
    pub fn tip_frame(&self) -> Pose {
        Pose {
            position_mm: self.pose.position_mm,
            orientation: self.pose.orientation * DQuat::from_rotation_z(self.tip_roll_rad),
        }
    }

    /// Current total width of the torsional play window, radians.
    pub fn play_window_rad(&self) -> f64 {
        window_rad(self.profile.torsional_play_deg_at_100mm, self.buried_mm())
    }

    /// Play still available before a roll in direction `sign(delta)` reaches the tip, radians.
    pub fn remaining_play_rad(&self, positive: bool) -> f64 {
        let half = 0.5 * self.play_window_rad();
        if positive {
            half - self.play.twist_rad
        } else {
            self.play.twist_rad + half
        }
    }

    /// The contrast outlet, assuming the distal few millimetres are straight.
    pub fn outlet(&self) -> OutletFootprint {
        let axis = self.pose.tangent();
        let o = self.profile.opening;
        OutletFootprint {
            centre_mm: self.pose.position_mm
                - axis * (o.distal_edge_from_tip_mm + 0.5 * o.length_mm),
            axis,
            facing: self.bevel_world(),
            length_mm: o.length_mm,
            diameter_mm: self.profile.outer_diameter_mm,
        }
    }

    /// Points of the whole shaft for drawing, hub first: the external straight part along the
    /// entry direction, the skin entry, then the buried channel up to the tip.
    pub fn shaft_polyline(&self, max_step_mm: f64) -> Vec<DVec3> {
        let external_mm = (self.profile.shaft_length_mm - self.buried_mm()).max(0.0);
        let mut pts = vec![self.entry.position_mm - self.hub_direction() * external_mm];
        let buried = self.tract.polyline(self.buried_mm(), max_step_mm);
        if buried.is_empty() {
            pts.push(self.entry.position_mm);
        } else {
            pts.extend(buried);
        }
        pts
    }

    fn response_length(&self) -> Option<f64> {
        self.profile.path.response_length_mm()
    }

    fn set_from_cursor(&mut self) {
        if let Some(seg) = self.tract.segments.get(self.cursor.segment) {
            self.pose = seg.pose_at(self.cursor.offset_mm);
            self.response = seg.response_at(self.cursor.offset_mm, self.response_length());
        } else {
            self.pose = self.entry;
            self.response = self.entry_response;
        }
    }

    /// Cut the channel ahead of the tip (if any), so that the next advance branches. The
    /// discarded length counts towards a redirection when `new_direction` (the next advance
    /// leaves the old path: a hub tilt, or a bevel turn of a needle whose path follows its
    /// bevel; a straight needle's re-advance after a bevel turn runs along the old line).
    fn branch_here(&mut self, new_direction: bool) -> bool {
        if self.tract.is_end(self.cursor) {
            return false;
        }
        if new_direction {
            let discarded = self.tract.length_mm() - self.buried_mm();
            self.pending_branch_mm = self.pending_branch_mm.max(discarded);
        }
        self.tract.truncate_at(self.cursor);
        true
    }

    /// Direction of the external shaft, from the hub towards the skin entry.
    pub fn hub_direction(&self) -> DVec3 {
        self.hub_dir.unwrap_or_else(|| self.entry.tangent())
    }

    /// Direction the needle punctured the skin with.
    pub fn puncture_direction(&self) -> DVec3 {
        self.puncture_dir.unwrap_or_else(|| self.entry.tangent())
    }

    /// The hub direction after turning it by `deg` towards `toward`, and the rotation that does
    /// it.
    fn tilted(&self, toward: DVec3, deg: f64) -> Result<(DVec3, DQuat), NeedleError> {
        let hub = self.hub_direction();
        let across = toward - hub * toward.dot(hub);
        // A direction within 1e-9 rad of the hub has no usable across component.
        if across.length() <= 1e-9 * toward.length() {
            return Err(NeedleError::DegenerateTilt);
        }
        let axis = hub.cross(across).normalize();
        let rot = DQuat::from_axis_angle(axis, deg.to_radians());
        Ok(((rot * hub).normalize(), rot))
    }

    /// Angle the hub would make with the puncture direction after a tilt, degrees.
    pub fn hub_deviation_after_deg(&self, toward: DVec3, deg: f64) -> Result<f64, NeedleError> {
        let (hub, _) = self.tilted(toward, deg)?;
        Ok(hub
            .dot(self.puncture_direction())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees())
    }

    /// Tilt the hub by `deg` degrees towards `toward` (see [`super::hub`]): the external shaft
    /// pivots about the skin entry, the tip heading turns by the transmitted fraction, and the
    /// channel ahead of the tip (if any) is cut so that the next advance branches. Refused
    /// beyond [`MAX_HUB_DEVIATION_DEG`] from the puncture direction.
    pub fn tilt(&mut self, toward: DVec3, deg: f64) -> Result<TiltOutcome, NeedleError> {
        let deviation = self.hub_deviation_after_deg(toward, deg)?;
        if deviation > MAX_HUB_DEVIATION_DEG {
            return Err(NeedleError::TiltLimit {
                deviation_deg: deviation,
            });
        }
        let (hub, rot) = self.tilted(toward, deg)?;
        self.puncture_dir = Some(self.puncture_direction());
        self.hub_dir = Some(hub);
        let fraction = tip_turn_fraction(self.profile.outer_diameter_mm, self.buried_mm());
        let (axis, angle) = rot.to_axis_angle();
        let tip_rot = DQuat::from_axis_angle(axis, angle * fraction);
        let mut branched = false;
        if self.tract.segments.is_empty() {
            // Not yet in tissue: the whole needle re-aims about the entry point.
            self.entry.orientation = (tip_rot * self.entry.orientation).normalize();
            self.pose = self.entry;
        } else {
            branched = self.branch_here(true);
            let mut turned = self.pose;
            turned.orientation = (tip_rot * turned.orientation).normalize();
            let seg = TractSegment {
                start: turned,
                response_start: self.response,
                bevel: self.bevel_local(),
                curvature_per_mm: DVec2::ZERO,
                length_mm: 0.0,
                start_arc_mm: self.buried_mm(),
                kind: SegmentKind::Turn,
            };
            self.tract.segments.push(seg);
            self.cursor = TractCursor {
                segment: self.tract.segments.len() - 1,
                offset_mm: 0.0,
            };
            self.pose = turned;
        }
        self.contact_turn_rad = 0.0;
        Ok(TiltOutcome {
            hub_deviation_deg: deviation,
            tip_turn_deg: (angle * fraction).to_degrees(),
            branched,
        })
    }

    /// Apply a tip roll and branch if the tip is behind the end of its channel.
    fn turn_tip(&mut self, delta_rad: f64) -> bool {
        if delta_rad == 0.0 {
            return false;
        }
        self.tip_roll_rad += delta_rad;
        let curved = !matches!(self.profile.path, PathModel::Straight);
        self.branch_here(curved)
    }

    /// Roll the hub by `deg` degrees; the bevel turns only once the play is taken up.
    pub fn roll(&mut self, deg: f64) -> RollOutcome {
        let window = self.play_window_rad();
        let tip = self.play.roll(deg.to_radians(), window);
        let branched = self.turn_tip(tip);
        RollOutcome {
            tip_roll_rad: tip,
            branched,
        }
    }

    /// Withdraw the hub by `mm`; the tip moves back along its recorded channel (never past the
    /// skin entry). Twist that no longer fits the narrower play window turns the tip.
    pub fn withdraw(&mut self, mm: f64) -> WithdrawOutcome {
        let before = self.buried_mm();
        let target = (before - mm).max(0.0);
        if !self.tract.segments.is_empty() {
            let mut i = self.cursor.segment;
            while i > 0 && target < self.tract.segments[i].start_arc_mm {
                i -= 1;
            }
            let seg = &self.tract.segments[i];
            let offset = (target - seg.start_arc_mm).clamp(0.0, seg.length_mm);
            self.cursor = TractCursor {
                segment: i,
                offset_mm: offset,
            };
            self.set_from_cursor();
        }
        self.contact_turn_rad = 0.0;
        let released = self.play.set_window(self.play_window_rad());
        let branched = self.turn_tip(released);
        WithdrawOutcome {
            withdrawn_mm: before - self.buried_mm(),
            released_tip_roll_rad: released,
            branched,
        }
    }

    /// Feed the hub by `mm` against `bone`: first along any channel ahead of the tip, then
    /// cutting new tissue in equal substeps no longer than `substep_mm`.
    pub fn feed(&mut self, mm: f64, bone: &dyn BoneSurface) -> FeedOutcome {
        let available = (self.profile.shaft_length_mm - self.buried_mm()).max(0.0);
        let hub_limited = mm > available;
        let mut remaining = mm.min(available);
        let mut advanced = 0.0;
        let mut slides = 0;

        // Retrace the recorded channel.
        while remaining > 0.0 && !self.tract.is_end(self.cursor) {
            let n_seg = self.tract.segments.len();
            let seg_len = self.tract.segments[self.cursor.segment].length_mm;
            let avail = seg_len - self.cursor.offset_mm;
            if remaining >= avail - RETRACE_SNAP_MM {
                remaining = (remaining - avail).max(0.0);
                advanced += avail;
                if self.cursor.segment + 1 < n_seg {
                    self.cursor = TractCursor {
                        segment: self.cursor.segment + 1,
                        offset_mm: 0.0,
                    };
                } else {
                    self.cursor.offset_mm = seg_len;
                }
            } else {
                self.cursor.offset_mm += remaining;
                advanced += remaining;
                remaining = 0.0;
            }
        }
        let retraced = advanced;
        self.set_from_cursor();
        if retraced > 0.0 && remaining <= RETRACE_SNAP_MM {
            // Round-off left over from matching a withdrawal: not worth a sliver of new channel.
            remaining = 0.0;
        }

        // Cut new tissue.
        if remaining > 0.0 {
            if self.pending_branch_mm >= REDIRECT_MIN_DISCARD_MM {
                self.redirections += 1;
            }
            self.pending_branch_mm = 0.0;
            let n = ((remaining / self.substep_mm).ceil() as usize).max(1);
            let h = remaining / n as f64;
            for _ in 0..n {
                match self.cut_substep(h, bone, &mut slides) {
                    Ok(()) => advanced += h,
                    Err((done, arrest)) => {
                        advanced += done;
                        return FeedOutcome {
                            advanced_mm: advanced,
                            retraced_mm: retraced,
                            slides,
                            stop: FeedStop::Arrested(arrest),
                        };
                    }
                }
            }
        }
        let stop = if hub_limited {
            FeedStop::HubAtSkin
        } else {
            FeedStop::Completed
        };
        FeedOutcome {
            advanced_mm: advanced,
            retraced_mm: retraced,
            slides,
            stop,
        }
    }

    /// The arc this state would cut over `s_mm`, with the curvature from the exact mean response.
    fn planned_curvature(&self, s_mm: f64) -> DVec2 {
        match self.profile.path {
            PathModel::Straight => DVec2::ZERO,
            PathModel::Curved {
                nominal_radius_mm,
                response_length_mm,
            } => {
                mean_response(self.response, self.bevel_local(), s_mm, response_length_mm)
                    / nominal_radius_mm
            }
        }
    }

    /// Append a segment of length `len_mm` with curvature `k` from the current state, and move the
    /// tip to its end.
    fn push_segment(&mut self, k: DVec2, len_mm: f64, kind: SegmentKind) {
        let start_arc_mm = self.buried_mm();
        let seg = TractSegment {
            start: self.pose,
            response_start: self.response,
            bevel: self.bevel_local(),
            curvature_per_mm: k,
            length_mm: len_mm,
            start_arc_mm,
            kind,
        };
        self.tract.segments.push(seg);
        self.cursor = TractCursor {
            segment: self.tract.segments.len() - 1,
            offset_mm: len_mm,
        };
        self.pose = seg.end_pose();
        self.response = seg.response_at(len_mm, self.response_length());
    }

    /// One substep of `h` mm of new cutting, resolving bone contacts. On arrest returns the arc
    /// length completed before stopping.
    fn cut_substep(
        &mut self,
        h: f64,
        bone: &dyn BoneSurface,
        slides: &mut usize,
    ) -> Result<(), (f64, ContactArrest)> {
        let start = self.pose.position_mm;
        let tangent = self.pose.tangent();
        let end = arc_pose(&self.pose, self.planned_curvature(h), h);
        let Some(mut hit) = blocking(bone, start, end.position_mm, tangent) else {
            let k = self.planned_curvature(h);
            self.push_segment(k, h, SegmentKind::Cut);
            self.contact_turn_rad = 0.0;
            return Ok(());
        };

        // Longest sub-arc that keeps the contact gap, by bisection on its length; the chord of
        // each trial arc is what is ray-cast.
        let mut lo = 0.0;
        if let Some(at_start) = blocking(bone, start, start, tangent) {
            // Already at the gap and heading in: no travel possible before the contact.
            hit = at_start;
        } else {
            let mut hi = h;
            while hi - lo > CONTACT_BISECTION_TOL_MM {
                let mid = 0.5 * (lo + hi);
                let trial = arc_pose(&self.pose, self.planned_curvature(mid), mid);
                match blocking(bone, start, trial.position_mm, tangent) {
                    None => lo = mid,
                    Some(x) => {
                        hi = mid;
                        hit = x;
                    }
                }
            }
        }
        let mut done = 0.0;
        if lo > 0.0 {
            let k = self.planned_curvature(lo);
            self.push_segment(k, lo, SegmentKind::Cut);
            done = lo;
        }

        // Resolve contacts: arrest, or turn onto the surface and slide straight.
        let mut contacts = 0;
        loop {
            let t = self.pose.tangent();
            let incidence = (-t.dot(hit.normal)).clamp(-1.0, 1.0).asin().max(0.0);
            let arrest = |reason| {
                (
                    done,
                    ContactArrest {
                        reason,
                        surface_point_mm: hit.point_mm,
                        normal: hit.normal,
                        incidence_deg: incidence.to_degrees(),
                    },
                )
            };
            if incidence >= ARREST_INCIDENCE_DEG.to_radians() {
                return Err(arrest(ArrestReason::SteepIncidence));
            }
            if self.contact_turn_rad + incidence > TURNING_BUDGET_DEG.to_radians() {
                return Err(arrest(ArrestReason::TurningBudget));
            }
            contacts += 1;
            if contacts > MAX_CONTACTS_PER_SUBSTEP {
                return Err(arrest(ArrestReason::Wedged));
            }
            let left = h - done;
            // Slide direction: the tangent projected onto the surface; if the tip sits closer
            // than the contact gap, tilt it to regain the gap over 1 mm of travel.
            let height = (self.pose.position_mm - hit.point_mm).dot(hit.normal);
            let along = (t - hit.normal * t.dot(hit.normal)).normalize_or_zero();
            if along == DVec3::ZERO {
                return Err(arrest(ArrestReason::SteepIncidence));
            }
            let lift = (CONTACT_GAP_MM - height).max(0.0);
            let slide_dir = (along + hit.normal * lift).normalize();
            let turn = DQuat::from_rotation_arc(t, slide_dir);
            self.pose.orientation = (turn * self.pose.orientation).normalize();
            self.contact_turn_rad += t.dot(slide_dir).clamp(-1.0, 1.0).acos();
            *slides += 1;
            let p = self.pose.position_mm;
            match blocking(bone, p, p + slide_dir * left, slide_dir) {
                None => {
                    self.push_segment(DVec2::ZERO, left, SegmentKind::Slide);
                    return Ok(());
                }
                Some(next) => {
                    // Travel until the gap to the next contact plane is reached.
                    let sin_next = (-slide_dir.dot(next.normal)).max(f64::MIN_POSITIVE);
                    let s = (next.t_mm - CONTACT_GAP_MM / sin_next).clamp(0.0, left);
                    self.push_segment(DVec2::ZERO, s, SegmentKind::Slide);
                    done += s;
                    hit = next;
                }
            }
        }
    }
}

/// A blocking contact ahead: where the centre-line meets bone and the outward normal there.
#[derive(Debug, Clone, Copy)]
struct Blocking {
    point_mm: DVec3,
    normal: DVec3,
    /// Distance along the cast ray, millimetres.
    t_mm: f64,
}

/// Does the straight move from `from` to `to` cross bone, or end closer than
/// [`CONTACT_GAP_MM`] to the plane of the bone surface just ahead? A zero-length move is tested
/// along `fallback_dir`. The ray looks [`LOOKAHEAD_MM`] beyond the end of the move.
fn blocking(
    bone: &dyn BoneSurface,
    from: DVec3,
    to: DVec3,
    fallback_dir: DVec3,
) -> Option<Blocking> {
    let d = to - from;
    let len = d.length();
    let dir = if len > 0.0 { d / len } else { fallback_dir };
    let hit = first_entry(bone, from, dir, len + LOOKAHEAD_MM)?;
    // Height of the end of the move above the tangent plane at the hit.
    let end_height = (hit.t_mm - len) * (-dir.dot(hit.normal));
    (end_height < CONTACT_GAP_MM).then_some(Blocking {
        point_mm: from + dir * hit.t_mm,
        normal: hit.normal,
        t_mm: hit.t_mm,
    })
}

/// A needle with its ordered command log: the unit of record and replay.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Needle {
    /// State before the first command.
    pub initial: NeedleState,
    /// Current state.
    pub state: NeedleState,
    /// Every accepted command, in order.
    pub log: Vec<NeedleCommand>,
}

impl Needle {
    /// Start recording from `initial`.
    pub fn new(initial: NeedleState) -> Self {
        Self {
            state: initial.clone(),
            initial,
            log: Vec::new(),
        }
    }

    /// Apply one command against `bone` and record it.
    pub fn apply(
        &mut self,
        cmd: NeedleCommand,
        bone: &dyn BoneSurface,
    ) -> Result<CommandOutcome, NeedleError> {
        if !cmd.is_valid() {
            return Err(NeedleError::InvalidCommand(cmd));
        }
        self.log.push(cmd);
        Ok(match cmd {
            NeedleCommand::Feed { mm } => CommandOutcome::Feed(self.state.feed(mm, bone)),
            NeedleCommand::Roll { deg } => CommandOutcome::Roll(self.state.roll(deg)),
            NeedleCommand::Withdraw { mm } => CommandOutcome::Withdraw(self.state.withdraw(mm)),
            NeedleCommand::Tilt { toward, deg } => match self.state.tilt(toward, deg) {
                Ok(t) => CommandOutcome::Tilt(t),
                Err(e) => {
                    self.log.pop();
                    return Err(e);
                }
            },
        })
    }

    /// Rebuild a needle by applying `log` to `initial` against the same bone.
    pub fn replay(
        initial: NeedleState,
        log: &[NeedleCommand],
        bone: &dyn BoneSurface,
    ) -> Result<Self, NeedleError> {
        let mut needle = Self::new(initial);
        for &cmd in log {
            needle.apply(cmd, bone)?;
        }
        Ok(needle)
    }

    /// Apply a command with no bone present.
    pub fn apply_free(&mut self, cmd: NeedleCommand) -> Result<CommandOutcome, NeedleError> {
        self.apply(cmd, &NoBone)
    }
}
