//! The CPU finish of a fluoroscopy frame (automatic brightness, quantum noise, tone mapping):
//! all a new shot costs when nothing else changed (`render_worker`'s renderers keep the
//! transmission and only redo this), and the part of every other frame that runs on the CPU.
//!
//! The transmission is a synthetic lumbar-like field in `f32` (as the GPU renderer reads it
//! back): a soft-tissue background of `ln T` about -3.5, a vertebral column darker by up to 2.5
//! and two pedicle ovals, with collimator shutters on the outer 4 % of each side; 3,750 quanta
//! per open pixel (the session default at 2.5 mA). Rows: each phase alone (the metering median,
//! the noisy counts, the whole finish) at 512^2 and 1024^2 on every core, median of the runs,
//! and the FNV-1a hash of the frame, which the noise makes depend on every count (the hash is
//! the same for any thread count: each pixel has its own seed).
//!
//! `BENCH_QUICK=1` times 5 runs per row instead of 21.

use std::time::Instant;

use sim_core::fluoro::render::{exposure_centre, finish_frame_f32};
use sim_core::fluoro::{Exposure, QuantumNoise, RenderSettings};

/// A `side`^2 transmission and its exposure mask.
fn field(side: u32) -> (Vec<f32>, Vec<bool>) {
    let n = side as usize;
    let mut t = Vec::with_capacity(n * n);
    let mut exposed = Vec::with_capacity(n * n);
    for j in 0..n {
        for i in 0..n {
            let (x, y) = (i as f64 / n as f64 - 0.5, j as f64 / n as f64 - 0.5);
            let column = (-(x / 0.08).powi(2)).exp() * (1.0 + 0.3 * (y * 40.0).sin());
            let pedicle =
                |cx: f64| (-((x - cx) / 0.03).powi(2) - ((y * 10.0).sin() / 0.4).powi(2)).exp();
            let ln_t = -3.5 - 2.5 * column - 1.0 * (pedicle(-0.1) + pedicle(0.1));
            t.push(ln_t.exp() as f32);
            let edge = 0.46;
            exposed.push(x.abs() < edge && y.abs() < edge);
        }
    }
    (t, exposed)
}

fn median_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    let mut v: Vec<f64> = (0..runs)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let runs = if quick { 5 } else { 21 };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "CPU finish of a fluoroscopy frame (f32 transmission, noise, 3,750 quanta), {threads} threads"
    );
    println!();
    println!(
        "| image | metering median (ms) | whole finish with noise (ms) | finish without noise (ms) | frame hash |"
    );
    println!("|---:|---:|---:|---:|---|");
    for side in [512u32, 1024] {
        let (t, exposed) = field(side);
        let noisy = RenderSettings {
            noise: Some(QuantumNoise {
                photons_per_pixel: 3750.0,
                seed: 0x5eed,
            }),
            ..RenderSettings::default()
        };
        let clean = RenderSettings {
            noise: None,
            ..RenderSettings::default()
        };
        let t64 = sim_core::fluoro::TransmissionImage {
            width: side,
            height: side,
            transmission: t.iter().map(|&v| f64::from(v)).collect(),
            exposed: exposed.clone(),
            supersampled_pixels: 0,
        };
        let metering = median_ms(runs, || {
            std::hint::black_box(exposure_centre(
                &t64,
                &Exposure::default(),
                noisy.noise.as_ref(),
            ));
        });
        let mut hash = 0;
        let whole = median_ms(runs, || {
            let img = finish_frame_f32(side, side, &t, &exposed, &noisy);
            hash = fnv1a(&img.pixels);
        });
        let plain = median_ms(runs, || {
            std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &clean));
        });
        println!("| {side} | {metering:.2} | {whole:.2} | {plain:.2} | {hash:016x} |");
    }
}
