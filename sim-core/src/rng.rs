//! SplitMix64: the one small, seedable pseudo-random generator of the simulator.
//!
//! SplitMix64 is the generator of G. L. Steele Jr., D. Lea and C. H. Flood, "Fast splittable
//! pseudorandom number generators", OOPSLA 2014 (Java's `SplittableRandom`), in the form of
//! S. Vigna's public-domain reference implementation `splitmix64.c`
//! (<https://prng.di.unimi.it/splitmix64.c>): the state advances by the golden-ratio increment
//! `0x9E3779B97F4A7C15` and each output is the state passed through a variant of the MurmurHash3
//! finaliser (shifts 30, 27, 31; Stafford's "Mix13" multipliers). It is fast, passes BigCrush, and
//! its whole state is one `u64`, so a per-pixel or per-voxel generator costs nothing to seed.
//! It is not cryptographic.
//!
//! Everything here is exact integer arithmetic plus exact conversions, so the same seed gives
//! the same numbers on every platform: noise in frames, CT volumes and test commands replays bit
//! for bit.
//!
//! ```
//! use sim_core::rng::{SplitMix64, splitmix64};
//! let mut rng = SplitMix64::new(0);
//! // The first output of Vigna's reference implementation seeded with 0.
//! assert_eq!(rng.next_u64(), 0xE220_A839_7B1D_CDAF);
//! // The stateless hash is the first output of a generator seeded with its argument.
//! assert_eq!(splitmix64(0), 0xE220_A839_7B1D_CDAF);
//! let u = rng.next_f64();
//! assert!((0.0..1.0).contains(&u));
//! ```

/// The state increment: 2^64 divided by the golden ratio, rounded to odd (Steele et al. 2014).
pub const GOLDEN_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// A SplitMix64 generator (see the module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    /// A generator whose state is `seed` (every `u64` is a valid seed, 0 included).
    pub const fn new(seed: u64) -> SplitMix64 {
        SplitMix64 { state: seed }
    }

    /// The next 64 pseudo-random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN_GAMMA);
        mix(self.state)
    }

    /// Uniform in `[0, 1)`: [`unit_f64`] of the next output.
    pub fn next_f64(&mut self) -> f64 {
        unit_f64(self.next_u64())
    }

    /// Uniform in `(0, 1]`: [`unit_f64_nonzero`] of the next output (never zero, so its logarithm
    /// is finite).
    pub fn next_f64_nonzero(&mut self) -> f64 {
        unit_f64_nonzero(self.next_u64())
    }
}

/// SplitMix64 as a stateless hash of `x`: the first output of [`SplitMix64::new`]`(x)`. A
/// bijection of `u64` that decorrelates nearby inputs (seeds derived from indices, say).
pub const fn splitmix64(x: u64) -> u64 {
    mix(x.wrapping_add(GOLDEN_GAMMA))
}

/// The output function: Vigna's finaliser of SplitMix64.
const fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// 2^53 as an `f64` (exact).
const TWO_POW_53: f64 = (1u64 << 53) as f64;

/// The top 53 bits of `x` as a uniform deviate in `[0, 1)`: `(x >> 11) / 2^53`, exact (every
/// value is a multiple of 2^-53).
pub fn unit_f64(x: u64) -> f64 {
    (x >> 11) as f64 / TWO_POW_53
}

/// The top 53 bits of `x` as a uniform deviate in `(0, 1]`: `((x >> 11) + 1) / 2^53`, exact.
/// (The same value as `((x >> 11) as f64 + 1.0) / 2^53`: both sums are at most 2^53, which an
/// `f64` holds exactly.)
pub fn unit_f64_nonzero(x: u64) -> f64 {
    ((x >> 11) + 1) as f64 / TWO_POW_53
}

/// Uniform deviates in `[0, 1)` from `seed`: SplitMix64 steps through [`unit_f64`] (the
/// tests' random inputs).
#[cfg(test)]
pub(crate) fn uniform_stream(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = splitmix64(state);
        unit_f64(state)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_zero_gives_the_reference_sequence() {
        // Vigna's splitmix64.c with x = 0 (and Java's SplittableRandom(0).nextLong() sequence).
        let mut rng = SplitMix64::new(0);
        let got: Vec<u64> = (0..5).map(|_| rng.next_u64()).collect();
        assert_eq!(
            got,
            [
                0xE220_A839_7B1D_CDAF,
                0x6E78_9E6A_A1B9_65F4,
                0x06C4_5D18_8009_454F,
                0xF88B_B8A8_724C_81EC,
                0x1B39_896A_51A8_749B,
            ]
        );
    }

    #[test]
    fn seed_1234567_gives_the_published_test_vector() {
        // The SplitMix64 task on Rosetta Code lists these for seed 1234567.
        let mut rng = SplitMix64::new(1_234_567);
        let got: Vec<u64> = (0..5).map(|_| rng.next_u64()).collect();
        assert_eq!(
            got,
            [
                6_457_827_717_110_365_317,
                3_203_168_211_198_807_973,
                9_817_491_932_198_370_423,
                4_593_380_528_125_082_431,
                16_408_922_859_458_223_821,
            ]
        );
    }

    #[test]
    fn the_hash_is_the_first_output_of_a_generator_seeded_with_its_argument() {
        for x in [0, 1, 42, 1_234_567, u64::MAX, GOLDEN_GAMMA.wrapping_neg()] {
            assert_eq!(splitmix64(x), SplitMix64::new(x).next_u64());
        }
        // Each output is the hash of the previous state: next state = state + gamma.
        let mut rng = SplitMix64::new(7);
        rng.next_u64();
        assert_eq!(rng.next_u64(), splitmix64(7u64.wrapping_add(GOLDEN_GAMMA)));
    }

    #[test]
    fn unit_deviates_cover_their_half_open_intervals_exactly() {
        assert_eq!(unit_f64(0), 0.0);
        assert_eq!(unit_f64(u64::MAX), 1.0 - 2f64.powi(-53));
        assert_eq!(unit_f64_nonzero(0), 2f64.powi(-53));
        assert_eq!(unit_f64_nonzero(u64::MAX), 1.0);
        // The low 11 bits do not matter.
        assert_eq!(unit_f64(0x7FF), 0.0);
        let mut a = SplitMix64::new(3);
        let mut b = a.clone();
        let x = a.next_u64();
        assert_eq!(b.next_f64(), unit_f64(x));
        assert_eq!(
            unit_f64_nonzero(x),
            ((x >> 11) as f64 + 1.0) / TWO_POW_53,
            "integer and float increments agree"
        );
    }
}
