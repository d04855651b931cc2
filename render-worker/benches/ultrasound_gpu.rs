//! GPU B-mode ultrasound: frame time against error, and the CPU reference on the same frames.
//!
//! Scene (as sim-core's `benches/ultrasound.rs`, voxelised so both paths read the same
//! [`CtMedium`]): fat (-100 HU) to 8 mm over muscle (50 HU), a 3 mm labelled cortical plate at
//! 45 mm under half the field and an in-plane 22 G needle, on a 0.5 mm grid. 8 cm depth, both
//! probes, varying lines per frame, samples per line and march step around the defaults.
//!
//! Per variant it prints the median frame time of the GPU path (whole `scan`: set-up,
//! passes, read-back, frame assembly) and of `sim_core::ultrasound::scan` on the same request,
//! the GPU frame's error against the CPU frame of the same request (displayed-image NCC and mean
//! |grey| difference: the implementation error), and its error against a fine CPU reference
//! (2x the default lines and samples, 0.05 mm march: the sampling error). Then one profiled
//! frame per probe at the defaults (each pass submitted and waited for separately): medium
//! upload, CPU set-up, deposit, convolutions, march, display, read-back, assembly.
//!
//! `BENCH_QUICK=1`: the default and the 256-line variants of each probe, one repetition, no
//! fine reference.

#[allow(dead_code)]
mod common;

use std::time::Instant;

use glam::DVec3;
use render_worker::ultrasound::{GpuUltrasound, layered_test_volume};
use sim_core::compare::Compare;
use sim_core::stats::Timing;
use sim_core::ultrasound::{
    BModeFrame, CtMedium, NeedleShaft, ProbeKind, ProbePose, Sampling, ScanRequest, Settings, scan,
};
use sim_core::volume::{Volume, VolumeGrid};

fn scene() -> (Volume<f32>, Volume<u8>) {
    layered_test_volume(VolumeGrid {
        dims: [321, 81, 221],
        spacing_mm: [0.5; 3],
        origin_mm: [-80.0, -20.0, -15.0],
    })
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
    let quick = std::env::var_os("BENCH_QUICK").is_some();
    let Some(ctx) = common::gpu_or_skip() else {
        return;
    };
    println!(
        "adapter: {} ({}, {})",
        ctx.summary.name, ctx.summary.backend, ctx.summary.device_type
    );
    let (hu, labels) = scene();
    let medium = CtMedium {
        hu: &hu,
        labels: Some(&labels),
    };
    let t = Instant::now();
    let mut us = GpuUltrasound::new(&ctx).expect("pipelines");
    println!("pipelines: {:.0} ms", t.elapsed().as_secs_f64() * 1e3);
    let reps = if quick { 1 } else { 5 };
    let needle = NeedleShaft {
        hub_mm: DVec3::new(25.0, 0.0, -2.0),
        tip_mm: DVec3::new(-5.0, 0.0, 30.0),
        diameter_mm: 0.72,
    };
    for probe in [ProbeKind::Linear, ProbeKind::Curvilinear] {
        let spec = probe.spec();
        let settings = Settings {
            depth_mm: 80.0,
            focus_mm: 40.0,
            ..Settings::default_for(&spec)
        };
        let d = Sampling::for_settings(&spec, &settings);
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
            seed: 5,
        };
        let fine = (!quick).then(|| {
            scan(&req(Sampling {
                lines: 2 * d.lines,
                samples_per_line: 2 * d.samples_per_line,
                march_step_mm: 0.05,
                ..d
            }))
            .expect("fine reference")
        });
        let mut variants = vec![("default", d), ("256 lines", Sampling { lines: 256, ..d })];
        if !quick {
            variants.extend([
                (
                    "lines/2",
                    Sampling {
                        lines: d.lines / 2,
                        ..d
                    },
                ),
                (
                    "lines*2",
                    Sampling {
                        lines: d.lines * 2,
                        ..d
                    },
                ),
                (
                    "samples/2",
                    Sampling {
                        samples_per_line: d.samples_per_line / 2,
                        ..d
                    },
                ),
                (
                    "samples*2",
                    Sampling {
                        samples_per_line: d.samples_per_line * 2,
                        ..d
                    },
                ),
                (
                    "march 0.2",
                    Sampling {
                        march_step_mm: 0.2,
                        ..d
                    },
                ),
                (
                    "march 0.05",
                    Sampling {
                        march_step_mm: 0.05,
                        ..d
                    },
                ),
            ]);
        }
        println!(
            "\n{probe:?}, 8 cm (defaults: {} lines, {} samples, {} mm march, {:.3} mm cell)",
            d.lines, d.samples_per_line, d.march_step_mm, d.scatter_cell_mm
        );
        println!(
            "{:<11} {:>6} {:>7} {:>6} {:>9} {:>9} {:>10} {:>9} {:>10} {:>9}",
            "variant",
            "lines",
            "samples",
            "march",
            "gpu ms",
            "cpu ms",
            "ncc vs cpu",
            "|grey|",
            "ncc fine",
            "|grey|"
        );
        for (name, s) in variants {
            let r = req(s);
            let mut g = us.scan(&r, &medium, 1).expect("gpu frame");
            let gpu_ms =
                Timing::run(reps, || g = us.scan(&r, &medium, 1).expect("gpu frame")).median_ms();
            let mut c = scan(&r).expect("cpu frame");
            let cpu_ms = Timing::run(reps, || c = scan(&r).expect("cpu frame")).median_ms();
            let (ncc, grey) = errors(&g, &c);
            // Quick mode has no fine reference: its columns say so rather than print NaN.
            let (fncc, fgrey) = fine.as_ref().map_or(("-".into(), "-".into()), |f| {
                let (n, g) = errors(&g, f);
                (format!("{n:.4}"), format!("{g:.2}"))
            });
            println!(
                "{name:<11} {:>6} {:>7} {:>6} {gpu_ms:>9.1} {cpu_ms:>9.1} {ncc:>10.5} {grey:>9.3} {fncc:>10} {fgrey:>9}",
                s.lines, s.samples_per_line, s.march_step_mm
            );
        }
        us.profile = true;
        let _ = us
            .scan(&req(d), &medium, 2)
            .expect("profiled frame (new medium key)");
        let t = us.last_timings();
        us.profile = false;
        println!(
            "profile (default, fresh medium upload): medium {:.1} ms, set-up {:.1}, deposit {:.1}, \
             convolve {:.1}, march {:.1}, display {:.1}, read-back {:.1}, assembly {:.1}",
            t.medium_upload_ms,
            t.setup_ms,
            t.deposit_ms,
            t.convolve_ms,
            t.march_ms,
            t.display_ms,
            t.readback_ms,
            t.finish_ms
        );
    }
}
