//! Table lookups for the scatter loop: `(cos, sin)` and `exp(-x)` interpolated in fixed tables,
//! and a `floor` without a libm call. Every value depends only on its argument, so a frame is
//! the same whichever thread or module computes it.

/// Entries per turn of the [`cis`] table.
const CIS_N: usize = 4096;
/// Entries per unit argument of the [`exp_neg`] table, and its range.
const EXP_PER_UNIT: f64 = 128.0;
const EXP_MAX: f64 = 16.0;

fn cis_table() -> &'static [(f64, f64)] {
    static T: std::sync::OnceLock<Vec<(f64, f64)>> = std::sync::OnceLock::new();
    T.get_or_init(|| {
        (0..CIS_N)
            .map(|n| {
                let (s, c) = (std::f64::consts::TAU * n as f64 / CIS_N as f64).sin_cos();
                (c, s)
            })
            .collect()
    })
}

/// Entries of the [`exp_neg`] table: `EXP_MAX * EXP_PER_UNIT + 2`.
pub(super) const EXP_LEN: usize = 16 * 128 + 2;
const _: () = assert!(EXP_LEN == (EXP_MAX * EXP_PER_UNIT) as usize + 2);

pub(super) fn exp_table() -> &'static [f64; EXP_LEN] {
    static T: std::sync::OnceLock<[f64; EXP_LEN]> = std::sync::OnceLock::new();
    T.get_or_init(|| std::array::from_fn(|i| (-(i as f64) / EXP_PER_UNIT).exp()))
}

/// `(cos phi, sin phi)` from a 4096-entry table with a first-order correction: error below
/// `(pi / 4096)^2 / 2 = 3e-7`, several times faster than `sin_cos` in the scatter loop.
#[inline]
pub(crate) fn cis(phi: f64) -> (f64, f64) {
    let x = phi * (CIS_N as f64 / std::f64::consts::TAU);
    let n = floor_fast(x + 0.5);
    let d = (x - n) * (std::f64::consts::TAU / CIS_N as f64);
    let (c, s) = cis_table()[(n as i64).rem_euclid(CIS_N as i64) as usize];
    (c - s * d, s + c * d)
}

/// `floor` without a libm call (the baseline x86-64 target has no rounding instruction).
#[inline]
fn floor_fast(x: f64) -> f64 {
    let t = x as i64 as f64;
    if t > x { t - 1.0 } else { t }
}

/// `exp(-x)` for `x >= 0`, linearly interpolated in a table of step 1/128 (relative error below
/// `(1/128)^2 / 8 = 8e-6`); zero beyond 16.
#[inline]
pub(crate) fn exp_neg(x: f64) -> f64 {
    exp_neg_in(exp_table(), x)
}

/// [`exp_neg`] with the table at hand (the scatter loop fetches it once).
#[inline]
pub(super) fn exp_neg_in(tab: &[f64; EXP_LEN], x: f64) -> f64 {
    if x.is_nan() || x >= EXP_MAX {
        return 0.0;
    }
    let t = x.max(0.0) * EXP_PER_UNIT;
    // 0 <= t < 2048 here: through i64, the same index with a plain conversion; the `min` changes
    // nothing but lets the compiler drop the bounds checks.
    let i = (t as i64 as usize).min(EXP_LEN - 2);
    let f = t - i as f64;
    tab[i] + (tab[i + 1] - tab[i]) * f
}
