//! Scatter tests: the Monte Carlo's samplers, its broad-field scatter-to-primary ratios against
//! acceptance bands for an adult lumbar field, the superposition against the Monte Carlo, the grid, and the
//! frame's scatter under extreme inputs.

use super::kernel::{GAPS_MM, KVPS, KernelTable, PHOTONS, SEED, STEP_MM, WATER_MM};
use super::monte_carlo::{Beam, CentreScore, SlabSetup, field_centre, klein_nishina};
use super::superposition::{ScatterSettings, centre_spr, scatter_field, water_equivalent_mm};
use super::tables::ScatterTables;
use super::*;
use crate::fluoro::geometry::{ISOCENTRE_TO_DETECTOR_MM, SOURCE_TO_ISOCENTRE_MM};
use crate::rng::SplitMix64;

const SID_MM: f64 = SOURCE_TO_ISOCENTRE_MM + ISOCENTRE_TO_DETECTOR_MM;

fn broad(kvp: u32, water_mm: f64, gap_mm: f64, half_mm: f64, photons: usize) -> CentreScore {
    let setup = SlabSetup {
        kvp,
        water_mm,
        air_gaps_mm: vec![gap_mm],
        beam: Beam::Field {
            source_to_detector_mm: SID_MM,
            half_x_mm: half_mm,
            half_y_mm: half_mm,
        },
        grid: AntiScatterGrid::FLUOROSCOPY,
        photons,
        seed: 0x5CA7,
    };
    // A 40 mm disc at the largest gaps, where few scattered photons arrive.
    let disc = if gap_mm > 300.0 { 40.0 } else { 20.0 };
    field_centre(&setup, disc).expect("committed spectrum")
}

/// Numerical mean of `f(cos)` over the density `p(cos)` on [-1, 1] (midpoint rule).
fn mean_over(p: impl Fn(f64) -> f64, f: impl Fn(f64) -> f64) -> f64 {
    let n = 200_000;
    let (mut num, mut den) = (0.0, 0.0);
    for k in 0..n {
        let c = -1.0 + (k as f64 + 0.5) * 2.0 / n as f64;
        num += p(c) * f(c);
        den += p(c);
    }
    num / den
}

#[test]
fn scatter_klein_nishina_sampler_matches_the_cross_section() {
    // dsigma/dOmega ~ P^2 (P + 1/P - sin^2) with P = E'/E (Klein and Nishina 1929).
    for e in [30.0, 60.0, 100.0] {
        let k = e / 510.998_95;
        let kn = |c: f64| {
            let p = 1.0 / (1.0 + k * (1.0 - c));
            p * p * (p + 1.0 / p - (1.0 - c * c))
        };
        let exact_cos = mean_over(kn, |c| c);
        let exact_ratio = mean_over(kn, |c| 1.0 / (1.0 + k * (1.0 - c)));
        let mut rng = SplitMix64::new(7);
        let n = 400_000;
        let (mut sc, mut sr) = (0.0, 0.0);
        for _ in 0..n {
            let (c, e_out) = klein_nishina(&mut rng, e);
            sc += c;
            sr += e_out / e;
        }
        let (mc, mr) = (sc / n as f64, sr / n as f64);
        // 4 standard errors of the mean of cos (sd < 0.6 / sqrt(n) = 0.001).
        assert!(
            (mc - exact_cos).abs() < 0.004,
            "{e} keV: mean cos {mc} vs {exact_cos}"
        );
        assert!(
            (mr - exact_ratio).abs() < 0.001,
            "{e} keV: E'/E {mr} vs {exact_ratio}"
        );
    }
}

#[test]
fn scatter_broad_field_spr_of_an_ap_lumbar_view_is_in_the_published_bands() {
    // An AP lumbar field: about 20 cm of water, a 20 cm field, 80 kVp, the detector on the
    // patient (20 mm air gap). Acceptance bands, simulator choice: SPR 2 to 5 without a grid and
    // 0.4 to 1 with a ratio-10 grid, the range usually quoted for adult abdominal fields.
    let s = broad(80, 200.0, 20.0, 100.0, 600_000);
    let (spr, spr_err) = s.spr();
    let (grid, grid_err) = s.spr_grid();
    assert!(
        (2.0..=5.0).contains(&spr),
        "no grid: SPR {spr} +- {spr_err}"
    );
    assert!(
        (0.4..=1.0).contains(&grid),
        "grid: SPR {grid} +- {grid_err}"
    );
    // Tighter collimation (10 cm) scatters less.
    let narrow = broad(80, 200.0, 20.0, 50.0, 600_000);
    assert!(
        narrow.spr().0 < 0.6 * spr,
        "10 cm field {:?} vs 20 cm {spr}",
        narrow.spr()
    );
}

#[test]
fn scatter_superposition_matches_the_monte_carlo_on_broad_fields() {
    // Tolerance: 12 % of the Monte Carlo's ratio plus 2.5 of its standard errors. The 12 % is
    // the superposition's own error budget (parallel pencils for a divergent beam, linear
    // interpolation between tabulated gaps and thicknesses, 10 mm rings); the largest seen over
    // these cases while writing the test was 9 % (80 kVp, 200 mm, 20 mm gap, no grid).
    let cases = [
        (80, 200.0, 20.0, 100.0),
        (80, 200.0, 20.0, 50.0),
        (80, 200.0, 200.0, 100.0),
        (80, 200.0, 650.0, 100.0),
        (100, 320.0, 100.0, 100.0),
        (60, 100.0, 20.0, 120.0),
    ];
    for (kvp, water, gap, half) in cases {
        let mc = broad(kvp, water, gap, half, 400_000);
        for grid in [false, true] {
            let (want, err) = if grid { mc.spr_grid() } else { mc.spr() };
            let got = centre_spr(kvp, water, half, half, gap, grid).expect("spectrum");
            assert!(
                (got - want).abs() <= 0.12 * want + 2.5 * err,
                "{kvp} kVp {water} mm gap {gap} field {} grid {grid}: model {got}, MC {want} +- {err}",
                2.0 * half
            );
            // The frame's superposition of a uniform slab image agrees with the centre formula.
            let n = 256;
            let pitch = 300.0 / n as f64;
            let t0 = mc.primary;
            let exposed: Vec<bool> = (0..n * n)
                .map(|p| {
                    let x = ((p % n) as f64 + 0.5) * pitch - 150.0;
                    let y = ((p / n) as f64 + 0.5) * pitch - 150.0;
                    x.abs() < half && y.abs() < half
                })
                .collect();
            let settings = ScatterSettings {
                kvp,
                grid,
                air_gap_mm: gap,
                pixel_pitch_mm: pitch,
            };
            let field = scatter_field(&vec![t0; n * n], &exposed, n, n, &settings).expect("field");
            let frame = field.at(n / 2, n / 2) / (t0 * settings.primary_factor());
            assert!(
                (frame - got).abs() <= 0.05 * got,
                "{kvp} kVp {water} mm gap {gap} grid {grid}: frame {frame} vs centre {got}"
            );
        }
    }
}

#[test]
fn scatter_kernel_table_reproduces_from_the_monte_carlo() {
    // One table point rerun with a tenth of the photons and another seed: the committed
    // cumulative kernels at 100, 250 and 500 mm agree within 5 % (the rerun's scatter at 100 mm
    // behind the largest gap is about 3,000 photon tracks: a standard error near 2 %).
    let (k, w) = (1, 5);
    assert_eq!((KVPS[k], WATER_MM[w]), (80, 200.0));
    let fresh = KernelTable::simulate(80, 200.0, PHOTONS / 10, SEED ^ 0xFFFF).expect("spectrum");
    let table = KernelTable::get();
    for (g, kernel) in fresh.iter().enumerate() {
        let committed = table.at(k, w, g);
        for r_mm in [100.0, 250.0, 500.0] {
            let i = (r_mm / STEP_MM) as usize - 1;
            for (a, b) in [
                (kernel.cumulative[i], committed.cumulative[i]),
                (kernel.cumulative_grid[i], committed.cumulative_grid[i]),
            ] {
                assert!(
                    (a - b).abs() <= 0.05 * b,
                    "gap {} r {r_mm}: rerun {a} vs committed {b}",
                    GAPS_MM[g]
                );
            }
        }
    }
}

#[test]
fn scatter_grid_passes_focused_primary_and_stops_oblique_scatter() {
    let grid = AntiScatterGrid::FLUOROSCOPY;
    let tables = ScatterTables::get();
    let tp = grid.primary_transmission();
    assert!((tp - 0.728).abs() < 0.001, "primary transmission {tp}");
    // A focused photon passes as the primary does (the strips' tops stop it entirely).
    assert!((grid.transmission(0.0, 1.0, 50.0, tables) - tp).abs() < 1e-9);
    // Transmission falls with the angle until the interspaces close (tan 0.117 for ratio 10),
    // stays below a fifth of the primary's beyond, and rises with the energy (the strips are
    // penetrated).
    let at = |tan: f64| grid.transmission(tan, 1.0 / (1.0f64 + tan * tan).sqrt(), 50.0, tables);
    let mut last = tp;
    for tan in [0.02, 0.05, 0.08, 0.11] {
        let t = at(tan);
        assert!(t < last, "tan {tan}: {t} after {last}");
        last = t;
    }
    for tan in [0.12, 0.2, 0.3, 0.5, 1.0, 3.0] {
        assert!(at(tan) < 0.2 * tp, "tan {tan}: {}", at(tan));
    }
    let (lo, hi) = (
        grid.transmission(0.5, 0.9, 40.0, tables),
        grid.transmission(0.5, 0.9, 80.0, tables),
    );
    assert!(hi > lo, "80 keV {hi} vs 40 keV {lo}");
}

#[test]
fn scatter_falls_with_air_gap_and_collimation_and_grows_with_thickness() {
    let spr = |water, half, gap, grid| centre_spr(80, water, half, half, gap, grid).expect("spr");
    for grid in [false, true] {
        let mut last = f64::INFINITY;
        for gap in [0.0, 50.0, 150.0, 300.0, 650.0] {
            let s = spr(200.0, 100.0, gap, grid);
            assert!(s < last, "gap {gap}: {s} after {last}");
            last = s;
        }
        let mut last = f64::INFINITY;
        for half in [150.0, 100.0, 50.0, 25.0] {
            let s = spr(200.0, half, 50.0, grid);
            assert!(s < last, "half field {half}: {s} after {last}");
            last = s;
        }
        let mut last = 0.0;
        for water in [5.0, 50.0, 150.0, 250.0, 400.0] {
            let s = spr(water, 100.0, 50.0, grid);
            assert!(s > last, "water {water}: {s} after {last}");
            last = s;
        }
    }
}

#[test]
fn scatter_field_is_finite_and_non_negative_on_hostile_images() {
    let s = ScatterSettings {
        kvp: 80,
        grid: true,
        air_gap_mm: 300.0,
        pixel_pitch_mm: 0.6,
    };
    let n = 64;
    let images: Vec<Vec<f64>> = vec![
        vec![0.0; n * n],
        vec![1.0; n * n],
        vec![f64::NAN; n * n],
        vec![f64::INFINITY; n * n],
        vec![-1.0; n * n],
        (0..n * n)
            .map(|p| if p % 3 == 0 { 1e-300 } else { 2.0 })
            .collect(),
    ];
    for t in &images {
        let f = scatter_field(t, &vec![true; n * n], n, n, &s).expect("field");
        for v in &f.values {
            assert!(v.is_finite() && *v >= 0.0, "{v}");
        }
    }
    // Nothing exposed: no scatter. A 1 x 1 image, a mismatched mask and an unknown voltage.
    let none = scatter_field(&vec![0.5; n * n], &vec![false; n * n], n, n, &s).expect("field");
    assert!(none.values.iter().all(|&v| v == 0.0));
    assert!(scatter_field(&[0.5], &[true], 1, 1, &s).is_some());
    assert!(scatter_field(&[0.5, 0.5], &[true], 2, 1, &s).is_none());
    assert!(scatter_field(&[0.5], &[true], 1, 1, &ScatterSettings { kvp: 81, ..s }).is_none());
    // A pitch that is no detector's, a NaN air gap, a field far beyond the kernels' reach.
    for pitch in [0.0, -1.0, 1e-9, f64::NAN, f64::INFINITY] {
        let bad = ScatterSettings {
            pixel_pitch_mm: pitch,
            ..s
        };
        assert!(scatter_field(&vec![0.5; n * n], &vec![true; n * n], n, n, &bad).is_none());
    }
    let nan_gap = ScatterSettings {
        air_gap_mm: f64::NAN,
        ..s
    };
    let f = scatter_field(&vec![0.1; n * n], &vec![true; n * n], n, n, &nan_gap).expect("field");
    assert!(f.values.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(centre_spr(80, 200.0, 100.0, 100.0, f64::NAN, true).is_some_and(f64::is_finite));
    let huge = centre_spr(80, 200.0, 1e9, 1e9, 100.0, false).expect("spr");
    let reach = centre_spr(80, 200.0, 500.0, 500.0, 100.0, false).expect("spr");
    assert_eq!(huge, reach, "nothing scatters in from beyond the kernels' 500 mm");
    // The water curve inverts itself.
    for mm in [0.0, 10.0, 123.4, 400.0] {
        let t = super::superposition::water_transmission(80, mm).expect("spectrum");
        let back = water_equivalent_mm(80, t).expect("spectrum");
        assert!((back - mm).abs() < 0.05, "{mm} mm -> {t} -> {back}");
    }
}
