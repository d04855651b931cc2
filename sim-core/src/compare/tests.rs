use super::*;
use crate::rng::SplitMix64;

/// A `w` x `h` grey image of random levels.
fn random_grey(rng: &mut SplitMix64, w: usize, h: usize) -> Vec<u8> {
    (0..w * h).map(|_| (rng.next_u64() % 256) as u8).collect()
}

#[test]
fn identical_images_give_zero_difference() {
    let mut rng = SplitMix64::new(0x434f_4d50);
    for case in 0..50 {
        let (w, h) = (1 + case % 13, 1 + case % 7);
        let img = random_grey(&mut rng, w, h);
        let d = Compare::image(w, h).all(&img, &img).unwrap();
        assert_eq!(d.pixels, w * h, "case {case}");
        assert_eq!(
            (d.max_abs, d.mean_abs, d.mean_signed, d.rms),
            (0.0, 0.0, 0.0, 0.0)
        );
        assert_eq!((d.median_abs, d.p99_abs), (0.0, 0.0));
        assert_eq!((d.pixels_over, d.values_over), (0, 0));
        assert_eq!(d.fraction_within(), 1.0);
        assert_eq!(d.psnr_db(255.0), f64::INFINITY);
        assert_eq!(d.check(), Ok(()));
        // Exact agreement holds for fields too, in any mix of types.
        let field: Vec<f32> = img.iter().map(|&g| f32::from(g) * 0.37).collect();
        let field64: Vec<f64> = field.iter().map(|&v| f64::from(v)).collect();
        let d = Compare::image(w, h).all(&field, &field64).unwrap();
        assert_eq!((d.max_abs, d.values_over), (0.0, 0), "case {case}");
    }
}

#[test]
fn a_single_changed_pixel_is_found_at_its_coordinates() {
    let mut rng = SplitMix64::new(0x5049_5845);
    for case in 0..200 {
        let (w, h) = (
            1 + (rng.next_u64() % 40) as usize,
            1 + (rng.next_u64() % 30) as usize,
        );
        let expected = random_grey(&mut rng, w, h);
        let mut actual = expected.clone();
        let (x, y) = ((rng.next_u64() as usize) % w, (rng.next_u64() as usize) % h);
        let delta = 2 + (rng.next_u64() % 100) as u8;
        actual[y * w + x] = expected[y * w + x].wrapping_add(delta);
        let d = Compare::image(w, h)
            .tolerance(Tolerance::absolute(1.0))
            .all(&actual, &expected)
            .unwrap();
        let changed = (f64::from(actual[y * w + x]) - f64::from(expected[y * w + x])).abs();
        assert_eq!(d.max_abs, changed, "case {case}");
        let at = d.largest.unwrap();
        assert_eq!((at.x, at.y, at.channel), (x, y, None), "case {case}");
        assert_eq!((d.pixels_over, d.values_over), (1, 1), "case {case}");
        let worst = d.check().unwrap_err().worst().unwrap();
        assert_eq!((worst.x, worst.y), (x, y), "case {case}");
        assert_eq!(worst.actual, f64::from(actual[y * w + x]));
        assert_eq!(worst.expected, f64::from(expected[y * w + x]));
        assert_eq!(d.fraction_over(), 1.0 / (w * h) as f64);
    }
}

#[test]
fn a_changed_channel_is_reported_with_its_pixel_and_channel() {
    let expected: Vec<f64> = (0..4 * 3 * 5).map(f64::from).collect();
    let mut actual = expected.clone();
    // Pixel (2, 1) of a 4 x 3 image with 5 channels, channel 3.
    actual[(4 + 2) * 5 + 3] += 0.5;
    let d = Compare::image(4, 3)
        .channels(5)
        .tolerance(Tolerance::absolute(0.1))
        .all(&actual, &expected)
        .unwrap();
    assert_eq!(
        (d.pixels, d.values(), d.values_over, d.pixels_over),
        (12, 60, 1, 1)
    );
    let err = d.check().unwrap_err();
    let w = err.worst().unwrap();
    assert_eq!((w.x, w.y, w.channel), (2, 1, Some(3)));
    let text = err.to_string();
    assert!(
        text.starts_with("1 of 60 values differ by more than 0.1"),
        "{text}"
    );
    assert!(
        text.contains("pixel (2, 1) channel 3: actual 33.5 expected 33"),
        "{text}"
    );
    assert!(text.contains("|difference| 0.5, bound 0.1"), "{text}");
}

#[test]
fn the_tolerance_is_absolute_or_relative_whichever_is_larger() {
    let t = Tolerance::absolute_or_relative(0.1, 0.005);
    assert_eq!(t.bound(2.0), 0.1);
    assert_eq!(t.bound(-100.0), 0.5);
    let expected = [2.0, 100.0, 100.0];
    let actual = [2.1, 100.5, 100.6];
    let d = Compare::values(3)
        .tolerance(t)
        .all(&actual, &expected)
        .unwrap();
    // 2.1 - 2.0 rounds to just over 0.1 in binary; 100.5 is exactly 0.5 from 100.
    assert_eq!(d.values_over, 2, "{d}");
    let w = d.worst.unwrap();
    assert_eq!((w.x, w.expected), (2, 100.0));
    assert!((d.worst_excess - 0.1).abs() < 1e-9, "{}", d.worst_excess);
    // The worst is the value furthest outside its bound, not the largest difference.
    let d = Compare::values(2)
        .tolerance(Tolerance::absolute_or_relative(0.0, 0.1))
        .all(&[1.5, 110.0], &[1.0, 100.0])
        .unwrap();
    assert_eq!((d.largest.unwrap().x, d.worst.unwrap().x), (1, 0));
}

#[test]
fn masks_and_pixel_lists_compare_only_their_pixels() {
    let expected = [0u8, 0, 0, 0, 0, 0];
    let actual = [9u8, 0, 0, 0, 0, 9];
    let c = Compare::image(3, 2);
    let d = c.at(&actual, &expected, [1, 2, 3, 4]).unwrap();
    assert_eq!((d.pixels, d.max_abs), (4, 0.0));
    assert_eq!(d.check(), Ok(()));
    let mask = [false, true, true, true, true, true];
    let d = c.masked(&actual, &expected, &mask).unwrap();
    assert_eq!((d.pixels, d.max_abs, d.pixels_over), (5, 9.0, 1));
    let at = d.largest.unwrap();
    assert_eq!((at.x, at.y), (2, 1));
    assert_eq!(
        c.at(&actual, &expected, [6]),
        Err(CompareError::PixelOutside {
            index: 6,
            width: 3,
            height: 2
        })
    );
    assert!(matches!(
        c.masked(&actual, &expected, &mask[..5]),
        Err(CompareError::Length { which: "mask", .. })
    ));
}

#[test]
fn an_empty_comparison_does_not_pass() {
    let d = Compare::image(2, 2).at(&[0u8; 4], &[0u8; 4], []).unwrap();
    assert_eq!(d.pixels, 0);
    assert!(d.fraction_within().is_nan());
    assert!(d.mean_abs.is_nan() && d.ncc.is_nan());
    assert_eq!(d.check(), Err(CompareError::NothingCompared));
}

#[test]
fn images_of_the_wrong_size_are_refused() {
    let c = Compare::image(3, 2);
    assert!(matches!(
        c.all(&[0u8; 5], &[0u8; 6]),
        Err(CompareError::Length {
            which: "actual image",
            len: 5,
            needed: 6,
            ..
        })
    ));
    let e = c.channels(2).all(&[0u8; 12], &[0u8; 6]).unwrap_err();
    assert_eq!(
        e.to_string(),
        "the expected image has 6 values where 12 are needed (3 x 2 pixels, 2 channels)"
    );
}

#[test]
fn nan_fails_and_equal_infinities_agree() {
    let c = Compare::values(3).tolerance(Tolerance::absolute(1e-3));
    let d = c
        .all(
            &[f64::NEG_INFINITY, 1.0, 2.0],
            &[f64::NEG_INFINITY, 1.0, 2.0],
        )
        .unwrap();
    assert_eq!((d.max_abs, d.values_over), (0.0, 0));
    let d = c.all(&[0.0, f64::NAN, 2.0], &[0.0, 1.0, 2.0]).unwrap();
    assert_eq!(d.values_over, 1);
    assert!(d.max_abs.is_nan());
    assert_eq!(d.check().unwrap_err().worst().unwrap().x, 1);
    // An infinite value against a finite one under a relative bound is outside it too.
    let d = Compare::values(1)
        .tolerance(Tolerance::absolute_or_relative(0.0, 0.1))
        .all(&[1.0], &[f64::INFINITY])
        .unwrap();
    assert_eq!(d.values_over, 1);
}

#[test]
fn means_percentiles_and_psnr_of_known_differences() {
    // Differences 1, -1, 2, -2, 0, 0, 0, 4 (actual minus expected).
    let expected = [10u8; 8];
    let actual = [11u8, 9, 12, 8, 10, 10, 10, 14];
    let d = Compare::image(4, 2).all(&actual, &expected).unwrap();
    assert_eq!(d.mean_abs, 10.0 / 8.0);
    assert_eq!(d.mean_signed, 4.0 / 8.0);
    assert_eq!(d.rms, (26.0f64 / 8.0).sqrt());
    // Sorted |d|: 0 0 0 1 1 2 2 4; the median is between 1 and 1.
    assert_eq!(d.median_abs, 1.0);
    assert!(
        (d.p99_abs - (2.0 + 0.93 * 2.0)).abs() < 1e-12,
        "{}",
        d.p99_abs
    );
    assert_eq!(d.largest.map(|s| (s.x, s.y)), Some((3, 1)));
    assert!((d.psnr_db(255.0) - 20.0 * (255.0 / d.rms).log10()).abs() < 1e-12);
    let uniform = Compare::image(4, 2).all(&[11u8; 8], &expected).unwrap();
    assert!((uniform.psnr_db(255.0) - 48.130_803_608).abs() < 1e-6);
}

#[test]
fn ncc_is_one_for_a_linear_map_and_minus_one_for_its_negation() {
    let mut rng = SplitMix64::new(0x4e43_4321);
    let a: Vec<f64> = (0..500).map(|_| rng.next_f64()).collect();
    let b: Vec<f64> = a.iter().map(|x| 3.0 * x + 7.0).collect();
    let c: Vec<f64> = a.iter().map(|x| 1.0 - x).collect();
    assert!((ncc(&a, &b) - 1.0).abs() < 1e-12);
    assert!((ncc(&a, &c) + 1.0).abs() < 1e-12);
    assert!(ncc(&a, &vec![2.0; 500]).is_nan());
    let noise: Vec<f64> = (0..500).map(|_| rng.next_f64()).collect();
    assert!(ncc(&a, &noise).abs() < 0.2);
    let d = Compare::values(500).all(&b, &a).unwrap();
    assert!((d.ncc - 1.0).abs() < 1e-12);
}

#[test]
fn a_diff_prints_on_one_line_with_where_it_is_largest() {
    let d = Compare::image(2, 2)
        .tolerance(Tolerance::absolute(1.0))
        .all(&[0u8, 0, 0, 5], &[0u8, 0, 0, 0])
        .unwrap();
    let text = d.to_string();
    assert!(!text.contains('\n'));
    assert!(
        text.starts_with("4 pixels: 75.00 % within 1, max |d| 5.000e0 at pixel (1, 1)"),
        "{text}"
    );
    assert_eq!(
        Tolerance::absolute_or_relative(0.1, 0.005).to_string(),
        "max(0.1, 0.5 % of the expected value)"
    );
}

#[test]
fn block_mean_diffs_average_within_whole_blocks() {
    // 5 x 2 pixels, blocks of 2: two whole blocks, the last column left out.
    let a = [0u8, 4, 10, 10, 99, 0, 4, 10, 10, 0];
    let b = [2u8, 2, 10, 14, 0, 2, 2, 10, 14, 0];
    assert_eq!(block_mean_diffs(&a, &b, 5, 2), vec![0.0, 2.0]);
    assert!(
        block_mean_diffs(&a, &b, 5, 3).is_empty(),
        "no whole 3 x 3 block"
    );
}
