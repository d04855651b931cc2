//! Progressive fluoroscopy frames: the cheap draft shown at once while the C-arm is being
//! moved, before the full frame (which follows as soon as no newer input is waiting).
//!
//! A full frame after a C-arm move redraws every triangle of the anatomy that reaches the image
//! (3.85 M in the default lumbar phantom: 71-97 ms at 512 x 512 with lavapipe, 2 cores). Its
//! draft draws the region's draft scene (`sim_core::fluoro::draft`: a twelfth of the
//! triangles, each mesh reduced on its own) at half the detector resolution with one sample per
//! pixel, then doubles it to the full frame's size (`crate::fluoro::draft`): 16-19 ms on the
//! same machine.
//!
//! The draft scene of a region is built once per worker, on a background thread, when the
//! region's first GPU renderer is made (about 2 s on 2 cores for the default phantom), and
//! uploaded once, with one draft renderer that all its sessions take turns at; until it is
//! ready a session simply sends no draft. Only
//! regions of at least [`DRAFT_MIN_TRIANGLES`] get one: below that the full frame is cheap.
//!
//! Replay: a draft is a pure function of the session's state (the draft scene is deterministic),
//! so a replay renders the same draft bit for bit; the frame header marks drafts (see
//! `session::frame`), and `.../replay/frame?quality=draft` renders one.

use std::collections::HashMap;
use std::sync::{Arc, Condvar, Mutex, PoisonError};

use sim_core::fluoro::draft::{DraftParams, draft_scene, draft_scene_stored};
use sim_core::fluoro::{Image, IodineField, Projection, RenderSettings};

use super::steel::{NeedleShaft, set_needle};
use crate::fluoro::{GpuAnatomy, GpuFluoroRenderer};
use crate::gpu::GpuContext;
use crate::session::region::{DRAFT_STORE_FILE, Region, log_store_outcome};

/// Regions with fewer triangles get no draft scene. Simulator choice: the 4 mm test phantom
/// (about 0.1 M triangles) renders a C-arm-moved frame in tens of milliseconds on lavapipe,
/// where a draft would add work; the default lumbar phantom (3.85 M) and the 1 mm cervical
/// phantom are well above.
pub const DRAFT_MIN_TRIANGLES: usize = 1_000_000;

/// One region's draft scene on the device.
enum Slot {
    Building,
    Ready(Arc<SharedDraft>),
    Failed,
}

/// A region's one draft renderer, shared by its sessions (a draft is drawn in about 30 ms; a
/// session that finds it busy waits that long rather than each session holding its own
/// targets, about 4 MB at 256 x 256).
pub(super) struct SharedDraft {
    renderer: Mutex<(GpuFluoroRenderer, Option<NeedleShaft>)>,
}

impl SharedDraft {
    fn new(anatomy: Arc<GpuAnatomy>) -> SharedDraft {
        SharedDraft {
            renderer: Mutex::new((GpuFluoroRenderer::with_anatomy(anatomy), None)),
        }
    }
}

/// The draft scenes of a worker's regions, uploaded once on its device (see the module doc).
pub struct DraftAnatomies {
    ctx: GpuContext,
    params: DraftParams,
    min_triangles: usize,
    slots: Mutex<HashMap<String, Slot>>,
    built: Condvar,
}

impl std::fmt::Debug for DraftAnatomies {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DraftAnatomies")
            .field("min_triangles", &self.min_triangles)
            .finish_non_exhaustive()
    }
}

impl DraftAnatomies {
    /// Draft scenes on `ctx` for regions of at least `min_triangles` triangles.
    pub fn new(ctx: GpuContext, min_triangles: usize) -> Arc<DraftAnatomies> {
        Arc::new(DraftAnatomies {
            ctx,
            params: DraftParams::default(),
            min_triangles,
            slots: Mutex::new(HashMap::new()),
            built: Condvar::new(),
        })
    }

    /// Whether `region` gets drafts; if so, starts building its draft scene unless that is
    /// under way or done.
    pub fn start(self: &Arc<Self>, region: &Arc<Region>) -> bool {
        if region.scene.triangle_count() < self.min_triangles {
            return false;
        }
        let mut slots = self.slots.lock().unwrap_or_else(PoisonError::into_inner);
        if slots.contains_key(&region.name) {
            return true;
        }
        slots.insert(region.name.clone(), Slot::Building);
        drop(slots);
        let (this, name, region) = (Arc::clone(self), region.name.clone(), Arc::clone(region));
        let spawned = std::thread::Builder::new()
            .name("draft-scene".into())
            .spawn(move || {
                let started = std::time::Instant::now();
                let scene = match &region.store {
                    Some(store) => {
                        let path = store.dir.join(DRAFT_STORE_FILE);
                        let (scene, outcome) =
                            draft_scene_stored(&region.scene, &this.params, &path, &store.key);
                        log_store_outcome(&region.name, "draft scene", &outcome);
                        scene
                    }
                    None => draft_scene(&region.scene, &this.params),
                };
                let slot = match GpuAnatomy::new(&this.ctx, &scene) {
                    Ok(a) => {
                        tracing::info!(
                            region = %region.name,
                            triangles = scene.triangle_count(),
                            seconds = started.elapsed().as_secs_f64(),
                            "draft scene ready"
                        );
                        Slot::Ready(Arc::new(SharedDraft::new(a)))
                    }
                    Err(e) => {
                        tracing::warn!(region = %region.name, "draft scene failed: {e}");
                        Slot::Failed
                    }
                };
                this.finish(&region.name, slot);
            });
        if let Err(e) = spawned {
            tracing::warn!("cannot start the draft scene thread: {e}");
            self.finish(&name, Slot::Failed);
        }
        true
    }

    fn finish(&self, region: &str, slot: Slot) {
        let mut slots = self.slots.lock().unwrap_or_else(PoisonError::into_inner);
        slots.insert(region.to_string(), slot);
        self.built.notify_all();
    }

    /// Waits until no draft scene is being built.
    pub fn wait_idle(&self) {
        let mut slots = self.slots.lock().unwrap_or_else(PoisonError::into_inner);
        while slots.values().any(|s| matches!(s, Slot::Building)) {
            slots = self
                .built
                .wait(slots)
                .unwrap_or_else(PoisonError::into_inner);
        }
    }

    /// Whether `region`'s draft renderer is ready, waiting while its draft scene is built.
    pub fn ready(&self, region: &str) -> bool {
        self.get(region, true).is_some()
    }

    /// The draft renderer of `region`: `None` if it has none, failed, or (unless `wait`) its
    /// draft scene is still being built.
    pub(super) fn get(&self, region: &str, wait: bool) -> Option<Arc<SharedDraft>> {
        let mut slots = self.slots.lock().unwrap_or_else(PoisonError::into_inner);
        loop {
            match slots.get(region) {
                Some(Slot::Ready(a)) => return Some(Arc::clone(a)),
                Some(Slot::Building) if wait => {
                    slots = self
                        .built
                        .wait(slots)
                        .unwrap_or_else(PoisonError::into_inner);
                }
                _ => return None,
            }
        }
    }
}

/// A session's way to its region's draft renderer.
pub(super) struct DraftRenderer {
    anatomies: Arc<DraftAnatomies>,
    region: String,
    shared: Option<Arc<SharedDraft>>,
}

impl DraftRenderer {
    pub(super) fn new(anatomies: Arc<DraftAnatomies>, region: &str) -> DraftRenderer {
        DraftRenderer {
            anatomies,
            region: region.to_string(),
            shared: None,
        }
    }

    /// The draft of the frame `render(needle, projection, settings, iodine)` would give, at the
    /// full frame's size; `None` when there is none to give (see [`DraftUse`]).
    pub(super) fn render(
        &mut self,
        needle: Option<&NeedleShaft>,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
        wait: bool,
    ) -> Result<Option<Image>, crate::fluoro::FluoroGpuError> {
        if !crate::fluoro::draft::draftable(projection) {
            return Ok(None);
        }
        if self.shared.is_none() {
            self.shared = self.anatomies.get(&self.region, wait);
        }
        let Some(shared) = &self.shared else {
            return Ok(None);
        };
        // Whatever another session left in it (needle, caches), the frame is the same bit for
        // bit: its caches are keyed on everything that decides a frame.
        let mut guard = shared
            .renderer
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let (renderer, current) = &mut *guard;
        set_needle(renderer, current, needle);
        Ok(Some(crate::fluoro::draft::render_draft_frame(
            renderer, projection, settings, iodine,
        )?))
    }
}
