//! The one error type of the anatomy pipeline: every variant names the file or structure at fault,
//! so a bad input is reported as "which file, what is wrong" rather than a bare I/O message.

use std::path::PathBuf;

/// What went wrong while importing, meshing, writing or loading an anatomy asset.
#[derive(Debug, thiserror::Error)]
pub enum AnatomyError {
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder concerned.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A file exists but its content is not what the format requires (truncated, bad header, ...).
    #[error("{path}: {message}")]
    BadFile {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// A file's SHA-256 does not match the provenance record (tampered or corrupted asset).
    #[error("{path}: SHA-256 mismatch (provenance records {expected}, file has {actual})")]
    HashMismatch {
        /// The file whose content changed.
        path: PathBuf,
        /// Hash recorded in `provenance.json`.
        expected: String,
        /// Hash of the file on disk.
        actual: String,
    },
    /// Inputs that do not fit together (grids that differ, a mask outside the CT, ...).
    #[error("{what}: {message}")]
    Invalid {
        /// The input concerned (a file name or a structure name).
        what: String,
        /// What is wrong.
        message: String,
    },
    /// Meshing a structure failed the closure / winding / volume checks.
    #[error("structure {structure}: {message}")]
    Mesh {
        /// The structure concerned.
        structure: String,
        /// What check failed.
        message: String,
    },
}

impl AnatomyError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        AnatomyError::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn bad_file(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        AnatomyError::BadFile {
            path: path.into(),
            message: message.into(),
        }
    }

    pub(crate) fn invalid(what: impl Into<String>, message: impl Into<String>) -> Self {
        AnatomyError::Invalid {
            what: what.into(),
            message: message.into(),
        }
    }
}
