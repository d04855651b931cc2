//! The CPU finish of a fluoroscopy frame (automatic brightness, quantum noise, tone mapping):
//! all a new shot costs when nothing else changed (`render_worker`'s renderers keep the
//! transmission and only redo this), and the part of every other frame that runs on the CPU.
//!
//! The transmission is a synthetic lumbar-like field in `f32` (as the GPU renderer reads it
//! back): a soft-tissue background of `ln T` about -3.5, a vertebral column darker by up to 2.5
//! and two pedicle ovals, with collimator shutters on the outer 4 % of each side; 3,750 quanta
//! per open pixel (the session default at 2.5 mA). Rows: each phase alone (the metering median,
//! the noisy counts, the whole finish) at 512^2 and 1024^2 on every core, median of the runs,
//! and the frame's SHA-256 (its first 16 hex digits), which the noise makes depend on every count (the hash is
//! the same for any thread count: each pixel has its own seed).
//!
//! Then the weighing of a branch-free generator against the exact one (#28 asks to weigh a
//! vectorised noise generator): per pixel one hashed uniform, the normal deviate from a
//! 4,096-entry inverse-CDF table, and Anscombe's square-root transform back to a count (no
//! loop, no logarithm), against the production sampler (each pixel's own SplitMix64, Knuth
//! below a mean of 10, Hörmann's PTRS above): nanoseconds per pixel on one thread, and the
//! total variation distance of 10^6 draws from the exact Poisson law at the means a session
//! meets (12 quanta behind the spine, 113 through soft tissue, 3,750 in the open field).
//!
//! `BENCH_QUICK=1` times 5 runs per row instead of 21, with 2 x 10^5 draws per mean.

use std::time::Instant;

use sim_core::fluoro::TransmissionImage;
use sim_core::fluoro::render::{apply_noise, exposure_centre, finish_frame_f32};
use sim_core::fluoro::{Exposure, QuantumNoise, RenderSettings};
use sim_core::hash::sha256_hex;
use sim_core::rng::{splitmix64, unit_f64};
use sim_core::stats::Timing;

#[path = "common/lumbar_field.rs"]
mod lumbar_field;
use lumbar_field::field;

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
        let t64 = TransmissionImage {
            width: side,
            height: side,
            transmission: t.iter().map(|&v| f64::from(v)).collect(),
            exposed: exposed.clone(),
            supersampled_pixels: 0,
        };
        let metering = Timing::run(runs, || {
            std::hint::black_box(exposure_centre(
                &t64,
                &Exposure::default(),
                noisy.noise.as_ref(),
            ));
        })
        .median_ms();
        let whole = Timing::run(runs, || {
            std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &noisy));
        })
        .median_ms();
        let plain = Timing::run(runs, || {
            std::hint::black_box(finish_frame_f32(side, side, &t, &exposed, &clean));
        })
        .median_ms();
        let frame = finish_frame_f32(side, side, &t, &exposed, &noisy);
        let hash = &sha256_hex(&frame.pixels)[..16];
        println!("| {side} | {metering:.2} | {whole:.2} | {plain:.2} | {hash} |");
    }
    weigh_generators(quick);
}

/// The standard normal quantile (Acklam's rational approximation, relative error below
/// 1.15e-9), for the table of the branch-free generator.
fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.38357751867269e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Entries of the inverse-CDF table (cell midpoints; linear in between).
const QUANTILES: usize = 4096;

/// The branch-free generator: a count of mean `mean` for pixel `p`.
#[inline]
fn approx_count(table: &[f64], seed: u64, p: usize, mean: f64) -> f64 {
    let u = unit_f64(splitmix64(
        seed ^ (p as u64).wrapping_mul(0xD1B5_4A32_D192_ED03),
    ));
    let x = u * (QUANTILES - 1) as f64;
    let i = x as usize;
    let z = table[i] + (x - i as f64) * (table[i + 1] - table[i]);
    let r = ((mean + 0.375).sqrt() + 0.5 * z).max(0.0);
    (r * r - 0.375).max(0.0).round()
}

/// `ln P(k)` of the Poisson law of mean `m`, by a running sum of logarithms.
fn poisson_pmf(m: f64, len: usize) -> Vec<f64> {
    let mut ln_fact = 0.0;
    (0..len)
        .map(|k| {
            if k > 1 {
                ln_fact += (k as f64).ln();
            }
            (k as f64 * m.ln() - m - ln_fact).exp()
        })
        .collect()
}

/// Total variation distance of the counts `draws` from the Poisson law of mean `m`.
fn tv_distance(draws: &[f64], m: f64) -> f64 {
    let len = (m + 12.0 * m.sqrt() + 30.0) as usize;
    let pmf = poisson_pmf(m, len);
    let mut hist = vec![0.0; len + 1];
    for &k in draws {
        hist[(k as usize).min(len)] += 1.0;
    }
    let n = draws.len() as f64;
    let mut tv: f64 = (0..len).map(|k| (hist[k] / n - pmf[k]).abs()).sum();
    tv += hist[len] / n;
    0.5 * tv
}

/// The weighing of the branch-free generator (see the module doc).
fn weigh_generators(quick: bool) {
    let draws = if quick { 200_000 } else { 1_000_000 };
    let table: Vec<f64> = (0..QUANTILES)
        .map(|i| normal_quantile((i as f64 + 0.5) / QUANTILES as f64))
        .collect();
    println!();
    println!(
        "Noise generators, one thread, {draws} pixels per mean: ns per pixel and total variation distance from Poisson"
    );
    println!();
    println!(
        "| mean quanta | exact (production) ns/px | exact TV | branch-free ns/px | branch-free TV |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for mean in [12.0, 113.0, 3750.0] {
        let mut img = TransmissionImage {
            width: draws as u32,
            height: 1,
            transmission: vec![1.0; draws],
            exposed: vec![true; draws],
            supersampled_pixels: 0,
        };
        let noise = QuantumNoise {
            photons_per_pixel: mean,
            seed: 0x5eed,
        };
        let t = Instant::now();
        apply_noise(&mut img, &noise);
        let exact_ns = t.elapsed().as_secs_f64() * 1e9 / draws as f64;
        let exact: Vec<f64> = img
            .transmission
            .iter()
            .map(|v| (v * mean).round())
            .collect();
        let t = Instant::now();
        let approx: Vec<f64> = (0..draws)
            .map(|p| approx_count(&table, noise.seed, p, mean))
            .collect();
        let approx_ns = t.elapsed().as_secs_f64() * 1e9 / draws as f64;
        println!(
            "| {mean:.0} | {exact_ns:.1} | {:.4} | {approx_ns:.1} | {:.4} |",
            tv_distance(&exact, mean),
            tv_distance(&approx, mean)
        );
    }
}
