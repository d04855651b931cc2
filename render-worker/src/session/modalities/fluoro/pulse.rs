//! Pulsed fluoroscopy: the live beam fires in short pulses at a rate the learner chooses, and the
//! screen holds the last pulse's image in between.
//!
//! Modern C-arms expose live fluoroscopy in pulses (typically 4 to 30 per second) rather than
//! continuously; at a fixed charge per pulse the dose rate follows the pulse rate, which is why
//! lowering it is the first dose-reduction habit taught (Mahesh, "Fluoroscopy: patient radiation
//! exposure issues", RadioGraphics 21:1033-1045, 2001; NCRP Report 168, 2010, section 4). The
//! model here:
//! - the learner picks 4, 7.5, 15 or 30 pulses per second (`pulse_rate` command; default 7.5),
//!   logged and replayed like every other command;
//! - each pulse carries the charge of one video frame of continuous fluoroscopy at the set tube
//!   current (`ma / 30` mAs: 30 pulses per second is the continuous beam), so a live second books
//!   `pps / 30` of the continuous second's dose. Simulator choice: real units raise the current
//!   per pulse somewhat at low rates to keep the image quality; we keep it constant so the dose
//!   reduction a learner sees is the textbook proportional one;
//! - pulses fire on a fixed grid from the moment the pedal is pressed; a change while live
//!   (C-arm, technique, needle, marker, spreading contrast) is imaged by the pulse it falls in if
//!   that pulse has made no image yet, else by the next one, at the first logged moment inside it
//!   (a later command, or the client's `tick`s, which it sends at the pulse rate while live runs;
//!   the session host holds a tick that comes a little before such a pulse until the pulse, see
//!   [`TICK_HOLD_PERIOD_FRACTION`]).
//!   So live frames cost at most one render per pulse whatever the input rate, and between
//!   pulses nothing renders (last-image hold).
//!
//! Sessions recorded before pulsing existed have no pulse rate in their state: they keep the
//! continuous beam (every change imaged at once, the full current), so their replays are exact.

use serde::Deserialize;

use crate::session::command::{CommandError, ErrorCode, ModalityCommand};

/// The pulse rates a learner may choose, pulses per second (the usual settings of a mobile C-arm).
pub const PULSE_RATES_PPS: [f64; 4] = [4.0, 7.5, 15.0, 30.0];
/// The rate a new session starts with, pulses per second. Simulator choice: 7.5 pulses per
/// second is the common low-dose default for spine procedures (NCRP Report 168, 2010).
pub const DEFAULT_PULSE_RATE_PPS: f64 = 7.5;
/// Frames per second of continuous fluoroscopy (the video rate), whose one frame's charge a
/// pulse carries.
pub const CONTINUOUS_FRAMES_PER_S: f64 = 30.0;
/// The command kind that sets the rate.
pub const PULSE_RATE_KIND: &str = "pulse_rate";

/// The fields of a `pulse_rate` command.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PulseRate {
    /// Pulses per second: one of [`PULSE_RATES_PPS`].
    pps: f64,
}

/// The rate a `pulse_rate` command asks for, or its field-named error.
pub fn parse(command: &ModalityCommand) -> Result<f64, CommandError> {
    let PulseRate { pps } = command.parse()?;
    if PULSE_RATES_PPS.contains(&pps) {
        Ok(pps)
    } else {
        Err(CommandError::field(
            "command.pps",
            ErrorCode::OutOfRange,
            format!("{pps} pulses per second: choose 4, 7.5, 15 or 30"),
        ))
    }
}

/// The fraction of the continuous beam's charge a live second delivers at `pps` (1 for a
/// session without a pulse rate, which runs the continuous beam).
pub fn duty(pps: Option<f64>) -> f64 {
    pps.map_or(1.0, |p| p / CONTINUOUS_FRAMES_PER_S)
}

/// Whether a pulse may image a change at `now_ms`: live runs since `live_since_ms` with pulses on
/// a fixed grid from that moment (pulse `k` at `live_since_ms + k * 1000 / pps`), and the pulse
/// that `now_ms` falls in has not made an image yet (the last image, at `last_ms`, belongs to an
/// earlier pulse or an earlier run). Always true for the continuous beam.
pub fn pulse_due(pps: Option<f64>, live_since_ms: u64, last_ms: Option<u64>, now_ms: u64) -> bool {
    let Some(pps) = pps else {
        return true;
    };
    let pulse = |t: u64| (t.saturating_sub(live_since_ms) as f64 * pps / 1000.0).floor();
    match last_ms {
        Some(last) if last >= live_since_ms => pulse(now_ms) > pulse(last),
        _ => true,
    }
}

/// How early a `tick` may come for the pulse a waiting change is due at, as a fraction of the
/// pulse period: the session host holds such a tick until that pulse
/// ([`next_pulse_ms`]) instead of applying it a little before it. A client ticks at the pulse
/// rate on its own clock, in a phase that the network's delays set against the session's pulse
/// grid, so about half of its ticks used to land just before a pulse and image the change a
/// whole period later (the capacity bench's live poses at one learner: 166 ms from tick to
/// frame at p95; 43 ms with ticks held). Simulator choice: a quarter period
/// (33 ms at 7.5 pulses per second, 8 ms at 30) absorbs a network's jitter and keeps a tick
/// that means an earlier moment from waiting long.
pub const TICK_HOLD_PERIOD_FRACTION: f64 = 0.25;

/// The first moment (ms) at which [`pulse_due`] holds for a change waiting in a live run since
/// `live_since_ms` whose last image was made at `last_ms`; `None` for the continuous beam,
/// whose changes never wait.
pub fn next_pulse_ms(pps: Option<f64>, live_since_ms: u64, last_ms: Option<u64>) -> Option<u64> {
    let pps = pps?;
    let Some(last) = last_ms.filter(|&l| l >= live_since_ms) else {
        return Some(live_since_ms);
    };
    // The pulse after the last image's, from the grid's formula; then settled by `pulse_due`
    // itself, so that the two agree to the millisecond whatever the rounding.
    let pulse = ((last - live_since_ms) as f64 * pps / 1000.0).floor() + 1.0;
    let mut t = live_since_ms + (pulse * 1000.0 / pps).ceil() as u64;
    while t > last + 1 && pulse_due(Some(pps), live_since_ms, Some(last), t - 1) {
        t -= 1;
    }
    while !pulse_due(Some(pps), live_since_ms, Some(last), t) {
        t += 1;
    }
    Some(t)
}

#[cfg(test)]
mod tests {
    use super::{duty, next_pulse_ms, pulse_due};

    #[test]
    fn the_next_pulse_is_the_first_moment_a_waiting_change_is_due() {
        assert_eq!(next_pulse_ms(None, 1000, Some(1000)), None);
        // Before any image of the run (or with one from before it), at once.
        assert_eq!(next_pulse_ms(Some(7.5), 1000, None), Some(1000));
        assert_eq!(next_pulse_ms(Some(7.5), 1000, Some(990)), Some(1000));
        assert_eq!(next_pulse_ms(Some(7.5), 1000, Some(1000)), Some(1134));
        assert_eq!(next_pulse_ms(Some(7.5), 1000, Some(1140)), Some(1267));
        // Every rate, run start and last image: due then and not a millisecond before.
        for pps in super::PULSE_RATES_PPS {
            for since in [0u64, 7, 1000, 123_457] {
                for after in 0..400u64 {
                    let last = since + after;
                    let t = next_pulse_ms(Some(pps), since, Some(last)).unwrap();
                    assert!(t > last, "{pps} {since} {last}: {t}");
                    assert!(pulse_due(Some(pps), since, Some(last), t));
                    assert!(!pulse_due(Some(pps), since, Some(last), t - 1));
                }
            }
        }
    }

    #[test]
    fn the_duty_and_the_pulse_grid_follow_the_rate() {
        assert_eq!(duty(None), 1.0);
        assert_eq!(duty(Some(7.5)), 0.25);
        assert_eq!(duty(Some(30.0)), 1.0);
        // 7.5 pulses per second from a run started at 1000 ms: pulses at 1000, 1133.3, 1266.7.
        assert!(!pulse_due(Some(7.5), 1000, Some(1000), 1133));
        assert!(pulse_due(Some(7.5), 1000, Some(1000), 1134));
        assert!(!pulse_due(Some(7.5), 1000, Some(1140), 1266));
        assert!(pulse_due(Some(7.5), 1000, Some(1140), 1267));
        // An image from before the run (a shot) does not hold the first pulse back.
        assert!(pulse_due(Some(4.0), 1000, Some(990), 1000));
        assert!(pulse_due(Some(4.0), 1000, None, 1000));
        assert!(pulse_due(None, 1000, Some(1000), 1001));
    }
}
