//! Progressive fluoroscopy frames: what the draft shown at once after a C-arm move costs and how
//! far it is from the full frame that follows.
//!
//! Per lumbar phantom (the procedural one at 3.5 mm voxels, from the tests' cache or built on
//! first use, and the default 1.5 mm one that sessions use, from the assets folder) it prints the triangles of the scene and of its
//! draft scene (`sim_core::fluoro::draft`) with the draft's build time, then per image size the
//! C-arm-moved frame (a new orbital angle every frame, 80 kVp, quantum noise) rendered in full
//! (2 x 2 supersampling at the needle's edges, as sessions render) and as a draft
//! (`render_worker::fluoro::draft`: draft scene, half resolution, one sample, doubled), mean
//! wall time after a warm-up frame; and the error of the draft against the full frame without
//! noise: mean and 99th percentile of the absolute difference of 8 x 8 pixel block means, in grey
//! levels (what a learner sees of a preview; pixel-level detail is what the full frame adds).
//!
//! `BENCH_QUICK=1`: 3 frames per row, 512 x 512 only, and the default phantom only if its
//! assets are already built (its first build takes over a minute). Without it: 8 frames, 512 and
//! 1024, the default phantom built if needed.

#[allow(dead_code)]
mod common;

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use render_worker::fluoro::GpuFluoroRenderer;
use render_worker::fluoro::draft::render_draft_frame;
use render_worker::session::Region;
use render_worker::session::loader::load_region;
use sim_core::anatomy::phantom;
use sim_core::compare::block_mean_diffs;
use sim_core::fluoro::draft::{DraftParams, draft_scene};
use sim_core::fluoro::{EnergyModel, Projection, QuantumNoise, RenderSettings};
use sim_core::stats::percentile;

fn view(n: u32, k: usize) -> Projection {
    // Around AP at L4, a 300 mm flat panel; each frame turned 4 degrees further.
    Projection {
        orbital_deg: -10.0 + 4.0 * k as f64,
        isocentre_mm: [0.0, 0.0, -40.0],
        detector_pixels: [n, n],
        pixel_pitch_mm: [300.0 / f64::from(n); 2],
        ..Projection::default()
    }
}

fn settings(noise: bool) -> RenderSettings {
    RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 2,
        adaptive: true,
        noise: noise.then_some(QuantumNoise {
            photons_per_pixel: 3000.0,
            seed: 11,
        }),
        ..RenderSettings::default()
    }
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let Some(ctx) = common::gpu_or_skip() else {
        return;
    };
    let frames = if quick { 3 } else { 8 };
    let sizes: &[u32] = if quick { &[512] } else { &[512, 1024] };
    println!(
        "Progressive fluoroscopy frames (C-arm moved), adapter: {} ({})",
        ctx.summary.name, ctx.summary.backend
    );
    // The 3.5 mm phantom from the tests' cache (built on first use), then the default one.
    let mut regions: Vec<(String, Arc<Region>)> =
        vec![("3.5 mm phantom".into(), common::phantom_region(3.5))];
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
    if !quick
        || assets
            .join(phantom::REGION_NAME)
            .join("provenance.json")
            .exists()
    {
        match load_region(&assets, phantom::REGION_NAME, &mut |_| {}) {
            Ok(r) => regions.push(("default 1.5 mm phantom".into(), Arc::new(r))),
            Err(e) => println!("default phantom not loaded: {e}"),
        }
    } else {
        println!("default phantom not built yet: its rows are skipped in quick mode");
    }
    println!();
    println!(
        "| scene | triangles | draft triangles | draft build (s) | image | full frame (ms) | draft (ms) | draft err, mean / p99 of 8x8 block means (grey levels) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for (name, region) in &regions {
        let scene = &region.scene;
        let t = Instant::now();
        let draft = draft_scene(scene, &DraftParams::default());
        let build_s = t.elapsed().as_secs_f64();
        let mut full_r = GpuFluoroRenderer::new(&ctx, scene).expect("upload");
        let mut draft_r = GpuFluoroRenderer::new(&ctx, &draft).expect("upload draft");
        for &n in sizes {
            let mut full_ms = 0.0;
            let mut draft_ms = 0.0;
            // Warm-up (targets, spectral table), then C-arm-moved frames.
            let _ = full_r.render_frame(&view(n, 0), &settings(true), None);
            let _ = render_draft_frame(&mut draft_r, &view(n, 0), &settings(true), None);
            for k in 1..=frames {
                let t = Instant::now();
                let _ = full_r
                    .render_frame(&view(n, k), &settings(true), None)
                    .expect("frame");
                full_ms += t.elapsed().as_secs_f64() * 1e3;
                let t = Instant::now();
                let _ = render_draft_frame(&mut draft_r, &view(n, k), &settings(true), None)
                    .expect("draft");
                draft_ms += t.elapsed().as_secs_f64() * 1e3;
            }
            let p = view(n, frames + 1);
            let full = full_r
                .render_frame(&p, &settings(false), None)
                .expect("frame");
            let d = render_draft_frame(&mut draft_r, &p, &settings(false), None).expect("draft");
            let diffs = block_mean_diffs(&d.pixels, &full.pixels, d.width as usize, 8);
            let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
            let p99 = percentile(&diffs, 99.0);
            println!(
                "| {name} | {} | {} | {build_s:.1} | {n} | {:.1} | {:.1} | {mean:.2} / {p99:.2} |",
                scene.triangle_count(),
                draft.triangle_count(),
                full_ms / frames as f64,
                draft_ms / frames as f64,
            );
        }
    }
}
