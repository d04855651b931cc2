//! Automatic placement toward a target by duty-cycled flipping.
//!
//! Duty-cycled rotation varies a bevel needle's effective curvature between zero and its nominal
//! value (Minhas et al. 2007); flipping the bevel by 180 degrees between limbs of different
//! lengths is the duty-cycled flipping of Majewicz et al. (2014). The policy here is a simulator
//! teaching aid, not a validated clinical technique:
//!
//! 1. Roll the bevel toward the target's side (through the torsional play, topping the hub roll
//!    up until the bevel itself has turned), so the rest of the approach is planar.
//! 2. Every decision is made on a grid of half-limbs, a limb being the feed that turns the
//!    nominal heading by `heading_change_per_limb_deg` (10 degrees: 21 mm for a 120 mm radius).
//!    Every pattern of 180 degree hub flips on that grid (so limbs of one, two or more
//!    half-limbs: opening and closing half-limbs, full limbs between flips) is simulated with the needle model itself
//!    (bending-response lag, play and bone contact included), and the one whose path passes
//!    closest to the target is chosen.
//!    Each schedule may start with a small bevel trim (a few degrees either way) to correct
//!    errors out of the flip plane.
//! 3. Only the first half-limb of the chosen schedule is executed (flip first if it starts with
//!    one; feed is paused during every roll), then the choice is made again from the new state.
//!
//! Every action goes through [`Needle::apply`], so the generated commands are in the log and
//! replay exactly.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::contact::BoneSurface;
use super::state::{CommandOutcome, ContactArrest, FeedStop, Needle, NeedleCommand, NeedleState};

/// Largest number of half-limb grid steps whose flip patterns are enumerated at each decision
/// (2^8 = 256 flip patterns). Simulator choice: eight half-limbs of a 120 mm-radius needle
/// cover 84 mm, more than a typical approach; later steps keep the last bevel.
const MAX_GRID: u32 = 8;

/// Small bevel trims tried before each schedule, degrees. The flips keep the bevel in one plane;
/// these trims steer out of it, which is needed when the bending response still points
/// elsewhere. Simulator choice.
const TRIMS_DEG: [f64; 7] = [0.0, -3.0, 3.0, -8.0, 8.0, -20.0, 20.0];

/// Tuning of the placement policy.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PlacementConfig {
    /// Nominal heading change per full limb, degrees (10: the reference simulator's profile
    /// target; simulator choice).
    pub heading_change_per_limb_deg: f64,
    /// Distance from the target that counts as reached, millimetres. Simulator choice: 1 mm,
    /// about the outer diameter of the modelled needles (0.70 to 1.27 mm), so a reached tip
    /// covers the target point with its own cross-section.
    pub tolerance_mm: f64,
    /// Largest bevel misalignment left after a flip or alignment roll before the hub is topped
    /// up, degrees (simulator choice).
    pub roll_tolerance_deg: f64,
    /// Safety cap on the number of decisions.
    pub max_decisions: usize,
}

impl Default for PlacementConfig {
    fn default() -> Self {
        Self {
            heading_change_per_limb_deg: 10.0,
            tolerance_mm: 1.0,
            roll_tolerance_deg: 0.5,
            max_decisions: 200,
        }
    }
}

/// Why a placement did not reach its target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum PlacementFailure {
    /// The target is not ahead of the tip.
    TargetBehind {
        /// Forward distance of the target along the tip tangent (<= 0), millimetres.
        forward_mm: f64,
    },
    /// The profile has a straight path and the target is off its line.
    NotSteerable {
        /// Distance of the target from the tip's line, millimetres.
        off_axis_mm: f64,
    },
    /// Reaching the target needs a tighter path than the profile's nominal radius.
    OutOfReach {
        /// Radius of the arc through the target tangent to the tip, millimetres.
        required_radius_mm: f64,
        /// The profile's nominal path radius, millimetres.
        nominal_radius_mm: f64,
    },
    /// Bone stopped the needle.
    Arrested(ContactArrest),
    /// The whole shaft is buried.
    HubAtSkin,
    /// The best reachable path still misses by more than the tolerance.
    Missed {
        /// Closest approach achieved, millimetres.
        closest_mm: f64,
    },
    /// The decision cap was hit.
    DecisionLimit,
}

/// What a placement did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlacementReport {
    /// True when the tip ended within the tolerance of the target.
    pub reached: bool,
    /// Distance from the final tip to the target, millimetres.
    pub final_distance_mm: f64,
    /// Why not, when not reached.
    pub failure: Option<PlacementFailure>,
    /// Number of 180 degree hub flips commanded.
    pub flips: usize,
    /// Commands issued (also appended to the needle's log).
    pub commands: Vec<NeedleCommand>,
}

/// Split the target offset into forward distance along the tangent and lateral vector.
fn target_in_frame(state: &NeedleState, target_mm: DVec3) -> (f64, DVec3) {
    let d = target_mm - state.tip_mm();
    let t = state.pose.tangent();
    let f = d.dot(t);
    (f, d - t * f)
}

/// Hub rolls that turn the bevel by `want_rad`, topping up what the play absorbed.
fn roll_bevel(state: &mut NeedleState, want_rad: f64, tol_rad: f64) -> Vec<NeedleCommand> {
    let mut cmds = Vec::new();
    let mut turned = 0.0;
    // Three top-ups suffice: after the first the twist sits at the window edge in this direction,
    // so further hub roll reaches the tip one-to-one.
    for _ in 0..4 {
        let deficit = want_rad - turned;
        if deficit.abs() <= tol_rad {
            break;
        }
        let deg = deficit.to_degrees();
        turned += state.roll(deg).tip_roll_rad;
        cmds.push(NeedleCommand::Roll { deg });
    }
    cmds
}

/// Apply `cmds` to a bare state (used for the simulated schedules).
fn run_on_state(
    state: &mut NeedleState,
    cmds: &[NeedleCommand],
    bone: &dyn BoneSurface,
) -> Option<FeedStop> {
    let mut stop = None;
    for &c in cmds {
        match c {
            NeedleCommand::Feed { mm } => {
                let out = state.feed(mm, bone);
                if out.stop != FeedStop::Completed {
                    stop = Some(out.stop);
                }
            }
            NeedleCommand::Roll { deg } => {
                state.roll(deg);
            }
            NeedleCommand::Withdraw { mm } => {
                state.withdraw(mm);
            }
            NeedleCommand::Tilt { toward, deg } => {
                // Placement never tilts; a refused tilt changes nothing.
                let _ = state.tilt(toward, deg);
            }
        }
    }
    stop
}

/// Closest approach of the target to the path cut from `from_segment` on (chords of the arcs).
fn closest_on_new_path(state: &NeedleState, from_segment: usize, target_mm: DVec3) -> (f64, f64) {
    let mut best = (state.tip_mm().distance(target_mm), state.buried_mm());
    for seg in state.tract.segments.iter().skip(from_segment) {
        let a = seg.start.position_mm;
        let b = seg.end_pose().position_mm;
        let ab = b - a;
        let u = if ab.length_squared() > 0.0 {
            ((target_mm - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let d = (a + ab * u).distance(target_mm);
        if d < best.0 {
            best = (d, seg.start_arc_mm + u * seg.length_mm);
        }
    }
    best
}

/// What every simulated schedule of one decision shares.
struct Lookahead<'a> {
    half_mm: f64,
    horizon_mm: f64,
    target_mm: DVec3,
    bone: &'a dyn BoneSurface,
    tol_rad: f64,
}

impl Lookahead<'_> {
    /// Simulate the schedule "trim the bevel by `trim_rad`, then flip before grid step `j` when
    /// bit `j` of `flips` is set, feeding half-limbs" until the tip passes the target plane;
    /// returns the closest approach and the buried arc length where it happens.
    fn simulate(&self, state: &NeedleState, trim_rad: f64, flips: u32) -> (f64, f64) {
        let mut sim = state.clone();
        let first_new = sim.tract.segments.len();
        if trim_rad != 0.0 {
            roll_bevel(&mut sim, trim_rad, self.tol_rad);
        }
        let mut fed = 0.0;
        let mut j = 0;
        while fed < self.horizon_mm {
            if j < 32 && flips & (1 << j) != 0 {
                roll_bevel(&mut sim, std::f64::consts::PI, self.tol_rad);
            }
            let step = self.half_mm.min(self.horizon_mm - fed);
            let stop = run_on_state(&mut sim, &[NeedleCommand::Feed { mm: step }], self.bone);
            fed += step;
            j += 1;
            if stop.is_some() || target_in_frame(&sim, self.target_mm).0 < 0.0 {
                break;
            }
        }
        closest_on_new_path(&sim, first_new, self.target_mm)
    }
}

/// Steer `needle` toward `target_mm` by duty-cycled flipping. The needle is moved (and its log
/// extended) only when the target is judged reachable.
pub fn place_toward(
    needle: &mut Needle,
    target_mm: DVec3,
    bone: &dyn BoneSurface,
    config: &PlacementConfig,
) -> PlacementReport {
    let mut report = PlacementReport {
        reached: false,
        final_distance_mm: needle.state.tip_mm().distance(target_mm),
        failure: None,
        flips: 0,
        commands: Vec::new(),
    };
    let tol_rad = config.roll_tolerance_deg.to_radians();
    let (forward, lateral) = target_in_frame(&needle.state, target_mm);
    if forward <= 0.0 {
        report.failure = Some(PlacementFailure::TargetBehind {
            forward_mm: forward,
        });
        return report;
    }
    let kappa = needle.state.profile.path.nominal_curvature_per_mm();
    let off = lateral.length();
    if kappa == 0.0 && off > config.tolerance_mm {
        report.failure = Some(PlacementFailure::NotSteerable { off_axis_mm: off });
        return report;
    }
    if kappa > 0.0 && off > 0.0 {
        let required = (forward * forward + off * off) / (2.0 * off);
        if required < 1.0 / kappa {
            report.failure = Some(PlacementFailure::OutOfReach {
                required_radius_mm: required,
                nominal_radius_mm: 1.0 / kappa,
            });
            return report;
        }
    }

    let issue = |needle: &mut Needle, cmds: Vec<NeedleCommand>, report: &mut PlacementReport| {
        let mut stop = None;
        for c in cmds {
            // Commands built here are always valid (finite, non-negative feeds).
            if let Ok(CommandOutcome::Feed(out)) = needle.apply(c, bone) {
                if out.stop != FeedStop::Completed {
                    stop = Some(out.stop);
                }
            }
            report.commands.push(c);
        }
        stop
    };

    // 1. Align the bevel with the target's side.
    if kappa > 0.0 && off > 0.0 {
        let bevel = needle.state.bevel_world();
        let t = needle.state.pose.tangent();
        let angle = bevel.cross(lateral).dot(t).atan2(bevel.dot(lateral));
        let mut sim = needle.state.clone();
        let cmds = roll_bevel(&mut sim, angle, tol_rad);
        issue(needle, cmds, &mut report);
    }

    let half_mm = if kappa > 0.0 {
        0.5 * config.heading_change_per_limb_deg.to_radians() / kappa
    } else {
        f64::INFINITY
    };

    // 2-3. Receding-horizon choice among flip schedules, executed half a limb at a time.
    for _ in 0..config.max_decisions {
        let (forward, _) = target_in_frame(&needle.state, target_mm);
        let dist = needle.state.tip_mm().distance(target_mm);
        if forward <= 1e-6 || dist <= 1e-6 {
            report.final_distance_mm = dist;
            report.reached = dist <= config.tolerance_mm;
            if !report.reached {
                report.failure = Some(PlacementFailure::Missed { closest_mm: dist });
            }
            return report;
        }
        // Horizon: the straight distance plus a margin for curvature and zig-zag (simulator
        // choice: 20 % + one limb).
        let horizon = dist * 1.2 + 2.0 * half_mm.min(dist);
        // Every flip pattern over the next grid steps (at most MAX_GRID of them; later steps
        // keep the last bevel), simulated with the full model.
        let grid = if half_mm.is_finite() {
            ((horizon / half_mm).ceil() as u32).min(MAX_GRID)
        } else {
            0
        };
        let look = Lookahead {
            half_mm,
            horizon_mm: horizon,
            target_mm,
            bone,
            tol_rad,
        };
        let mut best: Option<(f64, f64, f64, u32)> = None;
        // The first decision searches the whole circle of bevel trims, because the bending
        // response may still point far from the target's side; later ones only fine-tune.
        let wide: Vec<f64> = (0..24).map(|k| f64::from(k) * 15.0 - 180.0).collect();
        let trims: &[f64] = if report
            .commands
            .iter()
            .any(|c| matches!(c, NeedleCommand::Feed { .. }))
        {
            &TRIMS_DEG
        } else {
            &wide
        };
        for &trim_deg in trims {
            if kappa == 0.0 && trim_deg != 0.0 {
                continue;
            }
            let trim = trim_deg.to_radians();
            for flips in 0..(1u32 << grid) {
                let (miss, at_arc) = look.simulate(&needle.state, trim, flips);
                // Each flip or trim costs 1 micrometre so that ties prefer doing less
                // (simulator choice).
                let actions = flips.count_ones() + u32::from(trim != 0.0);
                let score = miss + 1e-3 * f64::from(actions);
                if best.is_none_or(|b| score < b.0) {
                    best = Some((score, at_arc, trim, flips));
                }
            }
        }
        let (_, at_arc, trim, flips) = best.expect("the empty schedule is always considered");
        let mut cmds = Vec::new();
        let mut sim = needle.state.clone();
        if trim != 0.0 {
            cmds.extend(roll_bevel(&mut sim, trim, tol_rad));
        }
        if flips & 1 != 0 {
            cmds.extend(roll_bevel(&mut sim, std::f64::consts::PI, tol_rad));
            report.flips += 1;
        }
        let to_closest = at_arc - needle.state.buried_mm();
        let feed = half_mm.min(to_closest.max(0.0));
        if feed <= 1e-6 {
            // The best schedule passes closest right here: stop.
            issue(needle, cmds, &mut report);
            let d = needle.state.tip_mm().distance(target_mm);
            report.final_distance_mm = d;
            report.reached = d <= config.tolerance_mm;
            if !report.reached {
                report.failure = Some(PlacementFailure::Missed { closest_mm: d });
            }
            return report;
        }
        cmds.push(NeedleCommand::Feed { mm: feed });
        if let Some(stop) = issue(needle, cmds, &mut report) {
            let d = needle.state.tip_mm().distance(target_mm);
            report.final_distance_mm = d;
            report.reached = d <= config.tolerance_mm;
            if !report.reached {
                report.failure = Some(match stop {
                    FeedStop::Arrested(a) => PlacementFailure::Arrested(a),
                    _ => PlacementFailure::HubAtSkin,
                });
            }
            return report;
        }
    }
    report.final_distance_mm = needle.state.tip_mm().distance(target_mm);
    report.failure = Some(PlacementFailure::DecisionLimit);
    report
}
