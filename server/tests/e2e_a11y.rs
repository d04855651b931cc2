//! Every screen passes axe-core's WCAG 2.0/2.1 A and AA rules with no violation
//! (`web-client/tests/a11y.mjs` in headless Chromium): login, stations, the fluoroscopy and
//! ultrasound session, the key map dialog, the result, the debrief, the review queue, a review,
//! the cohort dashboard and the LTI admin page.
//!
//! `PAINSIM_E2E_SCREENSHOTS=$PWD/docs cargo test -p server --test tests -- e2e_a11y` also
//! rewrites the README's pictures in `docs/screens/`.

use crate::disclosure::station_toml;
use crate::dispatch_support::demo_server_for;
use crate::e2e_browser::{BROWSER_TURN, can_run, run_script};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_screen_passes_axe_with_wcag_21_a_and_aa() {
    if !can_run("every_screen_passes_axe_with_wcag_21_a_and_aa") {
        return;
    }
    let _turn = BROWSER_TURN.lock().await;
    let srv = demo_server_for(true, None, &station_toml()).await;
    // `PAINSIM_E2E_SCREENSHOTS=docs` writes the screens' pictures to docs/screens/.
    let report = run_script("a11y.mjs", srv.addr, "screens", &[]).await;
    let screens = report["screens"].as_array().expect("screens");
    let names: Vec<&str> = screens.iter().map(|s| s["screen"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "login",
            "stations",
            "fluoroscopy session",
            "key map dialog",
            "ultrasound session",
            "result",
            "debrief",
            "review queue",
            "review",
            "cohort dashboard",
            "LTI admin"
        ]
    );
    let failing: Vec<String> = screens
        .iter()
        .filter(|s| !s["violations"].as_array().unwrap().is_empty())
        .map(|s| format!("{}: {:#}", s["screen"], s["violations"]))
        .collect();
    assert!(failing.is_empty(), "axe violations:\n{}", failing.join("\n"));
    assert_eq!(report["console_errors"], serde_json::json!([]), "{report:#}");
}
