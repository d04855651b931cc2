//! Contrast and saline transport in the spinal compartments: the f64 CPU reference.
//!
//! Fluid injected through a needle flows through masked voxel domains (epidural, intrathecal,
//! subdural, vascular, intraneural, local pooling) under a Darcy-type pressure solve, carrying
//! iodine by conservative upwind fluxes plus diffusion, with clearance and drains; a ledger
//! accounts for every stock-equivalent mm^3 of iodine. Pure functions over plain data: no IO, no
//! GPU, no threads in the numerics, deterministic.
//!
//! - [`domains`]: the grid from the phantom (`phantom_grid(params, crop_grid(lo, hi, 1.0))`),
//!   the vertebral levels ([`domains::phantom_levels`]);
//! - [`grid`]: [`ContrastGrid`] (per-cell [`Domain`] and [`CellProps`]) and its [`Faces`];
//! - [`pressure`], [`multigrid`]: the linear system, PCG and its stop rule, the preconditioner;
//!   `cells` (private): the same operator and multigrid compressed to the live cells, which is
//!   what a model step solves;
//! - [`model`]: [`ContrastModel`]: `start_injection(&NeedleOutlet, &Injection)`,
//!   `stop_injection()`, `puncture(&NeedleOutlet, depth_mm)`, `advance(dt_s) -> StepReport`,
//!   `ledger()`, `density_stock()` (whole-voxel stock-equivalent density for
//!   `crate::fluoro::IodineField::new`);
//! - [`classify`]: `classify(&model, &levels) -> PatternReport` for scorers;
//! - [`outlet`]: [`NeedleOutlet`] (tip, direction, opening, outer diameter), [`Agent`],
//!   [`Injection`] (mL, mL/s), validation and routing.
//!
//! ```
//! use sim_core::contrast::*;
//! use sim_core::volume::VolumeGrid;
//! let vg = VolumeGrid { dims: [12, 4, 4], spacing_mm: [1.0; 3], origin_mm: [0.0; 3] };
//! let grid = ContrastGrid::uniform(vg, Domain::Epidural, Domain::Epidural.default_props());
//! let mut model = ContrastModel::new(grid, ModelConfig::default());
//! let outlet = NeedleOutlet::tuohy([3.0, 1.5, 1.5], [1.0, 0.0, 0.0]);
//! let dose = Injection { agent: Agent::CONTRAST, volume_ml: 0.01, rate_ml_s: 0.1 };
//! model.start_injection(&outlet, &dose).unwrap();
//! model.advance(0.2).unwrap();
//! // 0.01 mL of stock contrast is 10 mm^3 of stock-equivalent iodine; epidural clearance
//! // (1/1200 per s) has removed about 0.01 % of it in 0.2 s.
//! assert!((model.retained_mm3() - 10.0).abs() < 0.01);
//! assert!(model.ledger().balance_error(model.retained_mm3()) < 1e-12);
//! ```

pub mod benchmark;
mod cells;
pub mod classify;
pub mod domains;
pub mod grid;
pub mod ledger;
pub mod model;
pub mod multigrid;
pub mod outlet;
pub mod pressure;
mod transport;
mod window;

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
