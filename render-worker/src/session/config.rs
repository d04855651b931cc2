//! A session's fixed settings: what stays the same for its whole life, also in snapshots, with
//! each modality's part ([`FluoroConfig`] for the C-arm); and the settings this crate reads from
//! the process environment.
//!
//! # The environment
//! This module is the only place in the crate that reads the environment ([`env`]). Every
//! variable is one row of [`WORKER_SETTINGS`] (name, default, meaning), read through
//! [`Settings`], which refuses a name that is not in its table and takes the default from the
//! table itself, so the README's table (checked against these rows by the server's
//! `configuration` test) cannot drift from what the code does. [`WorkerConfig`] is filled from
//! it for the `render-worker` binary; [`ultrasound_renderer`] is the one setting read by the
//! device code, which the server's in-process worker shares. The server's table
//! (`server::config::SETTINGS`) uses the same [`Setting`] rows and [`Settings`] reader.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// Fixed settings of a session.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SessionConfig {
    /// C-arm detector and rendering.
    pub fluoro: FluoroConfig,
    /// Seed of everything random (quantum noise).
    pub seed: u64,
}

impl Default for SessionConfig {
    fn default() -> Self {
        SessionConfig {
            fluoro: FluoroConfig::default(),
            seed: 0x5e55_1011,
        }
    }
}

/// Fixed settings of a session's C-arm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FluoroConfig {
    /// Square detector size, pixels.
    pub detector_pixels: u32,
    /// Detector side, mm (300: a 30 cm flat panel, as `Projection::default`).
    pub detector_mm: f64,
    /// Supersampling of silhouette pixels (`n x n`). Simulator choice for live use: 2.
    pub supersample: u32,
    /// Quantum noise on (seeded per image).
    pub noise: bool,
}

impl Default for FluoroConfig {
    fn default() -> Self {
        FluoroConfig {
            detector_pixels: 512,
            detector_mm: 300.0,
            supersample: 2,
            noise: true,
        }
    }
}

/// One environment variable: its name, its default and what it means. A table of these is the
/// single description of a process's settings, in the code and in the README.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Setting {
    /// The variable's name.
    pub name: &'static str,
    /// What applies when the variable is unset or blank.
    pub default: SettingDefault,
    /// What it sets, one sentence fragment (Markdown), as the README shows it.
    pub meaning: &'static str,
}

/// What applies when a setting is unset or blank.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SettingDefault {
    /// This text, parsed by the same code as a value from the environment.
    Value(&'static str),
    /// This whole number (a named constant of the code, which documents the choice), parsed by
    /// the same code as a value from the environment.
    Number(u64),
    /// Nothing: the feature the setting turns on stays off (its meaning says what unset does).
    Unset,
    /// Computed at start-up, described in these words (Markdown).
    Derived(&'static str),
}

/// A name that is no longer read. Start-up refuses it when set, rather than ignoring a
/// deployment's setting or guessing which of its successors was meant.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Retired {
    /// The old name.
    pub name: &'static str,
    /// What to set instead (Markdown), e.g. "`A` (the login session) or `B` (the live session)".
    pub instead: &'static str,
}

/// A setting whose value was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid configuration: {variable}={value:?}: {reason}")]
pub struct SettingError {
    /// The environment variable.
    pub variable: &'static str,
    /// Its value.
    pub value: String,
    /// Why it was refused.
    pub reason: String,
}

/// The process environment, as a lookup for [`Settings`]: the only function of the crate that
/// reads it. A value that is not valid Unicode counts as unset.
pub fn env(name: &str) -> Option<String> {
    std::env::var(name).ok()
}

/// Reads the settings of one table through a lookup (the process environment, or a map in
/// tests).
pub struct Settings<'a> {
    table: &'static [Setting],
    lookup: &'a dyn Fn(&str) -> Option<String>,
}

impl<'a> Settings<'a> {
    /// A reader of `table` through `lookup`.
    pub fn new(table: &'static [Setting], lookup: &'a dyn Fn(&str) -> Option<String>) -> Self {
        Settings { table, lookup }
    }

    /// Refuses the first of `retired` that is set, naming what to set instead.
    pub fn refuse_retired(&self, retired: &'static [Retired]) -> Result<(), SettingError> {
        for r in retired {
            if let Some(value) = (self.lookup)(r.name) {
                return Err(SettingError {
                    variable: r.name,
                    value,
                    reason: format!(
                        "this name is no longer read; set {} instead",
                        r.instead.replace('`', "")
                    ),
                });
            }
        }
        Ok(())
    }

    /// The row of `name`. A name outside the table is a programming error: every setting the
    /// code reads must be described there.
    pub fn row(&self, name: &str) -> &'static Setting {
        self.table
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("{name} is read but is not a row of its settings table"))
    }

    /// The value set, if any; a blank value counts as unset (a deployment file that writes
    /// `NAME=` means the default).
    pub fn value(&self, name: &str) -> Option<String> {
        let row = self.row(name);
        (self.lookup)(row.name).filter(|v| !v.trim().is_empty())
    }

    /// The value set, else the table's default when that is a value; `None` for a default that
    /// is unset or derived.
    pub fn value_or_default(&self, name: &str) -> Option<String> {
        self.value(name).or_else(|| match self.row(name).default {
            SettingDefault::Value(v) => Some(v.to_owned()),
            SettingDefault::Number(n) => Some(n.to_string()),
            SettingDefault::Unset | SettingDefault::Derived(_) => None,
        })
    }

    /// The value, or the table's default, parsed as `T` and accepted by `ok`; `what` says what
    /// is expected, for the error. Panics when the row's default is not a value: such a row is
    /// read with [`Settings::parse_set`].
    pub fn parse<T: std::str::FromStr>(
        &self,
        name: &str,
        what: &str,
        ok: impl Fn(&T) -> bool,
    ) -> Result<T, SettingError> {
        let raw = self
            .value_or_default(name)
            .unwrap_or_else(|| panic!("{name} has no default value in its settings table"));
        self.accept(name, raw, what, ok)
    }

    /// The value set, parsed as `T` and accepted by `ok`; `None` when unset.
    pub fn parse_set<T: std::str::FromStr>(
        &self,
        name: &str,
        what: &str,
        ok: impl Fn(&T) -> bool,
    ) -> Result<Option<T>, SettingError> {
        self.value(name)
            .map(|raw| self.accept(name, raw, what, ok))
            .transpose()
    }

    /// A whole number of seconds, at least 1, as a duration.
    pub fn seconds(&self, name: &str) -> Result<std::time::Duration, SettingError> {
        self.parse::<u64>(name, "a whole number of seconds, at least 1", |v| *v >= 1)
            .map(std::time::Duration::from_secs)
    }

    /// A whole number of at least `min`.
    pub fn count<T>(&self, name: &str, min: T) -> Result<T, SettingError>
    where
        T: std::str::FromStr + PartialOrd + std::fmt::Display,
    {
        let what = format!("a whole number, at least {min}");
        self.parse(name, &what, |v: &T| *v >= min)
    }

    /// A switch: `true`/`false` (also `1`/`0`, `yes`/`no`, `on`/`off`) or `auto` (`None`), from
    /// the value or the table's default.
    pub fn switch(&self, name: &str) -> Result<Option<bool>, SettingError> {
        let raw = self
            .value_or_default(name)
            .unwrap_or_else(|| panic!("{name} has no default value in its settings table"));
        match raw.trim().to_ascii_lowercase().as_str() {
            "auto" => Ok(None),
            "1" | "true" | "yes" | "on" => Ok(Some(true)),
            "0" | "false" | "no" | "off" => Ok(Some(false)),
            _ => Err(SettingError {
                variable: self.row(name).name,
                value: raw,
                reason: "expected true, false or auto".into(),
            }),
        }
    }

    /// The log filter (`RUST_LOG`, tracing-subscriber syntax): the value when it parses, else
    /// the table's default (a filter that does not parse must not silence the logs that would
    /// say so).
    pub fn log_filter(&self) -> tracing_subscriber::EnvFilter {
        let default = match self.row("RUST_LOG").default {
            SettingDefault::Value(v) => v,
            other => panic!("RUST_LOG needs a filter as its default, not {other:?}"),
        };
        self.value("RUST_LOG")
            .and_then(|v| tracing_subscriber::EnvFilter::try_new(v).ok())
            .unwrap_or_else(|| tracing_subscriber::EnvFilter::new(default))
    }

    fn accept<T: std::str::FromStr>(
        &self,
        name: &str,
        raw: String,
        what: &str,
        ok: impl Fn(&T) -> bool,
    ) -> Result<T, SettingError> {
        match raw.trim().parse::<T>() {
            Ok(v) if ok(&v) => Ok(v),
            _ => Err(SettingError {
                variable: self.row(name).name,
                value: raw,
                reason: format!("expected {what}"),
            }),
        }
    }
}

/// Sessions one `render-worker` takes until its start-up calibration
/// ([`super::calibration::calibrate_when_ready`]) has measured its own, when
/// `RENDER_WORKER_CAPACITY` does not fix it. Simulator choice: a small lab group on one
/// machine, as the server's in-process worker before its calibration.
pub const DEFAULT_WORKER_CAPACITY: usize = 8;

/// Default drain after SIGTERM, seconds. Simulator choice: a learner mid-action finishes a
/// step within seconds, a whole session never does; 25 s leaves the servers time to move the
/// rest within Kubernetes' default 30 s grace period.
pub const DEFAULT_DRAIN_SECS: u64 = 25;

/// The settings of this crate: the `render-worker` binary's, and the ultrasound renderer that
/// the server's in-process worker reads too. The README's render-worker table is these rows.
pub const WORKER_SETTINGS: &[Setting] = &[
    Setting {
        name: "RENDER_WORKER_BIND",
        default: SettingDefault::Value("127.0.0.1:8081"),
        meaning: "address the `render-worker` binary listens on (host:port)",
    },
    Setting {
        name: "RENDER_WORKER_ASSETS",
        default: SettingDefault::Value("assets"),
        meaning: "folder of the anatomy regions, with the station definitions in its `stations/`",
    },
    Setting {
        name: "RENDER_WORKER_CAPACITY",
        default: SettingDefault::Derived(
            "calibrated at start-up: the sessions of a scripted learner that this machine's \
             faster fluoroscopy renderer (GPU or CPU reference, both timed on the heaviest \
             station) holds at half CPU load, shown in `/healthz` (`calibration`) and announced \
             to the server; 8 until the calibration is made",
        ),
        meaning: "most sessions the worker hosts at once (at least 1); set, it fixes the \
                  capacity and the calibration only chooses the renderer",
    },
    Setting {
        name: "RENDER_WORKER_REGISTER_URL",
        default: SettingDefault::Unset,
        meaning: "the server's `/api/workers`: with `RENDER_WORKER_TOKEN`, the worker registers \
                  there and keeps announcing itself; unset (both unset) = a standalone worker",
    },
    Setting {
        name: "RENDER_WORKER_TOKEN",
        default: SettingDefault::Unset,
        meaning: "the server's `PAINSIM_WORKER_TOKEN`, presented when registering",
    },
    Setting {
        name: "RENDER_WORKER_PUBLIC_URL",
        default: SettingDefault::Derived("`http://` + the bound address"),
        meaning: "the URL the server reaches this worker at, announced when registering",
    },
    Setting {
        name: "RENDER_WORKER_DRAIN_SECS",
        default: SettingDefault::Number(DEFAULT_DRAIN_SECS),
        meaning: "on SIGTERM the worker takes no new sessions and waits this many seconds for \
                  its live ones to end, then hands the rest back to the servers, which restore \
                  them on other workers from snapshot and log; keep it below the orchestrator's \
                  grace period (Kubernetes: `terminationGracePeriodSeconds`)",
    },
    Setting {
        name: "PAINSIM_ULTRASOUND_RENDERER",
        default: SettingDefault::Value("auto"),
        meaning: "B-mode frames on the GPU compute path (`gpu`), the sim-core CPU reference \
                  (`cpu`), or `auto`: the GPU on hardware adapters, the CPU reference under \
                  lavapipe (faster there); read by every worker, the server's in-process one too",
    },
    Setting {
        name: "RUST_LOG",
        default: SettingDefault::Value("info"),
        meaning: "log filter (tracing-subscriber syntax); one that does not parse means the default",
    },
];

/// The `render-worker` binary's settings, from [`WORKER_SETTINGS`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WorkerConfig {
    /// Listening address, `host:port` (a host name is resolved when binding).
    pub bind: String,
    /// Region folders, with `stations/` inside.
    pub assets: PathBuf,
    /// Most sessions at once, when fixed by the operator; `None`: calibrated.
    pub capacity: Option<usize>,
    /// Where and how to register with a server; `None` for a standalone worker.
    pub registration: Option<WorkerRegistration>,
    /// The URL announced to the server; `None` announces `http://` + the bound address.
    pub public_url: Option<String>,
    /// How long it drains after SIGTERM (`RENDER_WORKER_DRAIN_SECS`).
    pub drain: std::time::Duration,
}

/// How a worker joins a server.
#[derive(Clone, PartialEq, Eq)]
pub struct WorkerRegistration {
    /// The server's `/api/workers`.
    pub url: String,
    /// The cluster token (the server's `PAINSIM_WORKER_TOKEN`).
    pub token: String,
}

impl std::fmt::Debug for WorkerRegistration {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // The token is a credential: never in logs.
        f.debug_struct("WorkerRegistration")
            .field("url", &self.url)
            .field("token", &"<set>")
            .finish()
    }
}

impl WorkerConfig {
    /// Reads the settings through `lookup` ([`env`], or a map in tests).
    pub fn from_lookup(lookup: impl Fn(&str) -> Option<String>) -> Result<Self, SettingError> {
        let s = Settings::new(WORKER_SETTINGS, &lookup);
        let bind = s.value_or_default("RENDER_WORKER_BIND").unwrap_or_default();
        if !bind.contains(':') {
            return Err(SettingError {
                variable: "RENDER_WORKER_BIND",
                value: bind,
                reason: "expected host:port, e.g. 0.0.0.0:8081".into(),
            });
        }
        // Registration needs both; one without the other is a half-configured cluster, which
        // would otherwise run as an unannounced worker that the server never uses.
        let registration = match (
            s.value("RENDER_WORKER_REGISTER_URL"),
            s.value("RENDER_WORKER_TOKEN"),
        ) {
            (Some(url), Some(token)) => Some(WorkerRegistration { url, token }),
            (None, None) => None,
            (Some(url), None) => {
                return Err(SettingError {
                    variable: "RENDER_WORKER_REGISTER_URL",
                    value: url,
                    reason: "set RENDER_WORKER_TOKEN too (the server's PAINSIM_WORKER_TOKEN)"
                        .into(),
                });
            }
            (None, Some(_)) => {
                return Err(SettingError {
                    variable: "RENDER_WORKER_TOKEN",
                    value: "<set>".into(),
                    reason: "set RENDER_WORKER_REGISTER_URL too (the server's /api/workers)".into(),
                });
            }
        };
        Ok(WorkerConfig {
            bind: bind.trim().to_owned(),
            assets: PathBuf::from(
                s.value_or_default("RENDER_WORKER_ASSETS")
                    .unwrap_or_default(),
            ),
            capacity: s.parse_set(
                "RENDER_WORKER_CAPACITY",
                "a whole number, at least 1",
                |v: &usize| *v >= 1,
            )?,
            registration,
            public_url: s
                .value("RENDER_WORKER_PUBLIC_URL")
                .map(|u| u.trim().to_owned()),
            drain: s.seconds("RENDER_WORKER_DRAIN_SECS")?,
        })
    }

    /// The log filter of the `render-worker` binary (`RUST_LOG`).
    pub fn log_filter(lookup: impl Fn(&str) -> Option<String>) -> tracing_subscriber::EnvFilter {
        Settings::new(WORKER_SETTINGS, &lookup).log_filter()
    }
}

/// `PAINSIM_ULTRASOUND_RENDERER` as set (`cpu`, `gpu` or `auto`; `None` when unset), for
/// [`crate::session::devices::ultrasound_on_gpu`], which judges the value.
pub fn ultrasound_renderer(lookup: impl Fn(&str) -> Option<String>) -> Option<String> {
    Settings::new(WORKER_SETTINGS, &lookup).value("PAINSIM_ULTRASOUND_RENDERER")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn worker(pairs: &[(&str, &str)]) -> Result<WorkerConfig, SettingError> {
        let map: HashMap<String, String> = pairs
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        WorkerConfig::from_lookup(|k| map.get(k).cloned())
    }

    #[test]
    fn defaults_are_the_tables() {
        let c = worker(&[]).unwrap();
        assert_eq!(c.bind, "127.0.0.1:8081");
        assert_eq!(c.assets, PathBuf::from("assets"));
        assert_eq!(c.capacity, None, "calibrated");
        assert!(c.registration.is_none() && c.public_url.is_none());
        // A blank value is the default, as a deployment file's `NAME=` means.
        assert_eq!(
            worker(&[("RENDER_WORKER_CAPACITY", " ")]).unwrap().capacity,
            None
        );
        assert_eq!(
            worker(&[("RENDER_WORKER_CAPACITY", "3")]).unwrap().capacity,
            Some(3)
        );
    }

    #[test]
    fn bad_values_name_the_variable() {
        for (k, v) in [
            ("RENDER_WORKER_CAPACITY", "0"),
            ("RENDER_WORKER_CAPACITY", "eight"),
            ("RENDER_WORKER_BIND", "8081"),
        ] {
            assert_eq!(worker(&[(k, v)]).unwrap_err().variable, k, "{k}={v}");
        }
        let e = worker(&[(
            "RENDER_WORKER_REGISTER_URL",
            "http://server:8080/api/workers",
        )])
        .unwrap_err();
        assert!(e.reason.contains("RENDER_WORKER_TOKEN"), "{e}");
        let e = worker(&[("RENDER_WORKER_TOKEN", "secret-token-123456")]).unwrap_err();
        assert!(
            !e.to_string().contains("secret"),
            "the token stays out of messages: {e}"
        );
        let both = worker(&[
            (
                "RENDER_WORKER_REGISTER_URL",
                "http://server:8080/api/workers",
            ),
            ("RENDER_WORKER_TOKEN", "secret-token-123456"),
        ])
        .unwrap();
        let r = both.registration.unwrap();
        assert_eq!(r.url, "http://server:8080/api/workers");
        assert!(!format!("{r:?}").contains("secret"));
    }

    #[test]
    fn a_name_outside_the_table_is_refused() {
        let lookup = |_: &str| None;
        let s = Settings::new(WORKER_SETTINGS, &lookup);
        let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| s.value("NOT_A_ROW")));
        assert!(
            read.is_err(),
            "reading a name that is not in the table must panic"
        );
    }

    #[test]
    fn retired_names_are_refused_with_their_successors() {
        const RETIRED: &[Retired] = &[Retired {
            name: "OLD",
            instead: "`NEW_A` or `NEW_B`",
        }];
        let lookup = |k: &str| (k == "OLD").then(|| "5".to_owned());
        let e = Settings::new(WORKER_SETTINGS, &lookup)
            .refuse_retired(RETIRED)
            .unwrap_err();
        assert_eq!(e.variable, "OLD");
        assert!(e.reason.contains("NEW_A or NEW_B"), "{e}");
        let unset = |_: &str| None;
        assert!(
            Settings::new(WORKER_SETTINGS, &unset)
                .refuse_retired(RETIRED)
                .is_ok()
        );
    }

    #[test]
    fn ultrasound_renderer_is_the_value_set() {
        assert_eq!(ultrasound_renderer(|_| None), None);
        assert_eq!(
            ultrasound_renderer(|k| (k == "PAINSIM_ULTRASOUND_RENDERER").then(|| "cpu".into()))
                .as_deref(),
            Some("cpu")
        );
    }
}
