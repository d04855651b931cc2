//! Needle handling in a session: what each hand command costs as the learner sees it (command
//! and acknowledgement, no rendering), on the procedural phantom meshed at 2 mm (as in the
//! needle-handling tests), along a paramedian L4-L5 epidural line: 1 mm feeds through muscle and
//! ligament (insertion force sampled every 0.5 mm from the tissue at the tip, the shaft's
//! friction from the tissue along it), 0.5 mm feeds with the plunger held, hub tilts, withdrawals,
//! aspiration. Against error: the depth at which the plunger gives way minus the depth at which
//! the outlet reaches the epidural fat on the same line (found by a 0.01 mm march), which the
//! 0.5 mm feed step bounds.
//!
//! `BENCH_QUICK=1` repeats the epidural 2 times instead of 8 (CI).

#[allow(dead_code)]
mod common;

use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use render_worker::session::*;
use sim_core::needle::Tissue;
use sim_core::stats::median;

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let repeats = if quick { 2 } else { 8 };
    let t0 = Instant::now();
    let region = common::phantom_region(2.0);
    let station = common::station("l4-l5-interlaminar-epidural", &region);
    println!(
        "Needle handling on the 2 mm phantom (ready in {:.1} s: built, or loaded from the tests' cache)\n",
        t0.elapsed().as_secs_f64()
    );
    // The line of the session tests' scripted epidural.
    let target = DVec3::new(-10.0, -39.0, -54.0);
    let far = target + DVec3::new(-30.0, -120.0, 0.0);
    let dirn = (target - far).normalize();
    let skin = region.skin_entry(far, dirn, 200.0).expect("skin");
    let setback = {
        let o = sim_core::needle::InstrumentProfile::tuohy_18g().opening;
        o.distal_edge_from_tip_mm + 0.5 * o.length_mm
    };
    let mut s_mm = 0.0;
    while region.tissue_at((skin + dirn * s_mm).to_array()) != Tissue::EpiduralFat {
        s_mm += 0.01;
    }
    let boundary = s_mm + setback;
    let (mut feed1, mut feed05, mut tilt, mut withdraw, mut asp, mut err) =
        (vec![], vec![], vec![], vec![], vec![], vec![]);
    for _ in 0..repeats {
        let mut s = Session::new(
            SessionEnv::new(Arc::clone(&station), Arc::clone(&region), Backends::cpu(1)),
            SessionConfig::default(),
        );
        let mut seq = 0u64;
        let mut apply = |s: &mut Session, c: Command| {
            seq += 1;
            s.apply(Envelope { seq, command: c }, seq * 10)
                .expect("command accepted")
        };
        let timed = |s: &mut Session, apply: &mut dyn FnMut(&mut Session, Command) -> Ack, c| {
            let t = Instant::now();
            let a = apply(s, c);
            (t.elapsed().as_secs_f64() * 1e3, a)
        };
        apply(
            &mut s,
            Command::NeedlePlace {
                instrument: "tuohy-20g-89".into(),
                entry_mm: skin.to_array(),
                direction: dirn.to_array(),
                bevel_reference: [0.0, 0.0, 1.0],
            },
        );
        let outlet = |s: &Session| {
            let n = s.world().needle.as_ref().expect("needle");
            region.tissue_at(n.state.outlet().centre_mm.to_array())
        };
        while outlet(&s) != Tissue::InterspinousLigament {
            feed1.push(timed(&mut s, &mut apply, Command::NeedleFeed { mm: 1.0 }).0);
        }
        for deg in [1.0, -1.0] {
            tilt.push(
                timed(
                    &mut s,
                    &mut apply,
                    Command::NeedleTilt {
                        cc_deg: 0.0,
                        ml_deg: deg,
                    },
                )
                .0,
            );
            withdraw.push(timed(&mut s, &mut apply, Command::NeedleWithdraw { mm: 0.0 }).0);
        }
        apply(
            &mut s,
            Command::Syringe {
                action: SyringeAction::Attach,
                medium: None,
            },
        );
        apply(&mut s, Command::PlungerHold { on: true });
        loop {
            let (ms, a) = timed(&mut s, &mut apply, Command::NeedleFeed { mm: 0.5 });
            feed05.push(ms);
            if a.outcome["lor"]["gave_way"] == true {
                let depth = a.outcome["depth_mm"].as_f64().expect("depth");
                err.push(depth - boundary);
                break;
            }
        }
        asp.push(timed(&mut s, &mut apply, Command::Aspirate).0);
    }
    println!("| command | median ms |");
    println!("|---|---:|");
    println!("| needle_feed 1 mm (force) | {:.3} |", median(&feed1));
    println!(
        "| needle_feed 0.5 mm (force + held plunger) | {:.3} |",
        median(&feed05)
    );
    println!(
        "| needle_tilt (after a 1 degree turn's branch) | {:.3} |",
        median(&tilt)
    );
    println!("| needle_withdraw 0 mm | {:.3} |", median(&withdraw));
    println!("| aspirate | {:.3} |", median(&asp));
    let worst = err.iter().fold(0.0f64, |a, e| a.max(e.abs()));
    println!(
        "\nloss of resistance: given way {:.3} mm past the epidural boundary (worst of {}; the \
         feed step bounds it at 0.5 mm)",
        worst,
        err.len()
    );
}
