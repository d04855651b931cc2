//! Configuration from the environment, with defaults that run a complete platform locally.
//!
//! This module is the only place in the server that reads its settings. Every variable is one
//! row of [`SETTINGS`] (name, default, meaning), read through
//! [`render_worker::session::config::Settings`], which refuses a name that is not a row and
//! takes each default from its row; [`Config`] (with its learning-records and dispatch parts) is
//! filled from them, and the rest of the server receives the values through it. The README's
//! Configuration table is these rows; the `configuration` test of the server's test binary fails
//! when the two differ, when the code reads a variable that is not a row, or when a row is never
//! read. Names that once meant something else are in [`RETIRED`]: start-up refuses them.

use std::net::SocketAddr;
use std::path::PathBuf;

use crate::dispatch::{
    DEFAULT_SESSION_IDLE, DEFAULT_SESSIONS_PER_COURSE, DEFAULT_SESSIONS_PER_USER, DispatchConfig,
};
pub use crate::error::ConfigError;
use crate::records::config::{Argon2Cost, RecordsConfig};
use render_worker::session::config::SettingDefault::{Derived, Number, Unset, Value};
pub use render_worker::session::config::{
    Retired, Setting, SettingDefault, SettingError, Settings, env,
};

/// Default idle expiry of a login session, seconds. OWASP Session Management Cheat Sheet: idle
/// timeouts of 15 to 30 minutes for low-risk applications; the upper end, because a learner
/// reads a case or watches a demonstration without touching the API.
pub const DEFAULT_LOGIN_IDLE_SECS: u64 = 30 * 60;

/// Default absolute expiry of a login session, seconds. Simulator choice: one training day,
/// breaks included, needs one login; the next day needs a new one.
pub const DEFAULT_LOGIN_ABSOLUTE_SECS: u64 = 12 * 3600;

/// Every setting the server reads (the process's; the render-worker crate's table,
/// `render_worker::session::config::WORKER_SETTINGS`, adds the renderer choice of the in-process
/// worker). Each row's default is what the code uses when the variable is unset or blank.
pub const SETTINGS: &[Setting] = &[
    Setting {
        name: "PAINSIM_BIND",
        default: Value("127.0.0.1:8080"),
        meaning: "address the HTTP server listens on (host:port)",
    },
    Setting {
        name: "DATABASE_URL",
        default: Unset,
        meaning: "an existing PostgreSQL; unset = the embedded private cluster",
    },
    Setting {
        name: "PAINSIM_DATA_DIR",
        default: Value("data"),
        meaning: "where the embedded cluster (`pg/`) and caches live",
    },
    Setting {
        name: "PAINSIM_PG_USER",
        default: Value("postgres"),
        meaning: "account the embedded cluster runs as when the server runs as root",
    },
    Setting {
        name: "PAINSIM_WEB_DIR",
        default: Derived("the repository's `web-client/`"),
        meaning: "static files of the web client",
    },
    Setting {
        name: "PAINSIM_ASSETS_DIR",
        default: Derived("the repository's `assets/`"),
        meaning: "anatomy regions (the procedural phantoms are built and cached there)",
    },
    Setting {
        name: "PAINSIM_STATIONS_DIR",
        default: Derived("the repository's `assets/stations/`"),
        meaning: "station definitions",
    },
    Setting {
        name: "PAINSIM_MAX_BODY_BYTES",
        default: Value("1048576"),
        meaning: "largest accepted request body, bytes (at least 1024)",
    },
    Setting {
        name: "PAINSIM_PUBLIC_URL",
        default: Derived("`http://` + the bind address"),
        meaning: "the origin browsers and LMS platforms reach the server at: LTI 1.3 URLs, the \
                  LRS credentials' authority and the platform's xAPI activity ids are built on it",
    },
    Setting {
        name: "PAINSIM_COOKIE_SECURE",
        default: Value("auto"),
        meaning: "`Secure` cookies: `true`, `false`, or `auto` = secure unless `PAINSIM_BIND` is a \
                  loopback address (plain-http local runs)",
    },
    Setting {
        name: "PAINSIM_DEMO_ACCOUNTS",
        default: Value("auto"),
        meaning: "demo accounts with the published passwords: `auto` creates them only with the \
                  embedded database on a loopback bind (start-up says so either way), \
                  `true`/`false` force it",
    },
    Setting {
        name: "PAINSIM_LOGIN_IDLE_SECS",
        default: Number(DEFAULT_LOGIN_IDLE_SECS),
        meaning: "seconds a login session may go unused before it expires",
    },
    Setting {
        name: "PAINSIM_LOGIN_ABSOLUTE_SECS",
        default: Number(DEFAULT_LOGIN_ABSOLUTE_SECS),
        meaning: "seconds after login at which a login session expires, used or not",
    },
    Setting {
        name: "PAINSIM_ARGON2_MEMORY_KIB",
        default: Number(Argon2Cost::RECOMMENDED.memory_kib as u64),
        meaning: "argon2id memory of new password hashes, KiB (at least 8; OWASP Password \
                  Storage Cheat Sheet minimum)",
    },
    Setting {
        name: "PAINSIM_ARGON2_ITERATIONS",
        default: Number(Argon2Cost::RECOMMENDED.iterations as u64),
        meaning: "argon2id passes of new password hashes",
    },
    Setting {
        name: "PAINSIM_ARGON2_PARALLELISM",
        default: Number(Argon2Cost::RECOMMENDED.parallelism as u64),
        meaning: "argon2id lanes of new password hashes",
    },
    // Simulator choice, with the window below: five wrong passwords in 15 minutes is more than
    // a person mistyping, and stops guessing at one e-mail address long before it gets far.
    Setting {
        name: "PAINSIM_LOGIN_MAX_FAILURES",
        default: Value("5"),
        meaning: "failed logins per e-mail within the window before login is refused",
    },
    Setting {
        name: "PAINSIM_LOGIN_FAILURE_WINDOW_SECS",
        default: Value("900"),
        meaning: "the login throttling window, seconds",
    },
    // Simulator choice: a person logs in a few times an hour; 30 a minute with a burst of 10
    // lets a class behind one NAT address log in together and stops a script.
    Setting {
        name: "PAINSIM_AUTH_RATE_PER_MINUTE",
        default: Value("30"),
        meaning: "sustained rate of the per-client token bucket on `/api/auth/*`",
    },
    Setting {
        name: "PAINSIM_AUTH_BURST",
        default: Value("10"),
        meaning: "burst of the per-client token bucket on `/api/auth/*`",
    },
    // Simulator choice: a learner's client writes a few times a minute (opening attempts,
    // reported activity); 10 per second sustained and 100 at once is far above any person and
    // far below a script (about 250 activity events/s were accepted before).
    Setting {
        name: "PAINSIM_WRITE_RATE_PER_MINUTE",
        default: Value("600"),
        meaning: "sustained rate of the per-account limit of authenticated writes (POST, PUT, \
                  PATCH, DELETE; 429 with `Retry-After` beyond it)",
    },
    Setting {
        name: "PAINSIM_WRITE_BURST",
        default: Value("100"),
        meaning: "burst of the per-account limit of authenticated writes",
    },
    Setting {
        name: "PAINSIM_REQUIRE_TOTP_FOR_APPROVAL",
        default: Value("true"),
        meaning: "faculty approvals and returns need a TOTP-verified login",
    },
    Setting {
        name: "PAINSIM_IN_PROCESS_CAPACITY",
        default: Derived(
            "calibrated at start-up: the sessions of a scripted learner that this machine's \
             faster fluoroscopy renderer (GPU or CPU reference, both timed on the heaviest \
             station) holds at half CPU load, shown in `/healthz` (`render_worker.calibration`); \
             8 until the calibration is made",
        ),
        meaning: "most live simulation sessions the server's own (in-process) worker hosts at \
                  once; `0` = none, sessions run only on registered render workers; a number \
                  fixes it (the calibration still chooses the renderer)",
    },
    Setting {
        name: "PAINSIM_SESSIONS_PER_USER",
        default: Number(DEFAULT_SESSIONS_PER_USER as u64),
        meaning: "most live (unsubmitted) simulation sessions one user holds; more answer 429 \
                  `session_limit` with `\"scope\": \"user\"`",
    },
    Setting {
        name: "PAINSIM_SESSIONS_PER_COURSE",
        default: Number(DEFAULT_SESSIONS_PER_COURSE as u64),
        meaning: "most live (unsubmitted) simulation sessions of one course's attempts; more \
                  answer 429 `session_limit` with `\"scope\": \"course\"`",
    },
    Setting {
        name: "PAINSIM_LIVE_SESSION_IDLE_SECS",
        default: Number(DEFAULT_SESSION_IDLE.as_secs()),
        meaning: "seconds without a command after which a live simulation session is closed, \
                  even with its websocket open (close code 4001; it resumes from its log)",
    },
    Setting {
        name: "PAINSIM_PREPARE_ANATOMY",
        default: Value("true"),
        meaning: "load (or build) the stations' anatomy at start-up; `false` leaves it to the \
                  first session",
    },
    Setting {
        name: "PAINSIM_WORKER_TOKEN",
        default: Unset,
        meaning: "bearer token remote render workers register with (at least 16 characters); \
                  unset = registrations are refused",
    },
    Setting {
        name: "PAINSIM_REPLICA_ID",
        default: Derived("the host name and the process id"),
        meaning: "this server replica's name in the shared state (which replica relays a \
                  session, which one marked a worker dead); a pod name in Kubernetes",
    },
    Setting {
        name: "PAINSIM_ADMIN_PASSWORD",
        default: Derived("read from standard input"),
        meaning: "password for `server create-admin --email ...`",
    },
    Setting {
        name: "RUST_LOG",
        default: Value("info,sqlx=warn,wgpu_core=warn,wgpu_hal=warn,naga=warn"),
        meaning: "log filter (tracing-subscriber syntax); one that does not parse means the default",
    },
];

/// Names the server no longer reads, with their successors. Start-up refuses them when set, so
/// a deployment's old setting is never silently ignored or given the wrong one of two meanings.
pub const RETIRED: &[Retired] = &[
    Retired {
        name: "PAINSIM_SESSION_IDLE_SECS",
        instead: "`PAINSIM_LOGIN_IDLE_SECS` (idle expiry of a login session) or \
                  `PAINSIM_LIVE_SESSION_IDLE_SECS` (closing a live simulation session that gets \
                  no command)",
    },
    Retired {
        name: "PAINSIM_SESSION_ABSOLUTE_SECS",
        instead: "`PAINSIM_LOGIN_ABSOLUTE_SECS`",
    },
    Retired {
        name: "PAINSIM_IN_PROCESS_SESSIONS",
        instead: "`PAINSIM_IN_PROCESS_CAPACITY` (a number of sessions; `0` = none in-process)",
    },
];

impl From<SettingError> for ConfigError {
    fn from(e: SettingError) -> ConfigError {
        ConfigError {
            variable: e.variable,
            value: e.value,
            reason: e.reason,
        }
    }
}

/// Server configuration.
#[derive(Debug, Clone)]
pub struct Config {
    /// Listening address.
    pub bind: SocketAddr,
    /// External database; `None` runs the embedded private cluster.
    pub database_url: Option<String>,
    /// Data folder (embedded cluster under `data_dir/pg`).
    pub data_dir: PathBuf,
    /// Static web client folder.
    pub web_dir: PathBuf,
    /// Largest accepted request body in bytes.
    pub max_body_bytes: usize,
    /// The server's public origin (scheme, host and port, no trailing slash): LTI 1.3 URLs given
    /// to platforms and the IRIs of the platform's own xAPI activities are built on it.
    pub public_url: String,
    /// Learning-records settings (login sessions, passwords, TOTP, stations).
    pub records: RecordsConfig,
    /// Dispatch of live simulation sessions (in-process worker, limits, cluster token). Its
    /// stations are `records.stations_dir`.
    pub dispatch: DispatchConfig,
}

impl Config {
    /// Reads the process environment.
    pub fn from_env() -> Result<Config, ConfigError> {
        Self::from_lookup(env)
    }

    /// Reads configuration through `lookup` (the environment, or a map in tests).
    pub fn from_lookup(lookup: impl Fn(&str) -> Option<String>) -> Result<Config, ConfigError> {
        let s = Settings::new(SETTINGS, &lookup);
        s.refuse_retired(RETIRED)?;
        let bind_raw = s.value_or_default("PAINSIM_BIND").unwrap_or_default();
        let bind: SocketAddr = bind_raw
            .trim()
            .parse()
            .map_err(|e: std::net::AddrParseError| ConfigError {
                variable: "PAINSIM_BIND",
                value: bind_raw.clone(),
                reason: format!("{e} (expected host:port, e.g. 127.0.0.1:8080)"),
            })?;
        let max_body_bytes = s.count("PAINSIM_MAX_BODY_BYTES", 1024usize)?;
        let public_url = match s.value("PAINSIM_PUBLIC_URL") {
            None => format!("http://{bind}"),
            Some(raw) => {
                let trimmed = raw.trim().trim_end_matches('/').to_owned();
                let ok = (trimmed.starts_with("http://") || trimmed.starts_with("https://"))
                    && !trimmed.contains(['?', '#', ' '])
                    && trimmed.split("://").nth(1).is_some_and(|h| !h.is_empty());
                if !ok {
                    return Err(ConfigError {
                        variable: "PAINSIM_PUBLIC_URL",
                        value: raw,
                        reason: "expected an http(s) origin such as https://sim.example.org".into(),
                    });
                }
                trimmed
            }
        };
        Ok(Config {
            bind,
            public_url,
            database_url: s.value("DATABASE_URL"),
            data_dir: PathBuf::from(s.value_or_default("PAINSIM_DATA_DIR").unwrap_or_default()),
            web_dir: s
                .value("PAINSIM_WEB_DIR")
                .map(PathBuf::from)
                .unwrap_or_else(|| {
                    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../web-client"))
                }),
            max_body_bytes,
            records: records(&s, bind.ip().is_loopback(), max_body_bytes)?,
            dispatch: dispatch(&s)?,
        })
    }
}

/// The learning-records part of [`Config`].
fn records(
    s: &Settings<'_>,
    loopback_bind: bool,
    max_body_bytes: usize,
) -> Result<RecordsConfig, ConfigError> {
    Ok(RecordsConfig {
        cookie_secure: s.switch("PAINSIM_COOKIE_SECURE")?.unwrap_or(!loopback_bind),
        demo_accounts: s.switch("PAINSIM_DEMO_ACCOUNTS")?,
        loopback_bind,
        session_idle: s.seconds("PAINSIM_LOGIN_IDLE_SECS")?,
        session_absolute: s.seconds("PAINSIM_LOGIN_ABSOLUTE_SECS")?,
        argon2: Argon2Cost {
            memory_kib: s.count("PAINSIM_ARGON2_MEMORY_KIB", 8u32)?,
            iterations: s.count("PAINSIM_ARGON2_ITERATIONS", 1u32)?,
            parallelism: s.count("PAINSIM_ARGON2_PARALLELISM", 1u32)?,
        },
        login_max_failures: s.count("PAINSIM_LOGIN_MAX_FAILURES", 1u32)?,
        login_failure_window: s.seconds("PAINSIM_LOGIN_FAILURE_WINDOW_SECS")?,
        auth_rate_per_minute: s.count("PAINSIM_AUTH_RATE_PER_MINUTE", 1u32)?,
        auth_burst: s.count("PAINSIM_AUTH_BURST", 1u32)?,
        write_rate_per_minute: s.count("PAINSIM_WRITE_RATE_PER_MINUTE", 1u32)?,
        write_burst: s.count("PAINSIM_WRITE_BURST", 1u32)?,
        require_totp_for_approval: s
            .switch("PAINSIM_REQUIRE_TOTP_FOR_APPROVAL")?
            .unwrap_or(true),
        stations_dir: s
            .value("PAINSIM_STATIONS_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| {
                PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/stations"))
            }),
        max_body_bytes,
    })
}

/// Shortest cluster token accepted. Simulator choice: 16 characters of a random token are far
/// beyond guessing over the network; a shorter one is more likely a placeholder.
const MIN_WORKER_TOKEN_CHARS: usize = 16;

/// The dispatch part of [`Config`].
fn dispatch(s: &Settings<'_>) -> Result<DispatchConfig, ConfigError> {
    let worker_token = s.value("PAINSIM_WORKER_TOKEN").map(|t| t.trim().to_owned());
    if let Some(t) = worker_token
        .as_ref()
        .filter(|t| t.chars().count() < MIN_WORKER_TOKEN_CHARS)
    {
        return Err(ConfigError {
            variable: "PAINSIM_WORKER_TOKEN",
            value: format!("<{} characters>", t.chars().count()),
            reason: format!("expected at least {MIN_WORKER_TOKEN_CHARS} characters"),
        });
    }
    Ok(DispatchConfig {
        assets_root: s
            .value("PAINSIM_ASSETS_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets"))),
        in_process_capacity: s.parse_set(
            "PAINSIM_IN_PROCESS_CAPACITY",
            "a whole number, at least 0",
            |_: &usize| true,
        )?,
        worker_token,
        prepare_at_start: s.switch("PAINSIM_PREPARE_ANATOMY")?.unwrap_or(true),
        sessions_per_user: s.count("PAINSIM_SESSIONS_PER_USER", 1usize)?,
        sessions_per_course: s.count("PAINSIM_SESSIONS_PER_COURSE", 1usize)?,
        live_session_idle: s.seconds("PAINSIM_LIVE_SESSION_IDLE_SECS")?,
        replica_id: s
            .value("PAINSIM_REPLICA_ID")
            .map(|r| r.trim().chars().take(128).collect::<String>())
            .filter(|r| !r.is_empty()),
    })
}

/// `PAINSIM_ADMIN_PASSWORD` through `lookup` ([`env`]), for `server create-admin`; `None`
/// reads the password from standard input.
pub fn admin_password(lookup: impl Fn(&str) -> Option<String>) -> Option<String> {
    Settings::new(SETTINGS, &lookup).value("PAINSIM_ADMIN_PASSWORD")
}

/// `PAINSIM_PG_USER` through `lookup` ([`env`]): the account a root server runs the embedded
/// cluster as.
pub fn embedded_pg_user(lookup: impl Fn(&str) -> Option<String>) -> String {
    Settings::new(SETTINGS, &lookup)
        .value_or_default("PAINSIM_PG_USER")
        .unwrap_or_default()
}

/// The log filter (`RUST_LOG`) through `lookup` ([`env`]); read before the rest of the
/// configuration, so that its errors are logged.
pub fn log_filter(lookup: impl Fn(&str) -> Option<String>) -> tracing_subscriber::EnvFilter {
    Settings::new(SETTINGS, &lookup).log_filter()
}

// The test defaults of the learning records' settings live here, beside the table that
// defines the defaults, so `records::config` never imports this module.
impl RecordsConfig {
    /// Defaults with cheap password hashing, for tests.
    pub fn for_tests() -> RecordsConfig {
        let mut c = Config::from_lookup(|_| None)
            .expect("defaults are valid")
            .records;
        c.argon2 = Argon2Cost::TEST_ONLY;
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;
    use std::time::Duration;

    fn cfg(pairs: &[(&str, &str)]) -> Result<Config, ConfigError> {
        let map: HashMap<String, String> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        Config::from_lookup(|k| map.get(k).cloned())
    }

    #[test]
    fn defaults_run_the_embedded_platform_locally() {
        let c = cfg(&[]).unwrap();
        assert_eq!(c.bind.to_string(), "127.0.0.1:8080");
        assert!(c.database_url.is_none());
        assert_eq!(c.data_dir, PathBuf::from("data"));
        assert!(
            c.web_dir.join("index.html").exists(),
            "default web dir points at the repository's web-client/"
        );
        assert_eq!(c.records.argon2, Argon2Cost::RECOMMENDED);
        assert!(c.records.require_totp_for_approval);
        assert!(
            !c.records.cookie_secure,
            "default bind is loopback plain http"
        );
        assert!(
            c.records
                .stations_dir
                .join("l4-l5-left-facet.toml")
                .exists()
        );
        assert_eq!(c.records.session_idle, Duration::from_secs(1800));
        assert_eq!(c.dispatch.live_session_idle, DEFAULT_SESSION_IDLE);
        assert_eq!(c.dispatch.in_process_capacity, None);
        assert!(c.dispatch.assets_root.join("stations").is_dir());
        assert!(c.dispatch.prepare_at_start && c.dispatch.worker_token.is_none());
        assert_eq!(embedded_pg_user(|_| None), "postgres");
        assert_eq!(admin_password(|_| None), None);
    }

    #[test]
    fn bind_decides_the_automatic_switches() {
        assert!(
            cfg(&[("PAINSIM_BIND", "0.0.0.0:80")])
                .unwrap()
                .records
                .cookie_secure
        );
        assert!(
            cfg(&[("PAINSIM_COOKIE_SECURE", "true")])
                .unwrap()
                .records
                .cookie_secure
        );
        assert!(
            !cfg(&[("PAINSIM_BIND", "0.0.0.0:80")])
                .unwrap()
                .records
                .loopback_bind
        );
    }

    #[test]
    fn the_two_idle_limits_are_set_apart() {
        let c = cfg(&[
            ("PAINSIM_LOGIN_IDLE_SECS", "900"),
            ("PAINSIM_LIVE_SESSION_IDLE_SECS", "120"),
        ])
        .unwrap();
        assert_eq!(c.records.session_idle, Duration::from_secs(900));
        assert_eq!(c.dispatch.live_session_idle, Duration::from_secs(120));
        let c = cfg(&[("PAINSIM_LOGIN_ABSOLUTE_SECS", "3600")]).unwrap();
        assert_eq!(c.records.session_absolute, Duration::from_secs(3600));
    }

    #[test]
    fn retired_names_stop_start_up_naming_their_successors() {
        let e = cfg(&[("PAINSIM_SESSION_IDLE_SECS", "600")]).unwrap_err();
        assert_eq!(e.variable, "PAINSIM_SESSION_IDLE_SECS");
        assert!(
            e.reason.contains("PAINSIM_LOGIN_IDLE_SECS")
                && e.reason.contains("PAINSIM_LIVE_SESSION_IDLE_SECS"),
            "{e}"
        );
        let e = cfg(&[("PAINSIM_IN_PROCESS_SESSIONS", "4")]).unwrap_err();
        assert!(e.reason.contains("PAINSIM_IN_PROCESS_CAPACITY"), "{e}");
        let e = cfg(&[("PAINSIM_SESSION_ABSOLUTE_SECS", "3600")]).unwrap_err();
        assert!(e.reason.contains("PAINSIM_LOGIN_ABSOLUTE_SECS"), "{e}");
    }

    #[test]
    fn in_process_capacity_is_a_count_and_zero_means_none() {
        assert_eq!(
            cfg(&[("PAINSIM_IN_PROCESS_CAPACITY", "0")])
                .unwrap()
                .dispatch
                .in_process_capacity,
            Some(0)
        );
        assert_eq!(
            cfg(&[("PAINSIM_IN_PROCESS_CAPACITY", "3")])
                .unwrap()
                .dispatch
                .in_process_capacity,
            Some(3)
        );
        for bad in ["on", "-1", "2.5"] {
            assert_eq!(
                cfg(&[("PAINSIM_IN_PROCESS_CAPACITY", bad)])
                    .unwrap_err()
                    .variable,
                "PAINSIM_IN_PROCESS_CAPACITY"
            );
        }
    }

    #[test]
    fn bad_values_name_the_variable() {
        for (k, v) in [
            ("PAINSIM_BIND", "localhost"),
            ("PAINSIM_MAX_BODY_BYTES", "12"),
            ("PAINSIM_PUBLIC_URL", "sim.example.org"),
            ("PAINSIM_COOKIE_SECURE", "maybe"),
            ("PAINSIM_LOGIN_IDLE_SECS", "0"),
            ("PAINSIM_LIVE_SESSION_IDLE_SECS", "soon"),
            ("PAINSIM_ARGON2_MEMORY_KIB", "4"),
            ("PAINSIM_LOGIN_MAX_FAILURES", "-1"),
            ("PAINSIM_SESSIONS_PER_USER", "0"),
            ("PAINSIM_PREPARE_ANATOMY", "later"),
            ("PAINSIM_WORKER_TOKEN", "short"),
        ] {
            assert_eq!(cfg(&[(k, v)]).unwrap_err().variable, k, "{k}={v}");
        }
        let e = cfg(&[("PAINSIM_WORKER_TOKEN", "short")]).unwrap_err();
        assert!(
            !e.to_string().contains("short"),
            "the token stays out of messages: {e}"
        );
        assert!(
            cfg(&[("DATABASE_URL", "  ")])
                .unwrap()
                .database_url
                .is_none()
        );
        assert_eq!(cfg(&[]).unwrap().public_url, "http://127.0.0.1:8080");
        assert_eq!(
            cfg(&[("PAINSIM_PUBLIC_URL", "https://sim.example.org/")])
                .unwrap()
                .public_url,
            "https://sim.example.org"
        );
        assert!(
            !cfg(&[("PAINSIM_PREPARE_ANATOMY", "off")])
                .unwrap()
                .dispatch
                .prepare_at_start
        );
    }
}
