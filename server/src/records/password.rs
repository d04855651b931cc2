//! Password hashing with argon2id (PHC strings, parameters stored in the hash).

use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString};
use argon2::{Algorithm, Argon2, Params, Version};
use rand::RngCore;

use super::config::Argon2Cost;

/// Shortest accepted password. NIST SP 800-63B section 5.1.1.2 asks for at least 8 characters;
/// we ask for 12 because these accounts guard assessment records.
pub const MIN_PASSWORD_CHARS: usize = 12;
/// Longest accepted password (bounds the hashing work an attacker can request).
pub const MAX_PASSWORD_CHARS: usize = 256;

/// Why a new password is refused; the message is safe to show.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PasswordPolicyError {
    /// Fewer than [`MIN_PASSWORD_CHARS`] characters.
    #[error("password must have at least {MIN_PASSWORD_CHARS} characters")]
    TooShort,
    /// More than [`MAX_PASSWORD_CHARS`] characters.
    #[error("password must have at most {MAX_PASSWORD_CHARS} characters")]
    TooLong,
}

/// Checks a new password's length.
pub fn check_new_password(password: &str) -> Result<(), PasswordPolicyError> {
    let n = password.chars().count();
    if n < MIN_PASSWORD_CHARS {
        return Err(PasswordPolicyError::TooShort);
    }
    if n > MAX_PASSWORD_CHARS {
        return Err(PasswordPolicyError::TooLong);
    }
    Ok(())
}

/// Hashes a password with argon2id at the given cost. CPU-heavy: call from `spawn_blocking`.
pub fn hash_password(password: &str, cost: Argon2Cost) -> anyhow::Result<String> {
    let params = Params::new(cost.memory_kib, cost.iterations, cost.parallelism, None)
        .map_err(|e| anyhow::anyhow!("argon2 parameters: {e}"))?;
    let mut salt = [0u8; 16];
    rand::rng().fill_bytes(&mut salt);
    let salt = SaltString::encode_b64(&salt).map_err(|e| anyhow::anyhow!("salt: {e}"))?;
    let hash = Argon2::new(Algorithm::Argon2id, Version::V0x13, params)
        .hash_password(password.as_bytes(), &salt)
        .map_err(|e| anyhow::anyhow!("hashing: {e}"))?;
    Ok(hash.to_string())
}

/// True when `password` matches the PHC string `hash`. CPU-heavy: call from `spawn_blocking`.
pub fn verify_password(password: &str, hash: &str) -> bool {
    PasswordHash::new(hash).is_ok_and(|h| {
        Argon2::default()
            .verify_password(password.as_bytes(), &h)
            .is_ok()
    })
}

/// A hash of a random password, verified against when the e-mail is unknown so that the response
/// time does not reveal which accounts exist.
pub fn decoy_hash(cost: Argon2Cost) -> String {
    let mut pw = [0u8; 24];
    rand::rng().fill_bytes(&mut pw);
    hash_password(&hex::encode(pw), cost).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn argon2id_round_trip_and_parameters_in_the_hash() {
        let h = hash_password("correct horse battery", Argon2Cost::TEST_ONLY).unwrap();
        assert!(h.starts_with("$argon2id$v=19$m=64,t=1,p=1$"), "{h}");
        assert!(verify_password("correct horse battery", &h));
        assert!(!verify_password("correct horse batterY", &h));
        assert!(!verify_password("x", "not a phc string"));
        let r = hash_password("pw", Argon2Cost::RECOMMENDED).unwrap();
        assert!(r.starts_with("$argon2id$v=19$m=19456,t=2,p=1$"), "{r}");
        assert_ne!(
            hash_password("same", Argon2Cost::TEST_ONLY).unwrap(),
            hash_password("same", Argon2Cost::TEST_ONLY).unwrap()
        );
    }

    #[test]
    fn password_length_rules() {
        assert_eq!(
            check_new_password("short"),
            Err(PasswordPolicyError::TooShort)
        );
        assert!(check_new_password(&"x".repeat(12)).is_ok());
        assert_eq!(
            check_new_password(&"x".repeat(257)),
            Err(PasswordPolicyError::TooLong)
        );
        assert_eq!(
            PasswordPolicyError::TooShort.to_string(),
            "password must have at least 12 characters"
        );
    }
}
