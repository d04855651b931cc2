//! Tests of the CPU reference frame: determinism, metering, noise statistics, supersampling,
//! shutters and contrast.

use super::display::round_grey;
use super::noise::{ln_factorial, ln_factorial_series, noisy_count};
use super::*;
use crate::fluoro::{EnergyModel, FluoroMaterial, IodineField, Projection, Scene};
use crate::geom::{capped_cylinder, equal_area_vertex_radius};
use crate::material::MaterialClass;
use crate::mesh::TriMesh;

fn small_projection(n: u32) -> Projection {
    Projection {
        detector_pixels: [n, n],
        pixel_pitch_mm: [120.0 / n as f64; 2],
        ..Projection::default()
    }
}

fn body_with_needle(needle_x_mm: f64) -> Scene {
    let mut s = Scene::new();
    s.add(
        "body",
        FluoroMaterial::Tissue(MaterialClass::SoftTissue),
        &TriMesh::icosphere([0.0; 3], 40.0, 3),
    );
    let r = equal_area_vertex_radius(0.36, 16);
    s.add(
        "needle",
        FluoroMaterial::Steel,
        &capped_cylinder([needle_x_mm, 0.0, -25.0], [needle_x_mm, 0.0, 25.0], r, 16),
    );
    s
}

#[test]
fn frames_are_deterministic_and_thread_count_independent() {
    let scene = body_with_needle(3.3);
    let p = small_projection(48);
    let noise = QuantumNoise {
        photons_per_pixel: 2000.0,
        seed: 42,
    };
    let s1 = RenderSettings {
        noise: Some(noise),
        threads: 1,
        ..RenderSettings::default()
    };
    let s2 = RenderSettings { threads: 2, ..s1 };
    let a = render_frame(&scene, None, &p, &s1).unwrap();
    let b = render_frame(&scene, None, &p, &s2).unwrap();
    assert_eq!(a, b);
    let c = render_frame(
        &scene,
        None,
        &p,
        &RenderSettings {
            noise: Some(QuantumNoise { seed: 43, ..noise }),
            ..s1
        },
    )
    .unwrap();
    assert_ne!(a, c, "another seed gives other grain");
}

#[test]
fn brightness_is_metered_on_the_noise_free_image() {
    // Uniform T with 11.5 expected quanta per pixel: the noisy counts are integers, so a
    // meter on the noisy frame would put the median count (11 or 12) at the target grey.
    // Metered on the noise-free image, count k shows at 0.5 + ln(k / 11.5) / 3.5 exactly.
    let (n, photons) = (64usize, 1000.0);
    let lambda = 11.5;
    let t = TransmissionImage {
        width: n as u32,
        height: n as u32,
        transmission: vec![lambda / photons; n * n],
        exposed: vec![true; n * n],
        supersampled_pixels: 0,
    };
    for seed in [1, 2, 3] {
        let noise = QuantumNoise {
            photons_per_pixel: photons,
            seed,
        };
        let settings = RenderSettings {
            noise: Some(noise),
            ..RenderSettings::default()
        };
        let mut noisy = t.clone();
        apply_noise(&mut noisy, &noise);
        let img = finish_frame(&t, &settings);
        let e = settings.exposure;
        for (p, &g) in img.pixels.iter().enumerate() {
            let ln_t = noisy.transmission[p].max(0.5 / photons).ln();
            let want =
                (e.target_grey + (ln_t - (lambda / photons).ln()) / e.log_range).clamp(0.0, 1.0);
            assert_eq!(g, (want * 255.0).round() as u8, "seed {seed} pixel {p}");
        }
    }
}

#[test]
fn quantum_noise_has_poisson_variance() {
    // Uniform transmission 0.25 at 4000 quanta: mean 1000 counts, so the relative standard
    // deviation of T is 1/sqrt(1000) = 3.16 %. 10,000 pixels estimate it to about 1 %.
    let n = 100usize;
    let mut t = TransmissionImage {
        width: n as u32,
        height: n as u32,
        transmission: vec![0.25; n * n],
        exposed: vec![true; n * n],
        supersampled_pixels: 0,
    };
    apply_noise(
        &mut t,
        &QuantumNoise {
            photons_per_pixel: 4000.0,
            seed: 7,
        },
    );
    let mean = t.transmission.iter().sum::<f64>() / (n * n) as f64;
    let var = t
        .transmission
        .iter()
        .map(|v| (v - mean).powi(2))
        .sum::<f64>()
        / (n * n - 1) as f64;
    let rel_sd = var.sqrt() / mean;
    assert!((mean - 0.25).abs() < 0.25 * 0.002, "{mean}");
    assert!(
        (rel_sd - 1.0 / 1000f64.sqrt()).abs() < 0.05 / 1000f64.sqrt(),
        "{rel_sd}"
    );
}

#[test]
fn noisy_counts_follow_the_poisson_distribution() {
    // Pearson's chi-square of 20,000 draws against the exact Poisson pmf (bins with an
    // expected count of at least 5, tails pooled), at means on both sides of the switch
    // from Knuth's method to PTRS and far above it. The 99.9 % quantile of chi-square with
    // d degrees of freedom is below d + 3.1 sqrt(2 d) + 10 for the 13 to 263 here
    // (Wilson-Hilferty), so a correct sampler fails this with probability about 1e-3 per
    // mean; the seeds are fixed, so the test is deterministic.
    let draws = 20_000usize;
    for (case, mean) in [3.7, 9.99, 10.0, 12.5, 29.5, 31.0, 150.0, 2500.0]
        .into_iter()
        .enumerate()
    {
        let noise = QuantumNoise {
            photons_per_pixel: mean,
            seed: 1000 + case as u64,
        };
        let mut hist = std::collections::BTreeMap::<u64, usize>::new();
        let (mut sum, mut sum2) = (0.0, 0.0);
        for p in 0..draws {
            let k = noisy_count(&noise, p, 1.0);
            assert!(k >= 0.0 && k.fract() == 0.0, "{k}");
            *hist.entry(k as u64).or_default() += 1;
            sum += k;
            sum2 += k * k;
        }
        let m = sum / draws as f64;
        let var = sum2 / draws as f64 - m * m;
        // Standard errors of the mean and the variance: sqrt(mean / n), mean sqrt(2 / n).
        assert!(
            (m - mean).abs() < 5.0 * (mean / draws as f64).sqrt(),
            "{mean}: {m}"
        );
        assert!(
            (var - mean).abs() < 5.0 * mean * (2.0 / draws as f64).sqrt(),
            "{mean}: {var}"
        );
        // Bins [lo, hi] around the mean with expected counts >= 5; outside pooled.
        let pmf = |k: u64| (-mean + k as f64 * mean.ln() - ln_factorial(k as f64)).exp();
        let expected = |k: u64| pmf(k) * draws as f64;
        let mode = mean.floor() as u64;
        let lo = (0..=mode).find(|&k| expected(k) >= 5.0).unwrap_or(0);
        let hi = (mode..)
            .take_while(|&k| expected(k) >= 5.0)
            .last()
            .unwrap_or(mode);
        let mut chi2 = 0.0;
        let mut inside_expected = 0.0;
        let mut inside_observed = 0usize;
        for k in lo..=hi {
            let (o, e) = (*hist.get(&k).unwrap_or(&0) as f64, expected(k));
            chi2 += (o - e).powi(2) / e;
            inside_expected += e;
            inside_observed += o as usize;
        }
        let (o, e) = (
            (draws - inside_observed) as f64,
            draws as f64 - inside_expected,
        );
        if e >= 5.0 {
            chi2 += (o - e).powi(2) / e;
        }
        let dof = (hi - lo) as f64 + 1.0;
        let bound = dof + 3.1 * (2.0 * dof).sqrt() + 10.0;
        eprintln!("poisson mean {mean}: chi2 {chi2:.1} over {dof} bins (bound {bound:.1})");
        assert!(chi2 < bound, "mean {mean}: chi2 {chi2} >= {bound}");
    }
}

#[test]
fn ln_factorial_matches_the_exact_sum() {
    let mut exact = 0.0f64;
    for k in 0..400u32 {
        if k > 1 {
            exact += f64::from(k).ln();
        }
        let got = ln_factorial(f64::from(k));
        // Summing 400 logarithms in f64 accumulates a few ulps of ln 400! (about 2000).
        assert!(
            (got - exact).abs() <= 1e-12 * exact.max(1.0),
            "{k}: {got} vs {exact}"
        );
    }
    // The table holds the series bit for bit, and beyond it the series answers.
    for k in (0..20_000u32).step_by(7).chain([8191, 8192, 8193]) {
        let k = f64::from(k);
        assert_eq!(
            ln_factorial(k).to_bits(),
            ln_factorial_series(k).to_bits(),
            "{k}"
        );
    }
}

#[test]
fn the_fast_finish_equals_noise_then_tone_mapping() {
    // finish_frame's table over counts and row split must give exactly apply_noise then
    // to_display_centred: a ramp of transmissions (Knuth and PTRS means, zero, and T = 5,
    // whose counts run past the table), shutters, both polarities, several thread counts.
    let (w, h) = (37usize, 23usize);
    let t = TransmissionImage {
        width: w as u32,
        height: h as u32,
        transmission: (0..w * h)
            .map(|p| {
                if p % 97 == 0 {
                    5.0
                } else {
                    (p % 41) as f64 / 40.0
                }
            })
            .collect(),
        exposed: (0..w * h).map(|p| p % 13 != 0).collect(),
        supersampled_pixels: 0,
    };
    for (photons, invert, threads) in [(40.0, false, 1), (40.0, true, 3), (3000.0, false, 0)] {
        let noise = QuantumNoise {
            photons_per_pixel: photons,
            seed: 5,
        };
        let settings = RenderSettings {
            noise: Some(noise),
            invert,
            threads,
            ..RenderSettings::default()
        };
        let centre = exposure_centre(&t, &settings.exposure, Some(&noise));
        let mut noisy = t.clone();
        apply_noise(&mut noisy, &noise);
        let want = to_display_centred(&noisy, &settings.exposure, invert, Some(&noise), centre);
        assert_eq!(
            finish_frame(&t, &settings),
            want,
            "{photons} {invert} {threads}"
        );
        // Without noise: the whole `to_display`, whatever the split.
        let clean = RenderSettings {
            noise: None,
            ..settings
        };
        assert_eq!(
            finish_frame(&t, &clean),
            to_display(&t, &clean.exposure, invert, None),
            "{invert} {threads}"
        );
    }
}

#[test]
fn supersampling_keeps_a_subpixel_needle_shift_smooth() {
    // A needle parallel to the image columns, moved by 1/8 pixel at a time. Its signal (the
    // intensity it removes, summed over the image) should not depend on where it falls within
    // a pixel. With 4 x 4 n-rooks samples each needle edge is resolved to 1/16 pixel; the
    // needle is 0.72 mm x 2.03 / 0.586 mm = 2.5 pixels wide, so the bound is 2 x (1/16) / 2.5
    // = 5 %. Centre sampling jumps by whole pixels (up to 1 / 2.5 = 40 %).
    let p = Projection {
        detector_pixels: [96, 96],
        pixel_pitch_mm: [300.0 / 512.0; 2],
        ..Projection::default()
    };
    let pitch_at_iso = p.pixel_pitch_mm[0] / p.isocentre_magnification();
    let body = {
        let mut s = Scene::new();
        s.add(
            "body",
            FluoroMaterial::Tissue(MaterialClass::SoftTissue),
            &TriMesh::icosphere([0.0; 3], 40.0, 3),
        );
        s
    };
    let settings = RenderSettings {
        energy: EnergyModel::Mono60,
        ..RenderSettings::default()
    };
    let single = RenderSettings {
        supersample: 1,
        ..settings
    };
    let removed = |s: &RenderSettings, x: f64| {
        let base = render_transmission(&body, None, &p, s).unwrap();
        let t = render_transmission(&body_with_needle(x), None, &p, s).unwrap();
        t.transmission
            .iter()
            .zip(&base.transmission)
            .map(|(a, b)| b - a)
            .sum::<f64>()
    };
    let (mut ss, mut one) = (Vec::new(), Vec::new());
    for k in 0..8 {
        let x = 2.0 + k as f64 * pitch_at_iso / 8.0;
        ss.push(removed(&settings, x));
        one.push(removed(&single, x));
    }
    let spread = |v: &[f64]| {
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                (l.min(x), h.max(x))
            });
        (hi - lo) / hi
    };
    assert!(
        spread(&ss) < 0.05,
        "supersampled spread {}: {ss:?}",
        spread(&ss)
    );
    assert!(
        spread(&one) > 0.15,
        "centre sampling aliases: spread {}: {one:?}",
        spread(&one)
    );
}

#[test]
fn shutters_and_brightness() {
    let scene = body_with_needle(0.0);
    let mut p = small_projection(40);
    p.collimation.x_max_mm = 30.0;
    let img = render_frame(&scene, None, &p, &RenderSettings::default()).unwrap();
    // Right of the blade (x > 30 mm, i.e. columns above 20 + 30/3 = 30): shutter grey.
    assert!(
        img.pixels[5 * 40 + 35..5 * 40 + 40]
            .iter()
            .all(|&g| g == SHUTTER_GREY)
    );
    // Fluoroscopy polarity: the needle (column 20) is darker than the tissue beside it.
    let row = 20 * 40;
    assert!(
        img.pixels[row + 20] < img.pixels[row + 14],
        "{:?}",
        &img.pixels[row..row + 40]
    );
    // Automatic brightness: a thicker patient (lower T everywhere) gives the same centre grey.
    let thick = {
        let mut s = Scene::new();
        s.add(
            "body",
            FluoroMaterial::Tissue(MaterialClass::SoftTissue),
            &TriMesh::icosphere([0.0; 3], 45.0, 3),
        );
        s
    };
    let thin = {
        let mut s = Scene::new();
        s.add(
            "body",
            FluoroMaterial::Tissue(MaterialClass::SoftTissue),
            &TriMesh::icosphere([0.0; 3], 40.0, 3),
        );
        s
    };
    let st = RenderSettings {
        energy: EnergyModel::Mono60,
        ..RenderSettings::default()
    };
    let a = render_frame(&thick, None, &small_projection(40), &st).unwrap();
    let b = render_frame(&thin, None, &small_projection(40), &st).unwrap();
    let c = 20 * 40 + 20;
    assert!(
        (i32::from(a.pixels[c]) - i32::from(b.pixels[c])).abs() <= 1,
        "{} {}",
        a.pixels[c],
        b.pixels[c]
    );
}

#[test]
fn iodine_column_darkens_the_frame_where_the_contrast_is() {
    // A synthetic contrast pool: a 21^3 grid of 1 mm voxels at 50 % stock in its middle
    // 11^3 voxels, centred 10 mm left of the isocentre (so it images right of centre).
    use crate::volume::{Volume, VolumeGrid};
    let grid = VolumeGrid {
        dims: [21, 21, 21],
        spacing_mm: [1.0; 3],
        origin_mm: [-20.0, -10.0, -10.0],
    };
    let mut v = Volume::filled(grid, 0.0f32);
    for k in 5..16 {
        for j in 5..16 {
            for i in 5..16 {
                v.set(i, j, k, 0.5);
            }
        }
    }
    let field = IodineField::new(v);
    let mut scene = Scene::new();
    scene.add(
        "body",
        FluoroMaterial::Tissue(MaterialClass::SoftTissue),
        &TriMesh::icosphere([0.0; 3], 40.0, 3),
    );
    let p = small_projection(40);
    let settings = RenderSettings::default();
    let with = render_transmission(&scene, Some(&field), &p, &settings).unwrap();
    let without = render_transmission(&scene, None, &p, &settings).unwrap();
    // Pool centre at x = -10 mm: column 20 + 10 x 2.03 / 3 = 26.8; row 20.
    let at = |t: &TransmissionImage, i: usize, j: usize| t.transmission[j * 40 + i];
    // Through the pool: 11 mm at 50 % (plus the trilinear ramps) = about 5.5 mm of stock;
    // at 80 kVp behind 8 cm of tissue that removes well over a third of the signal.
    assert!(at(&with, 26, 20) < 0.7 * at(&without, 26, 20));
    // Away from the pool nothing changes.
    assert_eq!(at(&with, 10, 20), at(&without, 10, 20));
}

/// A needle overlaid on an anatomy scene gives the frame of one scene holding both, bit for bit:
/// supersampling (silhouettes and steel edges), noise and metering included.
#[test]
fn a_needle_overlay_renders_as_one_scene() {
    let combined = body_with_needle(3.3);
    let mut body = Scene::new();
    body.add(
        "body",
        FluoroMaterial::Tissue(MaterialClass::SoftTissue),
        &TriMesh::icosphere([0.0; 3], 40.0, 3),
    );
    let mut needle = Scene::new();
    let r = equal_area_vertex_radius(0.36, 16);
    needle.add(
        "needle",
        FluoroMaterial::Steel,
        &capped_cylinder([3.3, 0.0, -25.0], [3.3, 0.0, 25.0], r, 16),
    );
    let p = small_projection(48);
    let settings = RenderSettings {
        noise: Some(QuantumNoise {
            photons_per_pixel: 2000.0,
            seed: 7,
        }),
        ..RenderSettings::default()
    };
    let layered = body.with_overlay(&needle);
    let a = render_transmission(layered, None, &p, &settings).unwrap();
    let b = render_transmission(&combined, None, &p, &settings).unwrap();
    assert!(a.supersampled_pixels > 0);
    assert_eq!(a.supersampled_pixels, b.supersampled_pixels);
    assert_eq!(a.transmission, b.transmission);
    assert_eq!(
        render_frame(layered, None, &p, &settings).unwrap(),
        render_frame(&combined, None, &p, &settings).unwrap()
    );
    assert_eq!(
        render_chords(layered, &p, 1),
        render_chords(&combined, &p, 1)
    );
}

/// The finish of an `f32` transmission equals the finish of its `f64` copy, with and without
/// noise, with shutters closing part of the image.
#[test]
fn the_f32_finish_equals_the_finish_of_the_widened_copy() {
    let p = Projection {
        collimation: crate::fluoro::Collimation {
            x_min_mm: -40.0,
            x_max_mm: 40.0,
            y_min_mm: -30.0,
            y_max_mm: 30.0,
            iris_radius_mm: None,
        },
        ..small_projection(48)
    };
    let t =
        render_transmission(&body_with_needle(3.3), None, &p, &RenderSettings::default()).unwrap();
    let narrow: Vec<f32> = t.transmission.iter().map(|&x| x as f32).collect();
    let widened = TransmissionImage {
        transmission: narrow.iter().map(|&x| f64::from(x)).collect(),
        ..t.clone()
    };
    assert!(t.exposed.iter().any(|e| !e), "shutters close part of it");
    for noise in [
        None,
        Some(QuantumNoise {
            photons_per_pixel: 2000.0,
            seed: 5,
        }),
    ] {
        let settings = RenderSettings {
            noise,
            ..RenderSettings::default()
        };
        assert_eq!(
            finish_frame_f32(t.width, t.height, &narrow, &t.exposed, &settings),
            finish_frame(&widened, &settings)
        );
    }
}

/// A detector signal kept from one finish finishes later shots (other seeds, other quanta,
/// no noise) exactly as the whole finish of the transmission does, for every combination of
/// scatter and receptor profile; it serves only the scatter and receptor it was made with (and
/// settings holding a NaN serve their own signal). The whole finish makes its frames through
/// the same signal; that it still makes the frames it made before the signal existed is what
/// render-worker's pinned session hashes check (scatter and the flat panel are a session's
/// defaults).
#[test]
fn a_kept_detector_signal_finishes_new_shots_as_the_transmission_does() {
    use crate::fluoro::receptor::{ReceptorKind, ReceptorSettings};
    use crate::fluoro::scatter::superposition::ScatterSettings;
    let p = small_projection(64);
    let t =
        render_transmission(&body_with_needle(3.3), None, &p, &RenderSettings::default()).unwrap();
    let narrow: Vec<f32> = t.transmission.iter().map(|&x| x as f32).collect();
    let pitch = p.pixel_pitch_mm[0];
    let scatter = ScatterSettings {
        kvp: 80,
        grid: true,
        air_gap_mm: 150.0,
        pixel_pitch_mm: pitch,
    };
    let receptor = |kind| ReceptorSettings {
        kind,
        pixel_pitch_mm: pitch,
    };
    let shots = [
        None,
        Some(QuantumNoise {
            photons_per_pixel: 2000.0,
            seed: 5,
        }),
        Some(QuantumNoise {
            photons_per_pixel: 700.0,
            seed: 6,
        }),
    ];
    let plain = finish_frame_f32(
        t.width,
        t.height,
        &narrow,
        &t.exposed,
        &RenderSettings::default(),
    );
    for scatter in [None, Some(scatter)] {
        for receptor in [
            None,
            Some(receptor(ReceptorKind::FlatPanel)),
            Some(receptor(ReceptorKind::ImageIntensifier)),
        ] {
            let with = |noise| RenderSettings {
                noise,
                scatter,
                receptor,
                ..RenderSettings::default()
            };
            let kept =
                DetectorSignal::of_f32(t.width, t.height, &narrow, &t.exposed, &with(shots[1]));
            for noise in shots {
                let settings = with(noise);
                assert!(kept.serves(&settings));
                let whole = finish_frame_f32(t.width, t.height, &narrow, &t.exposed, &settings);
                assert!(
                    kept.finish(&settings) == whole,
                    "scatter {scatter:?}, receptor {receptor:?}, noise {noise:?}"
                );
                if noise.is_none() && (scatter.is_some() || receptor.is_some()) {
                    assert!(whole != plain, "scatter or the receptor changes the frame");
                }
            }
            let other = RenderSettings {
                scatter: Some(ScatterSettings {
                    kvp: 95,
                    ..scatter.unwrap_or(ScatterSettings {
                        kvp: 80,
                        grid: false,
                        air_gap_mm: 0.0,
                        pixel_pitch_mm: pitch,
                    })
                }),
                ..with(None)
            };
            assert!(!kept.serves(&other), "another scatter needs another signal");
            let nan = RenderSettings {
                receptor: Some(ReceptorSettings {
                    kind: ReceptorKind::FlatPanel,
                    pixel_pitch_mm: f64::NAN,
                }),
                ..with(None)
            };
            let odd = DetectorSignal::of_f32(t.width, t.height, &narrow, &t.exposed, &nan);
            assert!(odd.serves(&nan) && odd.finish(&nan) == odd.finish(&nan));
        }
    }
}

/// Every grey a frame can meet, and the values next to each half, round as `f64::round`.
#[test]
fn round_grey_is_round_bit_for_bit() {
    let mut xs = vec![
        0.0,
        255.0,
        f64::NAN,
        0.49999999999999994,
        254.49999999999997,
    ];
    for k in 0..255 {
        let half = f64::from(k) + 0.5;
        xs.extend([half, half.next_down(), half.next_up(), f64::from(k)]);
    }
    let mut u = 0x1234_5678_9abc_def0_u64;
    for _ in 0..1_000_000 {
        u = crate::rng::splitmix64(u);
        xs.push(crate::rng::unit_f64(u) * 255.0);
    }
    for x in xs {
        assert_eq!(round_grey(x), x.round() as u8, "{x:?}");
    }
}

/// Receptor profiles through the finish (`crate::fluoro::receptor`): the distortion moves a
/// mark where `distort_px` says, the vignetting darkens only the intensifier's periphery.
mod receptor_profiles {
    use super::*;
    use crate::fluoro::receptor::{Distortion, ReceptorKind, ReceptorSettings, vignetting};

    /// A uniform field with a small dark square (a needle tip's silhouette) at `centre_px`.
    fn field_with_mark(n: usize, centre_px: [f64; 2]) -> Vec<f32> {
        (0..n * n)
            .map(|p| {
                let (x, y) = ((p % n) as f64 + 0.5, (p / n) as f64 + 0.5);
                let inside = (x - centre_px[0]).abs() < 3.0 && (y - centre_px[1]).abs() < 3.0;
                if inside { 0.01 } else { 0.1 }
            })
            .collect()
    }

    /// Centroid of the pixels darker than the midpoint of the image's grey range.
    fn dark_centroid(pixels: &[u8], n: usize) -> [f64; 2] {
        let (lo, hi) = (*pixels.iter().min().unwrap(), *pixels.iter().max().unwrap());
        let mid = (u16::from(lo) + u16::from(hi)) / 2;
        let (mut sx, mut sy, mut c) = (0.0, 0.0, 0.0);
        for (p, &g) in pixels.iter().enumerate() {
            if u16::from(g) < mid {
                let w = f64::from(mid as u8 - g);
                sx += w * ((p % n) as f64 + 0.5);
                sy += w * ((p / n) as f64 + 0.5);
                c += w;
            }
        }
        [sx / c, sy / c]
    }

    #[test]
    fn distortion_moves_a_mark_where_distort_px_says_and_the_flat_panel_leaves_it() {
        let n = 256;
        let mark = [200.0, 60.0];
        let t = field_with_mark(n, mark);
        let exposed = vec![true; n * n];
        for kind in ReceptorKind::ALL {
            let settings = RenderSettings {
                receptor: Some(ReceptorSettings {
                    kind,
                    pixel_pitch_mm: 300.0 / n as f64,
                }),
                ..RenderSettings::default()
            };
            let img = finish_frame_f32(n as u32, n as u32, &t, &exposed, &settings);
            let seen = dark_centroid(&img.pixels, n);
            let want = match Distortion::of(kind, n as u32, n as u32) {
                Some(d) => d.distort_px(mark),
                None => mark,
            };
            // Half a pixel: the centroid of a 6-pixel mark resampled bilinearly and blurred.
            assert!(
                (seen[0] - want[0]).hypot(seen[1] - want[1]) < 0.5,
                "{}: mark at {seen:?}, expected {want:?}",
                kind.name()
            );
        }
    }

    #[test]
    fn receptor_vignetting_darkens_the_intensifier_periphery_only() {
        let n = 128;
        let settings = RenderSettings::default();
        let exposed = vec![true; n * n];
        let frame = |kind| {
            let mut img = crate::fluoro::Image {
                width: n as u32,
                height: n as u32,
                pixels: vec![128; n * n],
            };
            super::frame::vignette(&mut img, &exposed, kind, &settings);
            img.pixels
        };
        let (fp, ii) = (
            frame(ReceptorKind::FlatPanel),
            frame(ReceptorKind::ImageIntensifier),
        );
        assert!(
            fp.iter().all(|&g| g == 128),
            "a flat panel has no vignetting"
        );
        let at = |img: &[u8], i: usize, j: usize| i32::from(img[j * n + i]);
        assert_eq!(at(&ii, n / 2, n / 2), 128, "the centre keeps its grey");
        // The middle of the left edge: 1 - 0.2 rho^2 at rho about 0.97, 255 ln(v) / 3.5 grey
        // darker (the default log range).
        let v = vignetting(ReceptorKind::ImageIntensifier, n, n, 2, n / 2);
        let want = 128.0 + 255.0 / 3.5 * v.ln();
        assert_eq!(f64::from(at(&ii, 2, n / 2)), want.round(), "v {v}");
        // Darker towards every corner.
        assert!(at(&ii, 0, 0) < at(&ii, 2, n / 2));
    }
}
