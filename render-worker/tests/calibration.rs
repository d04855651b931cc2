//! The start-up calibration: it times real sessions on each candidate renderer, chooses one and
//! reports it with the capacity in the host's health.

use std::sync::Arc;
use std::time::Duration;

use render_worker::session::calibration::{
    self, GIVE_UP_FACTOR, MAX_CALIBRATED_CAPACITY, TARGET_UTILISATION, calibrate, calibrate_host,
    capacity_for,
};
use render_worker::session::demo::{demo_region, demo_station};
use render_worker::session::modalities::fluoro::{FluoroRenderError, NeedleShaft};
use render_worker::session::region::Region;
use render_worker::session::*;
use sim_core::fluoro::{Image, IodineField, Projection, RenderSettings};

/// The CPU reference, but every frame first waits `delay` (per 128 x 128 pixels of the frame, as
/// a renderer's work grows), asleep or (`spin`) busy: slower to see, and with `spin` also
/// costlier.
struct Sluggish {
    inner: CpuFluoroBackend,
    delay: Duration,
    spin: bool,
}

struct SluggishRenderer {
    inner: Box<dyn FluoroRenderer>,
    delay: Duration,
    spin: bool,
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
        let [w, h] = projection.detector_pixels;
        let delay = self
            .delay
            .mul_f64(f64::from(w) * f64::from(h) / (128.0 * 128.0));
        if self.spin {
            let t = std::time::Instant::now();
            let mut x = 0u64;
            while t.elapsed() < delay {
                x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
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

/// A renderer that does the CPU reference's work and twice as much again is not chosen, in
/// either order, and every figure of both is measured. (The extra work is two frames, so the
/// choice holds although other tests of this binary share the process CPU time it is measured
/// by.)
#[test]
fn the_renderer_a_learner_waits_less_for_is_chosen() {
    let station = demo_station(&[]);
    let region = Arc::new(demo_region());
    let cpu: Arc<dyn FluoroBackend> = Arc::new(CpuFluoroBackend { threads: 1 });
    let alone = calibrate(&station, &region, &small(), &[Arc::clone(&cpu)]).expect("calibration");
    let frame_ms = alone.timings[0].carm_moved_ms.unwrap();
    // Two frames more: a sluggish frame is three of the reference's, apart from it while other
    // tests share the CPU, and its 32^2 probe (which scales the probe's fixed cost of about
    // 5 ms by 16 too) stays below the early stop at GIVE_UP_FACTOR (8) frames. (A flat 150 ms
    // floor crossed that stop once a frame took under 21 ms.)
    let delay_ms = 2.0 * frame_ms;
    let slow: Arc<dyn FluoroBackend> = Arc::new(Sluggish {
        inner: CpuFluoroBackend { threads: 1 },
        delay: Duration::from_secs_f64(delay_ms / 1e3),
        spin: true,
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
        for t in [fast, sluggish] {
            assert!(t.stopped.is_none(), "{t:#?}");
            for ms in [t.carm_moved_ms, t.needle_moved_ms, t.new_shot_ms] {
                let ms = ms.expect("measured");
                assert!(ms.is_finite() && ms > 0.0, "{t:#?}");
            }
            let load = t.learner_load.expect("load");
            assert!(load.is_finite() && load > 0.0, "{t:#?}");
        }
        // The delay shows in every waited-for frame.
        // (Half the delay: each frame waits it once, the timing noise of a shared CPU aside.)
        assert!(
            sluggish.carm_moved_ms.unwrap() >= fast.carm_moved_ms.unwrap() + 0.5 * delay_ms,
            "{c:#?}"
        );
        assert!(
            sluggish.needle_moved_ms.unwrap() >= 0.5 * delay_ms,
            "{sluggish:#?}"
        );
    }
}

/// A candidate whose first frame is many times the best C-arm-moved frame is stopped there.
#[test]
fn a_renderer_far_slower_than_the_best_is_stopped_after_one_frame() {
    let station = demo_station(&[]);
    let region = Arc::new(demo_region());
    let cpu: Arc<dyn FluoroBackend> = Arc::new(CpuFluoroBackend { threads: 1 });
    let first = calibrate(&station, &region, &small(), &[Arc::clone(&cpu)]).expect("calibration");
    let best = first.timings[0].carm_moved_ms.unwrap();
    let far: Arc<dyn FluoroBackend> = Arc::new(Sluggish {
        inner: CpuFluoroBackend { threads: 1 },
        delay: Duration::from_secs_f64(2.0 * GIVE_UP_FACTOR * best / 1e3),
        spin: false,
    });
    let c = calibrate(&station, &region, &small(), &[cpu, far]).expect("calibration");
    assert_eq!(c.chosen, 0);
    let stopped = &c.timings[1];
    assert!(
        stopped
            .stopped
            .as_deref()
            .is_some_and(|s| s.contains("times the best")),
        "{stopped:#?}"
    );
    assert!(stopped.carm_moved_ms.is_none() && stopped.capacity.is_none());
    // Stopped by its quarter-side probe frame, scaled to the full frame by pixel count.
    let [side, ms, full_ms] = stopped.probe.expect("probe");
    assert_eq!(side, 32.0);
    assert!((full_ms - 16.0 * ms).abs() < 1e-9 * full_ms);
    assert!(full_ms > GIVE_UP_FACTOR * c.timings[0].carm_moved_ms.unwrap());
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
