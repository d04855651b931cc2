//! The web client's files are served, its tooling (npm packages, browser tests, scripts,
//! package manifests) is not, however the path is spelt.

use axum::http::{Method, StatusCode};

use crate::records_support::TestApp;

#[tokio::test]
async fn the_client_is_served_and_its_tooling_is_not() {
    let app = TestApp::new(&[]).await;
    for (path, status) in [
        ("/", StatusCode::OK),
        ("/app.js", StatusCode::OK),
        ("/styles.css", StatusCode::OK),
        ("/learner/some/client/route", StatusCode::OK),
        ("/tests/e2e.mjs", StatusCode::NOT_FOUND),
        ("/tests/harness.mjs", StatusCode::NOT_FOUND),
        ("/scripts/check-licenses.mjs", StatusCode::NOT_FOUND),
        ("/package.json", StatusCode::NOT_FOUND),
        ("/package-lock.json", StatusCode::NOT_FOUND),
        ("/node_modules/axe-core/package.json", StatusCode::NOT_FOUND),
        (
            "/%6Eode_modules/axe-core/package.json",
            StatusCode::NOT_FOUND,
        ),
        ("/Tests/e2e.mjs", StatusCode::NOT_FOUND),
    ] {
        let r = app.send(Method::GET, path, None, None).await;
        assert_eq!(r.status, status, "{path}");
    }
    // Files that exist on disk in the web folder, so the 404s above are refusals, not misses.
    let web = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../web-client");
    assert!(web.join("tests/e2e.mjs").is_file());
    assert!(web.join("package-lock.json").is_file());
}
