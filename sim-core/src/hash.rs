//! SHA-256 as lower-case hex: the one digest helper of the platform (asset file hashes, the
//! phantom's cache key, and, in `render-worker` and `server`, session snapshots, logs and
//! frames).

use sha2::{Digest, Sha256};

/// SHA-256 (FIPS 180-4) of a byte string, as 64 lower-case hex digits.
///
/// ```
/// assert_eq!(
///     sim_core::hash::sha256_hex(b"abc"),
///     "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
/// );
/// ```
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_fips_180_2_examples() {
        // FIPS 180-2, appendix B: the empty string is the common known answer, "abc" B.1 and the
        // 448-bit message B.2.
        assert_eq!(
            sha256_hex(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
        assert_eq!(
            sha256_hex(b"abcdbcdecdefdefgefghfghighijhijkijkljklmklmnlmnomnopnopq"),
            "248d6a61d20638b8e5c026930c3e6039a33ce45964ff2167f6ecedd419db06c1"
        );
    }
}
