//! Settings of the learning records, from the environment.
//!
//! | variable | default | meaning |
//! |---|---|---|
//! | `PAINSIM_DEMO_ACCOUNTS` | `auto` | create the demo accounts (published passwords): `true`, `false`, or `auto` = only when `PAINSIM_BIND` is a loopback address and the database is the embedded one |
//! | `PAINSIM_COOKIE_SECURE` | `auto` | `Secure` cookie attribute: `true`, `false`, or `auto` = secure unless `PAINSIM_BIND` is a loopback address (plain-http local runs) |
//! | `PAINSIM_SESSION_IDLE_SECS` | `1800` | a session unused this long expires |
//! | `PAINSIM_SESSION_ABSOLUTE_SECS` | `43200` | a session expires this long after login, used or not |
//! | `PAINSIM_ARGON2_MEMORY_KIB` / `_ITERATIONS` / `_PARALLELISM` | `19456` / `2` / `1` | argon2id cost for new hashes (OWASP Password Storage Cheat Sheet, 2023 minimum) |
//! | `PAINSIM_LOGIN_MAX_FAILURES` | `5` | failed logins per e-mail within the window before login is refused |
//! | `PAINSIM_LOGIN_FAILURE_WINDOW_SECS` | `900` | the throttling window |
//! | `PAINSIM_AUTH_RATE_PER_MINUTE` / `PAINSIM_AUTH_BURST` | `30` / `10` | per-client token bucket on `/api/auth/*` |
//! | `PAINSIM_WRITE_RATE_PER_MINUTE` / `PAINSIM_WRITE_BURST` | `600` / `100` | per-account token bucket on authenticated writes (POST, PUT, PATCH, DELETE) |
//! | `PAINSIM_REQUIRE_TOTP_FOR_APPROVAL` | `true` | reviewers must have logged in with a TOTP code to approve or return |
//! | `PAINSIM_STATIONS_DIR` | the repository's `assets/stations/` | station definitions |

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use crate::error::ConfigError;

/// argon2id cost parameters for new password hashes. Verification always uses the parameters
/// stored in the hash itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Argon2Cost {
    /// Memory in KiB.
    pub memory_kib: u32,
    /// Passes over memory.
    pub iterations: u32,
    /// Lanes.
    pub parallelism: u32,
}

impl Argon2Cost {
    /// OWASP Password Storage Cheat Sheet: argon2id with m = 19 MiB, t = 2, p = 1.
    pub const RECOMMENDED: Argon2Cost = Argon2Cost {
        memory_kib: 19_456,
        iterations: 2,
        parallelism: 1,
    };
    /// Cheap parameters for tests only (argon2's minimum memory is 8 KiB per lane).
    pub const TEST_ONLY: Argon2Cost = Argon2Cost {
        memory_kib: 64,
        iterations: 1,
        parallelism: 1,
    };
}

/// Learning-records settings.
#[derive(Debug, Clone)]
pub struct RecordsConfig {
    /// Whether session cookies carry `Secure`.
    pub cookie_secure: bool,
    /// Idle expiry of a session.
    pub session_idle: Duration,
    /// Absolute expiry of a session.
    pub session_absolute: Duration,
    /// Cost of new password hashes.
    pub argon2: Argon2Cost,
    /// Failed logins per e-mail within `login_failure_window` before login is refused.
    pub login_max_failures: u32,
    /// Throttling window.
    pub login_failure_window: Duration,
    /// Sustained rate of the per-client auth limiter.
    pub auth_rate_per_minute: u32,
    /// Burst of the per-client auth limiter.
    pub auth_burst: u32,
    /// Sustained rate of the per-account limiter of authenticated writes.
    pub write_rate_per_minute: u32,
    /// Burst of the per-account limiter of authenticated writes.
    pub write_burst: u32,
    /// Approving or returning needs a TOTP-verified session.
    pub require_totp_for_approval: bool,
    /// Station definitions.
    pub stations_dir: PathBuf,
    /// Largest request body (the server-wide `PAINSIM_MAX_BODY_BYTES`), named in 413 errors.
    pub max_body_bytes: usize,
    /// `PAINSIM_DEMO_ACCOUNTS`: create the demo accounts (whose passwords are published in the
    /// README) at start-up: `Some(true)` always, `Some(false)` never, `None` (auto) only with the
    /// embedded database on a loopback bind.
    pub demo_accounts: Option<bool>,
    /// Whether `PAINSIM_BIND` is a loopback address.
    pub loopback_bind: bool,
}

fn parse<T: std::str::FromStr>(
    lookup: &impl Fn(&str) -> Option<String>,
    variable: &'static str,
    default: T,
    what: &str,
    ok: impl Fn(&T) -> bool,
) -> Result<T, ConfigError> {
    match lookup(variable) {
        None => Ok(default),
        Some(raw) => raw
            .trim()
            .parse::<T>()
            .ok()
            .filter(|v| ok(v))
            .ok_or_else(|| ConfigError {
                variable,
                value: raw.clone(),
                reason: format!("expected {what}"),
            }),
    }
}

fn parse_bool(
    lookup: &impl Fn(&str) -> Option<String>,
    variable: &'static str,
) -> Result<Option<bool>, ConfigError> {
    match lookup(variable).map(|s| s.trim().to_ascii_lowercase()) {
        None => Ok(None),
        Some(s) if s == "auto" => Ok(None),
        Some(s) if ["1", "true", "yes", "on"].contains(&s.as_str()) => Ok(Some(true)),
        Some(s) if ["0", "false", "no", "off"].contains(&s.as_str()) => Ok(Some(false)),
        Some(s) => Err(ConfigError {
            variable,
            value: s,
            reason: "expected true, false or auto".into(),
        }),
    }
}

impl RecordsConfig {
    /// Reads the settings through `lookup` (the environment, or a map in tests).
    pub fn from_lookup(
        lookup: impl Fn(&str) -> Option<String>,
    ) -> Result<RecordsConfig, ConfigError> {
        let loopback_bind = lookup("PAINSIM_BIND")
            .unwrap_or_else(|| "127.0.0.1:8080".into())
            .parse::<SocketAddr>()
            .is_ok_and(|a| a.ip().is_loopback());
        let secs = |variable, default: u64| {
            parse(
                &lookup,
                variable,
                default,
                "a whole number of seconds, at least 1",
                |v| *v >= 1,
            )
            .map(Duration::from_secs)
        };
        let positive = |variable, default: u32| {
            parse(&lookup, variable, default, "a positive whole number", |v| {
                *v >= 1
            })
        };
        let r = Argon2Cost::RECOMMENDED;
        Ok(RecordsConfig {
            cookie_secure: parse_bool(&lookup, "PAINSIM_COOKIE_SECURE")?.unwrap_or(!loopback_bind),
            demo_accounts: parse_bool(&lookup, "PAINSIM_DEMO_ACCOUNTS")?,
            loopback_bind,
            session_idle: secs("PAINSIM_SESSION_IDLE_SECS", 1800)?,
            session_absolute: secs("PAINSIM_SESSION_ABSOLUTE_SECS", 12 * 3600)?,
            argon2: Argon2Cost {
                memory_kib: parse(
                    &lookup,
                    "PAINSIM_ARGON2_MEMORY_KIB",
                    r.memory_kib,
                    "KiB, at least 8",
                    |v| *v >= 8,
                )?,
                iterations: positive("PAINSIM_ARGON2_ITERATIONS", r.iterations)?,
                parallelism: positive("PAINSIM_ARGON2_PARALLELISM", r.parallelism)?,
            },
            login_max_failures: positive("PAINSIM_LOGIN_MAX_FAILURES", 5)?,
            login_failure_window: secs("PAINSIM_LOGIN_FAILURE_WINDOW_SECS", 900)?,
            auth_rate_per_minute: positive("PAINSIM_AUTH_RATE_PER_MINUTE", 30)?,
            auth_burst: positive("PAINSIM_AUTH_BURST", 10)?,
            // Our choice: a learner's client writes a few times a minute (opening attempts,
            // reported activity); 10 per second sustained and 100 at once is far above any
            // person and far below a script (about 250 activity events/s were accepted before).
            write_rate_per_minute: positive("PAINSIM_WRITE_RATE_PER_MINUTE", 600)?,
            write_burst: positive("PAINSIM_WRITE_BURST", 100)?,
            require_totp_for_approval: parse_bool(&lookup, "PAINSIM_REQUIRE_TOTP_FOR_APPROVAL")?
                .unwrap_or(true),
            stations_dir: lookup("PAINSIM_STATIONS_DIR")
                .map(PathBuf::from)
                .unwrap_or_else(|| {
                    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/stations"))
                }),
            max_body_bytes: parse(
                &lookup,
                "PAINSIM_MAX_BODY_BYTES",
                1 << 20,
                "bytes, at least 1024",
                |v| *v >= 1024,
            )?,
        })
    }

    /// Reads the process environment.
    pub fn from_env() -> Result<RecordsConfig, ConfigError> {
        Self::from_lookup(|k| std::env::var(k).ok())
    }

    /// Defaults with cheap password hashing, for tests.
    pub fn for_tests() -> RecordsConfig {
        let mut c = Self::from_lookup(|_| None).expect("defaults are valid");
        c.argon2 = Argon2Cost::TEST_ONLY;
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn cfg(pairs: &[(&str, &str)]) -> Result<RecordsConfig, ConfigError> {
        let map: HashMap<String, String> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        RecordsConfig::from_lookup(|k| map.get(k).cloned())
    }

    #[test]
    fn defaults_are_the_recommended_ones() {
        let c = cfg(&[]).unwrap();
        assert_eq!(c.argon2, Argon2Cost::RECOMMENDED);
        assert!(c.require_totp_for_approval);
        assert!(!c.cookie_secure, "default bind is loopback plain http");
        assert!(
            cfg(&[("PAINSIM_BIND", "0.0.0.0:80")])
                .unwrap()
                .cookie_secure
        );
        assert!(
            cfg(&[("PAINSIM_COOKIE_SECURE", "true")])
                .unwrap()
                .cookie_secure
        );
        assert!(c.stations_dir.join("l4-l5-left-facet.toml").exists());
    }

    #[test]
    fn bad_values_name_the_variable() {
        for (k, v) in [
            ("PAINSIM_COOKIE_SECURE", "maybe"),
            ("PAINSIM_SESSION_IDLE_SECS", "0"),
            ("PAINSIM_ARGON2_MEMORY_KIB", "4"),
            ("PAINSIM_LOGIN_MAX_FAILURES", "-1"),
        ] {
            assert_eq!(cfg(&[(k, v)]).unwrap_err().variable, k);
        }
    }
}
