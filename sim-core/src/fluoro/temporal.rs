//! The temporal chain of live fluoroscopy: detector lag and the recursive (noise-reducing)
//! filter, as weights over the last frames of a live run, so that moving steel leaves a fading
//! trail and noise averages down, exactly and in any order of rendering.
//!
//! # Model
//! The detector's output for frame `k` keeps a fraction `l` of the previous frame's signal
//! (first-frame lag): `d_k = (1 - l) x_k + l x_{k-1}`, `d_0 = x_0`. The display's recursive
//! filter mixes it into the last displayed frame with weight `w`: `y_k = w d_k + (1 - w)
//! y_{k-1}`, `y_0 = d_0`. Unrolled, `y_k` is a weighted sum of the raw frames `x` since the
//! run's start with weights summing to 1.
//!
//! # Exact and bounded
//! A frame uses at most [`HISTORY_FRAMES`] raw frames: the weights are those of the recursion
//! started at the oldest frame used (so they sum to 1 exactly in real numbers, and the oldest
//! frame stands for everything before it). They are turned into integers summing to exactly
//! 2^16 ([`weights_q16`]) and applied to the 8-bit frames in integer arithmetic ([`combine`]),
//! so a still scene is displayed unchanged bit for bit, and the result depends only on which raw
//! frames are combined, never on the order they were rendered in.
//!
//! # Parameters
//! [`FIRST_FRAME_LAG`]: 5 %, within the few-percent first-frame lag of indirect (CsI) flat-panel
//! detectors measured by J. H. Siewerdsen and D. A. Jaffray, "A ghost story: spatio-temporal
//! response characteristics of an indirect-detection flat-panel imager", Med. Phys. 26 (1999)
//! 1624-1641. The filter weights of [`FilterLevel`] are simulator choices in the range C-arm
//! consoles offer (newest-frame weights of 1/2 to 1/4; an equivalent averaging of 3 to 7 frames
//! for noise).

use serde::{Deserialize, Serialize};

/// Fraction of a frame's signal that the detector still reads out in the next frame (module
/// docs).
pub const FIRST_FRAME_LAG: f64 = 0.05;

/// Most raw frames one displayed frame combines. Simulator choice: with the strongest filter
/// (newest weight 1/4) the seventh frame back would carry 0.75^6 / 4 = 4.5 % of the weight; six
/// frames keep the trail visible for under a second at 7.5 pulses per second while bounding the
/// work of a frame whose history has to be rendered again (after a restore).
pub const HISTORY_FRAMES: usize = 6;

/// The recursive filter's strength, as a C-arm console offers it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FilterLevel {
    /// No recursive filter (the detector's lag remains).
    Off,
    /// The newest frame weighs 1/2.
    Low,
    /// The newest frame weighs 1/4.
    High,
}

impl FilterLevel {
    /// Every level.
    pub const ALL: [FilterLevel; 3] = [FilterLevel::Off, FilterLevel::Low, FilterLevel::High];

    /// The JSON name.
    pub fn name(self) -> &'static str {
        match self {
            FilterLevel::Off => "off",
            FilterLevel::Low => "low",
            FilterLevel::High => "high",
        }
    }

    /// The level called `name`.
    pub fn parse(name: &str) -> Option<FilterLevel> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// Weight of the newest frame in the recursion.
    pub fn newest_weight(self) -> f64 {
        match self {
            FilterLevel::Off => 1.0,
            FilterLevel::Low => 0.5,
            FilterLevel::High => 0.25,
        }
    }
}

/// The weights of `m` raw frames (newest first, `m` clamped to 1..=[`HISTORY_FRAMES`]) in the
/// displayed frame, from the recursion started at the oldest of them (module docs).
pub fn weights(level: FilterLevel, lag: f64, m: usize) -> Vec<f64> {
    let m = m.clamp(1, HISTORY_FRAMES);
    let (w, l) = (level.newest_weight(), lag.clamp(0.0, 1.0));
    // y_t as coefficients over x_0..x_t (oldest first), t = 0..m-1.
    let mut y = vec![1.0];
    for t in 1..m {
        let mut next = vec![0.0; t + 1];
        for (i, c) in y.iter().enumerate() {
            next[i] += (1.0 - w) * c;
        }
        next[t] += w * (1.0 - l);
        next[t - 1] += w * l;
        y = next;
    }
    y.reverse();
    y
}

/// [`weights`] as integers summing to exactly 2^16: each rounded down, the remainder to the
/// newest frame.
pub fn weights_q16(level: FilterLevel, lag: f64, m: usize) -> Vec<u32> {
    let w = weights(level, lag, m);
    let mut q: Vec<u32> = w.iter().map(|c| (c * 65536.0).floor() as u32).collect();
    let sum: u32 = q.iter().sum();
    q[0] += 65536 - sum;
    q
}

/// The displayed frame: the raw 8-bit `frames` (newest first, all of one size) combined with
/// `weights_q16` (as many, summing to 2^16), rounded to nearest. `None` when the counts or sizes
/// disagree.
pub fn combine(frames: &[&[u8]], weights_q16: &[u32]) -> Option<Vec<u8>> {
    let n = frames.first()?.len();
    if frames.len() != weights_q16.len()
        || frames.iter().any(|f| f.len() != n)
        || weights_q16.iter().map(|&w| u64::from(w)).sum::<u64>() != 65536
    {
        return None;
    }
    // Blocks of pixels on all cores, each summed over the frames in a small accumulator that
    // stays in registers and cache (the same integer sums in the same order as one pass per
    // frame over the whole image, so the same bytes; about a quarter of that pass's time).
    const BLOCK: usize = 64;
    let mut out = vec![0u8; n];
    if n == 0 {
        return Some(out);
    }
    let chunk = CHUNK_PX.min(n);
    let threads = super::rows::thread_count(0);
    super::rows::par_rows(&mut out, chunk, threads, |j, row| {
        let start = j * chunk;
        for (b, out_block) in row.chunks_mut(BLOCK).enumerate() {
            let from = start + b * BLOCK;
            let mut acc = [32768u32; BLOCK];
            for (f, &w) in frames.iter().zip(weights_q16) {
                if w == 0 {
                    continue;
                }
                let pixels = &f[from..from + out_block.len()];
                for (a, &p) in acc.iter_mut().zip(pixels) {
                    *a += w * u32::from(p);
                }
            }
            for (o, a) in out_block.iter_mut().zip(acc) {
                *o = (a >> 16) as u8;
            }
        }
    });
    Some(out)
}

/// Pixels per work item of [`combine`] (a row of the work split, not of the image).
const CHUNK_PX: usize = 16_384;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lag_combine_equals_the_per_frame_sums_at_any_size() {
        for n in [
            0usize,
            1,
            63,
            64,
            65,
            4097,
            CHUNK_PX - 1,
            CHUNK_PX,
            CHUNK_PX + 1,
            70_001,
        ] {
            let frames: Vec<Vec<u8>> = (0..3)
                .map(|k| (0..n).map(|p| ((p * 31 + k * 97) % 256) as u8).collect())
                .collect();
            let refs: Vec<&[u8]> = frames.iter().map(|f| f.as_slice()).collect();
            let w = weights_q16(FilterLevel::High, FIRST_FRAME_LAG, 3);
            let got = combine(&refs, &w).expect("same sizes");
            let want: Vec<u8> = (0..n)
                .map(|p| {
                    let s: u32 = 32768
                        + frames
                            .iter()
                            .zip(&w)
                            .map(|(f, w)| w * u32::from(f[p]))
                            .sum::<u32>();
                    (s >> 16) as u8
                })
                .collect();
            assert_eq!(got, want, "{n} pixels");
        }
    }

    #[test]
    fn lag_weights_sum_to_one_and_follow_the_recursion() {
        for level in FilterLevel::ALL {
            for m in 1..=HISTORY_FRAMES + 2 {
                let w = weights(level, FIRST_FRAME_LAG, m);
                assert_eq!(w.len(), m.min(HISTORY_FRAMES));
                assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12, "{level:?} {m}");
                assert!(w.iter().all(|c| *c >= 0.0));
                let q = weights_q16(level, FIRST_FRAME_LAG, m);
                assert_eq!(q.iter().sum::<u32>(), 65536);
            }
        }
        // Two frames, filter off: the detector's lag alone, 5 % of the previous frame.
        let w = weights(FilterLevel::Off, FIRST_FRAME_LAG, 2);
        assert!(
            (w[0] - 0.95).abs() < 1e-15 && (w[1] - 0.05).abs() < 1e-15,
            "{w:?}"
        );
        // Three frames, low filter, no lag: y2 = x2/2 + x1/4 + x0/4 (x0 is the recursion's start).
        let w = weights(FilterLevel::Low, 0.0, 3);
        assert_eq!(w, vec![0.5, 0.25, 0.25]);
        // One frame: itself.
        assert_eq!(
            weights_q16(FilterLevel::High, FIRST_FRAME_LAG, 1),
            vec![65536]
        );
    }

    #[test]
    fn lag_and_filter_keep_a_still_scene_and_leave_a_trail() {
        let still: Vec<u8> = (0..=255).collect();
        for level in FilterLevel::ALL {
            for m in 1..=HISTORY_FRAMES {
                let frames: Vec<&[u8]> = vec![&still; m];
                let q = weights_q16(level, FIRST_FRAME_LAG, m);
                assert_eq!(combine(&frames, &q).unwrap(), still, "{level:?} {m}");
            }
        }
        // A bright dot that moved: the old place keeps a fading trail, the new one is dimmer
        // than the dot until the filter catches up.
        let mut old = vec![0u8; 4];
        old[1] = 200;
        let mut new = vec![0u8; 4];
        new[2] = 200;
        let q = weights_q16(FilterLevel::Low, FIRST_FRAME_LAG, 2);
        let out = combine(&[&new, &old], &q).unwrap();
        assert_eq!(out[0], 0);
        assert!(out[1] > 0 && out[1] < 120, "{out:?}");
        assert!(out[2] > 80 && out[2] < 200, "{out:?}");
        assert!(combine(&[&new, &old[..3]], &q).is_none());
        assert!(combine(&[&new], &q).is_none());
        assert!(combine(&[&new, &old], &[1, 2]).is_none());
    }
}
