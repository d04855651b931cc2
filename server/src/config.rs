//! Configuration from the environment, with defaults that run a complete platform locally.
//!
//! | variable | default | meaning |
//! |---|---|---|
//! | `PAINSIM_BIND` | `127.0.0.1:8080` | address the HTTP server listens on |
//! | `DATABASE_URL` | unset | an existing PostgreSQL; unset = the embedded private cluster |
//! | `PAINSIM_DATA_DIR` | `./data` | where the embedded cluster (and later caches) live |
//! | `PAINSIM_WEB_DIR` | the repository's `web-client/` | static files of the web client |
//! | `PAINSIM_MAX_BODY_BYTES` | `1048576` | largest accepted request body |
//! | `PAINSIM_PUBLIC_URL` | `http://` + the bind address | the origin browsers and LMS platforms reach the server at (LTI redirect and JWKS URLs, xAPI authority and activity ids) |
//! | `RUST_LOG` | `info` | log filter (tracing-subscriber syntax) |

use std::net::SocketAddr;
use std::path::PathBuf;

pub use crate::error::ConfigError;

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
    /// Learning-records settings (sessions, passwords, TOTP, stations); see `records::config`.
    pub records: crate::records::config::RecordsConfig,
}

impl Config {
    /// Reads the process environment.
    pub fn from_env() -> Result<Config, ConfigError> {
        Self::from_lookup(|k| std::env::var(k).ok())
    }

    /// Reads configuration through `lookup` (the environment, or a map in tests).
    pub fn from_lookup(lookup: impl Fn(&str) -> Option<String>) -> Result<Config, ConfigError> {
        let bind_raw = lookup("PAINSIM_BIND").unwrap_or_else(|| "127.0.0.1:8080".to_owned());
        let bind = bind_raw.parse().map_err(|e: std::net::AddrParseError| ConfigError {
            variable: "PAINSIM_BIND",
            value: bind_raw.clone(),
            reason: format!("{e} (expected host:port, e.g. 127.0.0.1:8080)"),
        })?;
        let max_raw = lookup("PAINSIM_MAX_BODY_BYTES").unwrap_or_else(|| "1048576".to_owned());
        let max_body_bytes = max_raw.parse::<usize>().ok().filter(|&n| n >= 1024).ok_or_else(|| ConfigError {
            variable: "PAINSIM_MAX_BODY_BYTES",
            value: max_raw.clone(),
            reason: "expected a whole number of bytes, at least 1024".into(),
        })?;
        let public_url = match lookup("PAINSIM_PUBLIC_URL").filter(|s| !s.trim().is_empty()) {
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
            database_url: lookup("DATABASE_URL").filter(|s| !s.trim().is_empty()),
            data_dir: lookup("PAINSIM_DATA_DIR").map(PathBuf::from).unwrap_or_else(|| PathBuf::from("data")),
            web_dir: lookup("PAINSIM_WEB_DIR")
                .map(PathBuf::from)
                .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../web-client"))),
            max_body_bytes,
            records: crate::records::config::RecordsConfig::from_lookup(&lookup)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn cfg(pairs: &[(&str, &str)]) -> Result<Config, ConfigError> {
        let map: HashMap<String, String> = pairs.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        Config::from_lookup(|k| map.get(k).cloned())
    }

    #[test]
    fn defaults_run_the_embedded_platform_locally() {
        let c = cfg(&[]).unwrap();
        assert_eq!(c.bind.to_string(), "127.0.0.1:8080");
        assert!(c.database_url.is_none());
        assert_eq!(c.data_dir, PathBuf::from("data"));
        assert!(c.web_dir.join("index.html").exists(), "default web dir points at the repository's web-client/");
    }

    #[test]
    fn bad_values_name_the_variable() {
        let e = cfg(&[("PAINSIM_BIND", "localhost")]).unwrap_err();
        assert_eq!(e.variable, "PAINSIM_BIND");
        let e = cfg(&[("PAINSIM_MAX_BODY_BYTES", "12")]).unwrap_err();
        assert_eq!(e.variable, "PAINSIM_MAX_BODY_BYTES");
        assert!(cfg(&[("DATABASE_URL", "  ")]).unwrap().database_url.is_none());
        let e = cfg(&[("PAINSIM_PUBLIC_URL", "sim.example.org")]).unwrap_err();
        assert_eq!(e.variable, "PAINSIM_PUBLIC_URL");
        assert_eq!(cfg(&[]).unwrap().public_url, "http://127.0.0.1:8080");
        assert_eq!(cfg(&[("PAINSIM_PUBLIC_URL", "https://sim.example.org/")]).unwrap().public_url, "https://sim.example.org");
    }
}
