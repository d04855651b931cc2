//! Scatter: what the superposition adds to a frame, and its accuracy against the Monte Carlo
//! for the cost of each.
//!
//! Rows 1: the superposition alone (`scatter_field`, coarse grid of at most 16 cells across)
//! and the whole CPU finish of a frame with and without scatter (noise on, 3,750 quanta), at
//! 512^2 and 1024^2 on every core, on the synthetic lumbar-like transmission of the
//! `fluoro_finish` bench (0.59 mm pixels at 512^2 over a 300 mm detector, 80 kVp, grid in, a
//! 350 mm air gap), median of the runs.
//!
//! Rows 2: the image receptor's profile on top (`sim_core::fluoro::receptor`: glare, the PSF
//! core and, for the image intensifier, distortion and vignetting): the finish with scatter and
//! each receptor, and what the receptor adds to the finish with scatter.
//!
//! Rows 3: the whole chain a live frame of a new session adds to the finish it had before
//! (noise and display of the primary): one brightness-control step (the metering's scatter
//! factor and the controller, on a metering of 80 rays through 200 mm of soft tissue and 15 mm of
//! bone), scatter, the receptor, and the temporal chain's strongest filter over 6 raw frames.
//!
//! Rows 4: the scatter-to-primary ratio at the centre of an AP lumbar-like field (200 mm water,
//! 200 mm field, 80 kVp, 20 mm air gap), without and with the grid: the superposition's
//! `centre_spr` and the Monte Carlo at rising photon counts, each with its run time; the error
//! column is against the largest Monte Carlo run.
//!
//! `BENCH_QUICK=1` times 5 runs per row instead of 21 and stops the Monte Carlo at 2 x 10^5
//! photons.

use std::time::Instant;

use sim_core::fluoro::attenuation::{CORTICAL_BONE_MU_60KEV_PER_CM, SOFT_TISSUE_MU_60KEV_PER_CM};
use sim_core::fluoro::brightness::{
    BrightnessCurve, FrameExposure, Metering, Technique, TubeLimits, next_technique,
};
use sim_core::fluoro::geometry::{ISOCENTRE_TO_DETECTOR_MM, SOURCE_TO_ISOCENTRE_MM};
use sim_core::fluoro::receptor::{ReceptorKind, ReceptorSettings};
use sim_core::fluoro::render::finish_frame_f32;
use sim_core::fluoro::scatter::AntiScatterGrid;
use sim_core::fluoro::scatter::monte_carlo::{Beam, SlabSetup, field_centre};
use sim_core::fluoro::scatter::superposition::{ScatterSettings, centre_spr, scatter_field};
use sim_core::fluoro::spectrum::Basis;
use sim_core::fluoro::temporal::{
    FIRST_FRAME_LAG, FilterLevel, HISTORY_FRAMES, combine, weights_q16,
};
use sim_core::fluoro::{QuantumNoise, RenderSettings};
use sim_core::stats::Timing;

#[path = "common/lumbar_field.rs"]
mod lumbar_field;
use lumbar_field::field;

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let runs = if quick { 5 } else { 21 };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("Scatter superposition in a frame, {threads} threads");
    println!();
    println!(
        "| image | superposition (ms) | finish with scatter (ms) | finish without (ms) | added by scatter (ms) | centre SPR of the frame |"
    );
    println!("|---:|---:|---:|---:|---:|---:|");
    for side in [512u32, 1024] {
        let (t, exposed) = field(side);
        let n = side as usize;
        let scatter = ScatterSettings {
            kvp: 80,
            grid: true,
            air_gap_mm: 350.0,
            pixel_pitch_mm: 300.0 / f64::from(side),
        };
        let noise = Some(QuantumNoise {
            photons_per_pixel: 3750.0,
            seed: 0x5eed,
        });
        let with = RenderSettings {
            noise,
            scatter: Some(scatter),
            ..RenderSettings::default()
        };
        let without = RenderSettings {
            noise,
            ..RenderSettings::default()
        };
        let superposition = Timing::run(runs, || {
            std::hint::black_box(scatter_field(&t, &exposed, n, n, &scatter));
        })
        .median_ms();
        let a = Timing::run(runs, || {
            std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &with));
        })
        .median_ms();
        let b = Timing::run(runs, || {
            std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &without));
        })
        .median_ms();
        let f = scatter_field(&t, &exposed, n, n, &scatter).expect("field");
        let centre = n / 2 * n + n / 2;
        let spr = f.at(n / 2, n / 2) / (f64::from(t[centre]) * scatter.primary_factor());
        println!(
            "| {side} | {superposition:.2} | {a:.2} | {b:.2} | {:.2} | {spr:.3} |",
            a - b
        );
    }
    println!();
    println!(
        "| image | receptor | finish with scatter and receptor (ms) | added by the receptor (ms) |"
    );
    println!("|---:|---|---:|---:|");
    for side in [512u32, 1024] {
        let (t, exposed) = field(side);
        let pitch = 300.0 / f64::from(side);
        let scatter = ScatterSettings {
            kvp: 80,
            grid: true,
            air_gap_mm: 350.0,
            pixel_pitch_mm: pitch,
        };
        let base = RenderSettings {
            noise: Some(QuantumNoise {
                photons_per_pixel: 3750.0,
                seed: 0x5eed,
            }),
            scatter: Some(scatter),
            ..RenderSettings::default()
        };
        let plain = Timing::run(runs, || {
            std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &base));
        })
        .median_ms();
        for kind in ReceptorKind::ALL {
            let with = RenderSettings {
                receptor: Some(ReceptorSettings {
                    kind,
                    pixel_pitch_mm: pitch,
                }),
                ..base
            };
            let ms = Timing::run(runs, || {
                std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &with));
            })
            .median_ms();
            println!("| {side} | {} | {ms:.2} | {:.2} |", kind.name(), ms - plain);
        }
    }
    println!();
    println!("| image | receptor | whole chain added to a live frame (ms) | goal (ms) |");
    println!("|---:|---|---:|---:|");
    let metering = Metering {
        depths: (0..80)
            .map(|_| {
                let mut a = [0.0; Basis::COUNT];
                a[Basis::Water.index()] = SOFT_TISSUE_MU_60KEV_PER_CM * 20.0;
                a[Basis::Bone.index()] = CORTICAL_BONE_MU_60KEV_PER_CM * 1.5;
                a
            })
            .collect(),
        air_gap_mm: 600.0,
    };
    let exposure = FrameExposure {
        frame_s: 1.0 / 30.0,
        duty: 0.25,
        source_to_detector_mm: SOURCE_TO_ISOCENTRE_MM + ISOCENTRE_TO_DETECTOR_MM,
        source_to_skin_mm: 600.0,
    };
    for side in [512u32, 1024] {
        let (t, exposed) = field(side);
        let pitch = 300.0 / f64::from(side);
        let noise = Some(QuantumNoise {
            photons_per_pixel: 3750.0,
            seed: 0x5eed,
        });
        let before = RenderSettings {
            noise,
            ..RenderSettings::default()
        };
        let plain = Timing::run(runs, || {
            std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &before));
        })
        .median_ms();
        let n = (side * side) as usize;
        let history: Vec<Vec<u8>> = (0..HISTORY_FRAMES)
            .map(|k| (0..n).map(|p| ((p * 7 + k * 13) % 251) as u8).collect())
            .collect();
        let weights = weights_q16(FilterLevel::High, FIRST_FRAME_LAG, HISTORY_FRAMES);
        for kind in ReceptorKind::ALL {
            let with = RenderSettings {
                scatter: Some(ScatterSettings {
                    kvp: 80,
                    grid: true,
                    air_gap_mm: 600.0,
                    pixel_pitch_mm: pitch,
                }),
                receptor: Some(ReceptorSettings {
                    kind,
                    pixel_pitch_mm: pitch,
                }),
                ..before
            };
            let ms = Timing::run(runs, || {
                let technique = Technique { kvp: 80, ma: 2.5 };
                let factor = metering.scatter_factor(80, 150.0, 150.0, true);
                let k = metering.detector_kerma_ngy(technique, &exposure) * factor;
                std::hint::black_box(next_technique(
                    BrightnessCurve::Standard,
                    &TubeLimits::default(),
                    &exposure,
                    technique,
                    k,
                ));
                let frame = finish_frame_f32(side, side, &t, &exposed, &with);
                let mut refs: Vec<&[u8]> = vec![frame.pixels.as_slice()];
                refs.extend(history[1..].iter().map(|h| h.as_slice()));
                std::hint::black_box(combine(&refs, &weights));
            })
            .median_ms();
            let goal = if side == 512 { 3.0 } else { 10.0 };
            println!(
                "| {side} | {} | {:.2} | {goal:.0} |",
                kind.name(),
                ms - plain
            );
        }
    }
    println!();
    println!("SPR at the centre, 200 mm water, 200 mm field, 80 kVp, 20 mm air gap");
    println!();
    println!(
        "| method | photons | run time (ms) | SPR no grid | SPR grid | error no grid | error grid |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    let counts: &[usize] = if quick {
        &[25_000, 50_000, 200_000]
    } else {
        &[25_000, 100_000, 400_000, 1_600_000]
    };
    let mut rows = Vec::new();
    for &photons in counts {
        let setup = SlabSetup {
            kvp: 80,
            water_mm: 200.0,
            air_gaps_mm: vec![20.0],
            beam: Beam::Field {
                source_to_detector_mm: SOURCE_TO_ISOCENTRE_MM + ISOCENTRE_TO_DETECTOR_MM,
                half_x_mm: 100.0,
                half_y_mm: 100.0,
            },
            grid: AntiScatterGrid::FLUOROSCOPY,
            photons,
            seed: 0xBE4C,
        };
        let start = Instant::now();
        let s = field_centre(&setup, 20.0).expect("spectrum");
        rows.push((
            "Monte Carlo",
            photons,
            start.elapsed().as_secs_f64() * 1e3,
            s.spr().0,
            s.spr_grid().0,
        ));
    }
    let start = Instant::now();
    let model = (
        centre_spr(80, 200.0, 100.0, 100.0, 20.0, false).expect("spr"),
        centre_spr(80, 200.0, 100.0, 100.0, 20.0, true).expect("spr"),
    );
    rows.push((
        "superposition",
        0,
        start.elapsed().as_secs_f64() * 1e3,
        model.0,
        model.1,
    ));
    let reference = rows[counts.len() - 1];
    for (method, photons, ms, a, b) in rows {
        println!(
            "| {method} | {photons} | {ms:.1} | {a:.3} | {b:.3} | {:+.1} % | {:+.1} % |",
            100.0 * (a / reference.3 - 1.0),
            100.0 * (b / reference.4 - 1.0)
        );
    }
}
