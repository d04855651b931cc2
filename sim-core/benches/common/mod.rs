//! Shared helpers of the sim-core benchmarks (included with `mod common;`).

use std::time::Instant;

/// Median wall time of `reps` runs of `f`, seconds.
pub fn median_seconds(reps: usize, mut f: impl FnMut()) -> f64 {
    let mut times: Vec<f64> = (0..reps)
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}
