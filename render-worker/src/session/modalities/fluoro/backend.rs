//! Fluoroscopy renderers: the f64 CPU reference of `sim_core::fluoro` and the GPU renderer of
//! `render_worker::fluoro`, behind one trait, with the same output type.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use sim_core::fluoro::{
    FluoroMaterial, Image, IodineField, Projection, RenderSettings, Scene, SceneRef,
};

use super::draft::{DraftAnatomies, DraftRenderer};
use super::steel::{NeedleShaft, needle_meshes, set_needle};
use crate::session::modalities::modality::DraftUse;
use crate::session::region::Region;

/// Why a fluoroscopy renderer could not be made or could not render.
#[derive(Debug, thiserror::Error)]
pub enum FluoroRenderError {
    /// The CPU reference has no spectrum for the tube voltage.
    #[error(transparent)]
    Cpu(#[from] sim_core::fluoro::spectrum::UnknownKvp),
    /// The GPU renderer failed (missing feature, device lost, scene too large).
    #[error(transparent)]
    Gpu(#[from] crate::fluoro::FluoroGpuError),
}

/// Makes fluoroscopy renderers: the CPU reference, or the GPU renderer (same output type).
/// Shared by every session of a worker; each session gets its own [`FluoroRenderer`], created on
/// its first exposure, or before its first input where the renderer prefetches (see
/// [`FluoroBackend::prefetches`]).
pub trait FluoroBackend: Send + Sync {
    /// What renders (e.g. `cpu-reference`, or the GPU adapter's name), for records and health.
    fn profile(&self) -> BackendProfile;
    /// A renderer of `region` for one session.
    fn renderer(&self, region: &Arc<Region>) -> Result<Box<dyn FluoroRenderer>, FluoroRenderError>;
    /// Whether its renderers keep work between frames, so that [`FluoroRenderer::prefetch`]
    /// makes a later frame cheaper (the GPU renderer's caches). A session makes its renderer
    /// ahead of its first exposure only then: a renderer that keeps nothing (the CPU reference)
    /// is made at the first exposure, from whatever the backend offers by then.
    fn prefetches(&self) -> bool {
        false
    }
    /// Other configurations of the same renderer worth timing against it at start-up (the
    /// calibration's further candidates); none by default.
    fn alternatives(&self) -> Vec<Arc<dyn FluoroBackend>> {
        Vec::new()
    }
    /// Waits for what its renderers started in the background (the GPU backend's draft
    /// scenes), so that frames timed next are not slowed by it.
    fn finish_background_work(&self) {}
    /// Makes now, and keeps, what this backend keeps of `region` for its sessions (the GPU
    /// backend that keeps its uploads: the region's anatomy and draft scene), so that the first
    /// session of the region does not make them before its first frame; returns whether it
    /// keeps them (made now, or found made). Backends that keep nothing between sessions do
    /// nothing and return `false`.
    fn prepare(&self, _region: &Arc<Region>) -> Result<bool, FluoroRenderError> {
        Ok(false)
    }
}

/// One session's renderer (may hold per-session resources, such as uploaded meshes).
pub trait FluoroRenderer: Send {
    /// One frame of the region with the needle and the iodine field (stock-equivalent density),
    /// if any, through `projection`. Without iodine the frame is exactly the one of a scene that
    /// never had contrast.
    fn render(
        &mut self,
        needle: Option<&NeedleShaft>,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<Image, FluoroRenderError>;

    /// Prepares ahead what a later [`FluoroRenderer::render`] with the same arguments (noise
    /// seed aside) needs, so that it answers sooner, with the same frame bit for bit. A
    /// renderer that keeps nothing between frames (the CPU reference) does nothing.
    fn prefetch(
        &mut self,
        _needle: Option<&NeedleShaft>,
        _projection: &Projection,
        _settings: &RenderSettings,
        _iodine: Option<&IodineField>,
    ) -> Result<(), FluoroRenderError> {
        Ok(())
    }

    /// The draft of the frame [`FluoroRenderer::render`] would give with the same arguments
    /// (see `draft`): cheaper, coarser, the same size. `None` where this renderer has none to
    /// give: the CPU reference never drafts; the GPU renderer drafts for [`DraftUse::Live`]
    /// only when the full frame must redraw the anatomy and the region's draft scene is ready.
    fn render_draft(
        &mut self,
        _needle: Option<&NeedleShaft>,
        _projection: &Projection,
        _settings: &RenderSettings,
        _iodine: Option<&IodineField>,
        _use: DraftUse,
    ) -> Result<Option<Image>, FluoroRenderError> {
        Ok(None)
    }
}

/// Which renderer made a frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BackendProfile {
    /// Renderer kind: `cpu-reference` or `gpu`.
    pub kind: String,
    /// Device or adapter (`cpu` for the reference).
    pub device: String,
}

/// The f64 CPU reference renderer of `sim_core::fluoro`.
#[derive(Debug, Clone, Copy)]
pub struct CpuFluoroBackend {
    /// Render threads per frame (0: all cores).
    pub threads: usize,
}

impl FluoroBackend for CpuFluoroBackend {
    fn profile(&self) -> BackendProfile {
        BackendProfile {
            kind: "cpu-reference".to_string(),
            device: "cpu".to_string(),
        }
    }

    fn renderer(&self, region: &Arc<Region>) -> Result<Box<dyn FluoroRenderer>, FluoroRenderError> {
        Ok(Box::new(CpuRenderer {
            region: Arc::clone(region),
            threads: self.threads,
            needle: None,
        }))
    }
}

/// The CPU renderer of one session: the region's scene, shared with every other session, with
/// the needle's prisms as an overlay (a small scene of its own, rebuilt only when the needle
/// moved; the anatomy's BVHs are never copied).
struct CpuRenderer {
    region: Arc<Region>,
    threads: usize,
    needle: Option<(NeedleShaft, Scene)>,
}

impl FluoroRenderer for CpuRenderer {
    fn render(
        &mut self,
        needle: Option<&NeedleShaft>,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<Image, FluoroRenderError> {
        let settings = RenderSettings {
            threads: self.threads,
            ..*settings
        };
        match needle {
            None => self.needle = None,
            Some(n) if self.needle.as_ref().is_none_or(|(c, _)| c != n) => {
                let mut scene = Scene::new();
                for (k, mesh) in needle_meshes(n).iter().enumerate() {
                    scene.add(format!("needle_{k}"), FluoroMaterial::Steel, mesh);
                }
                self.needle = Some((n.clone(), scene));
            }
            Some(_) => {}
        }
        // The needle's entries come after every anatomy entry, as if added to a copy of the
        // region's scene: the same frame, bit for bit (see `SceneRef`).
        let scene = match &self.needle {
            Some((_, overlay)) => self.region.scene.with_overlay(overlay),
            None => SceneRef::from(&self.region.scene),
        };
        Ok(sim_core::fluoro::render_frame(
            scene, iodine, projection, &settings,
        )?)
    }
}

/// The GPU renderer of `render_worker::fluoro` on a worker's device. The sessions of one region
/// draw one read-only upload of its anatomy (a [`crate::fluoro::GpuAnatomy`]: on a software
/// adapter such as lavapipe, hundreds of megabytes of host memory for the default phantom),
/// made by the region's first renderer and freed with its last; each session's renderer holds
/// only its needle, targets and caches.
#[derive(Debug, Clone)]
pub struct GpuFluoroBackend {
    /// The device shared by every session.
    pub ctx: crate::gpu::GpuContext,
    /// `false`: every renderer uploads its own copy of the anatomy (what each session cost
    /// before the uploads were shared; the memory benchmark's baseline).
    share_anatomy: bool,
    anatomies: Arc<crate::fluoro::AnatomyCache>,
    /// `Some`: every anatomy this backend uploads is held here as long as the backend lives, so
    /// a region's next first session finds it uploaded (see [`GpuFluoroBackend::keeping_uploads`]).
    kept: Option<Arc<std::sync::Mutex<Vec<Arc<crate::fluoro::GpuAnatomy>>>>>,
    /// The draft scenes of its regions (progressive frames, see `draft`); `None`: no drafts.
    drafts: Option<Arc<DraftAnatomies>>,
    /// Whether its renderers rasterise the L-buffer passes on the CPU where the adapter is
    /// software (`render_worker::fluoro`'s `raster`; default `true`), or leave it to the
    /// adapter ([`GpuFluoroBackend::with_adapter_geometry`]).
    cpu_geometry: bool,
}

impl GpuFluoroBackend {
    /// The GPU renderer on `ctx`, one anatomy upload per region shared by its sessions.
    pub fn new(ctx: crate::gpu::GpuContext) -> GpuFluoroBackend {
        GpuFluoroBackend {
            share_anatomy: true,
            cpu_geometry: true,
            anatomies: Arc::default(),
            kept: None,
            drafts: Some(DraftAnatomies::new(
                ctx.clone(),
                super::draft::DRAFT_MIN_TRIANGLES,
            )),
            ctx,
        }
    }

    /// The same renderer, drafting (see `draft`) for regions of at least `min_triangles`
    /// triangles (default [`super::draft::DRAFT_MIN_TRIANGLES`]), or never with `None`.
    pub fn drafting_from(self, min_triangles: Option<usize>) -> GpuFluoroBackend {
        GpuFluoroBackend {
            drafts: min_triangles.map(|n| DraftAnatomies::new(self.ctx.clone(), n)),
            ..self
        }
    }

    /// The same renderer with every L-buffer pass drawn by the adapter, also on a software
    /// adapter (the start-up calibration's other candidate there; the frames of sessions
    /// recorded before the CPU geometric pass). It shares this backend's uploads.
    pub fn with_adapter_geometry(self) -> GpuFluoroBackend {
        GpuFluoroBackend {
            cpu_geometry: false,
            ..self
        }
    }

    /// Whether its renderers draw the L-buffer passes on the CPU (a software adapter,
    /// unless made [`GpuFluoroBackend::with_adapter_geometry`]).
    pub fn cpu_geometry(&self) -> bool {
        self.cpu_geometry && self.ctx.summary.is_software
    }

    /// The draft scene of `region` once it is built (blocking until then), for tests and
    /// benchmarks that need drafts at once; `None` where the region gets none.
    pub fn wait_for_draft_scene(&self, region: &Arc<Region>) -> Option<()> {
        let drafts = self.drafts.as_ref()?;
        drafts.start(region).then_some(())?;
        drafts.ready(&region.name).then_some(())
    }

    /// The GPU renderer on `ctx` that keeps each region's anatomy uploaded once made, while this
    /// backend lives, instead of freeing it with the region's last session: a server whose
    /// regions stay loaded pays the upload (about half a second for the default phantom on
    /// lavapipe) once, at its start-up calibration, not at the first shot of every learner who
    /// finds the station empty. Memory: one upload per region, as the regions themselves.
    pub fn keeping_uploads(ctx: crate::gpu::GpuContext) -> GpuFluoroBackend {
        GpuFluoroBackend {
            kept: Some(Arc::default()),
            ..GpuFluoroBackend::new(ctx)
        }
    }

    /// The GPU renderer on `ctx` with one anatomy upload per session (same frames, the memory
    /// of one upload per session): the baseline the memory benchmark compares against.
    pub fn with_private_uploads(ctx: crate::gpu::GpuContext) -> GpuFluoroBackend {
        GpuFluoroBackend {
            share_anatomy: false,
            ..GpuFluoroBackend::new(ctx)
        }
    }

    /// Shared anatomy uploads that some session's renderer still holds.
    pub fn shared_anatomies(&self) -> usize {
        self.anatomies.live()
    }
}

impl FluoroBackend for GpuFluoroBackend {
    fn profile(&self) -> BackendProfile {
        let summary = &self.ctx.summary;
        BackendProfile {
            kind: "gpu".to_string(),
            device: if self.cpu_geometry() {
                format!(
                    "{} ({}), L-buffer passes on the CPU",
                    summary.name, summary.backend
                )
            } else {
                format!("{} ({})", summary.name, summary.backend)
            },
        }
    }

    fn alternatives(&self) -> Vec<Arc<dyn FluoroBackend>> {
        if self.cpu_geometry() {
            vec![Arc::new(self.clone().with_adapter_geometry())]
        } else {
            Vec::new()
        }
    }

    fn renderer(&self, region: &Arc<Region>) -> Result<Box<dyn FluoroRenderer>, FluoroRenderError> {
        let anatomy = if self.share_anatomy {
            self.anatomies
                .get_or_upload(&self.ctx, region, |r| &r.scene)?
        } else {
            crate::fluoro::GpuAnatomy::new(&self.ctx, &region.scene)?
        };
        if let Some(kept) = &self.kept {
            let mut kept = kept
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            if !kept.iter().any(|a| Arc::ptr_eq(a, &anatomy)) {
                kept.push(Arc::clone(&anatomy));
            }
        }
        let draft = self
            .drafts
            .as_ref()
            .filter(|d| d.start(region))
            .map(|d| DraftRenderer::new(Arc::clone(d), &region.name));
        let mut renderer = crate::fluoro::GpuFluoroRenderer::with_anatomy(anatomy);
        renderer.set_cpu_geometry(self.cpu_geometry);
        Ok(Box::new(GpuRenderer {
            renderer,
            needle: None,
            draft,
        }))
    }

    fn prefetches(&self) -> bool {
        true
    }

    fn finish_background_work(&self) {
        if let Some(d) = &self.drafts {
            d.wait_idle();
        }
    }

    fn prepare(&self, region: &Arc<Region>) -> Result<bool, FluoroRenderError> {
        if self.kept.is_none() || !self.share_anatomy {
            return Ok(false);
        }
        // A renderer makes the anatomy (kept) and starts the draft scene; the draft is waited
        // for, so that regions are prepared one after another.
        drop(self.renderer(region)?);
        self.finish_background_work();
        Ok(true)
    }
}

struct GpuRenderer {
    renderer: crate::fluoro::GpuFluoroRenderer,
    needle: Option<NeedleShaft>,
    /// Its draft renderer, where the region gets drafts.
    draft: Option<DraftRenderer>,
}

impl GpuRenderer {
    /// Makes the renderer's needle mesh `needle`'s, if it changed.
    fn set_needle(&mut self, needle: Option<&NeedleShaft>) {
        set_needle(&mut self.renderer, &mut self.needle, needle);
    }
}

impl FluoroRenderer for GpuRenderer {
    fn render(
        &mut self,
        needle: Option<&NeedleShaft>,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<Image, FluoroRenderError> {
        self.set_needle(needle);
        Ok(self.renderer.render_frame(projection, settings, iodine)?)
    }

    fn prefetch(
        &mut self,
        needle: Option<&NeedleShaft>,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
    ) -> Result<(), FluoroRenderError> {
        // The caches hold frames without iodine only.
        if iodine.is_some() {
            return Ok(());
        }
        self.set_needle(needle);
        Ok(self.renderer.prefetch(projection, settings)?)
    }

    fn render_draft(
        &mut self,
        needle: Option<&NeedleShaft>,
        projection: &Projection,
        settings: &RenderSettings,
        iodine: Option<&IodineField>,
        use_: DraftUse,
    ) -> Result<Option<Image>, FluoroRenderError> {
        let Some(draft) = self.draft.as_mut() else {
            return Ok(None);
        };
        // A full frame on the kept geometry (needle moved, or nothing) is cheap already.
        if use_ == DraftUse::Live && self.renderer.geometry_cached(projection) {
            return Ok(None);
        }
        Ok(draft.render(
            needle,
            projection,
            settings,
            iodine,
            use_ == DraftUse::Replay,
        )?)
    }
}
