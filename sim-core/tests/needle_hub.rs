//! Hub tilt, partial withdrawal and redirection: the transmitted tip turn, branching
//! from the old channel, the deviation limit, the redirection count on scripted paths, a soak of
//! random commands and bit-identical replay.

use glam::DVec3;
use sim_core::needle::hub::{MAX_HUB_DEVIATION_DEG, tip_turn_fraction};
use sim_core::needle::{
    CommandOutcome, InitialResponse, InstrumentProfile, Needle, NeedleCommand, NeedleError,
    NeedleState, NoBone, SegmentKind, SphereBone,
};
use sim_core::rng::SplitMix64;

/// A rigid 18 G Tuohy at the origin travelling along +z, bevel towards +x.
fn tuohy() -> Needle {
    Needle::new(
        NeedleState::new(
            InstrumentProfile::tuohy_18g(),
            DVec3::ZERO,
            DVec3::Z,
            DVec3::X,
            0.5,
            InitialResponse::Relaxed,
        )
        .unwrap(),
    )
}

fn feed(mm: f64) -> NeedleCommand {
    NeedleCommand::Feed { mm }
}

fn withdraw(mm: f64) -> NeedleCommand {
    NeedleCommand::Withdraw { mm }
}

/// Tilt towards +y (negative: towards -y).
fn tilt_y(deg: f64) -> NeedleCommand {
    NeedleCommand::Tilt {
        toward: DVec3::Y * deg.signum(),
        deg: deg.abs(),
    }
}

fn angle_deg(a: DVec3, b: DVec3) -> f64 {
    a.normalize()
        .dot(b.normalize())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

#[test]
fn tilt_before_the_skin_reaims_the_whole_needle() {
    let mut n = tuohy();
    n.apply_free(tilt_y(10.0)).unwrap();
    n.apply_free(feed(20.0)).unwrap();
    // Rigid needle, nothing buried at the tilt: the path runs 10 degrees off +z towards +y.
    let tip = n.state.tip_mm();
    assert!((angle_deg(tip, DVec3::Z) - 10.0).abs() < 1e-9, "{tip}");
    assert!((tip.length() - 20.0).abs() < 1e-9);
    assert!(angle_deg(n.state.hub_direction(), tip) < 1e-9);
}

#[test]
fn a_buried_tilt_turns_the_tip_by_the_transmitted_fraction_and_branches() {
    let mut n = tuohy();
    n.apply_free(feed(40.0)).unwrap();
    n.apply_free(withdraw(10.0)).unwrap();
    let at = n.state.tip_mm();
    let CommandOutcome::Tilt(t) = n.apply_free(tilt_y(10.0)).unwrap() else {
        panic!("not a tilt outcome");
    };
    let expected = 10.0 * tip_turn_fraction(n.state.profile.outer_diameter_mm, 30.0);
    assert!((t.tip_turn_deg - expected).abs() < 1e-9, "{t:?}");
    assert!((t.hub_deviation_deg - 10.0).abs() < 1e-9);
    assert!(t.branched, "10 mm of channel lay ahead of the tip");
    // The tip has not moved; the channel ahead is gone and a turn segment starts the branch.
    assert_eq!(n.state.tip_mm(), at);
    assert!((n.state.tract.length_mm() - 30.0).abs() < 1e-9);
    assert_eq!(
        n.state.tract.segments.last().unwrap().kind,
        SegmentKind::Turn
    );
    n.apply_free(feed(10.0)).unwrap();
    let new_dir = n.state.tip_mm() - at;
    assert!((angle_deg(new_dir, DVec3::Z) - expected).abs() < 1e-6);
    assert!(new_dir.y > 0.0);
    assert_eq!(n.state.redirections, 1);
    // Withdrawing behind the branch point and re-advancing retraces the new branch exactly.
    let end = n.state.tip_mm();
    n.apply_free(withdraw(15.0)).unwrap();
    n.apply_free(feed(15.0)).unwrap();
    assert_eq!(n.state.tip_mm(), end);
    assert_eq!(n.state.redirections, 1);
}

#[test]
fn tilts_beyond_the_limit_are_refused_and_change_nothing() {
    let mut n = tuohy();
    n.apply_free(feed(20.0)).unwrap();
    for _ in 0..4 {
        n.apply_free(tilt_y(10.0)).unwrap();
    }
    let before = n.clone();
    let err = n.apply_free(tilt_y(10.0)).unwrap_err();
    assert!(
        matches!(err, NeedleError::TiltLimit { deviation_deg } if deviation_deg > MAX_HUB_DEVIATION_DEG)
    );
    assert_eq!(n, before, "a refused tilt is not logged and moves nothing");
    for bad in [
        NeedleCommand::Tilt {
            toward: n.state.hub_direction() * 3.0,
            deg: 5.0,
        },
        NeedleCommand::Tilt {
            toward: DVec3::new(f64::NAN, 0.0, 0.0),
            deg: 5.0,
        },
        NeedleCommand::Tilt {
            toward: DVec3::X,
            deg: -1.0,
        },
        NeedleCommand::Tilt {
            toward: DVec3::ZERO,
            deg: 1.0,
        },
    ] {
        assert!(n.apply_free(bad).is_err(), "{bad:?}");
    }
    assert_eq!(n, before);
}

/// Scripted paths with the redirection count a physician would give.
#[test]
fn redirection_counter_matches_scripted_reference_counts() {
    let roll = |deg| NeedleCommand::Roll { deg };
    let cases: Vec<(&str, Vec<NeedleCommand>, u32)> = vec![
        ("straight in", vec![feed(30.0), feed(10.0)], 0),
        (
            "withdraw and readvance along the same channel",
            vec![feed(30.0), withdraw(10.0), feed(15.0)],
            0,
        ),
        (
            "steer at the channel end",
            vec![feed(20.0), tilt_y(5.0), feed(10.0)],
            0,
        ),
        (
            "small back-off and re-aim (an adjustment)",
            vec![feed(20.0), withdraw(1.0), tilt_y(5.0), feed(5.0)],
            0,
        ),
        (
            "withdraw, re-aim, advance",
            vec![feed(30.0), withdraw(10.0), tilt_y(5.0), feed(10.0)],
            1,
        ),
        (
            "two redirections",
            vec![
                feed(30.0),
                withdraw(10.0),
                tilt_y(5.0),
                feed(10.0),
                withdraw(8.0),
                tilt_y(-8.0),
                feed(12.0),
            ],
            2,
        ),
        (
            "re-aim but withdraw again before advancing",
            vec![feed(30.0), withdraw(10.0), tilt_y(5.0), withdraw(5.0)],
            0,
        ),
        (
            "a rigid straight needle's bevel turned behind the channel end, then advanced (the \
             same line: not a redirection)",
            vec![
                feed(30.0),
                withdraw(10.0),
                roll(180.0),
                roll(180.0),
                feed(12.0),
            ],
            0,
        ),
        (
            "withdraw to the skin, re-aim, advance",
            vec![feed(25.0), withdraw(25.0), tilt_y(10.0), feed(20.0)],
            1,
        ),
    ];
    for (name, script, expected) in cases {
        let mut n = tuohy();
        for c in &script {
            n.apply_free(*c).unwrap();
        }
        assert_eq!(n.state.redirections, expected, "{name}");
    }
}

/// A bevel-steered needle re-advanced after a bevel turn behind its channel's end leaves the
/// old path: one redirection.
#[test]
fn a_bevel_turn_of_a_steerable_needle_behind_the_channel_end_is_a_redirection() {
    let mut n = Needle::new(
        NeedleState::new(
            InstrumentProfile::flexible_prebent(),
            DVec3::ZERO,
            DVec3::Z,
            DVec3::X,
            0.5,
            InitialResponse::Settled,
        )
        .unwrap(),
    );
    for c in [
        feed(30.0),
        withdraw(10.0),
        NeedleCommand::Roll { deg: 180.0 },
        NeedleCommand::Roll { deg: 180.0 },
        feed(12.0),
    ] {
        n.apply_free(c).unwrap();
    }
    assert_eq!(n.state.redirections, 1);
}

/// The tip always lies on its recorded channel, the channel is continuous, and nothing is
/// non-finite, over 10^5 random feeds, withdrawals, rolls and tilts against a bone sphere.
#[test]
fn soak_of_random_hub_commands_keeps_the_tip_on_its_channel() {
    let bone = SphereBone {
        centre_mm: DVec3::new(4.0, 0.0, 60.0),
        radius_mm: 12.0,
    };
    let mut rng = SplitMix64::new(19);
    let mut n = tuohy();
    let mut refused = 0;
    for i in 0..100_000 {
        let u = rng.next_f64();
        let cmd = if u < 0.35 {
            feed(rng.next_f64() * 4.0)
        } else if u < 0.6 {
            withdraw(rng.next_f64() * 6.0)
        } else if u < 0.75 {
            NeedleCommand::Roll {
                deg: rng.next_f64() * 360.0 - 180.0,
            }
        } else {
            let a = rng.next_f64() * std::f64::consts::TAU;
            NeedleCommand::Tilt {
                toward: DVec3::new(a.cos(), a.sin(), 0.0),
                deg: rng.next_f64() * 8.0,
            }
        };
        if n.apply(cmd, &bone).is_err() {
            refused += 1;
        }
        let s = &n.state;
        let tip = s.tip_mm();
        assert!(
            tip.is_finite() && s.pose.orientation.is_finite(),
            "step {i}"
        );
        assert!(s.buried_mm() >= 0.0 && s.buried_mm() <= s.profile.shaft_length_mm + 1e-9);
        // The tip is where the cursor says on the channel.
        if let Some(seg) = s.tract.segments.get(s.cursor.segment) {
            let on = seg.pose_at(s.cursor.offset_mm).position_mm;
            assert!(on.distance(tip) < 1e-9, "step {i}: tip off its channel");
        }
        // Consecutive segments join.
        for w in s.tract.segments.windows(2) {
            let gap = w[0].end_pose().position_mm.distance(w[1].start.position_mm);
            assert!(gap < 1e-9, "step {i}: channel broken by {gap} mm");
        }
        assert!(
            angle_deg(s.hub_direction(), s.puncture_direction()) <= MAX_HUB_DEVIATION_DEG + 1e-9
        );
        // Withdrawals keep the channel short enough to inspect every step.
        if s.tract.segments.len() > 400 {
            n.apply_free(withdraw(200.0)).unwrap();
            n.state.tract.truncate_at(n.state.cursor);
        }
    }
    assert!(refused > 0, "the soak reached the deviation limit");
    assert!(n.state.redirections > 0);
}

#[test]
fn tilt_logs_replay_bit_identically() {
    let bone = SphereBone {
        centre_mm: DVec3::new(0.0, 3.0, 45.0),
        radius_mm: 8.0,
    };
    let mut rng = SplitMix64::new(7);
    let mut n = tuohy();
    for _ in 0..2000 {
        let cmd = match rng.next_u64() % 4 {
            0 => feed(rng.next_f64() * 3.0),
            1 => withdraw(rng.next_f64() * 4.0),
            2 => NeedleCommand::Roll {
                deg: rng.next_f64() * 90.0,
            },
            _ => NeedleCommand::Tilt {
                toward: DVec3::new(rng.next_f64() - 0.5, rng.next_f64() - 0.5, 0.0),
                deg: rng.next_f64() * 6.0,
            },
        };
        let _ = n.apply(cmd, &bone);
    }
    let again = Needle::replay(n.initial.clone(), &n.log, &bone).unwrap();
    assert_eq!(again, n);
    let json = serde_json::to_string(&n).unwrap();
    let back: Needle = serde_json::from_str(&json).unwrap();
    assert_eq!(back, n);
    let _ = NoBone;
}
