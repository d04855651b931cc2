//! A station's first image: how long the first sessions of a region take to make their first
//! image (the prefetch a session thread runs before its first input, then the first shot), on
//! the default lumbar phantom with the server's renderer (the GPU renderer that keeps each
//! region's anatomy), with the region prepared beforehand (`FluoroBackend::prepare`, as the
//! server does after its start-up calibration) and without (the first session then makes the
//! anatomy and starts the draft scene). The goal: a new session's first frame within 300 ms of
//! its region being ready.
//!
//! `BENCH_QUICK=1` runs each case once instead of three times (CI).

#[allow(dead_code)]
mod common;

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Instant;

use render_worker::session::modalities::fluoro::{FluoroBackend, GpuFluoroBackend};
use render_worker::session::*;
use sim_core::anatomy::phantom;

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let runs = if quick { 1 } else { 3 };
    let Ok(ctx) = render_worker::session::devices::open_gpu() else {
        println!("No GPU adapter opened: the first image is the CPU reference's, nothing kept.");
        return;
    };
    let root = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("regions");
    let t = Instant::now();
    let region = Arc::new(
        render_worker::session::loader::load_region(&root, phantom::REGION_NAME, &mut |_| {})
            .expect("default lumbar phantom"),
    );
    let loaded_ms = ms(t);
    let station = common::station("l4-l5-left-facet", &region);
    println!(
        "## A station's first image (default lumbar phantom, {} triangles, loaded in {:.1} s; {})\n",
        region.scene.triangle_count(),
        loaded_ms / 1e3,
        ctx.summary.name
    );
    println!(
        "Each run: a new renderer that keeps its regions, then two sessions one after the other, \
         each its prefetch and its first shot.\n"
    );
    println!(
        "| region | run | prepare (ms) | session 1: prefetch / first shot (ms) | session 2: prefetch / first shot (ms) |"
    );
    println!("|---|---:|---:|---:|---:|");
    let views: BTreeSet<ViewId> = [ViewId::FLUOROSCOPY].into();
    for prepared in [false, true] {
        for run in 0..runs {
            let fluoro = Arc::new(GpuFluoroBackend::keeping_uploads(ctx.clone()));
            let prepare_ms = prepared.then(|| {
                let t = Instant::now();
                fluoro.prepare(&region).expect("prepare");
                ms(t)
            });
            let mut backends = Backends::gpu(ctx.clone());
            backends.fluoro = Arc::clone(&fluoro) as Arc<dyn FluoroBackend>;
            let mut cells = Vec::new();
            for _ in 0..2 {
                let mut s = Session::new(
                    SessionEnv::new(Arc::clone(&station), Arc::clone(&region), backends.clone()),
                    SessionConfig::default(),
                );
                let t = Instant::now();
                s.prefetch();
                let prefetch = ms(t);
                s.apply(
                    Envelope {
                        seq: 1,
                        command: Command::Shot,
                    },
                    100,
                )
                .expect("shot");
                let t = Instant::now();
                let frames = s.render_dirty(&views).expect("first image");
                assert!(!frames.is_empty(), "the shot gives an image");
                cells.push(format!("{prefetch:.0} / {:.0}", ms(t)));
            }
            // The draft scene a first session started, built before the next run (untimed).
            fluoro.finish_background_work();
            println!(
                "| {} | {} | {} | {} | {} |",
                if prepared { "prepared" } else { "not prepared" },
                run + 1,
                prepare_ms.map_or("-".into(), |v| format!("{v:.0}")),
                cells[0],
                cells[1]
            );
        }
    }
}
