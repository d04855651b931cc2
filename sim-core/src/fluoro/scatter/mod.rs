//! Scatter: the fog of scattered photons on the detector, by kernel superposition on a coarse
//! grid, with an anti-scatter grid and an air gap; and the Monte Carlo it is checked against.

pub mod grid;
pub mod kernel;
pub mod monte_carlo;
pub mod superposition;
pub mod tables;

pub use grid::AntiScatterGrid;

#[cfg(test)]
mod tests;
