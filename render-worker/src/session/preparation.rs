//! Region preparation: which regions a worker has loaded, which are being loaded or built (the
//! phantom pipeline takes tens of seconds cold), how far they are, and waiting for them.
//!
//! [`Regions`] owns the loaded regions and their preparation state. A region is prepared at
//! most once at a time: a caller first *claims* it ([`Regions::claim`]), then loads it
//! ([`Regions::load_claimed`]), on a background thread ([`Regions::spawn_preparation`]) or on
//! its own ([`Regions::blocking`], which otherwise waits for the preparation under way). The
//! session host ([`super::host`]) maps the outcomes to its errors; this module knows nothing of
//! sessions.

use std::collections::BTreeMap;
use std::sync::{Arc, Condvar, Mutex};
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
        /// `"mesh"`).
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

/// Expected duration of a phantom build when no progress has been reported yet, s. Measured:
/// about 18 s for the default lumbar phantom on the 2-core development machine.
pub const EXPECTED_BUILD_S: f64 = 20.0;

/// Longest `Retry-After` handed out, s. Simulator choice: a client told to come back in at most
/// a few seconds shows progress that moves, and starts within that much of the build's end.
pub const MAX_RETRY_AFTER_S: f64 = 3.0;

/// Fraction of a phantom build done at a progress report. The stage weights are a simulator
/// choice from one timed build of the default phantom on 2 cores (voxelization about 40 % of
/// the time, label volume 10 %, meshing the structures the rest); they only shape the progress
/// shown and the `Retry-After` estimate.
pub fn build_fraction(p: &Progress) -> f64 {
    let part = if p.total == 0 {
        0.0
    } else {
        (p.done as f64 / p.total as f64).clamp(0.0, 1.0)
    };
    match p.stage {
        "voxelize" => 0.40 * part,
        "labels" => 0.40 + 0.10 * part,
        "mesh" => 0.50 + 0.45 * part,
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
}

impl Regions {
    /// No region loaded yet; `loader` prepares them.
    pub fn new(loader: Box<RegionLoader>) -> Regions {
        Regions {
            loaded: Mutex::new(BTreeMap::new()),
            prep: Mutex::new(BTreeMap::new()),
            prepared: Condvar::new(),
            loader,
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

    /// Prepares the claimed `regions` one after the other on a background thread; returns at
    /// once.
    pub fn spawn_preparation(self: &Arc<Self>, regions: Vec<String>) {
        if regions.is_empty() {
            return;
        }
        let this = Arc::clone(self);
        let spawned = std::thread::Builder::new()
            .name("region-prepare".into())
            .spawn(move || {
                for r in regions {
                    match this.load_claimed(&r) {
                        Ok(_) => tracing::info!(region = %r, "region ready"),
                        Err(e) => tracing::error!(region = %r, "region preparation failed: {e}"),
                    }
                }
            });
        if let Err(e) = spawned {
            tracing::error!("cannot start the region preparation thread: {e}");
        }
    }

    /// Loads a region the caller claimed, recording progress and the outcome, and wakes anyone
    /// waiting for it.
    pub fn load_claimed(&self, region: &str) -> Result<Arc<Region>, PrepareError> {
        let started = Instant::now();
        let mut progress = |p: &Progress| {
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
