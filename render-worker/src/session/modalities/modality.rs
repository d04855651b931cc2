//! The contract between a session and one of its modalities (see [`super`]).

use std::sync::Arc;

use sim_core::rubric::Measurements;

use crate::session::command::{Command, CommandClass, CommandError};
use crate::session::config::SessionConfig;
use crate::session::devices::Backends;
use crate::session::image::{ViewId, ViewImage};
use crate::session::region::Region;
use crate::session::world::{StationContext, World, WorldChange};

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
    /// A snapshot's state for this modality does not parse.
    #[error("{modality} state: {message}")]
    State {
        /// Modality name.
        modality: &'static str,
        /// The parser's reason.
        message: String,
    },
}

/// One modality of a session.
pub trait Modality: Send {
    /// Stable name, used as the key of its state in snapshots (`"fluoroscopy"`); the same as the
    /// station's modality name.
    fn name(&self) -> &'static str;

    /// Command classes this modality handles.
    fn accepts(&self) -> &'static [CommandClass];

    /// Views it can render.
    fn views(&self) -> &'static [ViewId];

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
    fn image_ray(&self, _pixel: [f64; 2]) -> Option<Result<(glam::DVec3, glam::DVec3), String>> {
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

    /// Views whose content is newer than their last render.
    fn dirty_views(&self) -> Vec<ViewId>;

    /// Renders `view` (called only for dirty, visible views); marks it clean.
    fn render(&mut self, view: ViewId, world: &World) -> Result<Option<ViewImage>, ModalityError>;

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
    /// The renderers this device offers.
    pub backends: &'a Backends,
}
