//! Ultrasound in a session: the one-off cost of the session's prefetch before its first input
//! (painting the acoustic volume of the region's crop) and of its first scan, and the cost of
//! each probe move as the learner sees it: the command,
//! the B-mode frame (sim-core CPU reference through the session's backend) and its draft (shown
//! first, see `Sampling::draft`), square to the region's axes and rocked, and the placement
//! view, on the procedural phantom (meshed at 4 mm as in the tests, painted at 0.5 mm),
//! curvilinear probe at its default 100 mm depth and sampling.
//!
//! A last table drives a session host as a held key does (each oblique move sent once the last
//! one's first frame came): time to each move's first frame, and the full frames of poses
//! already left that were published (newer input stops them, see `render_worker::interrupt`).
//!
//! `BENCH_QUICK=1` runs 3 moves instead of 15 (CI; 12 held-key moves instead of 60).

#[allow(dead_code)]
mod common;

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Instant;

use glam::DVec3;
use render_worker::session::modalities::ultrasound::snap_to_skin;
use render_worker::session::*;
use sim_core::stats::median;

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let moves = if quick { 3 } else { 15 };
    let t0 = Instant::now();
    let region = common::phantom_region(4.0);
    let station = common::station("l4-l5-left-facet-ultrasound", &region);
    let target = DVec3::from_array(station.targets["left_l4_l5_facet_posterior_joint_line"]);
    println!(
        "Ultrasound session on the 4 mm phantom (ready in {:.1} s: built, or loaded from the tests' cache)\n",
        t0.elapsed().as_secs_f64()
    );
    let mut s = Session::new(
        SessionEnv::new(Arc::clone(&station), Arc::clone(&region), Backends::cpu(0)),
        SessionConfig::default(),
    );
    let skin = snap_to_skin(
        &region,
        DVec3::new(target.x, target.y - 30.0, target.z),
        DVec3::Y,
    )
    .map(|(p, _)| p)
    .unwrap_or(target);
    // What a session thread does before its first input: paint the acoustic volume.
    let t = Instant::now();
    s.prefetch();
    let prefetch_s = t.elapsed().as_secs_f64();
    let mut seq = 0u64;
    let mut apply = |s: &mut Session, c: Command| {
        seq += 1;
        s.apply(Envelope { seq, command: c }, seq * 10)
            .expect("command accepted")
    };
    apply(
        &mut s,
        Command::ProbePose {
            position_mm: (skin - DVec3::Y * 5.0).to_array(),
            beam_dir: [0.0, 1.0, 0.0],
            marker_dir: [1.0, 0.0, 0.0],
        },
    );
    let us: BTreeSet<ViewId> = [ViewId::ULTRASOUND].into();
    let pl: BTreeSet<ViewId> = [ViewId::PLACEMENT].into();
    let t = Instant::now();
    let first = s.render_dirty(&us).expect("render");
    let first_s = t.elapsed().as_secs_f64();
    let img = &first[0].image;
    let t = Instant::now();
    s.render_dirty(&pl).expect("render");
    let first_pl_s = t.elapsed().as_secs_f64();
    let (mut cmd, mut bmode, mut place, mut drafts) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let (mut oblique, mut oblique_drafts) = (Vec::new(), Vec::new());
    // Slides square to the region's axes (the probe as placed), then the same slides with the
    // probe rocked and turned (oblique to the scatter lattice, as a learner holds it).
    for k in 0..2 * moves {
        let turn = if k == moves { 1.0 } else { 0.0 };
        let t = Instant::now();
        apply(
            &mut s,
            Command::ProbeMove {
                slide_mm: [if k % 2 == 0 { 1.0 } else { -1.0 }, 0.0],
                tilt_deg: [4.0 * turn, -3.0 * turn],
                rotate_deg: 7.0 * turn,
            },
        );
        cmd.push(t.elapsed().as_secs_f64());
        // What a live session does: the draft at once, then the full frame.
        let t = Instant::now();
        let d = s.render_drafts(&us).expect("render");
        assert_eq!(d.len(), 1, "the CPU reference drafts each image");
        let draft_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        s.render_dirty(&us).expect("render");
        let full_s = t.elapsed().as_secs_f64();
        if k < moves {
            bmode.push(full_s);
            drafts.push(draft_s);
        } else {
            oblique.push(full_s);
            oblique_drafts.push(draft_s);
        }
        let t = Instant::now();
        s.render_dirty(&pl).expect("render");
        place.push(t.elapsed().as_secs_f64());
    }
    let median_ms = |v: &[f64]| 1e3 * median(v);
    println!("| step | time (ms) |");
    println!("|---|---:|");
    println!(
        "| session prefetch before the first input (paints the acoustic volume) | {:.0} |",
        prefetch_s * 1e3
    );
    println!("| first B-mode frame after it | {:.0} |", first_s * 1e3);
    println!(
        "| first placement frame incl. the skin buffer | {:.0} |",
        first_pl_s * 1e3
    );
    println!(
        "| probe_move command (skin snap), median | {:.2} |",
        median_ms(&cmd)
    );
    println!(
        "| B-mode frame {} x {} px, median of {moves} | {:.0} |",
        img.width,
        img.height,
        median_ms(&bmode)
    );
    println!(
        "| its draft (shown first), median of {moves} | {:.0} |",
        median_ms(&drafts)
    );
    println!(
        "| B-mode frame, probe rocked 4 and 3 degrees and turned 7, median of {moves} | {:.0} |",
        median_ms(&oblique)
    );
    println!(
        "| its draft (shown first), median of {moves} | {:.0} |",
        median_ms(&oblique_drafts)
    );
    println!(
        "| placement frame, median of {} | {:.1} |",
        2 * moves,
        median_ms(&place)
    );
    held_keys(&region, &station, skin, 4 * moves);
}

/// Probe moves as a held key sends them, through a session host (its thread draws a draft of
/// each move, then the full frame unless newer input stops it): each move sent as soon as the
/// previous one's first frame has come, the probe rocked and turned (oblique to the scatter
/// lattice). Reports the time from each move to its first frame, and how many full frames of
/// poses already left were published (each one a wait for the move after it).
fn held_keys(region: &Arc<Region>, station: &Arc<StationContext>, skin: DVec3, moves: usize) {
    let host = SessionHost::with_regions(
        vec![(station.station.clone(), "bench".into())],
        vec![Arc::clone(region)],
        Backends::cpu(0),
        2,
        SessionConfig::default(),
    );
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    let (latency, left) = rt.block_on(async {
        let h = host.create(&station.station.id).await.expect("session");
        h.set_visible([ViewId::ULTRASOUND].into());
        let mut frames = h.frames();
        let mut seq = 1;
        let mut until = async |seq: u64, full: bool, left: &mut usize| loop {
            frames.changed().await.expect("session alive");
            let f = frames.borrow_and_update()[&ViewId::ULTRASOUND].clone();
            if f.input_seq < seq && !f.draft && f.input_seq > 1 {
                *left += 1;
            }
            if f.input_seq == seq && (!full || !f.draft) {
                return;
            }
        };
        let mut left = 0;
        h.command(Envelope {
            seq,
            command: Command::ProbePose {
                position_mm: (skin - DVec3::Y * 5.0).to_array(),
                beam_dir: [0.0, 1.0, 0.0],
                marker_dir: [1.0, 0.0, 0.0],
            },
        })
        .await
        .expect("pose");
        until(seq, true, &mut left).await;
        let mut latency = Vec::new();
        for k in 0..moves {
            seq += 1;
            let t = Instant::now();
            h.command(Envelope {
                seq,
                command: Command::ProbeMove {
                    slide_mm: [if k % 2 == 0 { 0.5 } else { -0.5 }, 0.0],
                    tilt_deg: [
                        if k == 0 { 4.0 } else { 0.3 },
                        if k == 0 { -3.0 } else { 0.2 },
                    ],
                    rotate_deg: if k == 0 { 7.0 } else { 0.5 },
                },
            })
            .await
            .expect("move");
            until(seq, false, &mut left).await;
            latency.push(t.elapsed().as_secs_f64() * 1e3);
        }
        until(seq, true, &mut left).await;
        (latency, left)
    });
    host.shutdown();
    let mut sorted = latency.clone();
    sorted.sort_by(f64::total_cmp);
    let at =
        |q: f64| sorted[((q * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1)];
    println!();
    println!(
        "Held key, {moves} oblique probe moves through a session host, each sent once the last one's first frame came:"
    );
    println!();
    println!(
        "| move to its first frame, p50 / p95 / max (ms) | full frames of poses already left |"
    );
    println!("|---:|---:|");
    println!(
        "| {:.0} / {:.0} / {:.0} | {left} of {} |",
        at(0.5),
        at(0.95),
        sorted[sorted.len() - 1],
        moves - 1
    );
}
