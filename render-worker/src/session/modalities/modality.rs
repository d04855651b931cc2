//! The contract between a session and one of its modalities (see [`super`]).

use std::sync::Arc;

use sim_core::rubric::Measurements;

use crate::session::command::{Agent, Command, CommandError, CommandSpec, Engagement};
use crate::session::config::SessionConfig;
use crate::session::image::{ViewId, ViewImage};
use crate::session::region::Region;
use crate::session::world::{ImageRayError, StationContext, World, WorldChange};

/// Why a modality could not render or restore.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ModalityError {
    /// The renderer failed (device lost, out of memory, a scene it cannot draw).
    #[error("{modality} rendering failed: {message}")]
    Render {
        /// Modality name.
        modality: &'static str,
        /// The renderer's reason.
        message: String,
    },
    /// Newer input made the render obsolete before it was done (see `crate::interrupt`): the
    /// view stays dirty and nothing of the render is shown.
    #[error("{modality} render superseded by newer input")]
    Interrupted {
        /// Modality name.
        modality: &'static str,
    },
    /// A snapshot's state for this modality does not parse.
    #[error("{modality} state: {message}")]
    State {
        /// Modality name.
        modality: &'static str,
        /// The parser's reason.
        message: String,
    },
}

/// What a modality declares about itself: the data from which the session core routes
/// commands, the protocol tells clients what a session offers (views and their wire codes,
/// command kinds), and the server records engagement. Nothing outside the modality's folder
/// lists these.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ModalitySpec {
    /// Stable name: the station's modality name and the key of its state in snapshots
    /// (`"fluoroscopy"`).
    pub name: &'static str,
    /// What a learner calls it, for messages (`"contrast injection"`).
    pub label: &'static str,
    /// Views it can render.
    pub views: &'static [ViewId],
    /// Command kinds it handles, each with its engagement event.
    pub commands: &'static [CommandSpec],
    /// Numbers a client needs to drive it (for the contrast modality, the tick interval of its
    /// logged clock), by name with their unit suffix; sent in the session protocol's hello.
    pub constants: &'static [(&'static str, f64)],
}

impl ModalitySpec {
    /// Whether this modality handles commands of kind `kind`.
    pub fn handles(&self, kind: &str) -> bool {
        self.commands.iter().any(|c| c.kind == kind)
    }
}

/// Fluid a modality pushed through the needle while applying a command; the session books it in
/// the world's injection ledger and tells every modality ([`WorldChange::FluidInjected`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FluidDelivery {
    /// What was injected.
    pub agent: Agent,
    /// Volume, ml.
    pub volume_ml: f64,
    /// Rate, ml/s.
    pub rate_ml_per_s: f64,
}

/// One modality of a session.
pub trait Modality: Send {
    /// What this modality declares (the same value its factory registration carries).
    fn spec(&self) -> &'static ModalitySpec;

    /// Stable name ([`ModalitySpec::name`]).
    fn name(&self) -> &'static str {
        self.spec().name
    }

    /// Views it can render ([`ModalitySpec::views`]).
    fn views(&self) -> &'static [ViewId] {
        self.spec().views
    }

    /// The engagement event an accepted `command` of this modality stands for; by default the
    /// one its [`ModalitySpec`] declares for the kind.
    fn engagement(&self, command: &Command) -> Option<Engagement> {
        crate::session::command::engagement_of(self.spec().commands, command.name())
    }

    /// Fluid pushed through the needle by the command just applied (taken once).
    fn take_fluid(&mut self) -> Option<FluidDelivery> {
        None
    }

    /// Applies a validated command of an accepted class at simulation time `world.clock_ms`;
    /// returns a JSON outcome for the acknowledgement.
    fn apply(
        &mut self,
        command: &Command,
        world: &World,
    ) -> Result<serde_json::Value, CommandError>;

    /// Simulated time moved from `from_ms` to `world.clock_ms` (before the command that moved
    /// it is applied). A modality that evolves over time (contrast spreading) steps its model
    /// here; because every clock value comes from a logged command, replay takes the same steps.
    fn advance(&mut self, _from_ms: u64, _world: &World) {}

    /// When a `tick` applied at `now_ms` should be applied instead: the moment, a little later,
    /// at which a change this modality holds for a clock of its own (live fluoroscopy's next
    /// pulse) is imaged, if a tick could be early for it; `None` to apply it at once. Only the
    /// session host asks, before applying a tick; the tick is logged at the moment it is
    /// applied, so replay needs nothing of this.
    fn tick_hold_until(&self, _now_ms: u64) -> Option<u64> {
        None
    }

    /// Reacts to a change of the shared world made by another part of the session.
    fn world_changed(&mut self, change: &WorldChange, world: &World);

    /// The iodine field this modality makes, brought to `world.clock_ms`, with a version that
    /// changes whenever the field does (the session publishes it in [`World::iodine`] and
    /// announces a new version as [`WorldChange::Iodine`]). Only the contrast modality makes
    /// one; the version must depend on the logged commands alone, not on how often this is
    /// called.
    fn iodine(&mut self, _world: &World) -> Option<(u64, Arc<sim_core::fluoro::IodineField>)> {
        None
    }

    /// The C-arm's central beam, for a modality that drives a C-arm (the session publishes it
    /// in [`World::carm`] and announces a change as [`WorldChange::CArm`]).
    fn carm(&self) -> Option<crate::session::world::CArmAxis> {
        None
    }

    /// The ray through continuous pixel `pixel` of the image this modality displays (the
    /// fluoroscopy modality: from the focal spot through that pixel of the last image), as
    /// origin and unit direction in the model frame, or why there is none; `None` from a
    /// modality without such an image.
    fn image_ray(
        &self,
        _pixel: [f64; 2],
    ) -> Option<Result<(glam::DVec3, glam::DVec3), ImageRayError>> {
        None
    }

    /// The projection of the image this modality displays last (the fluoroscopy modality: the
    /// last image's C-arm pose and detector), `None` from a modality without one or before the
    /// first image.
    fn displayed_projection(&self) -> Option<sim_core::fluoro::geometry::Projection> {
        None
    }

    /// Whether fluid is still leaving a syringe this modality drives (a contrast injection under
    /// way at `world.clock_ms`); the loss-of-resistance syringe cannot go on the hub meanwhile.
    fn injecting(&self) -> bool {
        false
    }

    /// What this modality shows of the needle, added under its name to the acknowledgement of
    /// every needle command (the ultrasound modality: whether the shaft and the tip are in the
    /// scan plane), so a client needs no extra command to learn it.
    fn needle_feedback(&self, _world: &World) -> Option<serde_json::Value> {
        None
    }

    /// What this modality reports in the acknowledgement of every tick (fields merged into
    /// it): fluoroscopy's technique, which the brightness control steps on the pulses that
    /// ticks image, so a client's exposure readout follows live fluoroscopy.
    fn tick_status(&self) -> Option<serde_json::Value> {
        None
    }

    /// Views whose content is newer than their last render.
    fn dirty_views(&self) -> Vec<ViewId>;

    /// Renders `view` (called only for dirty, visible views); marks it clean.
    fn render(&mut self, view: ViewId, world: &World) -> Result<Option<ViewImage>, ModalityError>;

    /// A draft of `view` (a cheaper, coarser image of the same content, shown before the full
    /// one while input is still coming; see `fluoro::draft`). Leaves the view dirty: the full
    /// render follows. `None` (the default) where the modality has none to give.
    fn render_draft(
        &mut self,
        _view: ViewId,
        _world: &World,
        _use: DraftUse,
    ) -> Result<Option<ViewImage>, ModalityError> {
        Ok(None)
    }

    /// Prepares, while the session waits for input, what its next frames will likely need
    /// (the fluoroscopy modality: the renderer and the transmission of the view a first shot
    /// would show). It changes no state: what the session acknowledges, logs, snapshots and
    /// renders is the same with or without it, bit for bit.
    fn prefetch(&mut self, _world: &World) -> Result<(), ModalityError> {
        Ok(())
    }

    /// Whether [`Modality::prefetch`] has a view to prepare that a pause in the input would let
    /// it do now (the fluoroscopy modality: the C-arm was moved, beam off, to a view neither on
    /// screen nor prepared). The session host prefetches once the input has paused for
    /// `host::PREFETCH_AFTER_PAUSE`.
    fn prefetch_pending(&self) -> bool {
        false
    }

    /// Adds this modality's measurements (rubric keys) computed from live state.
    fn measure(&self, world: &World, out: &mut Measurements);

    /// Settings worth recording with a result (C-arm pose and technique, ...).
    fn record(&self) -> serde_json::Value;

    /// Serializable state (everything that decides its future and its frames).
    fn state(&self) -> serde_json::Value;

    /// Replaces the state with one from [`Modality::state`].
    fn restore(&mut self, state: serde_json::Value) -> Result<(), ModalityError>;
}

/// What a modality is built from.
#[derive(Clone, Copy)]
pub struct ModalityContext<'a> {
    /// The session's fixed settings.
    pub config: &'a SessionConfig,
    /// Station and resolved targets.
    pub station: &'a Arc<StationContext>,
    /// Anatomy.
    pub region: &'a Arc<Region>,
    /// The renderers this device offers, by modality name.
    pub renderers: &'a super::renderers::Renderers,
}

/// Why a draft ([`Modality::render_draft`]) is asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DraftUse {
    /// A live session: only where the full render is expensive (fluoroscopy: the C-arm moved)
    /// and the draft can be made at once; never waits.
    Live,
    /// A replay of a draft that was shown: always, waiting for the draft scene if needed.
    Replay,
}
