//! A symmetric multigrid preconditioner for [`Stencil`] systems on masked box grids.
//!
//! Coarsening merges the cells of 2 x 2 x 2 blocks into aggregates: the cells of a block that
//! couple through faces inside it (cells a membrane or a solid separates stay in separate
//! aggregates, so a coarse unknown never ties two compartments together). Prolongation `P` is
//! piecewise constant on the aggregates, restriction is `P^T`, and the coarse operator is the
//! Galerkin product `P^T A P`: a coarse coupling sums the fine faces crossing between two
//! aggregates, so mobility jumps, solid cells and drains carry over exactly (the reason for
//! Galerkin rather than rediscretisation on a masked, 1000x-contrast grid). Piecewise-constant
//! aggregation corrects smooth errors too weakly for a V-cycle, so the cycle is a W-cycle (in
//! 3-D the coarse levels cost 2/8 of the level above, so the whole W-cycle costs about 4/3 of the
//! fine-level work) with the coarse correction scaled by [`Multigrid::OVERCORRECTION`] (Braess,
//! "Towards algebraic multigrid for elliptic problems of second order", Computing 55, 1995, and
//! Vanek et al., Computing 56, 1996, scale unsmoothed-aggregation corrections the same way).
//!
//! Smoothing is red-black Gauss-Seidel (colours by lattice parity; aggregates of one block do not
//! couple, so the colouring carries to every level), red then black before the correction and
//! black then red after it; the cycle is therefore a symmetric operator, and it is positive
//! definite because the smoothing is convergent and the scaled coarse correction stays below 2,
//! so it is a valid PCG preconditioner. The coarsest level (at most
//! [`Multigrid::COARSEST_CELLS`] unknowns) is solved exactly by a dense Cholesky factorisation.
//!
//! The levels store only the active cells, as compressed rows (`super::cells`); the model's
//! steps build the same hierarchy directly on their live cells.
//!
//! Design target: a count of PCG iterations that does not grow with the grid, at most 30 to a
//! 1e-6 energy-norm error on the solver benchmark's grid ([`super::benchmark::solver_grid`]) at
//! 128^3 (a simulator choice: a budget of about one second per solve at 128^3 on one core). The
//! contrast tests assert it; the contrast benchmark reports the count at 64^3 and 128^3.

use super::cells::{CellMultigrid, CellOp};
use super::pressure::Stencil;

/// The multigrid hierarchy of one operator.
#[derive(Debug, Clone)]
pub struct Multigrid {
    /// Box index of each active cell.
    cells: Vec<usize>,
    inner: CellMultigrid,
    rb: Vec<f64>,
    zb: Vec<f64>,
    /// Smoothing sweeps before and after the coarse correction.
    pub sweeps: usize,
    /// Coarse visits per level (1 = V-cycle, 2 = W-cycle).
    pub gamma: usize,
    /// Coarse-correction scale.
    pub alpha: f64,
}

impl Multigrid {
    /// Coarsening stops once a level has at most this many cells.
    pub const COARSEST_CELLS: usize = super::cells::COARSEST_CELLS;
    /// Default scale of the coarse correction (see [`super::cells::OVERCORRECTION`]).
    pub const OVERCORRECTION: f64 = super::cells::OVERCORRECTION;
    /// Red-black sweeps before and after the correction (see [`super::cells::SWEEPS`]).
    pub const SWEEPS: usize = super::cells::SWEEPS;

    /// Builds the hierarchy of `a` (its active cells; couplings to inactive cells are ignored).
    pub fn new(a: &Stencil) -> Multigrid {
        let cells: Vec<usize> = (0..a.len()).filter(|&c| a.active[c]).collect();
        let strides = a.strides();
        let coupling = |ax: usize, c: usize| {
            let nb = c + strides[ax];
            if nb < a.len() && a.active[nb] {
                a.off[ax][c]
            } else {
                0.0
            }
        };
        let mut op = CellOp::from_cells(a.dims, &cells, coupling, |_| 0.0);
        for (d, &c) in op.diag.iter_mut().zip(&cells) {
            *d = a.diag[c];
        }
        let n = cells.len();
        Multigrid {
            inner: CellMultigrid::new(&op),
            cells,
            rb: vec![0.0; n],
            zb: vec![0.0; n],
            sweeps: Self::SWEEPS,
            gamma: 2,
            alpha: Self::OVERCORRECTION,
        }
    }

    /// Number of levels.
    pub fn depth(&self) -> usize {
        self.inner.depth()
    }

    /// `z = M^-1 r` (one cycle from a zero guess; inactive cells pass through unchanged).
    pub fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        for (v, &c) in self.rb.iter_mut().zip(&self.cells) {
            *v = r[c];
        }
        self.inner.sweeps = self.sweeps;
        self.inner.gamma = self.gamma;
        self.inner.alpha = self.alpha;
        self.inner.apply(&self.rb, &mut self.zb);
        z.copy_from_slice(r);
        for (&v, &c) in self.zb.iter().zip(&self.cells) {
            z[c] = v;
        }
    }
}
