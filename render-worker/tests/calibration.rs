//! The start-up calibration: it times real sessions on each candidate renderer, chooses one and
//! reports it with the capacity in the host's health.

use std::sync::Arc;
use std::time::Duration;

use render_worker::session::calibration::{
    self, EARLY_STOP_NOISE_MS, GIVE_UP_FACTOR, MAX_CALIBRATED_CAPACITY, Probe, SAME_COST,
    TARGET_UTILISATION, calibrate, calibrate_host, capacity_for,
};
use render_worker::session::demo::{demo_region, demo_station};
use render_worker::session::modalities::fluoro::{FluoroRenderError, NeedleShaft};
use render_worker::session::region::Region;
use render_worker::session::*;
use sim_core::fluoro::{Image, IodineField, Projection, RenderSettings};

/// The CPU reference, but every frame (from the second of each renderer with `spare_first`: its
/// set-up is the reference's) first waits `delay` (per 128 x 128 pixels of the frame, as a
/// renderer's work grows), asleep or (`spin`) busy for that much CPU time: slower to see, and
/// with `spin` also costlier.
struct Sluggish {
    inner: CpuFluoroBackend,
    delay: Duration,
    spin: bool,
    spare_first: bool,
}

struct SluggishRenderer {
    inner: Box<dyn FluoroRenderer>,
    delay: Duration,
    spin: bool,
    spared: bool,
}

impl FluoroBackend for Sluggish {
    fn profile(&self) -> BackendProfile {
        BackendProfile {
            kind: "sluggish".into(),
            device: "cpu".into(),
        }
    }

    fn renderer(&self, region: &Arc<Region>) -> Result<Box<dyn FluoroRenderer>, FluoroRenderError> {
        Ok(Box::new(SluggishRenderer {
            inner: self.inner.renderer(region)?,
            delay: self.delay,
            spin: self.spin,
            spared: !self.spare_first,
        }))
    }
}

impl FluoroRenderer for SluggishRenderer {
    fn render(
        &mut self,
        needle: Option<&NeedleShaft>,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<Image, FluoroRenderError> {
        if !self.spared {
            self.spared = true;
            return self.inner.render(needle, projection, settings, iodine);
        }
        let [w, h] = projection.detector_pixels;
        let delay = self
            .delay
            .mul_f64(f64::from(w) * f64::from(h) / (128.0 * 128.0));
        if self.spin {
            // Busy for `delay` of this thread's own CPU time: the cost is the same however
            // many other threads share the cores (the wall time is at least as long).
            let start = calibration::thread_cpu_s();
            assert!(start > 0.0, "the thread's CPU clock");
            let mut x = 0u64;
            while calibration::thread_cpu_s() - start < delay.as_secs_f64() {
                for _ in 0..1000 {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            }
        } else {
            std::thread::sleep(delay);
        }
        self.inner.render(needle, projection, settings, iodine)
    }
}

/// Sessions of 128 x 128 pixels: a sixteenth of the shipped frame's work, the same code.
fn small() -> SessionConfig {
    let mut c = SessionConfig::default();
    c.fluoro.detector_pixels = 128;
    c
}

#[test]
fn capacity_is_the_target_load_over_one_learner_s_load() {
    assert_eq!(capacity_for(TARGET_UTILISATION / 10.0), 10);
    assert_eq!(capacity_for(TARGET_UTILISATION / 10.5), 10);
    // A learner who alone takes more than the target still gets a session.
    assert_eq!(capacity_for(0.9), 1);
    assert_eq!(capacity_for(1e-9), MAX_CALIBRATED_CAPACITY);
    assert_eq!(capacity_for(f64::NAN), MAX_CALIBRATED_CAPACITY);
}

/// Set in the child process of [`in_own_process`].
const CHILD: &str = "CALIBRATION_TEST_CHILD_PROCESS";

/// Runs this binary's test `name` alone in a child process, so that the process CPU time a
/// calibration measures is that test's own and not that of the tests running beside it in this
/// process. True in the child (run the test's body there), false in the parent once the child
/// passed.
fn in_own_process(name: &str) -> bool {
    if std::env::var_os(CHILD).is_some() {
        return true;
    }
    let out = std::process::Command::new(std::env::current_exe().expect("test binary"))
        .args([name, "--exact", "--nocapture", "--test-threads=1"])
        .env(CHILD, "1")
        .output()
        .expect("run the test in a child process");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{name} failed:\n{stdout}\n{stderr}");
    // The child ran exactly that test (a renamed test would otherwise pass by running none).
    assert!(stdout.contains("1 passed"), "{name} did not run:\n{stdout}");
    false
}

/// A renderer that does the CPU reference's work and twice as much again is not chosen, in
/// either order, and every figure of both is measured (in a process of its own: the choice
/// rests on process CPU time).
#[test]
fn the_renderer_a_learner_waits_less_for_is_chosen() {
    if !in_own_process("calibration::the_renderer_a_learner_waits_less_for_is_chosen") {
        return;
    }
    let station = demo_station(&[]);
    let region = Arc::new(demo_region());
    let cpu: Arc<dyn FluoroBackend> = Arc::new(CpuFluoroBackend { threads: 1 });
    let alone = calibrate(&station, &region, &small(), &[Arc::clone(&cpu)]).expect("calibration");
    // One candidate: nothing to compare a probe with, so none is taken.
    assert!(alone.timings[0].probe.is_none());
    // A frame's CPU time more, busy, from each renderer's second frame: a sluggish frame costs
    // two of the reference's. Its first frame is the reference's and its probe estimates about
    // two frames, far from the early stop (8), so it is measured in full however noisy the
    // shared CPU (a busy wait beside two busy loops on 2 cores takes about thrice its CPU time).
    let delay_ms = alone.timings[0].carm_moved_cpu_ms.unwrap();
    let slow: Arc<dyn FluoroBackend> = Arc::new(Sluggish {
        inner: CpuFluoroBackend { threads: 1 },
        delay: Duration::from_secs_f64(delay_ms / 1e3),
        spin: true,
        spare_first: true,
    });
    for order in [[&slow, &cpu], [&cpu, &slow]] {
        let candidates = [Arc::clone(order[0]), Arc::clone(order[1])];
        let c = calibrate(&station, &region, &small(), &candidates).expect("calibration");
        assert_eq!(c.renderer.kind, "cpu-reference", "{c:#?}");
        assert_eq!(c.timings[c.chosen].renderer, c.renderer);
        assert_eq!(c.capacity, c.timings[c.chosen].capacity.unwrap());
        assert!(c.capacity >= 1);
        assert_eq!(
            (c.station.as_str(), c.region.as_str()),
            ("demo-station", "demo-region")
        );
        let (fast, sluggish) = if c.chosen == 0 {
            (&c.timings[0], &c.timings[1])
        } else {
            (&c.timings[1], &c.timings[0])
        };
        // The candidate measured second was probed; the first was not.
        assert!(c.timings[0].probe.is_none(), "{c:#?}");
        let probe = c.timings[1].probe.expect("probed");
        assert_eq!(probe.sides, [16, 32]);
        assert!(
            probe.frame_ms.iter().all(|ms| ms.is_finite() && *ms > 0.0),
            "{c:#?}"
        );
        assert!(probe.full_ms >= probe.frame_ms[1], "{c:#?}");
        for t in [fast, sluggish] {
            assert!(t.stopped.is_none(), "{t:#?}");
            for ms in [t.carm_moved_ms, t.needle_moved_ms, t.new_shot_ms] {
                let ms = ms.expect("measured");
                assert!(ms.is_finite() && ms > 0.0, "{t:#?}");
            }
            let load = t.learner_load.expect("load");
            assert!(load.is_finite() && load > 0.0, "{t:#?}");
        }
        // The delay shows in every waited-for frame: each waits it in full before its work
        // (a floor, whatever else shares the CPU; the frames of both beside each other are not
        // compared, as the tests beside this one slow either by more than a frame).
        for ms in [
            sluggish.carm_moved_ms,
            sluggish.needle_moved_ms,
            sluggish.new_shot_ms,
        ] {
            assert!(ms.unwrap() >= delay_ms, "{sluggish:#?}");
        }
        // And in its cost: two frames' CPU time for one, beyond what counts as the same cost
        // (SAME_COST), so the choice is made by cost, not by the C-arm frame among equals.
        for ms in [sluggish.carm_moved_cpu_ms, sluggish.needle_moved_cpu_ms] {
            assert!(ms.unwrap() >= delay_ms, "{sluggish:#?}");
        }
        assert!(
            sluggish.learner_load.unwrap() > SAME_COST * fast.learner_load.unwrap(),
            "{c:#?}"
        );
    }
}

/// The probe's estimate: a part per frame and a part per pixel, from the two sizes.
#[test]
fn a_probe_estimates_the_full_frame_from_two_sizes() {
    // 4 ms a frame and 1 ms per 1,000 pixels: 68 ms at 256^2, whatever the probe sizes.
    let t = |side: u32| 4.0 + f64::from(side * side) / 1000.0;
    for sides in [[16, 32], [32, 64], [64, 128]] {
        let p = Probe::new(sides, [t(sides[0]), t(sides[1])], 256);
        assert!((p.full_ms - t(256)).abs() < 1e-9, "{p:?}");
    }
    // Scaling the larger probe by pixel count alone would count the 4 ms sixteen times.
    assert!(16.0 * t(64) - t(256) > 50.0);
    // A larger probe no slower than the smaller (noise): no cost per pixel is assumed.
    let p = Probe::new([16, 32], [9.0, 8.0], 128);
    assert_eq!(p.full_ms, 8.0);
}

/// A candidate whose probe estimates a frame many times the best candidate's is stopped there.
#[test]
fn a_renderer_far_slower_than_the_best_is_stopped_after_one_frame() {
    let station = demo_station(&[]);
    let region = Arc::new(demo_region());
    let cpu: Arc<dyn FluoroBackend> = Arc::new(CpuFluoroBackend { threads: 1 });
    let first = calibrate(&station, &region, &small(), &[Arc::clone(&cpu)]).expect("calibration");
    let best = first.timings[0].carm_moved_ms.unwrap();
    // Each frame waits 32 of the reference's frames: four times the early stop, so the
    // reference may be slowed fourfold by the tests beside it and the stop still holds.
    let far: Arc<dyn FluoroBackend> = Arc::new(Sluggish {
        inner: CpuFluoroBackend { threads: 1 },
        delay: Duration::from_secs_f64(4.0 * GIVE_UP_FACTOR * best / 1e3),
        spin: false,
        spare_first: false,
    });
    let c = calibrate(&station, &region, &small(), &[cpu, far]).expect("calibration");
    assert_eq!(c.chosen, 0);
    let stopped = &c.timings[1];
    assert!(
        stopped
            .stopped
            .as_deref()
            .is_some_and(|s| s.contains("times the best candidate's")),
        "{stopped:#?}"
    );
    assert!(stopped.carm_moved_ms.is_none() && stopped.capacity.is_none());
    assert!(
        stopped.first_frame_ms.is_nan(),
        "stopped before any full frame"
    );
    // Stopped by its probe's estimate of the full frame.
    let probe = stopped.probe.expect("probe");
    assert_eq!(probe.sides, [16, 32]);
    let best_now = c.timings[0].carm_moved_ms.unwrap();
    assert!(probe.frame_ms[1] > best_now, "{c:#?}");
    assert!(
        probe.full_ms > GIVE_UP_FACTOR * best_now && probe.full_ms - best_now > EARLY_STOP_NOISE_MS,
        "{c:#?}"
    );
    // The renderer measured first has no probe.
    assert!(c.timings[0].probe.is_none());
}

/// On a host: the capacity follows the calibration unless fixed, and health reports both.
#[test]
fn the_host_reports_the_calibration_and_takes_its_capacity() {
    let host = SessionHost::with_regions(
        vec![demo_station(&[])],
        vec![Arc::new(demo_region())],
        Backends::cpu(1),
        8,
        small(),
    );
    assert!(host.health().calibration.is_none());
    let mut candidates: Vec<Arc<dyn FluoroBackend>> = Vec::new();
    if let Some(ctx) = render_worker::gpu::context_for_tests() {
        candidates.push(Backends::gpu(ctx).fluoro);
    }
    candidates.push(Arc::new(CpuFluoroBackend { threads: 0 }));
    let c = calibrate_host(&host, &candidates, None).expect("calibration");
    let h = host.health();
    assert_eq!(h.capacity, c.capacity);
    let reported = h.calibration.expect("reported");
    assert_eq!(reported["renderer"]["kind"], c.renderer.kind.as_str());
    assert_eq!(reported["capacity"], c.capacity);
    assert_eq!(
        reported["timings"].as_array().map(Vec::len),
        Some(candidates.len())
    );
    println!("{}", serde_json::to_string_pretty(&reported).unwrap());
    // An operator's fixed capacity wins; the calibration is still reported.
    calibrate_host(&host, &candidates, Some(3)).expect("calibration");
    assert_eq!(host.health().capacity, 3);
    assert!(host.health().calibration.is_some());
    // Nothing to calibrate on: a clear error, the host unchanged.
    let empty = SessionHost::with_regions(
        Vec::new(),
        Vec::new(),
        Backends::cpu(1),
        5,
        SessionConfig::default(),
    );
    assert!(matches!(
        calibrate_host(&empty, &candidates, None),
        Err(calibration::CalibrationError::NoStation)
    ));
    assert_eq!(empty.health().capacity, 5);
}

/// After the calibration each fluoroscopy region is prepared with the host's renderer: one that
/// keeps its uploads makes the region's anatomy now and keeps it (a first session then finds it
/// made); one that keeps nothing, or the CPU reference, prepares nothing.
#[test]
fn regions_are_prepared_by_a_renderer_that_keeps_them() {
    let Some(ctx) = render_worker::gpu::context_for_tests() else {
        return;
    };
    let host_with = |fluoro: Arc<dyn FluoroBackend>| {
        SessionHost::with_regions(
            vec![demo_station(&[])],
            vec![Arc::new(demo_region())],
            Backends::new(fluoro, Backends::cpu(1).ultrasound),
            8,
            small(),
        )
    };
    let keeping = Arc::new(GpuFluoroBackend::keeping_uploads(ctx.clone()).drafting_from(Some(0)));
    let host = host_with(Arc::clone(&keeping) as Arc<dyn FluoroBackend>);
    assert_eq!(keeping.shared_anatomies(), 0);
    assert_eq!(calibration::prepare_fluoroscopy_regions(&host), 1);
    assert_eq!(keeping.shared_anatomies(), 1, "kept with no renderer alive");
    let (_, region) = host.fluoroscopy_stations().remove(0);
    let renderer = keeping.renderer(&region).expect("renderer");
    assert_eq!(
        keeping.shared_anatomies(),
        1,
        "the first session makes no other"
    );
    drop(renderer);
    // Preparing again makes nothing new.
    assert_eq!(calibration::prepare_fluoroscopy_regions(&host), 1);
    assert_eq!(keeping.shared_anatomies(), 1);

    let freeing = Arc::new(GpuFluoroBackend::new(ctx));
    let host = host_with(Arc::clone(&freeing) as Arc<dyn FluoroBackend>);
    assert_eq!(calibration::prepare_fluoroscopy_regions(&host), 0);
    assert_eq!(freeing.shared_anatomies(), 0);
    let host = host_with(Arc::new(CpuFluoroBackend { threads: 0 }));
    assert_eq!(calibration::prepare_fluoroscopy_regions(&host), 0);
}
