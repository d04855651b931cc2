//! Coherent speckle: a signed I/Q scatterer field fixed to the TISSUE, seen through the PSF.
//!
//! Scatterers sit on a regular lattice of side `h` in the region frame (cell `(i, j, k)` at
//! `(i h, j h, k h)`), each with a signed complex amplitude drawn from a SplitMix64 hash of the
//! seed and the cell's indices. Nothing depends on the probe: moving the probe moves the image
//! over speckle that stays with the anatomy. The amplitudes are triangular (sum of two uniforms)
//! rather than Gaussian; the PSF sums many of them, so the field it sees is Gaussian and the
//! envelope Rayleigh (tested), and a regular lattice finer than the PSF keeps the local scatter
//! energy constant (random positions would make it fluctuate and spoil the statistics).
//!
//! Each scatterer is weighted by the elevation profile at its distance from the slice, turned
//! by its carrier phase `2 k z` and deposited bilinearly on a (line, sample) grid. A Gaussian
//! across lines per depth row (its width converted from mm with the line spacing AT THAT DEPTH,
//! so diverging sector lines get the right blur) and a Gaussian along each line finish the
//! convolution; the deposit's own spread (variance 1/6 grid step^2) is subtracted from the
//! Gaussian's variance. Beam widths change with depth but the beam's energy does not: the
//! lateral and elevation profiles are scaled by `sqrt(w_focus / w(z))` so that uniform tissue
//! gives the same mean speckle at every depth (losses apart) and a point target is brightest
//! at the focus.
//!
//! The pieces, in the order a frame uses them:
//! - `grid`: the padded (line, sample) I/Q grid and its bilinear deposit.
//! - `tables`: per-sample beam widths and energy factors of the frame.
//! - `lookup`: the `cis` and `exp(-x)` tables of the scatter loop.
//! - `amplitude`: a scatterer's signed I/Q amplitude from the hash of its cell.
//! - `fascicle`: the fascicle honeycomb and anisotropy of nerve scatterers.
//! - `column`: what the deposit of one lattice column needs (context, reach, a cell's scatterer).
//! - `deposit`: the lattice bounds and the deposit of every scatterer within reach.
//! - `oblique`: the deposit of a column that crosses the slice obliquely, scatterer by scatterer.
//! - `convolve`: the lateral and axial Gaussians that finish the convolution.

mod amplitude;
mod column;
mod convolve;
mod deposit;
mod fascicle;
mod grid;
mod lookup;
mod oblique;
mod sector;
mod tables;

pub use deposit::{LatticeBounds, lattice_bounds};
pub use fascicle::{
    FASCICLE_CELL_MM, FASCICLE_INSIDE, FASCICLE_OUTSIDE, FASCICLE_RADIUS_MM, NERVE_ANISOTROPY_FLOOR,
};

pub(crate) use convolve::{LateralKernel, axial_taps, conv_sigma, convolve_axial_row};
pub(crate) use deposit::{ScatterField, deposit_scatterers};
pub(crate) use grid::IqGrid;
pub(crate) use lookup::{cis, exp_neg};
pub(crate) use tables::BeamTables;
