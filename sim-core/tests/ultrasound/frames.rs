//! The B-mode frame as a whole: bit-identical for the same inputs, bad input refused naming
//! its field, freeze holding the last live frame, envelopes against the recorded reference
//! within round-off, and a scan that is stopped part-way giving no frame.

use super::*;

#[test]
fn the_same_inputs_give_a_bit_identical_frame() {
    let probe = ProbeKind::Curvilinear;
    let st = settings(probe, 80.0, 40.0, 3.5);
    let sampling = Sampling {
        lines: 128,
        ..Sampling::for_settings(&probe.spec(), &st)
    };
    let pose =
        ProbePose::from_rotation(DVec3::new(3.0, -2.0, 1.0), DVec3::new(0.2, 0.1, 1.0), 17.0);
    let mut req = request(probe, pose, st, sampling, &BonePlate, &[]);
    req.needle = Some(NeedleShaft {
        hub_mm: DVec3::new(-20.0, 0.0, 0.0),
        tip_mm: DVec3::new(10.0, 1.0, 30.0),
        diameter_mm: 0.72,
    });
    let a = scan(&req).unwrap();
    let b = scan(&req).unwrap();
    assert_eq!(a.pixels, b.pixels);
    let bits = |f: &BModeFrame| {
        f.envelope
            .data
            .iter()
            .map(|x| x.to_bits())
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&a), bits(&b));
    assert!(a.pixels.iter().any(|&p| p > 0));
}

#[test]
fn bad_input_is_refused_naming_the_field() {
    let probe = ProbeKind::Linear;
    let st = Settings::default_for(&probe.spec());
    let sampling = Sampling::for_settings(&probe.spec(), &st);
    let medium = UniformMedium(SOFT_TISSUE);
    let base = request(probe, pose_at(0.0), st, sampling, &medium, &[]);
    let refuse = |req: ScanRequest<'_>, field: &str| {
        let err = scan(&req).unwrap_err();
        assert!(err.to_string().contains(field), "{err} should name {field}");
        err
    };
    let mut r = base;
    r.pose.position_mm.y = f64::NAN;
    assert_eq!(
        refuse(r, "pose.position_mm"),
        UltrasoundError::NonFinite {
            field: "pose.position_mm"
        }
    );
    let mut r = base;
    r.pose.marker_dir = DVec3::Z;
    refuse(r, "pose.marker_dir");
    let mut r = base;
    r.settings.depth_mm = 200.0;
    assert!(matches!(
        refuse(r, "settings.depth_mm"),
        UltrasoundError::OutOfRange {
            field: "settings.depth_mm",
            ..
        }
    ));
    let mut r = base;
    r.settings.frequency_mhz = 3.0;
    refuse(r, "settings.frequency_mhz");
    let mut r = base;
    r.probe = ProbeKind::Curvilinear;
    r.settings.depth_mm = 100.0;
    r.settings.frequency_mhz = 7.5;
    refuse(r, "settings.frequency_mhz");
    let mut r = base;
    r.settings.focus_mm = 100.0;
    refuse(r, "settings.focus_mm");
}

#[test]
fn freeze_holds_the_last_live_frame() {
    let probe = ProbeKind::Linear;
    let st = settings(probe, 20.0, 10.0, 7.5);
    let sampling = Sampling {
        lines: 64,
        ..Sampling::for_settings(&probe.spec(), &st)
    };
    let medium = UniformMedium(SOFT_TISSUE);
    let mut scanner = Scanner::new();
    let live = scanner
        .scan(&request(probe, pose_at(0.0), st, sampling, &medium, &[]))
        .unwrap()
        .clone();
    let frozen_st = Settings { frozen: true, ..st };
    let moved = request(probe, pose_at(5.0), frozen_st, sampling, &medium, &[]);
    assert_eq!(
        scanner.scan(&moved).unwrap(),
        &live,
        "frozen: the probe moved but the image did not"
    );
    // Frozen or not, bad input is still refused.
    let mut bad = moved;
    bad.pose.position_mm.x = f64::INFINITY;
    assert!(scanner.scan(&bad).is_err());
    let unfrozen = request(probe, pose_at(5.0), st, sampling, &medium, &[]);
    assert_ne!(scanner.scan(&unfrozen).unwrap().pixels, live.pixels);
}

/// Fat (sparse scatter) over muscle, a nerve along +y (fascicular, fibre axis known) and a
/// cortical plate under x < 0: every branch of the scatter deposit.
struct Mixed;

impl Mixed {
    fn in_nerve(p: DVec3) -> bool {
        (p.x - 4.0).hypot(p.z - 15.0) < 3.0
    }
}

impl AcousticMedium for Mixed {
    fn props(&self, p: DVec3) -> AcousticProps {
        if p.z < 6.0 {
            FAT
        } else if Mixed::in_nerve(p) {
            NERVE
        } else if p.x < 0.0 && (25.0..28.0).contains(&p.z) {
            CORTICAL_BONE
        } else {
            MUSCLE
        }
    }
    fn fibre_axis(&self, p: DVec3) -> Option<DVec3> {
        Mixed::in_nerve(p).then_some(DVec3::Y)
    }
}

/// The envelopes of four fixed scenes (linear at 7.5 MHz and curvilinear at 3.5 MHz, each
/// oblique to the scatterer lattice and square to it, with fat, nerve, bone, a needle and a
/// point target), line-major, one after the other.
fn reference_scenes() -> Vec<f32> {
    let square = ProbePose {
        position_mm: DVec3::new(0.5, 0.0, 0.0),
        beam_dir: DVec3::Z,
        marker_dir: DVec3::X,
    };
    let mut out = Vec::new();
    for (probe, f, depth, samples, pose) in [
        (
            ProbeKind::Linear,
            7.5,
            30.0,
            200,
            ProbePose::from_rotation(DVec3::new(1.0, 0.5, 0.0), DVec3::new(0.1, 0.15, 1.0), 23.0),
        ),
        (
            ProbeKind::Curvilinear,
            3.5,
            40.0,
            160,
            ProbePose::from_rotation(
                DVec3::new(-2.0, 1.0, 0.0),
                DVec3::new(-0.1, 0.2, 1.0),
                -31.0,
            ),
        ),
        (ProbeKind::Linear, 7.5, 30.0, 128, square),
        (ProbeKind::Curvilinear, 3.5, 40.0, 128, square),
    ] {
        let st = settings(probe, depth, 0.5 * depth, f);
        let sampling = Sampling {
            lines: 48,
            samples_per_line: samples,
            ..Sampling::for_settings(&probe.spec(), &st)
        };
        let target = [PointTarget {
            position_mm: pose.position_mm + pose.beam_dir.normalize() * 12.0,
            amplitude: 0.3,
        }];
        let mut req = request(probe, pose, st, sampling, &Mixed, &target);
        req.needle = Some(NeedleShaft {
            hub_mm: DVec3::new(-20.0, 0.0, 0.0),
            tip_mm: DVec3::new(10.0, 1.0, 20.0),
            diameter_mm: 0.72,
        });
        out.extend(scan(&req).unwrap().envelope.data);
    }
    out
}

/// Envelopes recorded from the straightforward scatter deposit (commit f479061, before the
/// performance work), little-endian `f32`.
const REFERENCE_ENVELOPES: &str = "tests/data/ultrasound_reference_envelopes.f32";

#[test]
fn the_frame_matches_the_recorded_reference_within_round_off() {
    // The speed-ups of the scatter pass sum the same terms in another order (and in f64 where
    // the straightforward deposit rounded each term to f32), so frames may differ by f32
    // round-off only: per sample at most 1e-4 relative (measured 1.3e-5 at worst, median 1.4e-7,
    // about two f32 ulps), relative to no less than 1 % of the median envelope (in a deep speckle
    // null the sum cancels and only an absolute bound means anything).
    // `ULTRASOUND_RECORD_REFERENCE=1` rewrites the file: only for a deliberate model change.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(REFERENCE_ENVELOPES);
    let now = reference_scenes();
    if std::env::var("ULTRASOUND_RECORD_REFERENCE").is_ok_and(|v| v == "1") {
        let bytes: Vec<u8> = now.iter().flat_map(|x| x.to_le_bytes()).collect();
        std::fs::write(&path, bytes).unwrap();
    }
    let bytes = std::fs::read(&path).unwrap();
    let recorded: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    assert_eq!(recorded.len(), now.len());
    let mut sorted = recorded.clone();
    sorted.sort_by(f32::total_cmp);
    let floor = 0.01 * f64::from(sorted[sorted.len() / 2]);
    let (worst, at) = recorded
        .iter()
        .zip(&now)
        .map(|(&a, &b)| (f64::from(a) - f64::from(b)).abs() / f64::from(a).max(floor))
        .enumerate()
        .fold((0.0, 0), |m, (i, d)| if d > m.0 { (d, i) } else { m });
    println!("max relative envelope difference {worst:.3e} (sample {at})");
    assert!(
        worst <= 1e-4,
        "sample {at}: {} against {}",
        now[at],
        recorded[at]
    );
}

/// A scan that is never stopped is `scan`'s frame bit for bit; one stopped at once, or after a
/// few of its checks (within the deposit, on either of its threads), gives no frame; and the
/// checks come often enough to stop a frame early (dozens per frame, not one at the end).
#[test]
fn a_stopped_scan_gives_no_frame_and_an_unstopped_one_is_the_scan() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let probe = ProbeKind::Linear;
    let s = settings(probe, 40.0, 20.0, 7.5);
    let sampling = Sampling {
        lines: 96,
        ..Sampling::for_settings(&probe.spec(), &s)
    };
    let medium = UniformMedium(MUSCLE);
    // Tilted and rotated: the oblique deposit, the slow path a learner's probe takes.
    let pose = ProbePose::from_rotation(DVec3::ZERO, DVec3::new(0.1, 0.2, 1.0), 17.0);
    let req = request(probe, pose, s, sampling, &medium, &[]);
    let whole = scan(&req).unwrap();
    let asked = AtomicUsize::new(0);
    let never = scan_unless(&req, &|| {
        asked.fetch_add(1, Ordering::Relaxed);
        false
    })
    .unwrap()
    .expect("a frame");
    assert_eq!(never.pixels, whole.pixels);
    assert_eq!(never.envelope.data, whole.envelope.data);
    let checks = asked.load(Ordering::Relaxed);
    assert!(checks >= 40, "asked {checks} times in a frame");
    assert!(scan_unless(&req, &|| true).unwrap().is_none());
    for after in [1, checks / 2, checks - 1] {
        let n = AtomicUsize::new(0);
        let stopped = scan_unless(&req, &|| n.fetch_add(1, Ordering::Relaxed) >= after).unwrap();
        assert!(
            stopped.is_none(),
            "stopped after {after} of {checks} checks"
        );
    }
    // Bad input is still an error, stopped or not.
    let bad = ScanRequest {
        pose: ProbePose {
            beam_dir: DVec3::ZERO,
            ..pose
        },
        ..req
    };
    assert!(scan_unless(&bad, &|| true).is_err());
}
