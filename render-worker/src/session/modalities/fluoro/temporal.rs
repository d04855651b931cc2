//! The temporal chain of live fluoroscopy in a session ([`sim_core::fluoro::temporal`]): each
//! live frame is displayed as the detector-lagged, recursively filtered mix of the raw frames of
//! its run, so moving steel leaves a fading trail and noise averages down.
//!
//! - The learner sets the filter with `{"type": "recursive_filter", "level": "off" | "low" |
//!   "high"}` (new sessions: low); the detector's lag is always there. Each live image records
//!   its run and its filter level, so the displayed frame is a function of the images alone:
//!   replay, and a restore in the middle of a run (whose missing raw frames are rendered again),
//!   give it bit for bit.
//! - A frame combines the raw frames of the same live run at the same C-arm pose, field and
//!   collimation (a move restarts the filter, as motion-detecting filters do) that image the
//!   same iodine field
//!   (while contrast spreads, each pulse images a new field: those frames are shown
//!   unfiltered, since an older field is not kept), at most
//!   [`sim_core::fluoro::temporal::HISTORY_FRAMES`].
//! - Shots and drafts are not filtered. Sessions recorded before the chain have no `temporal`
//!   in their state and are displayed as before.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};
use sim_core::fluoro::temporal::{FilterLevel, HISTORY_FRAMES};

use crate::session::command::{CommandError, ModalityCommand};
use crate::session::image::ViewImage;

/// The command kind that sets the filter.
pub const FILTER_KIND: &str = "recursive_filter";

/// The level a new session starts with (simulator choice: consoles default to a moderate
/// filter).
pub const DEFAULT_LEVEL: FilterLevel = FilterLevel::Low;

/// The chain's setting (part of the fluoroscopy state).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TemporalState {
    /// The recursive filter's level for the next live frames.
    pub level: FilterLevel,
}

/// The fields of a `recursive_filter` command.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FilterCommand {
    /// `off`, `low` or `high`.
    level: String,
}

/// The level a `recursive_filter` command asks for, or its field-named error.
pub fn parse(command: &ModalityCommand) -> Result<FilterLevel, CommandError> {
    let FilterCommand { level } = command.parse()?;
    crate::session::command::named_choice("level", &level, FilterLevel::parse, "off, low or high")
}

/// Raw (unfiltered) frames of the latest live images rendered in this process, by image index.
#[derive(Debug, Default)]
pub struct RawFrames {
    frames: VecDeque<(u64, ViewImage)>,
}

impl RawFrames {
    /// The raw frame of image `index`, if it is kept.
    pub fn get(&self, index: u64) -> Option<&ViewImage> {
        self.frames
            .iter()
            .find(|(i, _)| *i == index)
            .map(|(_, f)| f)
    }

    /// Drops every kept frame but those of `indices`.
    pub fn keep_only(&mut self, indices: &[u64]) {
        self.frames.retain(|(i, _)| indices.contains(i));
    }

    /// Keeps the raw frame of image `index` (the latest `HISTORY_FRAMES` are kept).
    pub fn put(&mut self, index: u64, frame: ViewImage) {
        self.frames.retain(|(i, _)| *i != index);
        self.frames.push_back((index, frame));
        while self.frames.len() > HISTORY_FRAMES {
            self.frames.pop_front();
        }
    }
}
