//! The web client's files: everything under the web folder except the client's own tooling
//! (its npm packages, browser tests and scripts, which are development tools and not part of
//! what a browser loads), with `index.html` for any other path (the client routes in the page).

use axum::extract::Request;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use tower::ServiceExt;
use tower_http::services::{ServeDir, ServeFile};

/// Top-level names under the web folder that are never served (404).
pub const NOT_SERVED: [&str; 5] = [
    "node_modules",
    "tests",
    "scripts",
    "package.json",
    "package-lock.json",
];

/// Whether a request path names one of [`NOT_SERVED`] (compared after percent-decoding, so
/// `/%6Eode_modules/` is refused too).
pub fn is_tooling(path: &str) -> bool {
    let decoded = percent_encoding::percent_decode_str(path).decode_utf8_lossy();
    let first = decoded
        .trim_start_matches('/')
        .split(['/', '\\'])
        .next()
        .unwrap_or("");
    NOT_SERVED.iter().any(|n| first.eq_ignore_ascii_case(n))
}

/// Serves the client from `dir`.
pub async fn serve(dir: std::path::PathBuf, req: Request) -> Response {
    if is_tooling(req.uri().path()) {
        return StatusCode::NOT_FOUND.into_response();
    }
    let files = ServeDir::new(&dir).fallback(ServeFile::new(dir.join("index.html")));
    match files.oneshot(req).await {
        Ok(r) => r.into_response(),
        Err(e) => match e {},
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tooling_paths_are_recognised_however_spelt() {
        for p in [
            "/node_modules/axe-core/axe.js",
            "/tests/e2e.mjs",
            "/scripts/check-licenses.mjs",
            "/package.json",
            "/%6Eode_modules/x",
            "/NODE_MODULES/x",
            "//tests/harness.mjs",
        ] {
            assert!(is_tooling(p), "{p}");
        }
        for p in [
            "/",
            "/app.js",
            "/index.html",
            "/styles.css",
            "/testsuite.js",
            "/a/tests/x",
        ] {
            assert!(!is_tooling(p), "{p}");
        }
    }
}
