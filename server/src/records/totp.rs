//! TOTP (RFC 6238: HMAC-SHA1, 6 digits, 30 s steps, one step of clock skew either way), the
//! parameters every common authenticator app uses.

use rand::RngCore;
use totp_rs::{Algorithm, TOTP};

/// Issuer shown in authenticator apps.
pub const ISSUER: &str = "pain-sim";
/// RFC 6238 time step.
pub const STEP_S: u64 = 30;
/// Accepted clock skew in steps on either side (RFC 6238 section 5.2 recommends at most one).
pub const SKEW_STEPS: u64 = 1;

/// A fresh 160-bit secret (RFC 4226 section 4 recommends 160 bits).
pub fn new_secret() -> Vec<u8> {
    let mut s = vec![0u8; 20];
    rand::rng().fill_bytes(&mut s);
    s
}

fn totp(secret: &[u8], account: &str) -> Option<TOTP> {
    TOTP::new(
        Algorithm::SHA1,
        6,
        SKEW_STEPS as u8,
        STEP_S,
        secret.to_vec(),
        Some(ISSUER.into()),
        account.replace(':', "_"),
    )
    .ok()
}

/// `otpauth://` URL and base32 secret for enrolment.
pub fn enrolment(secret: &[u8], account: &str) -> Option<(String, String)> {
    let t = totp(secret, account)?;
    Some((t.get_url(), t.get_secret_base32()))
}

/// The code for `unix_s` (for tests and the demo).
pub fn code_at(secret: &[u8], unix_s: u64) -> String {
    totp(secret, "x")
        .map(|t| t.generate(unix_s))
        .unwrap_or_default()
}

/// The time step matched by `code` at `unix_s`, if any and if it is later than `last_step`
/// (a code is accepted once: replaying it, or an older one, fails).
pub fn verify(secret: &[u8], code: &str, unix_s: u64, last_step: Option<i64>) -> Option<i64> {
    let t = totp(secret, "x")?;
    let code = code.trim();
    if code.len() != 6 || !code.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let now_step = unix_s / STEP_S;
    let mut matched = None;
    for step in now_step.saturating_sub(SKEW_STEPS)..=now_step + SKEW_STEPS {
        // Compare every candidate (no early exit) so timing does not reveal which one matched.
        if constant_time_eq(t.generate(step * STEP_S).as_bytes(), code.as_bytes()) {
            matched = Some(step as i64);
        }
    }
    matched.filter(|s| last_step.is_none_or(|last| *s > last))
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Seconds since the Unix epoch.
pub fn unix_now() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc_6238_sha1_vectors() {
        // RFC 6238 appendix B, SHA-1 secret "12345678901234567890"; our codes are the last 6
        // digits of the 8-digit values listed there.
        let secret = b"12345678901234567890";
        for (t, code8) in [
            (59u64, "94287082"),
            (1_111_111_109, "07081804"),
            (1_234_567_890, "89005924"),
            (2_000_000_000, "69279037"),
        ] {
            assert_eq!(code_at(secret, t), code8[2..], "t = {t}");
        }
    }

    #[test]
    fn skew_window_and_replay() {
        let s = new_secret();
        let now = 1_700_000_000;
        let code = code_at(&s, now);
        let step = (now / STEP_S) as i64;
        assert_eq!(verify(&s, &code, now, None), Some(step));
        assert_eq!(
            verify(&s, &code, now + STEP_S, None),
            Some(step),
            "one step late is accepted"
        );
        assert_eq!(
            verify(&s, &code, now + 2 * STEP_S, None),
            None,
            "two steps late is not"
        );
        assert_eq!(verify(&s, &code, now, Some(step)), None, "replay refused");
        assert_eq!(verify(&s, "12345", now, None), None);
        assert_eq!(verify(&s, "abcdef", now, None), None);
    }
}
