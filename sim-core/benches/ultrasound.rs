//! Ultrasound reference: frame time against error for lines per frame, samples per line and
//! march step, both probes, on an 8 cm frame.
//!
//! Scene: 8 mm of fat over muscle, a 3 mm cortical plate at 45 mm under half the field and an
//! in-plane 22 G needle at 25 degrees. The error of a variant is measured on the displayed image
//! (same pixel grid, same scatter seed) against a fine reference (4x the default lines, 2x the
//! default samples, 0.025 mm march): NCC of the grey levels and their mean absolute difference.
//! Time is the median of whole `scan` calls (scatter, march, envelope, scan conversion). A last
//! line times a pose oblique to the scatterer lattice (see the comment there), and a last table
//! the draft of a frame against the full one (square and oblique, default sampling).
//!
//! `BENCH_QUICK=1` runs one repetition and a shorter list (CI, under 5 s).

use std::hint::black_box;

use glam::DVec3;
use sim_core::compare::Compare;
use sim_core::stats::Timing;
use sim_core::ultrasound::tissue::{CORTICAL_BONE, FAT, MUSCLE};
use sim_core::ultrasound::{
    AcousticMedium, AcousticProps, BModeFrame, NeedleShaft, ProbeKind, ProbePose, Sampling,
    ScanRequest, Settings, scan,
};

struct Layers;

impl AcousticMedium for Layers {
    fn props(&self, p: DVec3) -> AcousticProps {
        if p.z < 8.0 {
            FAT
        } else if p.x < 0.0 && (45.0..48.0).contains(&p.z) {
            CORTICAL_BONE
        } else {
            MUSCLE
        }
    }
}

fn errors(a: &BModeFrame, reference: &BModeFrame) -> (f64, f64) {
    let inside: Vec<bool> = a
        .inside
        .iter()
        .zip(&reference.inside)
        .map(|(&p, &q)| p && q)
        .collect();
    let d = Compare::image(reference.width, reference.height)
        .masked(&a.pixels, &reference.pixels, &inside)
        .expect("frames on one pixel grid");
    (d.ncc, d.mean_abs)
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let reps = if quick { 1 } else { 7 };
    let medium = Layers;
    let dir = DVec3::new(25f64.to_radians().cos(), 0.0, 25f64.to_radians().sin());
    let needle = NeedleShaft {
        hub_mm: DVec3::new(-25.0, 0.0, 0.0) - dir * 10.0,
        tip_mm: DVec3::new(-25.0, 0.0, 0.0) + dir * 40.0,
        diameter_mm: 0.72,
    };
    println!("Ultrasound: 8 cm frame, median of {reps} (error vs fine reference on the image)");
    for (probe, f) in [(ProbeKind::Linear, 5.0), (ProbeKind::Curvilinear, 3.5)] {
        let spec = probe.spec();
        let settings = Settings {
            depth_mm: 80.0,
            focus_mm: 40.0,
            frequency_mhz: f,
            ..Settings::default_for(&spec)
        };
        let base = Sampling {
            pixel_mm: 0.2,
            ..Sampling::for_settings(&spec, &settings)
        };
        let req = |sampling: Sampling| ScanRequest {
            probe,
            pose: ProbePose {
                position_mm: DVec3::ZERO,
                beam_dir: DVec3::Z,
                marker_dir: DVec3::X,
            },
            settings,
            sampling,
            medium: &medium,
            needle: Some(needle),
            targets: &[],
            seed: 1,
        };
        let fine = Sampling {
            lines: 4 * base.lines,
            samples_per_line: 2 * base.samples_per_line,
            march_step_mm: 0.025,
            ..base
        };
        let reference = scan(&req(fine)).expect("valid request");
        println!();
        println!(
            "{probe:?} at {f} MHz (default {} lines, {} samples)",
            base.lines, base.samples_per_line
        );
        println!();
        println!("| lines | samples/line | march (mm) | time (ms) | NCC | mean abs diff (grey) |");
        println!("|---:|---:|---:|---:|---:|---:|");
        let s = base.samples_per_line;
        let mut variants = vec![
            (128, s, 0.1),
            (256, s, 0.1),
            (base.lines, s, 0.1),
            (256, s / 2, 0.1),
            (256, 2 * s, 0.1),
            (256, s, 0.4),
            (256, s, 0.2),
            (256, s, 0.05),
        ];
        variants.dedup();
        if quick {
            variants.truncate(3);
        }
        for (lines, samples, march) in variants {
            let sampling = Sampling {
                lines,
                samples_per_line: samples,
                march_step_mm: march,
                ..base
            };
            let frame = scan(&req(sampling)).expect("valid request");
            let (ncc, mad) = errors(&frame, &reference);
            let t = Timing::run(reps, || {
                black_box(scan(black_box(&req(sampling))).expect("valid request"));
            })
            .median_s();
            println!(
                "| {lines} | {samples} | {march} | {:.1} | {ncc:.3} | {mad:.2} |",
                t * 1e3
            );
        }
        // The rows above hold the probe square to the scatterer lattice, where a lattice column
        // keeps its in-plane point and is summed once; a tilted, rotated probe (the usual case
        // in a session) gives every scatterer its own point. Time only: a different image.
        let oblique = ScanRequest {
            pose: ProbePose::from_rotation(DVec3::ZERO, DVec3::new(0.1, 0.2, 1.0), 17.0),
            ..req(Sampling { lines: 256, ..base })
        };
        let t = Timing::run(reps, || {
            black_box(scan(black_box(&oblique)).expect("valid request"));
        })
        .median_s();
        println!();
        println!(
            "Oblique pose (beam (0.1, 0.2, 1), 17 degrees), 256 lines: {:.1} ms",
            t * 1e3
        );
        // The draft a session shows while the probe moves (`Sampling::draft`), against the full
        // frame of the same pose: its speckle is its own (a coarser lattice), so the error is
        // taken on 8 x 8 pixel block means (the anatomy a learner steers by), grey levels.
        println!();
        println!(
            "| pose | full frame (ms) | draft (ms) | draft error, 8x8 block means: mean / p99 (grey) |"
        );
        println!("|---|---:|---:|---:|");
        let square = req(Sampling::for_settings(&spec, &settings));
        let oblique = ScanRequest {
            sampling: square.sampling,
            ..oblique
        };
        for (name, full) in [("square", square), ("oblique", oblique)] {
            let draft = ScanRequest {
                sampling: full.sampling.draft(),
                ..full
            };
            let (a, b) = (scan(&full).expect("valid"), scan(&draft).expect("valid"));
            let (mean, p99) = block_error(&a, &b);
            let t_full = Timing::run(reps, || {
                black_box(scan(black_box(&full)).expect("valid request"));
            })
            .median_s();
            let t_draft = Timing::run(reps, || {
                black_box(scan(black_box(&draft)).expect("valid request"));
            })
            .median_s();
            println!(
                "| {name} | {:.1} | {:.1} | {mean:.2} / {p99:.2} |",
                t_full * 1e3,
                t_draft * 1e3
            );
        }
    }
}

/// Mean and 99th percentile of the absolute difference of 8 x 8 pixel block means (blocks
/// wholly inside both images), grey levels.
fn block_error(a: &BModeFrame, b: &BModeFrame) -> (f64, f64) {
    assert_eq!(
        (a.width, a.height),
        (b.width, b.height),
        "a draft keeps the image size"
    );
    let mut d = Vec::new();
    for by in (0..a.height / 8).map(|i| 8 * i) {
        for bx in (0..a.width / 8).map(|i| 8 * i) {
            let idx = (0..64).map(|i| (by + i / 8) * a.width + bx + i % 8);
            if idx.clone().any(|i| !a.inside[i] || !b.inside[i]) {
                continue;
            }
            let diff: f64 = idx
                .map(|i| f64::from(a.pixels[i]) - f64::from(b.pixels[i]))
                .sum();
            d.push((diff / 64.0).abs());
        }
    }
    d.sort_by(f64::total_cmp);
    let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
    (mean, d.get(d.len() * 99 / 100).copied().unwrap_or(0.0))
}
