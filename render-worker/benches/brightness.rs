//! Automatic brightness control on the lumbar phantom: what it costs a frame and where it
//! drives the technique.
//!
//! Per view (AP, 25 degree oblique, lateral) of the phantom at the L4 body centre:
//! - the metering of a new view (the central disc's rays through the scene, what a C-arm move
//!   adds to the next frame) and one controller step (what every frame adds; a needle step or a
//!   new shot at the same pose reuses the metering), median of the runs;
//! - per curve, with the anti-scatter grid in (a new session's default; the standard curve
//!   also with it out), the technique the loop settles on from 80 kVp / 2 mA metering the
//!   total signal behind the grid as sessions do (the primary times
//!   `Metering::scatter_factor`: the view's air gap and the scatter-to-primary ratio of its
//!   water-equivalent thickness over the open field are columns), the frames it takes to
//!   come within 5 % of the target, the skin entrance rate at 7.5 pulses per second, and the
//!   detected quanta of an unattenuated 512^2 and 1024^2 pixel per pulse at that technique (the
//!   noise the frame gets).
//!
//! Last, the dose of a fluoroscopy-guided L4 transforaminal injection at the published median
//! fluoroscopy time of that procedure (Y. Kim et al., 2014: 29 s and 0.68 Gy cm^2 median KAP for
//! lumbar transforaminal epidural steroid injections), the time spent a third each in the AP,
//! oblique and lateral views at the standard curve's settled technique, 7.5 pulses per second,
//! the open 300 mm field: incident air kerma at the skin entrance and KAP, and the KAP's
//! difference from the median.
//!
//! And the temporal chain's cost per live frame (detector lag and the strongest recursive filter
//! over a full history of 6 raw frames, integer weights) at 512^2 and 1024^2.
//!
//! `BENCH_QUICK=1`: the 3.5 mm phantom (cached where the other benches cache it) and 5 runs;
//! otherwise the 1.5 mm phantom that sessions use and 21 runs.

#[allow(dead_code)]
mod common;

use std::time::Instant;

use render_worker::session::modalities::fluoro::dose::source_to_skin_mm;
use render_worker::session::modalities::fluoro::scatter::{ScatterState, metering_factor};
use sim_core::fluoro::Projection;
use sim_core::fluoro::brightness::{
    BrightnessCurve, FrameExposure, METERING_RAYS_ACROSS, Technique, TubeLimits, meter,
    next_technique, skin_kerma_rate_mgy_per_min,
};
use sim_core::fluoro::detector::{FLAT_PANEL_DQE, detected_quanta_per_pixel};
use sim_core::fluoro::scatter::AntiScatterGrid;
use sim_core::fluoro::temporal::{
    FIRST_FRAME_LAG, FilterLevel, HISTORY_FRAMES, combine, weights_q16,
};
use sim_core::stats::Timing;

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let (voxel_mm, runs) = if quick { (3.5, 5) } else { (1.5, 21) };
    let t0 = Instant::now();
    let region = common::phantom_region(voxel_mm);
    println!(
        "Automatic brightness control, lumbar phantom at {voxel_mm} mm ({} triangles, ready in \
         {:.1} s), {} rays across the metering disc, 7.5 pulses per second",
        region.scene.triangle_count(),
        t0.elapsed().as_secs_f64(),
        METERING_RAYS_ACROSS
    );
    let iso = region.landmarks["L4_body_centre"];
    let limits = TubeLimits::default();
    // KAP and skin kerma per view at the standard curve's settled technique, for the last table.
    let mut tfesi: Vec<(&str, Technique, Projection)> = Vec::new();
    println!();
    println!(
        "| view | rays | metering a new view, ms | one step, us | curve | grid | air gap, mm | SPR | settles on | frames to 5 % | skin mGy/min | quanta per 512^2 px | per 1024^2 px |"
    );
    println!("|---|---:|---:|---:|---|---|---:|---:|---|---:|---:|---:|---:|");
    for (name, orbital) in [("AP", 0.0), ("oblique 25", 25.0), ("lateral", 90.0)] {
        let p = Projection {
            orbital_deg: orbital,
            isocentre_mm: iso,
            detector_pixels: [512, 512],
            pixel_pitch_mm: [300.0 / 512.0; 2],
            ..Projection::default()
        };
        let mut meter_s = Vec::new();
        let mut m = meter(&region.scene, &p, METERING_RAYS_ACROSS);
        for _ in 0..runs {
            let t = Instant::now();
            m = meter(&region.scene, &p, METERING_RAYS_ACROSS);
            meter_s.push(t.elapsed().as_secs_f64());
        }
        let e = FrameExposure {
            frame_s: 1.0 / 30.0,
            duty: 0.25,
            source_to_detector_mm: p.source_to_detector_mm(),
            source_to_skin_mm: source_to_skin_mm(&region, &p),
        };
        let runs_of_view = BrightnessCurve::ALL
            .into_iter()
            .map(|c| (c, true))
            .chain([(BrightnessCurve::Standard, false)]);
        for (curve, grid) in runs_of_view {
            let target = curve.target_ngy_per_frame();
            let mut t = Technique { kvp: 80, ma: 2.0 };
            let mut first_within = None;
            let mut step_s = Vec::new();
            let scatter = Some(ScatterState { grid });
            let mut spr = f64::NAN;
            for frame in 0..8 {
                let s0 = Instant::now();
                let factor = metering_factor(scatter, &m, t.kvp, &p);
                let k = m.detector_kerma_ngy(t, &e) * factor;
                let step = next_technique(curve, &limits, &e, t, k);
                step_s.push(s0.elapsed().as_secs_f64());
                if first_within.is_none() && (k / target - 1.0).abs() <= 0.05 {
                    first_within = Some(frame);
                }
                let primary = if grid {
                    AntiScatterGrid::FLUOROSCOPY.primary_transmission()
                } else {
                    1.0
                };
                spr = factor / primary - 1.0;
                t = step.technique;
            }
            if curve == BrightnessCurve::Standard && grid {
                tfesi.push((name, t, p));
            }
            let quanta = |side: f64| {
                let pitch = 300.0 / side;
                detected_quanta_per_pixel(
                    t.kvp,
                    t.ma / 30.0,
                    p.source_to_detector_mm(),
                    pitch * pitch,
                    FLAT_PANEL_DQE,
                )
                .unwrap_or(f64::NAN)
            };
            println!(
                "| {name} | {} | {:.2} | {:.1} | {} | {} | {:.0} | {spr:.2} | {} kVp {:.2} mA | {} | {:.1} | {:.0} | {:.0} |",
                m.depths.len(),
                Timing::from_seconds(meter_s.iter().copied()).median_ms(),
                Timing::from_seconds(step_s.iter().copied()).median_s() * 1e6,
                curve.name(),
                if grid { "in" } else { "out" },
                m.air_gap_mm,
                t.kvp,
                t.ma,
                first_within.map_or("never".into(), |f| f.to_string()),
                skin_kerma_rate_mgy_per_min(t, &e),
                quanta(512.0),
                quanta(1024.0),
            );
        }
    }
    println!();
    println!("| temporal chain, 6 raw frames | per live frame, ms |");
    println!("|---|---:|");
    for side in [512usize, 1024] {
        let frames: Vec<Vec<u8>> = (0..HISTORY_FRAMES)
            .map(|k| {
                (0..side * side)
                    .map(|p| ((p * 7 + k * 13) % 251) as u8)
                    .collect()
            })
            .collect();
        let refs: Vec<&[u8]> = frames.iter().map(|f| f.as_slice()).collect();
        let q = weights_q16(FilterLevel::High, FIRST_FRAME_LAG, HISTORY_FRAMES);
        let t = Timing::run(runs, || {
            std::hint::black_box(combine(&refs, &q));
        });
        println!("| {side}^2 | {:.2} |", t.median_ms());
    }
    // The published median: 29 s of fluoroscopy, 0.68 Gy cm^2 (Kim et al. 2014).
    let (seconds, published_kap) = (29.0, 0.68);
    let (mut kerma_mgy, mut kap) = (0.0, 0.0);
    for (_, t, p) in &tfesi {
        let (k, a) = render_worker::session::modalities::fluoro::dose::dose_of(
            &region,
            p,
            t.kvp,
            t.ma * 0.25,
            seconds / tfesi.len() as f64,
        );
        kerma_mgy += k;
        kap += a;
    }
    println!();
    println!(
        "L4 transforaminal at the published median fluoroscopy time ({seconds} s, a third each in {}), standard curve, 7.5 pulses per second, open field:",
        tfesi.iter().map(|v| v.0).collect::<Vec<_>>().join(", ")
    );
    println!(
        "incident air kerma at the skin {kerma_mgy:.2} mGy, KAP {kap:.3} Gy cm^2 (published median {published_kap} Gy cm^2: {:+.0} %)",
        (kap / published_kap - 1.0) * 100.0
    );
}
