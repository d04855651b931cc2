//! GPU B-mode ultrasound against sim-core's CPU reference on the same seed.
//!
//! Both frames come from the same lattice scatterers (same hash of cell and seed), so the GPU's
//! speckle must be the CPU's speckle, not merely statistically alike. The differences that
//! remain are f32 geometry and phases (about 1e-3 rad at 8 cm), the fixed-point deposit
//! (2^-24) and lattice cells or march samples exactly on a reach limit or voxel face; see the
//! tolerances below for the figures measured on lavapipe.
//!
//! With `REQUIRE_GPU=1` (CI) a missing adapter fails these tests (`context_for_tests`);
//! otherwise they print why and pass without running.

use glam::DVec3;
use render_worker::gpu::context_for_tests;
use render_worker::ultrasound::{GpuUltrasound, UltrasoundGpuError, layered_test_volume};
use sim_core::compare::{Compare, ncc};
use sim_core::ultrasound::{
    BModeFrame, CtMedium, NeedleShaft, PointTarget, ProbeKind, ProbePose, Sampling, ScanRequest,
    Settings, scan,
};
use sim_core::volume::{Volume, VolumeGrid};

/// A 1 mm grid covering both probes' 8 cm frames with their scatter margins: x +-80 mm
/// (lateral), y +-20 mm (elevation), z -15 ..= 95 mm (depth; the convex probe's outer lines
/// start 8 mm above its centre, and tissue must be there or they start in air).
fn grid() -> VolumeGrid {
    VolumeGrid {
        dims: [161, 41, 111],
        spacing_mm: [1.0; 3],
        origin_mm: [-80.0, -20.0, -15.0],
    }
}

/// Uniform soft tissue at 40 HU.
fn uniform_volume() -> Volume<f32> {
    Volume::filled(grid(), 40.0)
}

/// Fat over muscle with a labelled cortical plate at 45 mm (see `layered_test_volume`).
fn layered() -> (Volume<f32>, Volume<u8>) {
    layered_test_volume(grid())
}

/// Runs `test` with the GPU and the layered scene as a medium (nothing without an adapter:
/// see `context_for_tests`).
fn with_layered_scene(test: impl FnOnce(&render_worker::gpu::GpuContext, &CtMedium<'_>)) {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let (hu, labels) = layered();
    let medium = CtMedium {
        hu: &hu,
        labels: Some(&labels),
    };
    test(&ctx, &medium);
}

/// Probe at the origin looking along +z, marker towards +x (elevation is +y).
fn pose() -> ProbePose {
    ProbePose {
        position_mm: DVec3::ZERO,
        beam_dir: DVec3::Z,
        marker_dir: DVec3::X,
    }
}

/// An 8 cm frame at the probe's defaults, 128 lines (half the default, to keep the CPU
/// reference quick in tests; the bench uses the defaults).
fn request<'a>(
    probe: ProbeKind,
    medium: &'a CtMedium<'a>,
    needle: Option<NeedleShaft>,
    targets: &'a [PointTarget],
) -> ScanRequest<'a> {
    let spec = probe.spec();
    let settings = Settings {
        depth_mm: 80.0,
        focus_mm: 40.0,
        ..Settings::default_for(&spec)
    };
    let sampling = Sampling {
        lines: 128,
        ..Sampling::for_settings(&spec, &settings)
    };
    ScanRequest {
        probe,
        pose: pose(),
        settings,
        sampling,
        medium,
        needle,
        targets,
        seed: 11,
    }
}

/// An in-plane 22 G needle at about 40 degrees, tip at 30 mm depth.
fn needle() -> NeedleShaft {
    NeedleShaft {
        hub_mm: DVec3::new(25.0, 0.0, -2.0),
        tip_mm: DVec3::new(-5.0, 0.0, 30.0),
        diameter_mm: 0.72,
    }
}

/// The measured agreement of a GPU frame with the CPU frame.
#[derive(Debug)]
struct Agreement {
    /// NCC of the envelope amplitudes over every sample.
    envelope_ncc: f64,
    /// Mean of |dB_gpu - dB_cpu| over samples the display can show (CPU envelope above
    /// -(gain + dynamic range) dB, i.e. not clamped to black).
    mean_abs_db: f64,
    /// Mean of dB_gpu - dB_cpu over the same samples (a bias).
    mean_db: f64,
    /// NCC of the grey levels over pixels inside the scan in both frames.
    image_ncc: f64,
    /// Mean |grey_gpu - grey_cpu| over the same pixels.
    mean_abs_grey: f64,
}

fn agreement(gpu: &BModeFrame, cpu: &BModeFrame) -> Agreement {
    assert_eq!((gpu.width, gpu.height), (cpu.width, cpu.height));
    assert_eq!(
        (gpu.envelope.lines, gpu.envelope.samples),
        (cpu.envelope.lines, cpu.envelope.samples)
    );
    let ea: Vec<f64> = gpu.envelope.data.iter().map(|&v| f64::from(v)).collect();
    let eb: Vec<f64> = cpu.envelope.data.iter().map(|&v| f64::from(v)).collect();
    let floor_db = -(cpu.settings.gain_db + cpu.settings.dynamic_range_db);
    let db = |v: f64| 20.0 * v.max(1e-12).log10();
    let (shown_gpu, shown_cpu): (Vec<f64>, Vec<f64>) = ea
        .iter()
        .zip(&eb)
        .map(|(&a, &b)| (db(a), db(b)))
        .filter(|&(_, b)| b > floor_db)
        .unzip();
    let shown = Compare::values(shown_cpu.len())
        .all(&shown_gpu, &shown_cpu)
        .expect("paired samples");
    let inside: Vec<bool> = gpu
        .inside
        .iter()
        .zip(&cpu.inside)
        .map(|(&g, &c)| g && c)
        .collect();
    let grey = Compare::image(cpu.width, cpu.height)
        .masked(&gpu.pixels, &cpu.pixels, &inside)
        .expect("frames of one size");
    Agreement {
        envelope_ncc: ncc(&ea, &eb),
        mean_abs_db: shown.mean_abs,
        mean_db: shown.mean_signed,
        image_ncc: grey.ncc,
        mean_abs_grey: grey.mean_abs,
    }
}

/// Tolerances. Measured on lavapipe (128 lines, 8 cm, both probes, both scenes), worst case:
/// envelope NCC 1 - 2e-8, mean |dB| 0.0016 dB, mean dB 5e-5 dB, image NCC 1 - 6.4e-7, mean
/// |grey| 0.0025. Expected from f32: a phase error of 1e-3 rad at 8 cm (and relative errors of
/// 1e-6 in geometry and gains) changes a speckle sum by about 1e-3 of its amplitude, 0.01 dB, at
/// the worst sample; grey levels then change only where a value sits on a rounding edge. The
/// bounds are that worst-sample figure (0.01 dB, doubled) and about 10x the measured means, so
/// a GPU with less accurate `sin`/`exp` (a hardware adapter) still passes while any change of
/// the speckle pattern (NCC falls to about 0 for another seed or hash) fails by far.
const MIN_ENVELOPE_NCC: f64 = 0.99999;
const MAX_MEAN_ABS_DB: f64 = 0.02;
const MAX_MEAN_DB: f64 = 0.005;
const MIN_IMAGE_NCC: f64 = 0.9999;
const MAX_MEAN_ABS_GREY: f64 = 0.03;

fn check(name: &str, a: &Agreement) {
    eprintln!("{name}: {a:?}");
    assert!(a.envelope_ncc >= MIN_ENVELOPE_NCC, "{name}: {a:?}");
    assert!(a.mean_abs_db <= MAX_MEAN_ABS_DB, "{name}: {a:?}");
    assert!(a.mean_db.abs() <= MAX_MEAN_DB, "{name}: {a:?}");
    assert!(a.image_ncc >= MIN_IMAGE_NCC, "{name}: {a:?}");
    assert!(a.mean_abs_grey <= MAX_MEAN_ABS_GREY, "{name}: {a:?}");
}

#[test]
fn uniform_medium_matches_the_cpu_speckle() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let hu = uniform_volume();
    both_probes_match(&ctx, &hu, 1, "uniform");
}

/// An unlabelled HU volume: both probes' GPU frames agree with the CPU's (key `key`).
fn both_probes_match(ctx: &render_worker::gpu::GpuContext, hu: &Volume<f32>, key: u64, name: &str) {
    let medium = CtMedium { hu, labels: None };
    let mut us = GpuUltrasound::new(ctx).expect("pipelines");
    for probe in [ProbeKind::Linear, ProbeKind::Curvilinear] {
        let req = request(probe, &medium, None, &[]);
        let cpu = scan(&req).expect("cpu frame");
        let gpu = us.scan(&req, &medium, key).expect("gpu frame");
        check(&format!("{name} {probe:?}"), &agreement(&gpu, &cpu));
    }
}

#[test]
fn layered_scene_with_bone_and_needle_matches_the_cpu() {
    with_layered_scene(|ctx, medium| {
        let targets = [PointTarget {
            position_mm: DVec3::new(10.0, 0.0, 60.0),
            amplitude: 0.5,
        }];
        let mut us = GpuUltrasound::new(ctx).expect("pipelines");
        for probe in [ProbeKind::Linear, ProbeKind::Curvilinear] {
            let req = request(probe, medium, Some(needle()), &targets);
            let cpu = scan(&req).expect("cpu frame");
            let gpu = us.scan(&req, medium, 2).expect("gpu frame");
            assert_eq!(
                gpu.needle, cpu.needle,
                "{probe:?}: the needle view is sim-core's"
            );
            check(&format!("layered {probe:?}"), &agreement(&gpu, &cpu));
        }
    });
}

/// A probe rocked and turned (the lattice's columns cross the slice obliquely, so each
/// scatterer has its own in-plane point; under a curvilinear array the CPU steps each point's
/// angle from the last one's, the GPU converts each in f32): both probes agree within the
/// tolerances.
#[test]
fn oblique_poses_match_the_cpu() {
    with_layered_scene(|ctx, medium| {
        let mut us = GpuUltrasound::new(ctx).expect("pipelines");
        for probe in [ProbeKind::Linear, ProbeKind::Curvilinear] {
            for (beam, turn) in [
                (DVec3::new(0.1, 0.2, 1.0), 17.0),
                (DVec3::new(-0.05, 0.0, 1.0), -40.0),
            ] {
                let req = ScanRequest {
                    pose: ProbePose::from_rotation(DVec3::ZERO, beam, turn),
                    ..request(probe, medium, Some(needle()), &[])
                };
                let cpu = scan(&req).expect("cpu frame");
                let gpu = us.scan(&req, medium, 4).expect("gpu frame");
                check(
                    &format!("oblique {probe:?} {beam} {turn}"),
                    &agreement(&gpu, &cpu),
                );
            }
        }
    });
}

#[test]
fn air_under_the_face_is_gel_on_the_gpu_too() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    // Air above z = 4 mm (the face stands off the skin), soft tissue below: the march couples
    // through gel (sim_core::ultrasound::GEL) on both paths.
    let mut hu = uniform_volume();
    let g = hu.grid;
    for k in 0..g.dims[2] {
        if g.voxel_center_mm(0, 0, k)[2] < 4.0 {
            for j in 0..g.dims[1] {
                for i in 0..g.dims[0] {
                    hu.data[g.index(i, j, k)] = -1000.0;
                }
            }
        }
    }
    both_probes_match(&ctx, &hu, 3, "gel gap");
}

#[test]
fn repeated_gpu_frames_are_bit_identical() {
    with_layered_scene(|ctx, medium| {
        let mut us = GpuUltrasound::new(ctx).expect("pipelines");
        let req = request(ProbeKind::Linear, medium, Some(needle()), &[]);
        let a = us.scan(&req, medium, 3).expect("first");
        let b = us.scan(&req, medium, 3).expect("second");
        assert_eq!(a.pixels, b.pixels);
        let bits = |f: &BModeFrame| {
            f.envelope
                .data
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        };
        assert_eq!(bits(&a), bits(&b));
    });
}

#[test]
fn bad_input_is_refused_with_the_cpu_field_names() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let hu = uniform_volume();
    let medium = CtMedium {
        hu: &hu,
        labels: None,
    };
    let mut us = GpuUltrasound::new(&ctx).expect("pipelines");
    let base = request(ProbeKind::Linear, &medium, None, &[]);
    let mut cases = Vec::new();
    let mut r = base;
    r.settings.depth_mm = 5.0;
    cases.push(r);
    let mut r = base;
    r.pose.beam_dir = DVec3::ZERO;
    cases.push(r);
    let mut r = base;
    r.sampling.lines = 1;
    cases.push(r);
    let mut r = base;
    r.settings.gain_db = f64::NAN;
    cases.push(r);
    let mut r = base;
    r.needle = Some(NeedleShaft {
        diameter_mm: 0.0,
        ..needle()
    });
    cases.push(r);
    for r in cases {
        let cpu = scan(&r).expect_err("the CPU refuses it");
        match us.scan(&r, &medium, 4) {
            Err(UltrasoundGpuError::Invalid(e)) => assert_eq!(e, cpu),
            other => panic!("expected {cpu:?}, got {:?}", other.map(|f| f.width)),
        }
    }
}
