//! Why a session could not be restored, replayed or rendered. Command rejections are
//! [`CommandError`]s (they name a field and go to the client); these go to the host.

use super::command::CommandError;
use super::frame::FrameError;
use super::modalities::ModalityError;

/// A session-level failure.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SessionError {
    /// The snapshot was written by another snapshot format.
    #[error("snapshot format {found} is not {expected}")]
    SnapshotFormat {
        /// The snapshot's format.
        found: u32,
        /// This build's format.
        expected: u32,
    },
    /// The snapshot is of another station, revision or station file.
    #[error(
        "snapshot is of station {snapshot_station} revision {snapshot_revision}, not the loaded {loaded_station} revision {loaded_revision}"
    )]
    StationMismatch {
        /// The snapshot's station id.
        snapshot_station: String,
        /// The snapshot's station revision.
        snapshot_revision: u32,
        /// The loaded station id.
        loaded_station: String,
        /// The loaded station revision.
        loaded_revision: u32,
    },
    /// The snapshot is of another build of the region.
    #[error("snapshot is of another build of region {0}")]
    RegionMismatch(String),
    /// The log is shorter than what the snapshot already reflects.
    #[error("log has {log} entries, the snapshot already reflects {reflected}")]
    LogTooShort {
        /// Entries in the log.
        log: usize,
        /// Entries the snapshot reflects.
        reflected: usize,
    },
    /// The snapshot lacks a modality the station runs.
    #[error("snapshot has no state for {0}")]
    MissingModalityState(String),
    /// A logged command no longer applies (another build, a corrupted log).
    #[error("log entry seq {seq} no longer applies: {error}")]
    LogEntry {
        /// Its sequence number.
        seq: u64,
        /// Why.
        error: CommandError,
    },
    /// A modality failed.
    #[error(transparent)]
    Modality(#[from] ModalityError),
    /// A frame could not be encoded.
    #[error(transparent)]
    Encode(#[from] FrameError),
}
