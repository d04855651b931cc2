//! How a modality plugs into a session: its state, its commands, its views and renderer, its
//! scorers. The session routes each command by [`CommandClass`] to the one modality that accepts
//! it; a station without a modality never constructs it, so it costs nothing there.

use serde::{Deserialize, Serialize};
use sim_core::fluoro::Image;
use sim_core::rubric::Measurements;

use super::command::{Command, CommandClass, CommandError};
use super::world::World;

/// A rendered view of a session (one per modality display).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewId {
    /// The C-arm image.
    Fluoroscopy,
    /// The ultrasound B-mode image.
    Ultrasound,
}

impl ViewId {
    /// Wire code in the binary frame header.
    pub fn code(self) -> u8 {
        match self {
            ViewId::Fluoroscopy => 0,
            ViewId::Ultrasound => 1,
        }
    }

    /// Inverse of [`ViewId::code`].
    pub fn from_code(code: u8) -> Option<ViewId> {
        match code {
            0 => Some(ViewId::Fluoroscopy),
            1 => Some(ViewId::Ultrasound),
            _ => None,
        }
    }
}

/// What changed in the shared world after a command, so other modalities can react (a live
/// fluoroscopy view re-renders when the needle moves; a still image does not).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorldChange {
    /// The needle moved or was placed.
    Needle,
}

/// One modality of a session.
pub trait Modality: Send {
    /// Stable name, used as the key of its state in snapshots (`"fluoroscopy"`).
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

    /// Reacts to a change of the shared world made by another part of the session.
    fn world_changed(&mut self, change: WorldChange, world: &World);

    /// Views whose content is newer than their last render.
    fn dirty_views(&self) -> Vec<ViewId>;

    /// Renders `view` (called only for dirty, visible views); marks it clean.
    fn render(&mut self, view: ViewId, world: &World) -> Result<Option<Image>, String>;

    /// Adds this modality's measurements (rubric keys) computed from live state.
    fn measure(&self, world: &World, out: &mut Measurements);

    /// Settings worth recording with a result (C-arm pose and technique, ...).
    fn record(&self) -> serde_json::Value;

    /// Serializable state (everything that decides its future and its frames).
    fn state(&self) -> serde_json::Value;

    /// Replaces the state with one from [`Modality::state`].
    fn restore(&mut self, state: serde_json::Value) -> Result<(), String>;
}
