//! Region preparation: which regions a worker has loaded, which are being loaded or built (the
//! phantom pipeline takes tens of seconds cold), how far they are, and waiting for them.
//!
//! [`Regions`] owns the loaded regions and their preparation state. A region is prepared at
//! most once at a time: a caller first *claims* it ([`Regions::claim`]), then loads it
//! ([`Regions::load_claimed`]), on a background thread ([`Regions::spawn_preparation`]) or on
//! its own ([`Regions::blocking`], which otherwise waits for the preparation under way). The
//! session host ([`super::host`]) maps the outcomes to its errors; this module knows nothing of
//! sessions.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Condvar, Mutex, PoisonError};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use sim_core::anatomy::pipeline::Progress;

use super::loader::RegionLoadError;
use super::region::Region;

/// Where a region stands on a worker: reported in `/healthz`, and in the answer to a session
/// request that arrives while it is being prepared.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum RegionReadiness {
    /// Not requested yet (loaded on first use, or by
    /// [`super::host::SessionHost::prepare_in_background`]).
    NotStarted,
    /// Being loaded or built.
    Building {
        /// Stage of the build (`"start"`, or the phantom pipeline's `"voxelize"`, `"labels"`,
        /// `"mesh"`, `"interfaces"`).
        stage: String,
        /// Estimated fraction done, 0 to 1 (see [`build_fraction`]).
        fraction: f64,
        /// Seconds since it started.
        elapsed_s: f64,
        /// Estimated seconds left.
        remaining_s: f64,
    },
    /// Loaded; sessions start at once.
    Ready {
        /// Seconds the preparation took (0 for regions given to the host ready-made).
        prepare_s: f64,
    },
    /// Loading or building failed; sessions of its stations cannot start.
    Failed {
        /// Why, in words.
        reason: String,
    },
}

/// Expected duration of a phantom build when no progress has been reported yet, s. Measured
/// (dev profile) on the 2-core development machine: 37 s for the default lumbar phantom (meshed
/// from level sets; 50-55 s inside a starting server, which prepares its other regions and its
/// worker meanwhile), 16-18 s for the neck, 42 and 45 s for the slim and obese habitus.
pub const EXPECTED_BUILD_S: f64 = 50.0;

/// Longest `Retry-After` handed out, s. Simulator choice: a client told to come back in at most
/// a few seconds shows progress that moves, and starts within that much of the build's end.
pub const MAX_RETRY_AFTER_S: f64 = 3.0;

/// Fraction of a phantom build done at a progress report. The stage weights are a simulator
/// choice from timed builds of the default lumbar phantom on 2 cores: voxelization and the
/// label volume 5-7 % of the time, extracting the structures 4 % (mask meshes) to 20 % (level
/// sets), and the family steps that share their interfaces ("interfaces": welding, level-set
/// placement, decimation, refinement) the rest, 70-77 % (44 of 63 s for the level-set default,
/// 20 of 27 s for mask meshes). They only shape the progress shown and the `Retry-After`
/// estimate.
pub fn build_fraction(p: &Progress) -> f64 {
    let part = if p.total == 0 {
        0.0
    } else {
        (p.done as f64 / p.total as f64).clamp(0.0, 1.0)
    };
    match p.stage {
        "voxelize" => 0.05 * part,
        "labels" => 0.05 + 0.05 * part,
        "mesh" => 0.10 + 0.20 * part,
        "interfaces" => 0.30 + 0.70 * part,
        _ => 0.0,
    }
}

/// What is remembered of a region's preparation.
#[derive(Debug, Clone)]
enum Prep {
    Building {
        started: Instant,
        stage: String,
        fraction: f64,
    },
    Ready {
        prepare_s: f64,
    },
    Failed(String),
}

impl Prep {
    fn building() -> Prep {
        Prep::Building {
            started: Instant::now(),
            stage: "start".into(),
            fraction: 0.0,
        }
    }

    fn readiness(&self) -> RegionReadiness {
        match self {
            Prep::Building {
                started,
                stage,
                fraction,
            } => {
                let elapsed_s = started.elapsed().as_secs_f64();
                // Extrapolate from the progress so far once there is some; before that, the
                // expected build time.
                let remaining_s = if *fraction >= 0.05 {
                    elapsed_s * (1.0 - fraction) / fraction
                } else {
                    (EXPECTED_BUILD_S - elapsed_s).max(1.0)
                };
                RegionReadiness::Building {
                    stage: stage.clone(),
                    fraction: *fraction,
                    elapsed_s,
                    remaining_s,
                }
            }
            Prep::Ready { prepare_s } => RegionReadiness::Ready {
                prepare_s: *prepare_s,
            },
            Prep::Failed(reason) => RegionReadiness::Failed {
                reason: reason.clone(),
            },
        }
    }
}

/// Why a region is not there.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PrepareError {
    /// Loading or building it failed (the loader's reason, in words).
    #[error("{0}")]
    Failed(String),
    /// A thread preparing it panicked while holding the state.
    #[error("the region preparation state is poisoned")]
    Poisoned,
}

/// Loads a region by name, reporting build stages to the callback.
pub type RegionLoader =
    dyn Fn(&str, &mut dyn FnMut(&Progress)) -> Result<Region, RegionLoadError> + Send + Sync;

/// The loaded regions of a worker and the preparation of the others.
pub struct Regions {
    loaded: Mutex<BTreeMap<String, Arc<Region>>>,
    /// Preparation state of regions not given ready-made; `prepared` wakes its waiters.
    prep: Mutex<BTreeMap<String, Prep>>,
    prepared: Condvar,
    loader: Box<RegionLoader>,
    /// Whether the loader would only read a region's files (no build).
    quick: Box<QuickCheck>,
    /// Claimed regions waiting for preparation, and which preparation threads run.
    queue: Mutex<Queue>,
    /// Held by the thread whose loader is building a region (it reports build stages), so
    /// that builds run one at a time whichever thread took them (a region that looked built
    /// may turn out damaged and be built again).
    builds: Mutex<()>,
}

/// Whether loading a region would only read its files (a built, cached region), not build it.
pub type QuickCheck = dyn Fn(&str) -> bool + Send + Sync;

/// The regions waiting for preparation, next first, and the threads that take them: the main
/// one takes every region in order, one at a time (a phantom build already uses every core: two
/// builds at once would only finish both later); a helper takes only regions whose loader just
/// reads files (mostly one core each), so on a restart two load at once.
#[derive(Default)]
struct Queue {
    waiting: VecDeque<String>,
    main: bool,
    helper: bool,
}

impl Regions {
    /// No region loaded yet; `loader` prepares them, one at a time.
    pub fn new(loader: Box<RegionLoader>) -> Regions {
        Regions::with_quick_check(loader, Box::new(|_| false))
    }

    /// [`Regions::new`], where a region for which `quick` is true (its loader only reads files)
    /// may load beside another one on a machine of two or more cores.
    pub fn with_quick_check(loader: Box<RegionLoader>, quick: Box<QuickCheck>) -> Regions {
        Regions {
            loaded: Mutex::new(BTreeMap::new()),
            prep: Mutex::new(BTreeMap::new()),
            prepared: Condvar::new(),
            loader,
            quick,
            queue: Mutex::new(Queue::default()),
            builds: Mutex::new(()),
        }
    }

    /// Adds a region prepared elsewhere (ready at once, `prepare_s` 0).
    pub fn insert(&self, region: Arc<Region>) {
        if let Ok(mut m) = self.loaded.lock() {
            m.insert(region.name.clone(), region);
        }
    }

    /// The region if it is loaded.
    pub fn loaded(&self, region: &str) -> Option<Arc<Region>> {
        self.loaded.lock().ok()?.get(region).cloned()
    }

    fn prep_of(&self, region: &str) -> Option<Prep> {
        self.prep.lock().ok().and_then(|p| p.get(region).cloned())
    }

    /// Readiness of one region.
    pub fn readiness(&self, region: &str) -> RegionReadiness {
        if self.loaded(region).is_some() {
            let prepare_s = match self.prep_of(region) {
                Some(Prep::Ready { prepare_s }) => prepare_s,
                _ => 0.0,
            };
            return RegionReadiness::Ready { prepare_s };
        }
        self.prep_of(region)
            .map_or(RegionReadiness::NotStarted, |p| p.readiness())
    }

    /// Marks `region` as being prepared by the caller; false when it is loaded or already being
    /// prepared.
    pub fn claim(&self, region: &str) -> bool {
        if self.loaded(region).is_some() {
            return false;
        }
        let Ok(mut prep) = self.prep.lock() else {
            return false;
        };
        if matches!(prep.get(region), Some(Prep::Building { .. })) {
            return false;
        }
        prep.insert(region.to_string(), Prep::building());
        true
    }

    /// Prepares the claimed `regions` on background threads (after those already waiting), in
    /// order and one at a time, except that a region that only needs reading may load beside
    /// another (see [`Regions::with_quick_check`]); returns at once. A region a learner asks for
    /// meanwhile goes first ([`Regions::prefer`]).
    pub fn spawn_preparation(self: &Arc<Self>, regions: Vec<String>) {
        let mut queue = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
        for r in regions {
            if !queue.waiting.contains(&r) {
                queue.waiting.push_back(r);
            }
        }
        if queue.waiting.is_empty() {
            return;
        }
        let start_main = !queue.main;
        queue.main = true;
        let two_cores = std::thread::available_parallelism().is_ok_and(|n| n.get() >= 2);
        let start_helper = two_cores && !queue.helper;
        queue.helper |= start_helper;
        drop(queue);
        if start_main {
            let this = Arc::clone(self);
            let spawned = std::thread::Builder::new()
                .name("region-prepare".into())
                .spawn(move || this.prepare_in_order());
            if let Err(e) = spawned {
                tracing::error!("cannot start the region preparation thread: {e}");
                let mut queue = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
                queue.main = false;
                for r in std::mem::take(&mut queue.waiting) {
                    self.fail(
                        &r,
                        format!("cannot start the region preparation thread: {e}"),
                    );
                }
            }
        }
        if start_helper {
            let this = Arc::clone(self);
            let spawned = std::thread::Builder::new()
                .name("region-read".into())
                .spawn(move || this.read_quick_ones());
            if spawned.is_err() {
                // The main thread prepares them all.
                self.queue
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .helper = false;
            }
        }
    }

    /// The main preparation thread: every waiting region, next first.
    fn prepare_in_order(&self) {
        loop {
            let next = {
                let mut queue = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
                let next = queue.waiting.pop_front();
                queue.main = next.is_some();
                next
            };
            let Some(r) = next else { break };
            self.prepare_logged(&r);
        }
    }

    /// The helper thread: the first waiting region that only needs reading, until none is left
    /// (the main thread takes the rest).
    fn read_quick_ones(&self) {
        loop {
            let waiting: Vec<String> = self
                .queue
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .waiting
                .iter()
                .cloned()
                .collect();
            // Outside the lock: the check reads a file.
            let candidate = waiting.into_iter().find(|r| (self.quick)(r));
            let mut queue = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
            let Some(r) = candidate else {
                queue.helper = false;
                break;
            };
            // Taken by the main thread meanwhile: look again.
            let Some(k) = queue.waiting.iter().position(|w| *w == r) else {
                continue;
            };
            queue.waiting.remove(k);
            drop(queue);
            self.prepare_logged(&r);
        }
    }

    fn prepare_logged(&self, region: &str) {
        match self.load_claimed(region) {
            Ok(_) => tracing::info!(region, "region ready"),
            Err(e) => tracing::error!(region, "region preparation failed: {e}"),
        }
    }

    /// Moves `region` to the front of the regions waiting for preparation, if it waits (a
    /// learner asked for it: on a cold start the learner waits for that region's build only,
    /// not for the ones queued before it). True when it was waiting.
    pub fn prefer(&self, region: &str) -> bool {
        let mut queue = self.queue.lock().unwrap_or_else(PoisonError::into_inner);
        match queue.waiting.iter().position(|r| r == region) {
            Some(0) => true,
            Some(k) => {
                if let Some(r) = queue.waiting.remove(k) {
                    queue.waiting.push_front(r);
                }
                true
            }
            None => false,
        }
    }

    /// Marks a claimed region failed with `reason` and wakes its waiters.
    fn fail(&self, region: &str, reason: String) {
        if let Ok(mut prep) = self.prep.lock() {
            prep.insert(region.to_string(), Prep::Failed(reason));
        }
        self.prepared.notify_all();
    }

    /// Loads a region the caller claimed, recording progress and the outcome, and wakes anyone
    /// waiting for it.
    pub fn load_claimed(&self, region: &str) -> Result<Arc<Region>, PrepareError> {
        let started = Instant::now();
        // Its time and progress count from now, not from when it was queued.
        if let Ok(mut prep) = self.prep.lock() {
            prep.insert(region.to_string(), Prep::building());
        }
        let mut building = None;
        let mut progress = |p: &Progress| {
            // The loader reports stages only when it builds: one build at a time from here on.
            if building.is_none() {
                building = Some(self.builds.lock().unwrap_or_else(PoisonError::into_inner));
            }
            if let Ok(mut prep) = self.prep.lock()
                && let Some(Prep::Building {
                    stage, fraction, ..
                }) = prep.get_mut(region)
            {
                *stage = p.stage.to_string();
                *fraction = fraction.max(build_fraction(p));
            }
        };
        let result = (self.loader)(region, &mut progress).map(|r| {
            let r = Arc::new(r);
            self.insert(Arc::clone(&r));
            r
        });
        drop(building);
        let prepare_s = started.elapsed().as_secs_f64();
        if let Ok(mut prep) = self.prep.lock() {
            let state = match &result {
                Ok(_) => Prep::Ready { prepare_s },
                Err(e) => Prep::Failed(e.to_string()),
            };
            prep.insert(region.to_string(), state);
        }
        self.prepared.notify_all();
        result.map_err(|e| PrepareError::Failed(e.to_string()))
    }

    /// The region, loading it here if nobody is (blocking: possibly a whole phantom build), or
    /// waiting for the preparation under way.
    pub fn blocking(&self, region: &str) -> Result<Arc<Region>, PrepareError> {
        loop {
            if let Some(r) = self.loaded(region) {
                return Ok(r);
            }
            if self.claim(region) {
                return self.load_claimed(region);
            }
            // Claimed and waiting for the preparation thread: next, then.
            self.prefer(region);
            let prep = self.prep.lock().map_err(|_| PrepareError::Poisoned)?;
            if matches!(prep.get(region), Some(Prep::Building { .. })) {
                let _unused = self
                    .prepared
                    .wait_while(prep, |p| {
                        matches!(p.get(region), Some(Prep::Building { .. }))
                    })
                    .map_err(|_| PrepareError::Poisoned)?;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    /// The demo region under the name a test loader was asked for.
    fn named(name: &str) -> Result<Region, RegionLoadError> {
        let mut r = crate::session::demo::demo_region();
        r.name = name.to_string();
        Ok(r)
    }

    /// Claims `names` and queues them for preparation; returns them.
    fn claim_and_spawn(regions: &Arc<Regions>, names: &[&str]) -> Vec<String> {
        let names: Vec<String> = names.iter().map(|n| n.to_string()).collect();
        for n in &names {
            assert!(regions.claim(n));
        }
        regions.spawn_preparation(names.clone());
        names
    }

    /// What a test loader reports next, within 30 s.
    fn next<T>(rx: &mpsc::Receiver<T>) -> T {
        rx.recv_timeout(std::time::Duration::from_secs(30)).unwrap()
    }

    /// Regions queued behind a long build: the one a learner asks for (`prefer`) is prepared
    /// next, the others keep their order, and a region already being built is not moved.
    #[test]
    fn the_region_a_learner_asks_for_is_prepared_next() {
        let (started_tx, started_rx) = mpsc::channel::<String>();
        let (go_tx, go_rx) = mpsc::channel::<()>();
        let go_rx = Mutex::new(go_rx);
        let loader = move |name: &str, _progress: &mut dyn FnMut(&Progress)| {
            started_tx.send(name.to_string()).unwrap();
            // Each build waits for the test's go.
            go_rx.lock().unwrap().recv().unwrap();
            named(name)
        };
        let regions = Arc::new(Regions::new(Box::new(loader)));
        let names = claim_and_spawn(&regions, &["a", "b", "c", "d"]);
        let next = || next(&started_rx);
        assert_eq!(next(), "a");
        // While "a" builds, a learner asks for "d"; "a" itself is not waiting any more.
        assert!(regions.prefer("d"));
        assert!(!regions.prefer("a"));
        assert!(!regions.prefer("unknown"));
        go_tx.send(()).unwrap();
        assert_eq!(next(), "d");
        // Queued regions report a fresh start once their build begins.
        assert!(matches!(
            regions.readiness("d"),
            RegionReadiness::Building { fraction, .. } if fraction == 0.0
        ));
        go_tx.send(()).unwrap();
        assert_eq!(next(), "b");
        go_tx.send(()).unwrap();
        assert_eq!(next(), "c");
        go_tx.send(()).unwrap();
        for n in &names {
            assert!(regions.blocking(n).is_ok());
            assert!(matches!(
                regions.readiness(n),
                RegionReadiness::Ready { .. }
            ));
        }
        // A later preparation starts a new thread once the first has ended.
        assert!(regions.claim("e"));
        regions.spawn_preparation(vec!["e".into()]);
        assert_eq!(next(), "e");
        go_tx.send(()).unwrap();
        assert!(regions.blocking("e").is_ok());
    }

    /// Regions that only need reading load beside the one in progress (two at most); those that
    /// need a build never run beside another build.
    #[test]
    fn regions_that_only_need_reading_load_two_at_a_time() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        if std::thread::available_parallelism().map_or(1, |n| n.get()) < 2 {
            return;
        }
        let running = Arc::new(AtomicUsize::new(0));
        let (started_tx, started_rx) = mpsc::channel::<(String, usize)>();
        let (go_tx, go_rx) = mpsc::channel::<()>();
        let go_rx = Mutex::new(go_rx);
        let builds_at_once = Arc::new(AtomicUsize::new(0));
        let most_builds = Arc::new(AtomicUsize::new(0));
        let (r2, b2, m2) = (running.clone(), builds_at_once.clone(), most_builds.clone());
        let loader = move |name: &str, _progress: &mut dyn FnMut(&Progress)| {
            let now = r2.fetch_add(1, Ordering::SeqCst) + 1;
            let build = name.starts_with("cold");
            if build {
                let b = b2.fetch_add(1, Ordering::SeqCst) + 1;
                m2.fetch_max(b, Ordering::SeqCst);
            }
            started_tx.send((name.to_string(), now)).unwrap();
            go_rx.lock().unwrap().recv().unwrap();
            if build {
                b2.fetch_sub(1, Ordering::SeqCst);
            }
            r2.fetch_sub(1, Ordering::SeqCst);
            named(name)
        };
        let regions = Arc::new(Regions::with_quick_check(
            Box::new(loader),
            Box::new(|name: &str| name.starts_with("read")),
        ));
        let names = claim_and_spawn(&regions, &["cold-a", "cold-b", "read-c", "read-d"]);
        let next = || next(&started_rx);
        // The first build and the first region to read start together, before either ends.
        let mut first_two = [next(), next()];
        first_two.sort();
        assert_eq!(first_two[0].0, "cold-a");
        assert_eq!(first_two[1].0, "read-c");
        assert_eq!(first_two.iter().map(|s| s.1).max(), Some(2));
        for _ in 0..2 {
            go_tx.send(()).unwrap();
        }
        // Then the rest, never more than two at once and never two builds at once.
        let mut rest: Vec<String> = (0..2).map(|_| next().0).collect();
        for _ in 0..2 {
            go_tx.send(()).unwrap();
        }
        rest.sort();
        assert_eq!(rest, ["cold-b", "read-d"]);
        for n in &names {
            assert!(regions.blocking(n).is_ok(), "{n}");
        }
        assert_eq!(most_builds.load(Ordering::SeqCst), 1);
    }

    /// A region that looked built but is built after all (a damaged cache: its loader reports
    /// build stages) waits for the build under way instead of running beside it.
    #[test]
    fn a_region_that_turns_out_to_need_a_build_waits_for_the_other_build() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        let builds = Arc::new(AtomicUsize::new(0));
        let most = Arc::new(AtomicUsize::new(0));
        let (b2, m2) = (builds.clone(), most.clone());
        let loader = move |name: &str, progress: &mut dyn FnMut(&Progress)| {
            // Both regions build: "damaged" only looked built to the quick check.
            progress(&Progress {
                stage: "voxelize",
                done: 0,
                total: 1,
                item: String::new(),
            });
            let now = b2.fetch_add(1, Ordering::SeqCst) + 1;
            m2.fetch_max(now, Ordering::SeqCst);
            std::thread::sleep(std::time::Duration::from_millis(150));
            b2.fetch_sub(1, Ordering::SeqCst);
            named(name)
        };
        let regions = Arc::new(Regions::with_quick_check(
            Box::new(loader),
            Box::new(|name: &str| name == "damaged"),
        ));
        let names = claim_and_spawn(&regions, &["cold", "damaged"]);
        for n in &names {
            assert!(regions.blocking(n).is_ok(), "{n}");
        }
        assert_eq!(most.load(Ordering::SeqCst), 1, "two builds ran at once");
    }
}
