//! Start-up calibration: which fluoroscopy renderer serves learners best on this machine, and how
//! many live sessions it holds.
//!
//! Each candidate renderer (the GPU renderer on whatever adapter opened, a real GPU or lavapipe,
//! and the CPU reference) runs one real session of a station on its region, as a learner drives
//! it: a first shot (the renderer is made and, on a GPU, the anatomy uploaded), C-arm moves each
//! followed by a shot, needle steps of 1 mm each followed by a shot, and shots with nothing
//! changed. Each frame is timed from its command to the frame that shows it (wall time), and the
//! process CPU time over the timed frames gives the machine's cost of a frame (a renderer that
//! uses every core costs more than its wall time).
//!
//! A learner's demand follows the scripted learner of the `capacity` benchmark
//! (`server/benches/capacity.rs`): per action, 0.40 C-arm adjustments (one C-arm-moved frame),
//! 0.48 needle steps (one needle-moved frame), 0.12 seconds of live fluoroscopy at the default
//! 7.5 pulses per second (7.5 C-arm-moved frames), and a pause of 1.5 s on average; see
//! [`LearnerModel`]. The capacity is the number of such learners that keep the machine's CPU
//! [`TARGET_UTILISATION`] busy, at least 1. The renderer whose learner costs the least CPU is
//! chosen; renderers within [`SAME_COST`] of that cost count as equal, and of those the one
//! with the faster C-arm-moved frame (what a learner waits for) is chosen.
//!
//! Every candidate after the first takes a probe first: sessions with a detector of an eighth
//! and of a quarter the side, each a first shot and then C-arm-moved frames. A frame's cost is
//! a part per frame and a part per pixel; the two sizes give both, and so an estimate of the
//! full C-arm-moved frame (a probe's frame scaled up by pixel count alone would count the part
//! per frame, which dominates small frames, up to sixteen times over). A candidate whose
//! quarter-side frame already takes longer than the best candidate's full C-arm-moved frame
//! and whose estimate is [`GIVE_UP_FACTOR`] times that frame, or whose first
//! full frame takes that many times the best one's first frame (and either more than
//! [`EARLY_STOP_NOISE_MS`] longer), cannot win and is stopped there (the CPU reference on a GPU
//! machine), so calibration costs a few seconds of start-up.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::Serialize;
use sim_core::rubric::Station;

use super::command::{Command, Envelope};
use super::config::SessionConfig;
use super::devices::Backends;
use super::host::{SessionHandle, SessionHost};
use super::image::ViewId;
use super::modalities::fluoro::{BackendProfile, FluoroBackend};
use super::modalities::ultrasound::backend::CpuUltrasoundBackend;
use super::preparation::RegionReadiness;
use super::region::Region;

/// Share of the machine's CPU the learners of a full worker keep busy. Our choice: at half load a
/// queue of frames of near-constant cost keeps its 99th-percentile wait within about three frame
/// times (M/D/1 queue: mean wait rho / (2 (1 - rho)) service times at rho = 0.5), and the other
/// half is left for relaying, encoding, contrast transport and the web server.
pub const TARGET_UTILISATION: f64 = 0.5;

/// Most sessions a calibration grants, whatever the renderer's speed. Our choice: beyond this one
/// process's relay, memory (about 20 MB per session) and database pool are the limits.
pub const MAX_CALIBRATED_CAPACITY: usize = 64;

/// A candidate stops after its probe when that estimates a C-arm-moved frame of this many times
/// the best candidate's, or after its first frame when that took this many times the best
/// candidate's first frame.
/// Our choice: a factor 8 only stops renderers that are several times slower, whatever the
/// noise of a shared CPU.
pub const GIVE_UP_FACTOR: f64 = 8.0;

/// An estimate or a first frame at most this much longer than the best candidate's does not stop
/// a candidate, whatever the ratio, ms. Our choice: the wall time of a frame of a few milliseconds
/// moves by some scheduler periods when the CPU is shared (Linux CFS: 6 ms x (1 + log2 cores),
/// 18 ms on 4 cores), so a smaller difference says nothing of the renderer.
pub const EARLY_STOP_NOISE_MS: f64 = 50.0;

/// Learner costs within this factor of the cheapest count as equal. Our choice: the process's
/// other work (relays, the web server, a cache warming) falls into the few frames timed, so
/// costs closer than this are not told apart.
pub const SAME_COST: f64 = 1.15;

/// Timed frames of each kind per candidate.
const FRAMES_PER_KIND: usize = 3;

/// The scripted learner whose demand sets the capacity (the `capacity` benchmark's learner).
#[derive(Debug, Clone, Copy, Serialize)]
pub struct LearnerModel {
    /// Share of actions that are C-arm adjustments followed by a shot.
    pub carm_share: f64,
    /// Share of actions that are needle steps followed by a shot.
    pub needle_share: f64,
    /// Share of actions that are a second of live fluoroscopy.
    pub live_share: f64,
    /// C-arm-moved frames in one live second (the default pulse rate, pulses per second).
    pub live_frames: f64,
    /// Mean time of one action besides waiting for its frames (pose commands 60 ms apart, the
    /// live second, and the pause of 1 to 2 s), s.
    pub action_s: f64,
}

impl LearnerModel {
    /// The `capacity` benchmark's learner: 0.40 / 0.48 / 0.12, bursts of 3 to 5 poses 60 ms
    /// apart (0.24 s), 1 s live, pauses of 1.5 s on average, 7.5 pulses per second.
    pub const SCRIPTED: LearnerModel = LearnerModel {
        carm_share: 0.40,
        needle_share: 0.48,
        live_share: 0.12,
        live_frames: 7.5,
        action_s: 0.40 * 0.24 + 0.12 * 1.0 + 1.5,
    };

    /// Frames per action: (C-arm moved, needle moved).
    fn frames(&self) -> (f64, f64) {
        (
            self.carm_share + self.live_share * self.live_frames,
            self.needle_share,
        )
    }
}

/// What one candidate renderer measured.
#[derive(Debug, Clone, Serialize)]
pub struct RendererTiming {
    /// The renderer.
    pub renderer: BackendProfile,
    /// The session's first shot, renderer set-up included, ms (`null` when the probe stopped
    /// the candidate first).
    pub first_frame_ms: f64,
    /// When another candidate was measured before: its probe.
    pub probe: Option<Probe>,
    /// Median C-arm move and shot, command to frame, ms.
    pub carm_moved_ms: Option<f64>,
    /// Median 1 mm needle step and shot, ms.
    pub needle_moved_ms: Option<f64>,
    /// Median shot with nothing changed, ms.
    pub new_shot_ms: Option<f64>,
    /// Process CPU time per C-arm-moved frame, ms (all threads: lavapipe's or the CPU
    /// reference's workers).
    pub carm_moved_cpu_ms: Option<f64>,
    /// Process CPU time per needle-moved frame, ms.
    pub needle_moved_cpu_ms: Option<f64>,
    /// Share of this machine's CPU one scripted learner takes with this renderer.
    pub learner_load: Option<f64>,
    /// Sessions this renderer holds ([`TARGET_UTILISATION`] over the learner's load).
    pub capacity: Option<usize>,
    /// Why it was not measured to the end (stopped as too slow, or failed).
    pub stopped: Option<String>,
}

/// A candidate's cheap look: C-arm-moved frames at two small detector sizes, and the full
/// frame they give.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Probe {
    /// Detector sides, pixels: an eighth and a quarter of the full side (at least 16 and 32).
    pub sides: [u32; 2],
    /// Fastest C-arm-moved frame at each side, ms.
    pub frame_ms: [f64; 2],
    /// The full frame they give, ms: the larger probe plus the cost per pixel between the two
    /// (none when the larger was no slower) for the pixels it lacks.
    pub full_ms: f64,
}

impl Probe {
    /// The estimate of a `full_side`^2 frame from frames at `sides`.
    pub fn new(sides: [u32; 2], frame_ms: [f64; 2], full_side: u32) -> Probe {
        let n = |side: u32| f64::from(side) * f64::from(side);
        let per_pixel_ms = ((frame_ms[1] - frame_ms[0]) / (n(sides[1]) - n(sides[0]))).max(0.0);
        Probe {
            sides,
            frame_ms,
            full_ms: frame_ms[1] + per_pixel_ms * (n(full_side) - n(sides[1])).max(0.0),
        }
    }
}

/// The outcome of a calibration.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// The station whose session was driven.
    pub station: String,
    /// Its region.
    pub region: String,
    /// Cores of this machine.
    pub cores: usize,
    /// Every candidate, in the order tried.
    pub timings: Vec<RendererTiming>,
    /// Index into `timings` of the chosen renderer.
    pub chosen: usize,
    /// The chosen renderer.
    pub renderer: BackendProfile,
    /// Sessions the chosen renderer holds.
    pub capacity: usize,
    /// The learner the capacity is for.
    pub learner: LearnerModel,
    /// Wall time of the whole calibration, s.
    pub took_s: f64,
}

/// Why no calibration could be made.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// No candidate renderer was given.
    #[error("no renderer to calibrate")]
    NoCandidate,
    /// No station with fluoroscopy has its region loaded.
    #[error("no loaded fluoroscopy station to calibrate on")]
    NoStation,
    /// Every candidate failed.
    #[error("every renderer failed: {0}")]
    AllFailed(String),
}

/// Process CPU time (user + system of every thread), s, from the kernel's run-time accounting
/// (`CLOCK_PROCESS_CPUTIME_ID`, nanoseconds: `/proc/self/stat`'s 10 ms ticks are coarser than
/// the few frames a calibration times); 0 where that clock is missing.
pub fn process_cpu_s() -> f64 {
    cpu_clock_s(libc::CLOCK_PROCESS_CPUTIME_ID)
}

/// The calling thread's CPU time, s (`CLOCK_THREAD_CPUTIME_ID`, which brings the running
/// thread's account up to date: `/proc/thread-self/schedstat` lags by up to a scheduler tick);
/// 0 where that clock is missing.
pub fn thread_cpu_s() -> f64 {
    cpu_clock_s(libc::CLOCK_THREAD_CPUTIME_ID)
}

/// `clock_gettime(clock)`, s; 0 where the call fails.
#[expect(
    unsafe_code,
    reason = "clock_gettime(2) has no safe wrapper in std; it only writes `t`"
)]
fn cpu_clock_s(clock: libc::clockid_t) -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid, writable timespec for the call's duration.
    let rc = unsafe { libc::clock_gettime(clock, &mut t) };
    if rc != 0 {
        return 0.0;
    }
    t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// Where a needle enters for the calibration: from behind (-y), towards the station's first
/// target, where that line meets the skin; `None` when the station has no needle or target or
/// the line misses the skin.
fn needle_place(station: &Station, region: &Region) -> Option<Command> {
    let instrument = station
        .instruments
        .iter()
        .find(|i| i.kind.contains("needle"))?;
    let target = glam::DVec3::from(station.targets.first()?.position_mm);
    let dir = glam::DVec3::new(0.1, 1.0, 0.0).normalize();
    let entry = region.skin_entry(target - 150.0 * dir, dir, 200.0)?;
    Some(Command::NeedlePlace {
        instrument: instrument.id.clone(),
        entry_mm: entry.to_array(),
        direction: dir.to_array(),
        bevel_reference: [1.0, 0.0, 0.0],
    })
}

struct Driver {
    rt: tokio::runtime::Runtime,
    session: SessionHandle,
    seq: u64,
}

impl Driver {
    /// A new session of `station_id` on `host`, fluoroscopy visible.
    fn open(host: &SessionHost, station_id: &str) -> Result<Driver, String> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| e.to_string())?;
        let session = host
            .create_blocking(station_id)
            .map_err(|e| e.to_string())?;
        session.set_visible(BTreeSet::from([ViewId::FLUOROSCOPY]));
        Ok(Driver {
            rt,
            session,
            seq: 0,
        })
    }

    /// A new session of `station_id` on `host` after its first shot (the time of that shot, ms),
    /// with the work its renderer started in the background done: that work (the GPU
    /// renderer's draft scene) would slow the frames timed next, and on a server it is done
    /// after start-up.
    fn first_shot(host: &SessionHost, station_id: &str) -> Result<(Driver, f64), String> {
        let mut d = Driver::open(host, station_id)?;
        let ms = d.frame_after(&[Command::Shot])?;
        host.backends().fluoro.finish_background_work();
        Ok((d, ms))
    }

    /// Applies `commands` and waits for the full fluoroscopy frame that reflects the last one
    /// (after its draft, if one came first: both are work the learner's frame costs); wall time
    /// in ms.
    fn frame_after(&mut self, commands: &[Command]) -> Result<f64, String> {
        let t = Instant::now();
        let session = self.session.clone();
        let mut seq = self.seq;
        let out = self.rt.block_on(async {
            for c in commands {
                seq += 1;
                session
                    .command(Envelope {
                        seq,
                        command: c.clone(),
                    })
                    .await
                    .map_err(|e| format!("{}: {}", e.field, e.message))?;
            }
            let mut rx = session.frames();
            while rx
                .borrow_and_update()
                .get(&ViewId::FLUOROSCOPY)
                .is_none_or(|f| f.input_seq < seq || f.draft)
            {
                rx.changed()
                    .await
                    .map_err(|_| "the session ended".to_string())?;
            }
            Ok::<_, String>(())
        });
        self.seq = seq;
        out.map(|()| t.elapsed().as_secs_f64() * 1e3)
    }

    /// `FRAMES_PER_KIND` frames after `make(k)`'s commands: (median wall ms, CPU ms per frame).
    fn timed(
        &mut self,
        make: impl Fn(usize) -> Vec<Command>,
    ) -> Result<(Option<f64>, Option<f64>), String> {
        let cpu = process_cpu_s();
        let mut walls = Vec::new();
        for k in 0..FRAMES_PER_KIND {
            walls.push(self.frame_after(&make(k))?);
        }
        let cpu_ms = (process_cpu_s() - cpu) * 1e3 / FRAMES_PER_KIND as f64;
        Ok((median(walls), Some(cpu_ms)))
    }
}

/// A one-session host of `station` on `region` rendering fluoroscopy with `fluoro`.
fn calibration_host(
    station: &(Station, String),
    region: &Arc<Region>,
    config: &SessionConfig,
    fluoro: Arc<dyn FluoroBackend>,
) -> SessionHost {
    SessionHost::with_regions(
        vec![station.clone()],
        vec![Arc::clone(region)],
        Backends::new(fluoro, Arc::new(CpuUltrasoundBackend)),
        1,
        *config,
    )
}

/// The best candidate measured so far, for the early stop.
#[derive(Debug, Clone, Copy)]
struct Best {
    /// Its C-arm-moved frame, ms.
    carm_ms: f64,
    /// Its first frame, ms.
    first_ms: f64,
}

/// The `k`-th C-arm move of a calibration, and a shot.
fn carm_move(k: usize) -> Vec<Command> {
    vec![
        Command::CarmPose {
            orbital_deg: 4.0 * (k as f64 + 1.0),
            angular_deg: 2.0 * k as f64,
            table_mm: [0.0; 3],
        },
        Command::Shot,
    ]
}

/// The fastest of a new session's C-arm-moved frames (after its first shot), ms: the least
/// disturbed by other work on the machine, which only ever adds time.
fn carm_frames(
    station: &(Station, String),
    region: &Arc<Region>,
    config: &SessionConfig,
    fluoro: Arc<dyn FluoroBackend>,
) -> Result<f64, String> {
    let host = calibration_host(station, region, config, fluoro);
    let ms = Driver::first_shot(&host, &station.0.id).and_then(|(mut d, _)| {
        (0..FRAMES_PER_KIND)
            .map(|k| d.frame_after(&carm_move(k)))
            .try_fold(f64::INFINITY, |min, ms| Ok(min.min(ms?)))
    });
    host.shutdown();
    ms
}

/// Drives one session of `station` on `region` with `fluoro`, after a probe when there is a
/// `best` candidate so far (for the early stop).
fn measure(
    station: &(Station, String),
    region: &Arc<Region>,
    config: &SessionConfig,
    fluoro: Arc<dyn FluoroBackend>,
    best: Option<Best>,
    learner: &LearnerModel,
    cores: usize,
) -> RendererTiming {
    let mut timing = RendererTiming {
        renderer: fluoro.profile(),
        first_frame_ms: f64::NAN,
        probe: None,
        carm_moved_ms: None,
        needle_moved_ms: None,
        new_shot_ms: None,
        carm_moved_cpu_ms: None,
        needle_moved_cpu_ms: None,
        learner_load: None,
        capacity: None,
        stopped: None,
    };
    // A cheap look first when there is a best to beat: a far slower renderer (the CPU
    // reference beside a GPU) is stopped after a few frames of at most a sixteenth of the work.
    if let Some(best) = best {
        let full = config.fluoro.detector_pixels;
        let sides = [(full / 8).max(16), (full / 4).max(32)];
        let mut frame_ms = [0.0; 2];
        for (ms, side) in frame_ms.iter_mut().zip(sides) {
            let mut small = *config;
            small.fluoro.detector_pixels = side;
            match carm_frames(station, region, &small, Arc::clone(&fluoro)) {
                Ok(t) => *ms = t,
                Err(e) => {
                    timing.stopped = Some(format!("failed: {e}"));
                    return timing;
                }
            }
        }
        let probe = Probe::new(sides, frame_ms, full);
        timing.probe = Some(probe);
        // The larger probe's frame is a certain floor of the full frame's, the estimate its
        // size; the floor guards against an estimate that the noise of a shared CPU inflated.
        if frame_ms[1] > best.carm_ms
            && probe.full_ms > GIVE_UP_FACTOR * best.carm_ms
            && probe.full_ms - best.carm_ms > EARLY_STOP_NOISE_MS
        {
            timing.stopped = Some(format!(
                "C-arm-moved frames of {:.0} and {:.0} ms at {}^2 and {}^2 give about {:.0} ms at \
                 full size: over {GIVE_UP_FACTOR} times the best candidate's ({:.0} ms)",
                frame_ms[0], frame_ms[1], sides[0], sides[1], probe.full_ms, best.carm_ms
            ));
            return timing;
        }
    }
    let host = calibration_host(station, region, config, fluoro);
    let outcome = (|| -> Result<(), String> {
        let (mut d, first_ms) = Driver::first_shot(&host, &station.0.id)?;
        timing.first_frame_ms = first_ms;
        if let Some(best) = best.map(|b| b.first_ms)
            && timing.first_frame_ms > GIVE_UP_FACTOR * best
            && timing.first_frame_ms - best > EARLY_STOP_NOISE_MS
        {
            timing.stopped = Some(format!(
                "first frame {:.0} ms, over {GIVE_UP_FACTOR} times the best candidate's ({best:.0} ms)",
                timing.first_frame_ms
            ));
            return Ok(());
        }
        (timing.carm_moved_ms, timing.carm_moved_cpu_ms) = d.timed(carm_move)?;
        match needle_place(&station.0, region) {
            Some(place) => {
                d.frame_after(&[place, Command::Shot])?;
                (timing.needle_moved_ms, timing.needle_moved_cpu_ms) =
                    d.timed(|_| vec![Command::NeedleFeed { mm: 1.0 }, Command::Shot])?;
            }
            // No needle at this station: a needle step costs at most a C-arm move.
            None => {
                (timing.needle_moved_ms, timing.needle_moved_cpu_ms) =
                    (timing.carm_moved_ms, timing.carm_moved_cpu_ms);
            }
        }
        (timing.new_shot_ms, _) = d.timed(|_| vec![Command::Shot])?;
        Ok(())
    })();
    host.shutdown();
    if let Err(e) = outcome {
        timing.stopped = Some(format!("failed: {e}"));
    }
    if let (Some(c), Some(n)) = (timing.carm_moved_cpu_ms, timing.needle_moved_cpu_ms) {
        let (fc, fn_) = learner.frames();
        // CPU seconds a learner asks for per second of its actions, over the cores (the time it
        // waits for its frames is left out: a slower renderer is not credited with it).
        let cpu_per_action_s = (c * fc + n * fn_) / 1e3;
        let load = cpu_per_action_s / learner.action_s / cores.max(1) as f64;
        timing.learner_load = Some(load);
        timing.capacity = Some(capacity_for(load));
    }
    timing
}

/// Sessions held at `load` per learner: [`TARGET_UTILISATION`] over it, 1 to
/// [`MAX_CALIBRATED_CAPACITY`].
pub fn capacity_for(load: f64) -> usize {
    if !(load.is_finite() && load > 0.0) {
        return MAX_CALIBRATED_CAPACITY;
    }
    ((TARGET_UTILISATION / load).floor() as usize).clamp(1, MAX_CALIBRATED_CAPACITY)
}

/// Calibrates `candidates` (tried in this order; put the likely fastest first) on a session of
/// `station` on `region` configured by `config` (the detector size and supersampling that
/// sessions use).
pub fn calibrate(
    station: &(Station, String),
    region: &Arc<Region>,
    config: &SessionConfig,
    candidates: &[Arc<dyn FluoroBackend>],
) -> Result<Calibration, CalibrationError> {
    if candidates.is_empty() {
        return Err(CalibrationError::NoCandidate);
    }
    let began = Instant::now();
    let learner = LearnerModel::SCRIPTED;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut timings: Vec<RendererTiming> = Vec::new();
    for c in candidates {
        let best = timings
            .iter()
            .filter(|t| t.stopped.is_none())
            .filter_map(|t| {
                Some(Best {
                    carm_ms: t.carm_moved_ms?,
                    first_ms: t.first_frame_ms,
                })
            })
            .min_by(|a, b| a.carm_ms.total_cmp(&b.carm_ms));
        let t = measure(
            station,
            region,
            config,
            Arc::clone(c),
            best,
            &learner,
            cores,
        );
        tracing::info!(renderer = %t.renderer.kind, device = %t.renderer.device,
            first_ms = t.first_frame_ms, carm_ms = ?t.carm_moved_ms, capacity = ?t.capacity,
            stopped = ?t.stopped, "calibrated a fluoroscopy renderer");
        timings.push(t);
    }
    let measured = || {
        timings
            .iter()
            .enumerate()
            .filter(|(_, t)| t.stopped.is_none())
            .filter_map(|(k, t)| Some((k, t.learner_load?, t.carm_moved_ms?)))
    };
    let cheapest = measured().map(|(_, load, _)| load).min_by(f64::total_cmp);
    let chosen = measured()
        .filter(|(_, load, _)| cheapest.is_some_and(|c| *load <= SAME_COST * c))
        .min_by(|a, b| a.2.total_cmp(&b.2))
        .map(|(k, _, _)| k)
        .ok_or_else(|| {
            CalibrationError::AllFailed(
                timings
                    .iter()
                    .map(|t| {
                        format!(
                            "{}: {}",
                            t.renderer.kind,
                            t.stopped.as_deref().unwrap_or("no figure")
                        )
                    })
                    .collect::<Vec<_>>()
                    .join("; "),
            )
        })?;
    Ok(Calibration {
        station: station.0.id.clone(),
        region: region.name.clone(),
        cores,
        renderer: timings[chosen].renderer.clone(),
        capacity: timings[chosen].capacity.unwrap_or(1),
        chosen,
        timings,
        learner,
        took_s: began.elapsed().as_secs_f64(),
    })
}

/// Calibrates `candidates` on `host`'s heaviest loaded fluoroscopy station (the region with the
/// most triangles: the capacity holds for the costliest scene it serves), records the outcome in
/// the host's health, renders new sessions with the chosen candidate and sets the host's
/// capacity to the calibrated one, unless `fixed_capacity` (an operator's setting) is given.
pub fn calibrate_host(
    host: &SessionHost,
    candidates: &[Arc<dyn FluoroBackend>],
    fixed_capacity: Option<usize>,
) -> Result<Calibration, CalibrationError> {
    let (station, region) = host
        .fluoroscopy_stations()
        .into_iter()
        .max_by_key(|(_, r)| r.scene.triangle_count())
        .ok_or(CalibrationError::NoStation)?;
    let c = calibrate(&station, &region, &host.session_config(), candidates)?;
    host.set_calibration(serde_json::to_value(&c).unwrap_or_default());
    host.set_fluoro_backend(Arc::clone(&candidates[c.chosen]));
    host.set_capacity(fixed_capacity.unwrap_or(c.capacity));
    Ok(c)
}

/// Prepares every region of `host`'s fluoroscopy stations with its fluoroscopy renderer
/// ([`FluoroBackend::prepare`]: the GPU renderer that keeps its uploads makes each region's
/// anatomy and draft scene now, one region after another), so that a station's first session
/// does not make them before its first image (0.36 s for the default phantom's anatomy and
/// 1.7 s for its draft scene when not stored, which shared the 2 cores with that session's
/// first frames). Call it once the regions are loaded, before the calibration (with the
/// renderer the host starts with, which the calibration keeps unless another one is faster: the
/// calibration takes tens of seconds on a small machine, and learners meanwhile get prepared
/// regions), and again after it (which prepares the chosen renderer's regions if the choice
/// changed, and costs nothing otherwise), on the calibration's thread. Returns how many regions
/// the renderer keeps prepared (made now or before), and logs it with the time it took; a
/// region that fails is logged and skipped (its sessions meet the same error and report it).
pub fn prepare_fluoroscopy_regions(host: &SessionHost) -> usize {
    let started = Instant::now();
    let backend = host.backends().fluoro;
    let mut seen = BTreeSet::new();
    let mut prepared = 0;
    for (_, region) in host.fluoroscopy_stations() {
        if !seen.insert(region.name.clone()) {
            continue;
        }
        match backend.prepare(&region) {
            Ok(made) => prepared += usize::from(made),
            Err(e) => tracing::warn!(region = %region.name, error = %e,
                "could not prepare the region's fluoroscopy renderer"),
        }
    }
    tracing::info!(
        regions = prepared,
        took_s = started.elapsed().as_secs_f64(),
        "fluoroscopy regions prepared"
    );
    prepared
}

/// How often [`calibrate_when_ready`] looks at the host's regions. Simulator choice: a cold
/// phantom takes tens of seconds, so a quarter second costs nothing and starts at once after.
const READY_POLL: Duration = Duration::from_millis(250);

/// [`calibrate_host`] on `host`'s own renderers (its fluoroscopy renderer, then the CPU
/// reference unless that is the one it has) once no region is being prepared any more, with the
/// regions prepared for its renderer first ([`prepare_fluoroscopy_regions`]) (call it
/// after [`SessionHost::prepare_in_background`]: a region not started counts as pending) and one
/// of its fluoroscopy stations has its region loaded (blocking: call it on its own thread).
/// [`CalibrationError::NoStation`] when every preparation ended without such a region.
pub fn calibrate_when_ready(
    host: &SessionHost,
    fixed_capacity: Option<usize>,
) -> Result<Calibration, CalibrationError> {
    loop {
        let building = host.regions_readiness().values().any(|r| {
            !matches!(
                r,
                RegionReadiness::Ready { .. } | RegionReadiness::Failed { .. }
            )
        });
        if !building {
            break;
        }
        std::thread::sleep(READY_POLL);
    }
    prepare_fluoroscopy_regions(host);
    let own = host.backends().fluoro;
    let cpu = Backends::cpu(0).fluoro;
    let mut candidates = vec![Arc::clone(&own)];
    candidates.extend(own.alternatives());
    if own.profile().kind != cpu.profile().kind {
        candidates.push(cpu);
    }
    calibrate_host(host, &candidates, fixed_capacity)
}
