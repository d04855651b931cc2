//! Contrast and saline transport in the spinal compartments: the f64 CPU reference.

pub mod classify;
pub mod domains;
pub mod grid;
pub mod ledger;
pub mod model;
pub mod multigrid;
pub mod outlet;
pub mod pressure;
mod transport;

pub use grid::{CellProps, ContrastGrid, Domain, Faces, harmonic_face};
pub use ledger::Ledger;
pub use model::{ContrastModel, ModelConfig, Preconditioner, StepReport, steady_pressure};
pub use multigrid::Multigrid;
pub use outlet::{Agent, Injection, NeedleOutlet};
pub use pressure::{SolveStats, StopRule};

/// Refused input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ContrastError {
    /// A number outside its accepted range (or NaN / infinite).
    #[error("{field} must be finite and in ({min}, {max}] {unit}; got {value}")]
    OutOfRange {
        /// The offending field.
        field: &'static str,
        /// Its value.
        value: f64,
        /// Exclusive lower bound.
        min: f64,
        /// Inclusive upper bound.
        max: f64,
        /// Unit.
        unit: &'static str,
    },
    /// A coordinate that is NaN or infinite.
    #[error("{field}[{axis}] must be finite; got {value}")]
    NotFinite {
        /// The offending field.
        field: &'static str,
        /// Component index.
        axis: usize,
        /// Its value.
        value: f64,
    },
    /// A zero needle direction.
    #[error("outlet.direction must be non-zero")]
    ZeroDirection,
    /// The tip lies outside the transport grid.
    #[error(
        "outlet.tip_mm {tip_mm:?} lies outside the transport grid (no needle in the modelled body)"
    )]
    OutletOutsideGrid {
        /// The tip.
        tip_mm: [f64; 3],
    },
    /// The bevel touches no fluid domain (bone, ligament, air outside the body).
    #[error(
        "outlet.tip_mm {tip_mm:?}: the needle opening touches no fluid domain (bone, ligament or outside the body)"
    )]
    OutletNotInDomain {
        /// The tip.
        tip_mm: [f64; 3],
    },
}
