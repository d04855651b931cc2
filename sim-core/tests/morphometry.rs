//! The phantom's morphometry: lumbar dimensions measured on the built meshes against published
//! population means and standard deviations.

use sim_core::anatomy::phantom::morphometry::{
    MEAN_ONLY_TOLERANCE, Measured, MorphometryError, PUBLISHED, SOURCES, compare, measure,
    table_markdown,
};
use sim_core::anatomy::asset::RegionAsset;
use sim_core::anatomy::phantom::{self, PhantomParams};

/// The default phantom (the one the platform ships, 1.5 mm grid), built once per test binary
/// and cached by parameter hash under the test target's scratch folder (a rerun loads it). The
/// folder is the one the render-worker tests prepare the shipped lumbar region in
/// (`regions/lumbar-phantom`, the same generator, parameters and cache check), so a workspace
/// run meshes it once.
pub(crate) fn default_phantom() -> &'static RegionAsset {
    static A: std::sync::OnceLock<RegionAsset> = std::sync::OnceLock::new();
    A.get_or_init(|| {
        let t = std::time::Instant::now();
        let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("regions/lumbar-phantom");
        let asset = phantom::ensure_built_with(&dir, &PhantomParams::default(), &mut |_| {})
            .expect("phantom builds");
        eprintln!("default phantom ready in {:.1?}", t.elapsed());
        asset
    })
}

/// Its morphometry, measured once.
fn measured() -> &'static [Measured] {
    static M: std::sync::OnceLock<Vec<Measured>> = std::sync::OnceLock::new();
    M.get_or_init(|| measure(default_phantom()).expect("every dimension measurable"))
}

/// Every published dimension: within two standard deviations of its mean (Simulator choice: the
/// range of about 95 % of a normally distributed population, so every level is an ordinary
/// adult's), or within `MEAN_ONLY_TOLERANCE` of a mean published without one.
#[test]
fn every_dimension_is_within_two_sd_of_its_published_mean() {
    let rows = compare(measured()).expect("every reference has a measurement");
    eprintln!("{}", table_markdown(&rows));
    let outside: Vec<String> = rows
        .iter()
        .filter(|c| !c.agrees())
        .map(|c| format!("{} {:?}: {:.2} vs {:.2}", c.reference.level, c.reference.dimension, c.measured, c.reference.mean))
        .collect();
    assert!(outside.is_empty(), "outside 2 SD (or {MEAN_ONLY_TOLERANCE:.3} of a mean-only value): {outside:?}");
    for key in rows.iter().map(|c| c.reference.source) {
        assert!(SOURCES.iter().any(|(k, _)| *k == key), "source {key} is cited");
    }
}

/// Every dimension of every level is measured, and none is a degenerate ray (all positive,
/// finite, of anatomical size).
#[test]
fn every_level_is_measured_on_the_meshes() {
    let m = measured();
    for level in ["L1", "L2", "L3", "L4", "L5"] {
        let of_level: Vec<&Measured> = m.iter().filter(|x| x.level == level).collect();
        assert_eq!(of_level.len(), 11, "{level}: {of_level:?}");
        for x in of_level {
            // 1 mm to 100 mm (or 1 to 60 degrees): a chord that missed the bone or ran through
            // several bones would fall outside.
            let (lo, hi) = if x.dimension.unit() == "deg" { (1.0, 60.0) } else { (1.0, 100.0) };
            assert!(x.value.is_finite() && x.value > lo && x.value < hi, "{level} {:?} = {}", x.dimension, x.value);
        }
    }
}

/// A published reference without a measurement is named in the error, not skipped.
#[test]
fn a_reference_without_a_measurement_is_named() {
    let first = &PUBLISHED[0];
    let err = compare(&[]).unwrap_err();
    assert_eq!(
        err,
        MorphometryError::NoMeasurement {
            level: first.level,
            dimension: first.dimension,
        }
    );
    assert!(err.to_string().contains(first.level), "{err}");
}
