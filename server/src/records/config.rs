//! Settings of the learning records. They are read, with the rest of the server's, by
//! [`crate::config`] (whose `SETTINGS` table names, defaults and describes each variable); this
//! module holds their types.

use std::path::PathBuf;
use std::time::Duration;

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
    /// Idle expiry of a login session (`PAINSIM_LOGIN_IDLE_SECS`).
    pub session_idle: Duration,
    /// Absolute expiry of a login session (`PAINSIM_LOGIN_ABSOLUTE_SECS`).
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

