//! Order statistics and wall-clock timing for the workspace's tests and benches.
//!
//! One definition of a percentile serves every table and every tolerance check, so that a "p99"
//! printed by one bench means what it means in another. Everything here is pure computation over
//! slices; [`Timing::run`] reads the monotonic clock and nothing else.
//!
//! ```
//! use sim_core::stats::{Timing, mean, median, percentile};
//! let v = [4.0, 1.0, 3.0, 2.0];
//! assert_eq!(median(&v), 2.5);
//! assert_eq!(mean(&v), 2.5);
//! assert_eq!(percentile(&v, 0.0), 1.0);
//! assert_eq!(percentile(&v, 100.0), 4.0);
//! // Rank (4 - 1) x 0.9 = 2.7: 70 % of the way from 3 to 4.
//! assert!((percentile(&v, 90.0) - 3.7).abs() < 1e-12);
//! let t = Timing::from_seconds([0.3, 0.1, 0.2]);
//! assert_eq!((t.median_s(), t.min_s(), t.runs()), (0.2, 0.1, 3));
//! ```

use std::time::Instant;

/// The `p`-th percentile (`p` in percent, 0 to 100) of `values`, by linear interpolation between
/// closest ranks. With the values sorted ascending as `x[0] ..= x[n - 1]`, the rank is
/// `h = (n - 1) p / 100` and the result is `x[floor h] + (h - floor h) (x[floor h + 1] -
/// x[floor h])`. This is definition 7 of R. J. Hyndman and Y. Fan, "Sample quantiles in
/// statistical packages", The American Statistician 50(4), 1996, the default of R's `quantile`
/// and NumPy's `percentile` and Excel's `PERCENTILE.INC`: it is the minimum at 0, the maximum at
/// 100, the median at 50, never leaves the range of the data, and never decreases as `p` grows.
///
/// NaN when `values` is empty. Values are ordered by [`f64::total_cmp`], so a NaN among them
/// (which sorts above +inf) shows in the top percentiles instead of vanishing.
///
/// # Panics
/// If `p` is outside `0..=100` or NaN: a percentile is a caller's constant, and one out of range
/// is a bug in the caller.
pub fn percentile(values: &[f64], p: f64) -> f64 {
    percentile_of_sorted(&sorted(values.iter().copied()), p)
}

/// [`percentile`] of values already sorted ascending by [`f64::total_cmp`] (see [`sorted`]), for
/// several percentiles of one sample at the cost of one sort.
///
/// # Panics
/// If `p` is outside `0..=100` or NaN; in debug builds, also if `sorted` is not sorted.
pub fn percentile_of_sorted(sorted: &[f64], p: f64) -> f64 {
    assert!(
        (0.0..=100.0).contains(&p),
        "percentile {p} is outside 0..=100"
    );
    debug_assert!(
        sorted.is_sorted_by(|a, b| a.total_cmp(b).is_le()),
        "percentile_of_sorted needs sorted values"
    );
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = (sorted.len() - 1) as f64 * p / 100.0;
    let below = (rank.floor() as usize).min(sorted.len() - 1);
    let fraction = rank - below as f64;
    let lo = sorted[below];
    let Some(&hi) = sorted.get(below + 1) else {
        return lo;
    };
    if fraction <= 0.0 || lo == hi {
        return lo;
    }
    // The difference of two finite values can overflow (-MAX to MAX); the weighted form cannot.
    let gap = hi - lo;
    let v = if gap.is_finite() {
        lo + fraction * gap
    } else {
        lo * (1.0 - fraction) + hi * fraction
    };
    // Rounding could carry the interpolant an ulp past `hi`, where the next segment starts at
    // exactly `hi`: holding it inside [lo, hi] keeps the percentile monotone in `p`.
    if v < lo {
        lo
    } else if v > hi {
        hi
    } else {
        v
    }
}

/// The median of `values`: [`percentile`] 50, so the mean of the two middle values when their
/// number is even. NaN when `values` is empty.
pub fn median(values: &[f64]) -> f64 {
    percentile(values, 50.0)
}

/// The arithmetic mean of `values`; NaN when `values` is empty.
pub fn mean(values: &[f64]) -> f64 {
    values.iter().sum::<f64>() / values.len() as f64
}

/// `values` collected and sorted ascending by [`f64::total_cmp`], the order
/// [`percentile_of_sorted`] expects.
pub fn sorted(values: impl IntoIterator<Item = f64>) -> Vec<f64> {
    let mut v: Vec<f64> = values.into_iter().collect();
    v.sort_by(f64::total_cmp);
    v
}

/// Wall-clock times of repeated runs of one piece of work, in seconds, kept sorted.
///
/// Benches report the median (robust to the odd run slowed by another process) and, where tails
/// matter, the 95th percentile; both by [`percentile`]'s definition.
#[derive(Debug, Clone, PartialEq)]
pub struct Timing {
    seconds: Vec<f64>,
}

impl Timing {
    /// Calls `f` `runs` times, timing each call with the monotonic clock ([`Instant`]).
    pub fn run(runs: usize, mut f: impl FnMut()) -> Timing {
        Timing::from_seconds((0..runs).map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        }))
    }

    /// Times measured elsewhere (seconds, in any order).
    pub fn from_seconds(seconds: impl IntoIterator<Item = f64>) -> Timing {
        Timing {
            seconds: sorted(seconds),
        }
    }

    /// The number of runs timed.
    pub fn runs(&self) -> usize {
        self.seconds.len()
    }

    /// The times, seconds, ascending.
    pub fn seconds(&self) -> &[f64] {
        &self.seconds
    }

    /// The `p`-th percentile of the times (`p` in percent), seconds; NaN with no runs.
    pub fn percentile_s(&self, p: f64) -> f64 {
        percentile_of_sorted(&self.seconds, p)
    }

    /// The median time, seconds; NaN with no runs.
    pub fn median_s(&self) -> f64 {
        self.percentile_s(50.0)
    }

    /// The median time, milliseconds; NaN with no runs.
    pub fn median_ms(&self) -> f64 {
        1e3 * self.median_s()
    }

    /// The 95th percentile of the times, seconds; NaN with no runs.
    pub fn p95_s(&self) -> f64 {
        self.percentile_s(95.0)
    }

    /// The fastest run, seconds; NaN with no runs.
    pub fn min_s(&self) -> f64 {
        self.seconds.first().copied().unwrap_or(f64::NAN)
    }

    /// The slowest run, seconds; NaN with no runs.
    pub fn max_s(&self) -> f64 {
        self.seconds.last().copied().unwrap_or(f64::NAN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    /// `n` values from `rng`, spread over several decades and signs, with repeats, so that ties,
    /// negative values and wide gaps all occur.
    fn random_values(rng: &mut SplitMix64, n: usize) -> Vec<f64> {
        (0..n)
            .map(|_| {
                let u = rng.next_f64();
                match rng.next_u64() % 4 {
                    0 => (u * 10.0).floor(),
                    1 => -1e3 * u,
                    2 => 1e-6 * u,
                    _ => 1e6 * (u - 0.5),
                }
            })
            .collect()
    }

    #[test]
    fn known_values_follow_linear_interpolation_between_closest_ranks() {
        let v = [15.0, 20.0, 35.0, 40.0, 50.0];
        // Rank 4 x p / 100: 40 % is rank 1.6, 60 % of the way from 20 to 35.
        assert_eq!(percentile(&v, 40.0), 29.0);
        assert_eq!(percentile(&v, 50.0), 35.0);
        assert_eq!(percentile(&v, 75.0), 40.0);
        assert_eq!(percentile(&[7.0], 37.0), 7.0);
        assert_eq!(median(&[1.0, 2.0, 3.0, 10.0]), 2.5);
        assert_eq!(mean(&[1.0, 2.0, 3.0, 10.0]), 4.0);
        // The input order does not matter.
        assert_eq!(percentile(&[50.0, 15.0, 40.0, 20.0, 35.0], 40.0), 29.0);
    }

    #[test]
    fn empty_input_gives_nan() {
        assert!(percentile(&[], 50.0).is_nan());
        assert!(median(&[]).is_nan());
        assert!(mean(&[]).is_nan());
        let t = Timing::from_seconds([]);
        assert!(t.median_s().is_nan() && t.p95_s().is_nan() && t.min_s().is_nan());
    }

    #[test]
    #[should_panic(expected = "outside 0..=100")]
    fn a_percentile_above_100_is_refused() {
        let _ = percentile(&[1.0, 2.0], 101.0);
    }

    #[test]
    #[should_panic(expected = "outside 0..=100")]
    fn a_nan_percentile_is_refused() {
        let _ = percentile(&[1.0, 2.0], f64::NAN);
    }

    #[test]
    fn percentiles_are_the_extremes_at_0_and_100_and_monotone_in_between() {
        let mut rng = SplitMix64::new(0x5747_5354);
        for case in 0..200 {
            let n = 1 + case % 37;
            let v = random_values(&mut rng, n);
            let s = sorted(v.iter().copied());
            assert_eq!(percentile_of_sorted(&s, 0.0), s[0], "case {case}");
            assert_eq!(percentile_of_sorted(&s, 100.0), s[n - 1], "case {case}");
            let mut last = f64::NEG_INFINITY;
            for k in 0..=1000 {
                let p = f64::from(k) / 10.0;
                let q = percentile_of_sorted(&s, p);
                assert!(q >= last, "case {case}: p {p} gives {q} below {last}");
                assert!(
                    s[0] <= q && q <= s[n - 1],
                    "case {case}: {q} outside the data"
                );
                last = q;
            }
            // At an exact rank the percentile is that order statistic.
            for (i, &x) in s.iter().enumerate().skip(1) {
                let p = 100.0 * i as f64 / (n - 1) as f64;
                assert!(
                    (percentile_of_sorted(&s, p) - x).abs() <= 1e-9 * x.abs().max(1.0),
                    "case {case}: rank {i}"
                );
            }
        }
    }

    #[test]
    fn interpolation_near_the_largest_finite_values_stays_finite() {
        let v = [-f64::MAX, f64::MAX];
        let q = percentile(&v, 50.0);
        assert!(q.is_finite() && q.abs() <= f64::MAX, "{q}");
        assert_eq!(
            percentile(&[f64::INFINITY, f64::INFINITY], 50.0),
            f64::INFINITY
        );
    }

    #[test]
    fn a_nan_among_the_values_shows_at_the_top() {
        let v = [1.0, f64::NAN, 2.0];
        assert_eq!(percentile(&v, 0.0), 1.0);
        assert!(percentile(&v, 100.0).is_nan());
    }

    #[test]
    fn timing_sorts_its_runs_and_reports_median_and_p95() {
        let t = Timing::from_seconds((1..=20).rev().map(f64::from));
        assert_eq!(t.seconds()[0], 1.0);
        assert_eq!((t.runs(), t.min_s(), t.max_s()), (20, 1.0, 20.0));
        assert_eq!(t.median_s(), 10.5);
        assert_eq!(t.median_ms(), 10_500.0);
        // Rank 19 x 0.95 = 18.05: 5 % of the way from 19 to 20.
        assert!((t.p95_s() - 19.05).abs() < 1e-12, "{}", t.p95_s());
    }

    #[test]
    fn timing_runs_the_closure_once_per_run() {
        let mut calls = 0;
        let t = Timing::run(5, || calls += 1);
        assert_eq!((calls, t.runs()), (5, 5));
        assert!(t.seconds().iter().all(|&s| s >= 0.0));
        assert!(t.min_s() <= t.median_s() && t.median_s() <= t.max_s());
    }
}
