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

#[cfg(test)]
mod tests {
    use super::*;

    /// `cis` against `sin_cos` over phases of either sign up to the carrier phases of a deep
    /// frame (2 k z at 15 MHz and 20 cm is about 2.5e4 rad), at the table's knots and half-way
    /// between them: within the stated 3e-7 (`(pi / 4096)^2 / 2 = 2.94e-7`, plus the
    /// rounding of the phase's reduction, a few ulp of 2.5e4 rad).
    #[test]
    fn cis_is_within_its_stated_error() {
        let mut rand = crate::rng::uniform_stream(3);
        let step = std::f64::consts::TAU / CIS_N as f64;
        let mut phases: Vec<f64> = (0..200_000).map(|_| 5e4 * rand() - 2.5e4).collect();
        phases.extend((-3000..3000).flat_map(|n| [n as f64 * step, (n as f64 + 0.5) * step]));
        let mut worst: f64 = 0.0;
        for phi in phases {
            let (c, s) = cis(phi);
            let (sn, cs) = phi.sin_cos();
            worst = worst.max((c - cs).abs().max((s - sn).abs()));
        }
        eprintln!("largest cis error: {worst:e}");
        assert!(worst <= 3e-7, "{worst:e}");
    }

    /// `exp_neg` against libm over `[0, 16)` (random and at every knot and mid-point): within
    /// the stated relative 8e-6 (`(1/128)^2 / 8 = 7.6e-6`); zero from 16 on and for NaN; a
    /// negative argument counts as 0.
    #[test]
    fn exp_neg_is_within_its_stated_error() {
        let mut rand = crate::rng::uniform_stream(4);
        let mut xs: Vec<f64> = (0..200_000).map(|_| 16.0 * rand()).collect();
        xs.extend((0..2048).flat_map(|i| [i as f64 / 128.0, (i as f64 + 0.5) / 128.0]));
        let mut worst: f64 = 0.0;
        for x in xs {
            let want = (-x).exp();
            worst = worst.max((exp_neg(x) - want).abs() / want);
        }
        eprintln!("largest relative exp_neg error: {worst:e}");
        assert!(worst <= 8e-6, "{worst:e}");
        for x in [16.0, 1e300, f64::INFINITY, f64::NAN] {
            assert_eq!(exp_neg(x), 0.0, "{x}");
        }
        assert_eq!(exp_neg(-3.0), 1.0);
    }
}
