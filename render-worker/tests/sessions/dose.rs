//! The dose of a scripted procedure under the brightness control, against a published median.

use render_worker::session::*;

use super::support::{Driver, pose};

/// A fluoroscopy-guided left L4 transforaminal injection as a learner runs it on the demo
/// station, with the brightness control on its standard curve and the grid in (a new session):
/// AP to square the endplates, an ipsilateral oblique for the approach under intermittent live
/// fluoroscopy, a lateral for depth, an AP for the contrast run. 9 shots (0.9 s) and 28.1 s of
/// live fluoroscopy at 7.5 pulses per second, ticked every pulse as the client does: 29.0 s,
/// the published median fluoroscopy time of lumbar transforaminal injections (Y. Kim et al.,
/// "Radiation exposure in fluoroscopy-guided lumbar transforaminal epidural steroid injection",
/// 2014: median 29 s, median kerma-area product 0.68 Gy cm^2).
///
/// Returns the session's fluoroscopy time (s), air kerma (mGy) and kerma-area product (Gy cm^2).
fn scripted_l4_transforaminal() -> (f64, f64, f64) {
    let mut d = Driver::new();
    let mut t = 0u64;
    // (orbital, angular, shots, seconds of live fluoroscopy in bursts).
    let views: [(f64, f64, u32, &[f64]); 4] = [
        (0.0, 10.0, 3, &[2.0, 2.0]),
        (25.0, 10.0, 4, &[3.0, 3.0, 2.0, 2.0, 2.0, 2.0]),
        (90.0, 0.0, 1, &[2.5, 2.5]),
        (0.0, 10.0, 1, &[5.1]),
    ];
    for (orbital, angular, shots, bursts) in views {
        t += 1000;
        d.ok(t, pose(orbital, angular));
        for _ in 0..shots {
            t += 500;
            d.ok(t, Command::Shot);
        }
        for &seconds in bursts {
            t += 1000;
            d.ok(t, Command::Live { on: true });
            let end = t + (seconds * 1000.0).round() as u64;
            // The client ticks every pulse (133 ms at 7.5 pulses per second).
            while t + 133 < end {
                t += 133;
                d.ok(t, Command::Tick);
            }
            t = end;
            d.ok(t, Command::Live { on: false });
        }
    }
    let m = d.s.measurements();
    (
        m["fluoro_exposure_s"],
        m["air_kerma_mgy"],
        m["kerma_area_product_gycm2"],
    )
}

#[test]
fn brightness_dose_of_a_scripted_l4_transforaminal_is_near_the_published_median() {
    let (seconds, kerma_mgy, kap) = scripted_l4_transforaminal();
    let published_kap = 0.68;
    eprintln!(
        "scripted L4 transforaminal: {seconds:.1} s, air kerma {kerma_mgy:.2} mGy, KAP {kap:.3} \
         Gy cm^2 ({:+.0} % against the published median {published_kap})",
        (kap / published_kap - 1.0) * 100.0
    );
    assert!(
        (seconds - 29.0).abs() < 1e-9,
        "fluoroscopy time {seconds} s"
    );
    // Acceptance band, simulator choice: within a factor of two of the published median (one
    // phantom, one learner's script, against a median over patients of all sizes).
    assert!(
        (0.5 * published_kap..=2.0 * published_kap).contains(&kap),
        "KAP {kap} Gy cm^2"
    );
    assert!(kerma_mgy.is_finite() && kerma_mgy > 0.0, "{kerma_mgy}");
}
