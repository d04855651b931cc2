//! CPU fluoroscopy reference: frame time against error for the analytic sphere phantom.
//!
//! For each mesh resolution (icosphere subdivisions, volume-matched) and image size it prints the
//! scene build time (icospheres and BVHs), the chord pass (one ray per pixel), a full 80 kVp
//! frame (4 x 4 adaptive supersampling, automatic brightness, log mapping) and the median / p99
//! relative error of -ln T at pixel centres against the analytic spheres and needle.
//!
//! `BENCH_QUICK=1` runs a reduced grid (under a minute on 2 cores in the dev profile).

use std::time::Instant;

use sim_core::fluoro::analytic::{ErrorStats, SpherePhantom, neg_log_t_errors};
use sim_core::fluoro::{
    EnergyModel, Projection, RenderSettings, SpectralModel, render_chords, render_frame,
};

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let (subdivisions, sizes): (&[u32], &[u32]) = if quick {
        (&[3, 5, 7], &[128])
    } else {
        (&[3, 5, 6, 7], &[256, 512])
    };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "CPU fluoroscopy reference, sphere phantom (soft 100 mm, bone 30 mm, 22 G needle), {threads} threads"
    );
    println!();
    println!(
        "| triangles | image | scene build (s) | chord pass (ms) | 80 kVp frame (ms) | supersampled px | median rel. err -ln T | p99 rel. err -ln T |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|");
    let model = SpectralModel::new(EnergyModel::Spectral { kvp: 80 }).expect("80 kVp is tabulated");
    for &s in subdivisions {
        let phantom = SpherePhantom {
            subdivisions: s,
            volume_matched: true,
            needle_segments: 64,
        };
        let t0 = Instant::now();
        let (scene, reference) = phantom.build();
        let build_s = t0.elapsed().as_secs_f64();
        for &n in sizes {
            // The whole 200 mm sphere (406 mm on the detector) in the field.
            let p = Projection {
                detector_pixels: [n, n],
                pixel_pitch_mm: [448.0 / n as f64; 2],
                ..Projection::default()
            };
            let t1 = Instant::now();
            let chords = render_chords(&scene, &p, 0);
            let chord_ms = t1.elapsed().as_secs_f64() * 1e3;
            let e = ErrorStats::of(neg_log_t_errors(&chords, &reference, &p, &model));
            let settings = RenderSettings::default();
            let t2 = Instant::now();
            let t = sim_core::fluoro::render_transmission(&scene, None, &p, &settings)
                .expect("tabulated kVp");
            let frame = render_frame(&scene, None, &p, &settings).expect("tabulated kVp");
            // render_frame repeats the transmission pass; time the two together and halve, so the
            // supersampled pixel count can be reported from the first.
            let frame_ms = t2.elapsed().as_secs_f64() * 1e3 / 2.0;
            assert_eq!(frame.pixels.len(), (n * n) as usize);
            println!(
                "| {} | {n}x{n} | {build_s:.2} | {chord_ms:.0} | {frame_ms:.0} | {} | {:.2e} | {:.2e} |",
                scene.triangle_count(),
                t.supersampled_pixels,
                e.median,
                e.p99
            );
        }
    }
    // Inscribed icospheres (vertices on the sphere) against volume-matched ones: chord pass only.
    let n = sizes[0];
    let p = Projection {
        detector_pixels: [n, n],
        pixel_pitch_mm: [448.0 / n as f64; 2],
        ..Projection::default()
    };
    println!();
    println!("Mesh placement, {n}x{n}, 80 kVp, -ln T relative error (median / p99)");
    println!();
    println!(
        "| triangles | inscribed median | inscribed p99 | volume-matched median | volume-matched p99 |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for &s in subdivisions {
        let stats = |volume_matched: bool| {
            let (scene, reference) = SpherePhantom {
                subdivisions: s,
                volume_matched,
                needle_segments: 64,
            }
            .build();
            let chords = render_chords(&scene, &p, 0);
            (
                scene.triangle_count(),
                ErrorStats::of(neg_log_t_errors(&chords, &reference, &p, &model)),
            )
        };
        let (tris, a) = stats(false);
        let (_, b) = stats(true);
        println!(
            "| {tris} | {:.2e} | {:.2e} | {:.2e} | {:.2e} |",
            a.median, a.p99, b.median, b.p99
        );
    }
}
