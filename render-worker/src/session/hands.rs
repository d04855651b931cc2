//! Needle handling: what the learner's hands do with the needle and what they feel. The skin
//! marker, puncture at the marker, hub tilt, feed and withdrawal with the insertion force along
//! the path, the loss-of-resistance syringe, aspiration, and the counters the scorers read.
//!
//! Everything here is a pure function of the logged commands and the session seed, so replay is
//! bit-identical. The physics is sim-core's: [`sim_core::needle::force`] (insertion force),
//! [`sim_core::needle::syringe`] (plunger resistance, aspiration) and
//! [`sim_core::needle::hub`] (hub tilt, redirections); this module finds the tissue at the tip
//! and at the outlet in the region and keeps the tallies.
//!
//! What the learner is told is what the hands would feel (force in newtons, how the plunger
//! moves, what comes back on aspiration), never where the tip is.

use glam::DVec3;
use sim_core::needle::{
    BoneSurface, FeedStop, ForceModel, ForceSample, LorFeel, LorMedium, LorSyringe, Tissue, Tract,
    aspirate, is_false_loss,
};

use super::command::{Command, CommandError, ErrorCode, MAX_PROBE_SNAP_MM, SyringeAction};
use super::region::Region;
pub use super::world::Hands;
use super::world::ImageRayError;
use super::world::{self, NeedleInstrument, World};

/// Spacing of the force samples along a feed or withdrawal, mm: the session needles' substep
/// ([`world::NEEDLE_SUBSTEP_MM`]), so every cut substep gets one sample.
pub const FORCE_SAMPLE_MM: f64 = world::NEEDLE_SUBSTEP_MM;

/// Length of the radio-opaque skin marker (a clamp tip lying on the skin along the body axis),
/// mm. Simulator choice: the jaw of a Kelly clamp is about 10 mm long and 2 mm wide.
pub const MARKER_LENGTH_MM: f64 = 10.0;
/// Radius of the marker rod, mm (same choice).
pub const MARKER_RADIUS_MM: f64 = 1.0;

/// Rate at which saline leaves the loss-of-resistance syringe once the plunger gives way, for
/// the injection ledger, ml/s. Simulator choice: a hand push through a Tuohy needle, about
/// 0.5 ml/s.
pub const LOR_FLOW_ML_PER_S: f64 = 0.5;

/// What a needle command asks the session to do besides answering.
#[derive(Debug, Default)]
pub struct Effects {
    /// The needle geometry changed (re-render live views, tell the modalities).
    pub needle_moved: bool,
    /// The marker changed (a still image does not change; the next shot shows it).
    pub marker_moved: bool,
    /// Saline that left the loss-of-resistance syringe, ml, for the injection ledger.
    pub saline_ml: f64,
}

/// Everything [`apply`] needs besides the world.
pub struct Context<'a> {
    /// Anatomy.
    pub region: &'a Region,
    /// The session seed (aspiration draws).
    pub seed: u64,
    /// The ray through the pixel of a `skin_marker` command on the displayed fluoroscopy image:
    /// origin and unit direction, or why there is none.
    pub pixel_ray: Option<Result<(DVec3, DVec3), ImageRayError>>,
}

fn state_error(message: impl Into<String>) -> CommandError {
    CommandError::field("command.type", ErrorCode::State, message)
}

/// Applies a needle-class command.
pub fn apply(
    command: &Command,
    world: &mut World,
    ctx: &Context<'_>,
    effects: &mut Effects,
) -> Result<serde_json::Value, CommandError> {
    match command {
        Command::NeedlePlace {
            instrument,
            entry_mm,
            direction,
            bevel_reference,
        } => {
            let entry = DVec3::from_array(*entry_mm);
            let check = || {
                if ctx.region.bones().contains(entry) {
                    return Err(CommandError::field(
                        "command.entry_mm",
                        ErrorCode::Invalid,
                        "the entry point lies inside bone",
                    ));
                }
                Ok(())
            };
            insert_needle(
                world,
                instrument,
                entry,
                *direction,
                *bevel_reference,
                check,
            )?;
            effects.needle_moved = true;
            Ok(serde_json::json!({ "placed": instrument }))
        }
        Command::SkinMarker { pixel, position_mm } => {
            let at = marker_point(world, ctx, pixel.is_some(), *position_mm)?;
            world.hands.marker_mm = Some(at.to_array());
            effects.marker_moved = true;
            Ok(serde_json::json!({ "marker_mm": at.to_array() }))
        }
        Command::NeedlePuncture {
            instrument,
            direction,
            bevel_reference,
        } => {
            let Some(marker) = world.hands.marker_mm.map(DVec3::from_array) else {
                return Err(state_error(
                    "no skin marker: place one with skin_marker before puncturing",
                ));
            };
            let dir = match direction {
                Some(d) => DVec3::from_array(*d).normalize(),
                None => beam_dir(world),
            };
            // One millimetre along the direction must be under the skin.
            if ctx.region.contains("skin", (marker + dir).to_array()) != Some(true) {
                return Err(CommandError::field(
                    "command.direction",
                    ErrorCode::Invalid,
                    "the direction points out of the body at the marker",
                ));
            }
            let bevel = bevel_reference.map_or_else(
                || {
                    if dir.cross(DVec3::Z).length() > 1e-3 {
                        DVec3::Z
                    } else {
                        DVec3::NEG_Y
                    }
                },
                DVec3::from_array,
            );
            insert_needle(
                world,
                instrument,
                marker,
                dir.to_array(),
                bevel.to_array(),
                || Ok(()),
            )?;
            world.hands.marker_mm = None;
            effects.needle_moved = true;
            effects.marker_moved = true;
            Ok(serde_json::json!({
                "punctured": instrument,
                "entry_mm": marker.to_array(),
                "direction": dir.to_array(),
            }))
        }
        Command::NeedleTilt { cc_deg, ml_deg } => {
            if *cc_deg == 0.0 && *ml_deg == 0.0 {
                return Err(CommandError::field(
                    "command.cc_deg",
                    ErrorCode::Invalid,
                    "a tilt turns the hub: give cc_deg or ml_deg",
                ));
            }
            let n = needle_mut(world)?;
            let mut trial = n.state.clone();
            let mut turned = 0.0;
            let mut branched = false;
            for (field, deg, toward) in [
                ("command.cc_deg", *cc_deg, DVec3::Z),
                ("command.ml_deg", *ml_deg, DVec3::NEG_X),
            ] {
                if deg == 0.0 {
                    continue;
                }
                let out = trial.tilt(toward * deg.signum(), deg.abs()).map_err(|e| {
                    CommandError::field(field, ErrorCode::OutOfRange, e.to_string())
                })?;
                turned += out.tip_turn_deg;
                branched |= out.branched;
            }
            let deviation = trial
                .hub_direction()
                .dot(trial.puncture_direction())
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees();
            n.state = trial;
            effects.needle_moved = true;
            let ack = serde_json::json!({
                "hub_deviation_deg": deviation,
                "tip_turn_deg": turned,
                "branched": branched,
                "tip_mm": n.state.tip_mm().to_array(),
                "depth_mm": n.state.buried_mm(),
                "direction": n.state.pose.tangent().to_array(),
            });
            world.hands.giving_way = false;
            Ok(ack)
        }
        Command::NeedleFeed { mm } => feed(world, ctx, *mm, effects),
        Command::NeedleWithdraw { mm } => withdraw(world, ctx, *mm, effects),
        Command::NeedleRoll { deg } => {
            let n = needle_mut(world)?;
            let out = n.state.roll(*deg);
            effects.needle_moved = true;
            let ack = serde_json::json!({
                "outcome": out,
                "tip_mm": n.state.tip_mm().to_array(),
                "depth_mm": n.state.buried_mm(),
            });
            world.hands.giving_way = false;
            Ok(ack)
        }
        Command::Syringe { action, medium } => {
            needle_mut(world)?;
            match action {
                SyringeAction::Attach => {
                    let has = world
                        .station
                        .station
                        .instruments
                        .iter()
                        .any(|i| i.kind == "loss-of-resistance-syringe");
                    if !has {
                        return Err(CommandError::field(
                            "command.type",
                            ErrorCode::InstrumentUnavailable,
                            "this station's tray has no loss-of-resistance syringe",
                        ));
                    }
                    let m = medium.unwrap_or(LorMedium::Saline);
                    world.hands.syringe = Some(LorSyringe::new(m));
                    world.hands.giving_way = false;
                    Ok(serde_json::json!({ "attached": m }))
                }
                SyringeAction::Detach => {
                    world.hands.syringe = None;
                    world.hands.hold = false;
                    world.hands.giving_way = false;
                    Ok(serde_json::json!({ "attached": null }))
                }
            }
        }
        Command::Plunger { ml } => {
            let outlet = outlet_tissue(world, ctx)?;
            let Some(s) = world.hands.syringe.as_mut() else {
                return Err(state_error(
                    "no loss-of-resistance syringe on the needle: attach one first",
                ));
            };
            let feel = s.press(outlet, *ml);
            Ok(serde_json::json!({ "lor": felt(world, outlet, &feel, effects) }))
        }
        Command::PlungerHold { on } => {
            if !on {
                world.hands.hold = false;
                return Ok(serde_json::json!({ "hold": false }));
            }
            let outlet = outlet_tissue(world, ctx)?;
            let Some(s) = world.hands.syringe.as_mut() else {
                return Err(state_error(
                    "no loss-of-resistance syringe on the needle: attach one first",
                ));
            };
            let feel = s.hold(outlet);
            world.hands.hold = true;
            Ok(serde_json::json!({ "hold": true, "lor": felt(world, outlet, &feel, effects) }))
        }
        Command::Aspirate => {
            let n = needle_mut(world)?;
            if n.state.buried_mm() <= outlet_setback_mm(n) {
                return Err(state_error(
                    "the needle's opening is not under the skin: advance before aspirating",
                ));
            }
            // One draw per placement (the puncture and the outlet's millimetre cell), so
            // repeated aspiration at the same place gives the same answer and the published
            // per-placement miss rate holds.
            let cell = n.state.outlet().centre_mm.round();
            let place = [cell.x, cell.y, cell.z]
                .iter()
                .fold(u64::from(world.hands.skin_punctures), |h, v| {
                    sim_core::rng::splitmix64(h ^ (*v as i64 as u64))
                });
            let outlet = outlet_tissue(world, ctx)?;
            world.hands.aspirations += 1;
            let draw = sim_core::rng::unit_f64(sim_core::rng::splitmix64(
                ctx.seed ^ place.wrapping_mul(0xa5a5_5a5a_0f0f_f0f1),
            ));
            let got = aspirate(outlet, draw);
            Ok(serde_json::json!({ "aspirate": got, "text": got.text() }))
        }
        _ => Err(state_error("not a needle command")),
    }
}

/// Puts a new needle at a skin entry (a puncture): the instrument must be a needle on the tray,
/// the previous needle out of tissue, and `check` (the caller's own test of the entry) must
/// pass, in that order.
fn insert_needle(
    world: &mut World,
    instrument: &str,
    entry: DVec3,
    direction: [f64; 3],
    bevel_reference: [f64; 3],
    check: impl FnOnce() -> Result<(), CommandError>,
) -> Result<(), CommandError> {
    let station = &world.station.station;
    let Some(item) = station.instruments.iter().find(|i| i.id == instrument) else {
        return Err(CommandError::field(
            "command.instrument",
            ErrorCode::InstrumentUnavailable,
            format!("{instrument} is not on this station's tray"),
        ));
    };
    let Some(profile) = world::profile_for_kind(&item.kind) else {
        return Err(CommandError::field(
            "command.instrument",
            ErrorCode::InstrumentUnavailable,
            format!("{instrument} ({}) is not a needle", item.kind),
        ));
    };
    if world
        .needle
        .as_ref()
        .is_some_and(|n| n.state.buried_mm() > 0.0)
    {
        return Err(state_error(
            "the needle is in tissue: withdraw it fully before puncturing again",
        ));
    }
    check()?;
    let state = world::new_needle(profile, entry.to_array(), direction, bevel_reference)
        .map_err(|e| CommandError::field("command.direction", ErrorCode::Invalid, e.to_string()))?;
    let h = &mut world.hands;
    if let Some(old) = &world.needle {
        h.redirections_before += old.state.redirections;
    }
    h.skin_punctures += 1;
    h.force.reset();
    h.peak_force_n = 0.0;
    h.on_bone = false;
    h.syringe = None;
    h.hold = false;
    h.giving_way = false;
    let entered = world.needle.take().map(|n| n.entered).unwrap_or_default();
    world.needle = Some(NeedleInstrument {
        instrument: instrument.to_string(),
        state,
        entered,
    });
    Ok(())
}

fn needle_mut(world: &mut World) -> Result<&mut NeedleInstrument, CommandError> {
    world
        .needle
        .as_mut()
        .ok_or_else(|| state_error("no needle: puncture the skin (or place a needle) first"))
}

/// Unit direction of the C-arm's central beam, or straight anterior (+y, the AP beam) at a
/// station without one.
fn beam_dir(world: &World) -> DVec3 {
    world
        .carm
        .map_or(DVec3::Y, |c| DVec3::from_array(c.beam_dir).normalize())
}

/// Where the marker goes for a `skin_marker` command.
fn marker_point(
    world: &World,
    ctx: &Context<'_>,
    by_pixel: bool,
    position_mm: Option<[f64; 3]>,
) -> Result<DVec3, CommandError> {
    if by_pixel {
        let (origin, dir) = match &ctx.pixel_ray {
            Some(Ok(r)) => *r,
            Some(Err(why)) => {
                return Err(CommandError::field(
                    "command.pixel",
                    ErrorCode::Invalid,
                    why.to_string(),
                ));
            }
            None => {
                return Err(CommandError::field(
                    "command.pixel",
                    ErrorCode::ModalityUnavailable,
                    "no fluoroscopy image to mark at this station: give position_mm",
                ));
            }
        };
        return ctx.region.skin_entry(origin, dir, 5000.0).ok_or_else(|| {
            CommandError::field(
                "command.pixel",
                ErrorCode::Invalid,
                "the ray through that pixel misses the body",
            )
        });
    }
    let p = DVec3::from_array(position_mm.unwrap_or_default());
    let dir = beam_dir(world);
    let far = p - dir * 1000.0;
    let hit = ctx.region.skin_entry(far, dir, 2000.0);
    match hit {
        Some(h) if h.distance(p) <= MAX_PROBE_SNAP_MM => Ok(h),
        _ => Err(CommandError::field(
            "command.position_mm",
            ErrorCode::Invalid,
            format!("no skin within {MAX_PROBE_SNAP_MM} mm of that point along the beam"),
        )),
    }
}

/// Point of the recorded channel at buried arc length `s_mm` (the entry for `s <= 0`).
pub(crate) fn point_at_arc(tract: &Tract, entry: DVec3, s_mm: f64) -> DVec3 {
    let Some(i) = tract
        .segments
        .iter()
        .rposition(|seg| seg.start_arc_mm <= s_mm)
    else {
        return entry;
    };
    let seg = &tract.segments[i];
    seg.pose_at((s_mm - seg.start_arc_mm).clamp(0.0, seg.length_mm))
        .position_mm
}

/// Distance of the outlet's centre behind the tip, mm.
fn outlet_setback_mm(n: &NeedleInstrument) -> f64 {
    let o = n.state.profile.opening;
    o.distal_edge_from_tip_mm + 0.5 * o.length_mm
}

/// Tissue at the needle's outlet now.
fn outlet_tissue(world: &World, ctx: &Context<'_>) -> Result<Tissue, CommandError> {
    let n = world
        .needle
        .as_ref()
        .ok_or_else(|| state_error("no needle: puncture the skin (or place a needle) first"))?;
    let s = n.state.buried_mm() - outlet_setback_mm(n);
    if s <= 0.0 {
        return Ok(Tissue::Air);
    }
    Ok(ctx.region.tissue_at(n.state.outlet().centre_mm.to_array()))
}

/// Tissue samples along the channel, one per [`FORCE_SAMPLE_MM`] up to `up_to_mm` (sample `k`
/// is the tissue at the middle of the `k`-th interval).
fn channel_tissues(region: &Region, n: &NeedleInstrument, up_to_mm: f64) -> Vec<Tissue> {
    let entry = n.state.entry.position_mm;
    let count = (up_to_mm / FORCE_SAMPLE_MM).ceil().max(0.0) as usize;
    (0..count)
        .map(|k| {
            let s = ((k as f64 + 0.5) * FORCE_SAMPLE_MM).min(up_to_mm);
            region.tissue_at(point_at_arc(&n.state.tract, entry, s).to_array())
        })
        .collect()
}

/// Buried shaft length per tissue for the first `s_mm` of the channel.
fn shaft_lengths(samples: &[Tissue], s_mm: f64) -> Vec<(Tissue, f64)> {
    let mut out: Vec<(Tissue, f64)> = Vec::new();
    let mut left = s_mm;
    for &t in samples {
        if left <= 0.0 {
            break;
        }
        let len = left.min(FORCE_SAMPLE_MM);
        left -= len;
        match out.iter_mut().find(|(u, _)| *u == t) {
            Some(e) => e.1 += len,
            None => out.push((t, len)),
        }
    }
    out
}

/// The force report of a feed or withdrawal.
fn force_json(samples: &[(f64, ForceSample)], peak_n: f64) -> serde_json::Value {
    let last = samples.last().map(|s| s.1);
    serde_json::json!({
        "tip_n": last.map_or(0.0, |s| s.tip_n),
        "friction_n": last.map_or(0.0, |s| s.friction_n),
        "total_n": last.map_or(0.0, |s| s.total_n),
        "peak_n": peak_n,
        "pop": samples.iter().any(|s| s.1.pop),
        "samples": samples.iter().map(|(d, s)| [*d, s.total_n]).collect::<Vec<_>>(),
    })
}

/// Advances the needle, then walks the new stretch of channel for the force and (with the
/// plunger held) the syringe.
fn feed(
    world: &mut World,
    ctx: &Context<'_>,
    mm: f64,
    effects: &mut Effects,
) -> Result<serde_json::Value, CommandError> {
    let region = ctx.region;
    let n = needle_mut(world)?;
    let before = n.state.buried_mm();
    let out = n.state.feed(mm, &region.bones());
    let after = n.state.buried_mm();
    let retraced_to = before + out.retraced_mm;
    let tissues = channel_tissues(region, n, after);
    let setback = outlet_setback_mm(n);
    let entry = n.state.entry.position_mm;
    let tract = n.state.tract.clone();
    world::mark_entered(n, region);
    let tip_mm = n.state.tip_mm().to_array();
    if !world.hands.hold {
        // The needle moved without the plunger checked: the next give is a new episode.
        world.hands.giving_way = false;
    }
    let model = ForceModel::literature();
    let mut samples = Vec::new();
    let mut lor = None;
    let steps = ((after - before) / FORCE_SAMPLE_MM).ceil().max(0.0) as usize;
    let mut prev = before;
    for k in 1..=steps {
        let s = (before + k as f64 * FORCE_SAMPLE_MM).min(after);
        let tip = region.tissue_at(point_at_arc(&tract, entry, s).to_array());
        let shaft = shaft_lengths(&tissues, s);
        let h = &mut world.hands;
        let sample = if s <= retraced_to + 1e-9 {
            h.force.retrace(&model, tip, &shaft)
        } else {
            h.force.cut(&model, tip, s - prev.max(retraced_to), &shaft)
        };
        h.peak_force_n = h.peak_force_n.max(sample.total_n).max(sample.peak_n);
        samples.push((s, sample));
        prev = s;
        if world.hands.hold && world.hands.syringe.is_some() {
            let outlet_s = s - setback;
            let outlet = if outlet_s <= 0.0 {
                Tissue::Air
            } else {
                region.tissue_at(point_at_arc(&tract, entry, outlet_s).to_array())
            };
            if let Some(syr) = world.hands.syringe.as_mut() {
                let feel = syr.hold(outlet);
                let report = felt(world, outlet, &feel, effects);
                if feel.gave_way || lor.is_none() {
                    lor = Some(report);
                }
            }
        }
    }
    let on_bone = matches!(out.stop, FeedStop::Arrested(_)) || out.slides > 0;
    // A zero-length feed that meets nothing leaves the contact state as it was.
    let moved_or_touched = on_bone || out.advanced_mm > 0.0;
    let h = &mut world.hands;
    if matches!(out.stop, FeedStop::Arrested(_)) {
        let shaft = shaft_lengths(&tissues, after);
        let sample = h.force.bone_stop(&model, &shaft);
        h.peak_force_n = h.peak_force_n.max(sample.total_n).max(sample.peak_n);
        samples.push((after, sample));
    }
    if on_bone && !h.on_bone {
        h.bone_contacts += 1;
    }
    if moved_or_touched {
        h.on_bone = on_bone;
    }
    effects.needle_moved = true;
    let mut ack = serde_json::json!({
        "outcome": out,
        "tip_mm": tip_mm,
        "depth_mm": after,
        "bone_contact": on_bone,
        "force": force_json(&samples, h.peak_force_n),
    });
    if let (Some(l), Some(o)) = (lor, ack.as_object_mut()) {
        o.insert("lor".into(), l);
    }
    Ok(ack)
}

/// Pulls the needle back; the force along the way is friction only.
fn withdraw(
    world: &mut World,
    ctx: &Context<'_>,
    mm: f64,
    effects: &mut Effects,
) -> Result<serde_json::Value, CommandError> {
    let region = ctx.region;
    let n = needle_mut(world)?;
    let before = n.state.buried_mm();
    // The channel as it was: a withdrawal may release twist and cut the channel at the new tip.
    let tissues = channel_tissues(region, n, before);
    let tract = n.state.tract.clone();
    let entry = n.state.entry.position_mm;
    let out = n.state.withdraw(mm);
    let after = n.state.buried_mm();
    let tip_mm = n.state.tip_mm().to_array();
    world.hands.giving_way = false;
    let model = ForceModel::literature();
    let mut samples = Vec::new();
    let steps = ((before - after) / FORCE_SAMPLE_MM).ceil().max(0.0) as usize;
    for k in 1..=steps {
        let s = (before - k as f64 * FORCE_SAMPLE_MM).max(after);
        let tip = if s <= 0.0 {
            Tissue::Air
        } else {
            region.tissue_at(point_at_arc(&tract, entry, s).to_array())
        };
        let shaft = shaft_lengths(&tissues, s);
        samples.push((s, world.hands.force.retrace(&model, tip, &shaft)));
    }
    let h = &mut world.hands;
    if out.withdrawn_mm > 0.0 {
        h.on_bone = false;
    }
    if after <= 0.0 {
        // Out of the body: the skin closes behind it and the next entry is a new puncture.
        h.force.reset();
    }
    effects.needle_moved = true;
    Ok(serde_json::json!({
        "outcome": out,
        "tip_mm": tip_mm,
        "depth_mm": after,
        "force": force_json(&samples, h.peak_force_n),
    }))
}

/// Books what the plunger did: loss episodes (confirmed or false) and the volume that left the
/// syringe; returns the acknowledgement's `lor` object.
fn felt(
    world: &mut World,
    outlet: Tissue,
    feel: &LorFeel,
    effects: &mut Effects,
) -> serde_json::Value {
    let agent_injections = world
        .injections
        .len()
        .saturating_sub(world.hands.lor_ledger_entries);
    let h = &mut world.hands;
    // With the opening still outside the skin the fluid runs out of the needle: it neither
    // tests the tissue (no loss episode) nor reaches the body (nothing for the ledger).
    let in_body = outlet != Tissue::Air;
    if in_body && feel.gave_way && !h.giving_way {
        if is_false_loss(outlet, feel) {
            h.false_losses += 1;
        } else if outlet == Tissue::EpiduralFat && agent_injections == 0 {
            h.lor_confirmed = true;
        }
    }
    h.giving_way = in_body && feel.gave_way;
    h.lor_injected_ml += feel.injected_ml;
    let saline = h
        .syringe
        .as_ref()
        .is_some_and(|s| s.medium == LorMedium::Saline);
    if in_body && saline && feel.injected_ml > 0.0 {
        effects.saline_ml += feel.injected_ml;
    }
    serde_json::json!({
        "resistance": feel.resistance,
        "gave_way": feel.gave_way,
        "text": feel.text,
        "injected_ml": feel.injected_ml,
        "remaining_ml": h.syringe.as_ref().map_or(0.0, |s| s.contents_ml()),
    })
}
