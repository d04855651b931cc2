//! Why a GPU B-mode frame could not be made.

use sim_core::ultrasound::UltrasoundError;

/// Why a GPU frame could not be made.
#[derive(Debug, thiserror::Error)]
pub enum UltrasoundGpuError {
    /// The request is invalid: the same refusal, naming the same field, as the CPU's.
    #[error(transparent)]
    Invalid(#[from] UltrasoundError),
    /// The GPU could not make the frame (buffer limits, readback, mismatched volumes).
    #[error("ultrasound GPU: {0}")]
    Gpu(String),
}

/// A GPU failure with its message.
pub(super) fn gpu(msg: &str) -> UltrasoundGpuError {
    UltrasoundGpuError::Gpu(msg.to_owned())
}
