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
//! Last, a live drag through a session host on the last of those phantoms: frames published,
//! CPU time and the time from each pulse's tick to its draft, for a quick and a slow drag.
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
    if let Some((name, region)) = regions.last() {
        live_drag(&ctx, name, region, if quick { 2.0 } else { 5.0 });
    }
}

/// Live fluoroscopy while the C-arm is dragged, through a session host (its thread drafts each
/// pulse's image of a moved C-arm, then refines it unless a move waits for the next pulse or
/// comes during the refinement, see `render_worker::interrupt`): a pose every 40 ms (a quick
/// drag) or 100 ms (a slow one), a tick per pulse at the default 7.5 pulses per second, on
/// `region` at the default station. Reports the frames published, the process's CPU time
/// (cores busy on average) and the time from each tick to the draft of its pulse.
fn live_drag(ctx: &render_worker::gpu::GpuContext, name: &str, region: &Arc<Region>, run_s: f64) {
    use render_worker::session::modalities::fluoro::{FluoroBackend, GpuFluoroBackend};
    use render_worker::session::{Backends, Command, Envelope, SessionConfig, SessionHost, ViewId};
    use std::time::Duration;
    let stations = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let file = sim_core::rubric::load_station_dir(&stations)
        .expect("stations")
        .into_iter()
        .find(|f| f.station.id == "l4-l5-left-facet")
        .expect("the default station");
    // Drafting for any region: sessions draft only regions of at least `DRAFT_MIN_TRIANGLES`
    // (the default phantom), and quick mode on a fresh clone has only the 3.5 mm one.
    let backend = Arc::new(GpuFluoroBackend::new(ctx.clone()).drafting_from(Some(0)));
    backend.prepare(region).expect("prepare");
    backend.wait_for_draft_scene(region).expect("draft scene");
    let mut backends = Backends::gpu(ctx.clone());
    backends.fluoro = backend;
    let host = SessionHost::with_regions(
        vec![(file.station, "bench".into())],
        vec![Arc::clone(region)],
        backends,
        2,
        SessionConfig::default(),
    );
    let rt = tokio::runtime::Runtime::new().expect("runtime");
    println!();
    let forced = region.scene.triangle_count()
        < render_worker::session::modalities::fluoro::draft::DRAFT_MIN_TRIANGLES;
    let note = if forced {
        " (drafted here; a session drafts only larger regions)"
    } else {
        ""
    };
    println!("Live drag through a session host, {name}{note}, {run_s} s per row:");
    println!();
    println!(
        "| pose every (ms) | drafts | full frames | cores busy | tick to draft p50 / p95 (ms) |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for pose_ms in [40u64, 100] {
        rt.block_on(async {
            let h = host.create("l4-l5-left-facet").await.expect("session");
            let mut seq = 0u64;
            let mut send = |command: Command| {
                seq += 1;
                let (tx, _) = tokio::sync::mpsc::unbounded_channel();
                h.send(Envelope { seq, command }, tx).expect("sent");
            };
            send(Command::Shot);
            tokio::time::sleep(Duration::from_millis(1500)).await;
            let mut frames = h.frames();
            frames.borrow_and_update();
            let (cpu0, t0) = (process_cpu_s(), Instant::now());
            send(Command::Live { on: true });
            let period = Duration::from_millis(133);
            let (mut next_tick, mut next_pose) = (t0 + period, t0 + Duration::from_millis(20));
            let (mut orbital, mut drafts, mut fulls, mut last) = (0.0, 0, 0, 0);
            let (mut waits, mut tick_at) = (Vec::new(), None);
            while t0.elapsed().as_secs_f64() < run_s {
                let now = Instant::now();
                if now >= next_tick {
                    send(Command::Tick);
                    tick_at = Some(now);
                    next_tick += period;
                }
                if now >= next_pose {
                    orbital += 0.4;
                    send(Command::CarmPose {
                        orbital_deg: orbital,
                        angular_deg: 0.0,
                        table_mm: [0.0; 3],
                    });
                    next_pose += Duration::from_millis(pose_ms);
                }
                let wake = next_tick.min(next_pose);
                if tokio::time::timeout_at(wake.into(), frames.changed())
                    .await
                    .is_ok()
                {
                    let f = frames
                        .borrow_and_update()
                        .get(&ViewId::FLUOROSCOPY)
                        .cloned();
                    if let Some(f) = f.filter(|f| f.frame_seq != last) {
                        last = f.frame_seq;
                        if f.draft {
                            drafts += 1;
                            if let Some(t) = tick_at.take() {
                                waits.push(t.elapsed().as_secs_f64() * 1e3);
                            }
                        } else {
                            fulls += 1;
                        }
                    }
                }
            }
            let cores = (process_cpu_s() - cpu0) / t0.elapsed().as_secs_f64();
            send(Command::Live { on: false });
            let (p50, p95) = if waits.is_empty() {
                (f64::NAN, f64::NAN)
            } else {
                (percentile(&waits, 50.0), percentile(&waits, 95.0))
            };
            println!("| {pose_ms} | {drafts} | {fulls} | {cores:.2} | {p50:.0} / {p95:.0} |");
            host.close(&h.info.id).expect("closed");
        });
    }
    host.shutdown();
}

/// This process's CPU time so far (user and system), seconds: `/proc/self/stat` fields 14 and
/// 15, in clock ticks of `USER_HZ` (100 on Linux).
fn process_cpu_s() -> f64 {
    std::fs::read_to_string("/proc/self/stat")
        .ok()
        .and_then(|s| {
            let rest = &s[s.rfind(')')? + 1..];
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some((f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?) / 100.0)
        })
        .unwrap_or(f64::NAN)
}
