//! The signed I/Q amplitude of a lattice scatterer, drawn from a SplitMix64 hash of the seed and
//! the cell's indices, so that it is fixed to the tissue.

use crate::rng::splitmix64;

/// Hash of a lattice cell (three indices and the seed).
pub(super) fn cell_hash(seed: u64, i: i64, j: i64, k: i64) -> u64 {
    splitmix64(splitmix64(splitmix64(seed ^ i as u64) ^ j as u64) ^ k as u64)
}

/// Signed I and Q of a scatterer: each the sum of two 16-bit uniforms minus 1 (mean 0,
/// variance 1/6).
#[inline]
pub(super) fn iq_of_hash(x: u64) -> (f64, f64) {
    // u(a) + u(b) with u(sh) = ((x >> sh) & 0xFFFF) / 65536: the sum of the two 16-bit integers
    // scaled once is the same f64 (every step is exact), with one conversion instead of two.
    let pair = |a: u32, b: u32| {
        let n = ((x >> a) & 0xFFFF) as u32 + ((x >> b) & 0xFFFF) as u32;
        f64::from(n) / 65536.0 - 1.0
    };
    (pair(0, 16), pair(32, 48))
}
