//! Quantum noise: an exact Poisson count per exposed pixel, each from its own seeded generator.

use super::settings::{QuantumNoise, TransmissionImage};
use crate::rng::SplitMix64;

/// Poisson sample drawn from `rng` (a SplitMix64 seeded per pixel), exact: Knuth's product method
/// below a mean of [`PTRS_MIN_MEAN`], above it Hörmann's transformed rejection with squeeze
/// (PTRS; W. Hörmann, "The transformed rejection method for generating Poisson random
/// variables", Insurance: Mathematics and Economics 12, 1993, 39-45; constants from its Table 1):
/// two uniforms and two divisions per candidate, plus two logarithms when the squeeze does not
/// decide (about 65 % of candidates at a mean of 10, 25 % at 1000). (It replaced the normal
/// approximation above a mean of 30 and Knuth's method up to 30, which drew up to 30 uniforms per
/// pixel and was most of a frame's CPU time.)
fn poisson(rng: &mut SplitMix64, mean: f64) -> f64 {
    if mean <= 0.0 {
        return 0.0;
    }
    if mean < PTRS_MIN_MEAN {
        let limit = (-mean).exp();
        let (mut k, mut p) = (0.0, rng.next_f64_nonzero());
        while p > limit {
            k += 1.0;
            p *= rng.next_f64_nonzero();
        }
        return k;
    }
    let sqrt_mean = mean.sqrt();
    let b = 0.931 + 2.53 * sqrt_mean;
    let a = -0.059 + 0.02483 * b;
    let v_r = 0.9277 - 3.6224 / (b - 2.0);
    // Needed only when the squeeze does not decide (about two thirds of candidates at a
    // mean of 10, a quarter at 1000): computed then, once per sample.
    let mut slow: Option<(f64, f64)> = None;
    loop {
        let u = rng.next_f64_nonzero() - 0.5;
        let v = rng.next_f64_nonzero();
        let us = 0.5 - u.abs();
        let x = (2.0 * a / us + b) * u + mean + 0.43;
        if x < 0.0 {
            // k < 0: rejected (the squeeze region has x > 0).
            continue;
        }
        // floor(x) for x >= 0 by truncation (a conversion instruction, not a libm call).
        let k = x as u64 as f64;
        if us >= 0.07 && v <= v_r {
            return k;
        }
        if us < 0.013 && v > us {
            continue;
        }
        let (inv_alpha, ln_mean) =
            *slow.get_or_insert_with(|| (1.1239 + 1.1328 / (b - 3.4), mean.ln()));
        // ln v + ln alpha^-1 - ln(a / us^2 + b), as one logarithm.
        let lhs = (v * inv_alpha / (a / (us * us) + b)).ln();
        if lhs <= -mean + k * ln_mean - ln_factorial(k) {
            return k;
        }
    }
}

/// Smallest mean drawn with PTRS (its validity bound in Hörmann 1993).
const PTRS_MIN_MEAN: f64 = 10.0;

/// `ln k!` for `k = 0..=16` (Python's `math.lgamma(k + 1)`, correctly rounded to f64 within
/// an ulp; the test below checks them against sums of logarithms).
const LN_FACTORIAL_SMALL: [f64; 17] = [
    0.0,
    0.0,
    std::f64::consts::LN_2,
    1.7917594692280554,
    3.178053830347945,
    4.787491742782047,
    6.579251212010102,
    8.525161361065415,
    10.604602902745249,
    12.801827480081467,
    15.104412573075514,
    17.502307845873887,
    19.987214495661885,
    22.55216385312342,
    25.191221182738683,
    27.89927138384089,
    30.671860106080672,
];

/// Counts below this take `ln k!` from [`ln_factorial_table`]: the counts of open-field
/// pixels at the session's default dose (3,750 quanta at 2.5 mA, and 8 standard deviations
/// above) and of everything darker.
const LN_FACTORIAL_TABLE_LEN: usize = 8192;

/// `ln k!` for `k < LN_FACTORIAL_TABLE_LEN`, each entry [`ln_factorial_series`] of its `k` (so
/// bit for bit what the series gives), made once per process (64 KiB, about 0.2 ms).
fn ln_factorial_table() -> &'static [f64] {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        (0..LN_FACTORIAL_TABLE_LEN)
            .map(|k| ln_factorial_series(k as f64))
            .collect()
    })
}

/// `ln k!` for a whole `k >= 0`: from a table below [`LN_FACTORIAL_TABLE_LEN`] (the PTRS
/// sampler's slow path needs one per candidate: a logarithm saved), else
/// [`ln_factorial_series`].
pub(super) fn ln_factorial(k: f64) -> f64 {
    if k < LN_FACTORIAL_TABLE_LEN as f64 {
        return ln_factorial_table()[k as usize];
    }
    ln_factorial_series(k)
}

/// `ln k!` for a whole `k >= 0`: a table up to 16, then Stirling's series to the `x^-5` term
/// (truncation error below `1 / (1680 x^7)` at `x = k + 1 >= 17`: 1.4e-12).
pub(super) fn ln_factorial_series(k: f64) -> f64 {
    if k < 17.0 {
        return LN_FACTORIAL_SMALL[k as usize];
    }
    let x = k + 1.0;
    let x2 = x * x;
    (x - 0.5) * x.ln() - x
        + 0.5 * (std::f64::consts::TAU).ln()
        + (1.0 / 12.0 - (1.0 / 360.0 - 1.0 / (1260.0 * x2)) / x2) / x
}

/// The noisy count of pixel `p` (mean `photons_per_pixel x t`), from its own seeded generator.
pub(super) fn noisy_count(noise: &QuantumNoise, p: usize, t: f64) -> f64 {
    let mut rng = SplitMix64::new(noise.seed ^ (p as u64).wrapping_mul(0xD1B5_4A32_D192_ED03));
    poisson(&mut rng, noise.photons_per_pixel * t)
}

/// Applies quantum noise (if any) to a transmission image, in place.
pub fn apply_noise(t: &mut TransmissionImage, noise: &QuantumNoise) {
    for (p, v) in t.transmission.iter_mut().enumerate() {
        if t.exposed[p] {
            *v = noisy_count(noise, p, *v) / noise.photons_per_pixel;
        }
    }
}
