//! Needle kinematics: substep size against tip error and time per 100 mm insertion.
//!
//! Scenario (the same as the convergence test, extended to 100 mm): a flexible pre-bent needle
//! enters relaxed, is fed 20 mm, rolled 180 degrees at the hub, and fed on to 100 mm. The error
//! is the tip distance to a 1/256 mm-substep reference. Time is the median over repetitions of
//! the whole 100 mm insertion, without bone and with a bone mesh (a 1280-triangle icosphere,
//! queried every substep through the BVH but never touched).
//!
//! `BENCH_QUICK=1` runs fewer repetitions (CI).

use std::hint::black_box;

use glam::DVec3;
use sim_core::geom::Bvh;
use sim_core::mesh::TriMesh;
use sim_core::needle::{BoneSurface, InitialResponse, InstrumentProfile, NeedleState, NoBone};
use sim_core::stats::Timing;

fn insert_100mm(substep_mm: f64, bone: &dyn BoneSurface) -> DVec3 {
    let mut st = NeedleState::new(
        InstrumentProfile::flexible_prebent(),
        DVec3::ZERO,
        DVec3::Z,
        DVec3::X,
        substep_mm,
        InitialResponse::Relaxed,
    )
    .expect("valid needle");
    st.feed(20.0, bone);
    st.roll(180.0);
    st.feed(80.0, bone);
    st.tip_mm()
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let reps = if quick { 5 } else { 31 };
    // Bone off to the side of the path: every substep pays for a BVH query.
    let bone = Bvh::new(&TriMesh::icosphere([40.0, 0.0, 50.0], 10.0, 3));
    let reference = insert_100mm(1.0 / 256.0, &NoBone);
    println!(
        "Needle: 100 mm insertion with a 180 degree roll at 20 mm ({reps} repetitions, median)"
    );
    println!();
    println!(
        "| substep (mm) | substeps | tip error (mm) | time, no bone (us) | time, BVH bone (us) |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for h in [8.0, 4.0, 2.0, 1.0, 0.5, 0.25, 0.1] {
        let tip = insert_100mm(h, &NoBone);
        assert_eq!(
            tip,
            insert_100mm(h, &bone),
            "the untouched bone must not change the path"
        );
        let err = tip.distance(reference);
        let t_free = Timing::run(reps, || {
            black_box(insert_100mm(black_box(h), &NoBone));
        })
        .median_s();
        let t_bone = Timing::run(reps, || {
            black_box(insert_100mm(black_box(h), &bone));
        })
        .median_s();
        let steps = (20.0 / h).ceil() + (80.0 / h).ceil();
        println!(
            "| {h} | {steps} | {err:.3e} | {:.1} | {:.1} |",
            t_free * 1e6,
            t_bone * 1e6
        );
    }
}
