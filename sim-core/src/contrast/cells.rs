//! The compressed operator of the live cells and its multigrid: what a model step solves.
//!
//! The box [`super::pressure::Stencil`] sweeps every cell of the live window, but on the phantom
//! the live compartment (the epidural space, about 17 000 cells) fills under a tenth of the
//! window it spans (the whole crop along the canal). [`CellOp`] stores only the live cells, in
//! lattice order, with their couplings as compressed rows (at most six, always to lattice
//! neighbours), so the solve and the transport touch nothing else.
//!
//! [`CellMultigrid`] is the same method as [`super::multigrid::Multigrid`] on these rows: 2 x 2 x 2
//! aggregation on the lattice, Galerkin coarse operators (again 7-point, on the coarse lattice),
//! red-black Gauss-Seidel by lattice parity, a W-cycle with the over-corrected coarse correction,
//! and a dense Cholesky solve at the coarsest level.

use super::multigrid::{Multigrid, cholesky_factor, cholesky_solve};
use super::pressure::{self, OutletNode, SolveStats, StopRule};

/// A symmetric operator on a list of lattice cells: `y_k = diag_k x_k - sum val x_col` over the
/// row's couplings (all to face neighbours on the lattice).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct CellOp {
    /// Lattice coordinates of each unknown, in lattice order (z, then y, then x ascending).
    pub(super) coords: Vec<[u32; 3]>,
    /// Diagonal per unknown.
    pub(super) diag: Vec<f64>,
    /// Row starts into `col` and `val` (one more than unknowns).
    pub(super) start: Vec<u32>,
    /// Neighbour of each coupling, ascending within a row.
    pub(super) col: Vec<u32>,
    /// Coupling (the negated off-diagonal, > 0).
    pub(super) val: Vec<f64>,
}

/// Slot of the neighbour `q` of `p` (coordinates differ by one along one axis): -z, -y, -x, +x,
/// +y, +z, which is ascending lattice order.
fn slot(p: [u32; 3], q: [u32; 3]) -> usize {
    for a in 0..3 {
        if q[a] != p[a] {
            return if q[a] < p[a] { 2 - a } else { 3 + a };
        }
    }
    unreachable!("a coupling joins two distinct cells")
}

impl CellOp {
    /// Unknowns.
    pub(super) fn len(&self) -> usize {
        self.diag.len()
    }

    /// An operator from per-cell neighbour slots (`nb[k][s]` with coupling `g[k][s]`, slots as in
    /// [`slot`], absent where the coupling is 0) and diagonals.
    fn from_slots(
        coords: Vec<[u32; 3]>,
        diag: Vec<f64>,
        nb: &[[u32; 6]],
        g: &[[f64; 6]],
    ) -> CellOp {
        let mut start = Vec::with_capacity(diag.len() + 1);
        let (mut col, mut val) = (Vec::new(), Vec::new());
        start.push(0);
        for (ks, gs) in nb.iter().zip(g) {
            for s in 0..6 {
                if gs[s] != 0.0 {
                    col.push(ks[s]);
                    val.push(gs[s]);
                }
            }
            start.push(col.len() as u32);
        }
        CellOp {
            coords,
            diag,
            start,
            col,
            val,
        }
    }

    /// The operator of `cells` (full-grid indices, ascending) of a box of `dims`: couplings from
    /// `coupling(axis, c)` (the face between full cell `c` and its `+axis` neighbour, which must
    /// be in `cells` when non-zero), diagonal additions from `extra(k)`.
    pub(super) fn from_cells(
        dims: [usize; 3],
        cells: &[usize],
        coupling: impl Fn(usize, usize) -> f64,
        extra: impl Fn(usize) -> f64,
    ) -> CellOp {
        let strides = [1, dims[0], dims[0] * dims[1]];
        let index = |c: usize| -> u32 {
            cells
                .binary_search(&c)
                .unwrap_or_else(|_| panic!("cell {c} couples outside the live cells"))
                as u32
        };
        let coords: Vec<[u32; 3]> = cells
            .iter()
            .map(|&c| {
                [
                    (c % dims[0]) as u32,
                    ((c / dims[0]) % dims[1]) as u32,
                    (c / strides[2]) as u32,
                ]
            })
            .collect();
        let mut nb = vec![[0u32; 6]; cells.len()];
        let mut g = vec![[0.0; 6]; cells.len()];
        let mut diag: Vec<f64> = (0..cells.len()).map(&extra).collect();
        for (k, &c) in cells.iter().enumerate() {
            for a in 0..3 {
                let v = coupling(a, c);
                if v != 0.0 {
                    let j = index(c + strides[a]) as usize;
                    nb[k][3 + a] = j as u32;
                    g[k][3 + a] = v;
                    nb[j][2 - a] = k as u32;
                    g[j][2 - a] = v;
                    diag[k] += v;
                    diag[j] += v;
                }
            }
        }
        CellOp::from_slots(coords, diag, &nb, &g)
    }

    /// `y = A x`.
    pub(super) fn apply(&self, x: &[f64], y: &mut [f64]) {
        for (k, yk) in y.iter_mut().enumerate().take(self.len()) {
            let (s, e) = (self.start[k] as usize, self.start[k + 1] as usize);
            let mut v = self.diag[k] * x[k];
            for (&j, &g) in self.col[s..e].iter().zip(&self.val[s..e]) {
                v -= g * x[j as usize];
            }
            *yk = v;
        }
    }

    /// Galerkin coarsening by 2 x 2 x 2 lattice blocks: the coarse operator and the coarse
    /// unknown of each fine one.
    fn coarsen(&self) -> (CellOp, Vec<u32>) {
        let key = |c: &[u32; 3]| [c[2] / 2, c[1] / 2, c[0] / 2];
        let mut keys: Vec<[u32; 3]> = self.coords.iter().map(key).collect();
        keys.sort_unstable();
        keys.dedup();
        let parent: Vec<u32> = self
            .coords
            .iter()
            .map(|c| keys.binary_search(&key(c)).unwrap_or(0) as u32)
            .collect();
        let coords: Vec<[u32; 3]> = keys.iter().map(|k| [k[2], k[1], k[0]]).collect();
        let n = coords.len();
        let mut diag = vec![0.0; n];
        let mut nb = vec![[0u32; 6]; n];
        let mut g = vec![[0.0; 6]; n];
        for k in 0..self.len() {
            let p = parent[k] as usize;
            diag[p] += self.diag[k];
            let (s, e) = (self.start[k] as usize, self.start[k + 1] as usize);
            for (&j, &v) in self.col[s..e].iter().zip(&self.val[s..e]) {
                let q = parent[j as usize] as usize;
                if q == p {
                    // A coupling inside the block (met from both of its cells) cancels.
                    diag[p] -= v;
                } else {
                    let sl = slot(coords[p], coords[q]);
                    nb[p][sl] = q as u32;
                    g[p][sl] += v;
                }
            }
        }
        (CellOp::from_slots(coords, diag, &nb, &g), parent)
    }

    /// Dense row-major copy (for the coarsest level).
    fn dense(&self) -> Vec<f64> {
        let n = self.len();
        let mut m = vec![0.0; n * n];
        for k in 0..n {
            m[k * n + k] = self.diag[k];
            for t in self.start[k] as usize..self.start[k + 1] as usize {
                m[k * n + self.col[t] as usize] = -self.val[t];
            }
        }
        m
    }
}

#[derive(Debug, Clone)]
struct Level {
    a: CellOp,
    /// Unknowns of each lattice parity.
    colours: [Vec<u32>; 2],
    /// Coarse unknown of each unknown (empty on the coarsest level).
    parent: Vec<u32>,
    x: Vec<f64>,
    b: Vec<f64>,
    r: Vec<f64>,
}

/// The multigrid hierarchy of a [`CellOp`] (see the module docs).
#[derive(Debug, Clone)]
pub(super) struct CellMultigrid {
    levels: Vec<Level>,
    chol: Vec<f64>,
}

impl CellMultigrid {
    pub(super) fn new(a: &CellOp) -> CellMultigrid {
        let mut levels = Vec::new();
        let mut cur = a.clone();
        loop {
            let n = cur.len();
            let next = (n > Multigrid::COARSEST_CELLS).then(|| cur.coarsen());
            // Coarsening that no longer shrinks the level (cells far apart) ends the hierarchy;
            // the dense solve then takes the whole level.
            let next = next.filter(|(c, _)| c.len() < n);
            let mut colours = [Vec::new(), Vec::new()];
            for (k, c) in cur.coords.iter().enumerate() {
                colours[((c[0] + c[1] + c[2]) % 2) as usize].push(k as u32);
            }
            let parent = next.as_ref().map(|(_, p)| p.clone()).unwrap_or_default();
            levels.push(Level {
                a: cur,
                colours,
                parent,
                x: vec![0.0; n],
                b: vec![0.0; n],
                r: vec![0.0; n],
            });
            match next {
                Some((c, _)) => cur = c,
                None => break,
            }
        }
        let last = &levels[levels.len() - 1].a;
        let chol = cholesky_factor(last.dense(), last.len());
        CellMultigrid { levels, chol }
    }

    /// `z = M^-1 r` (one cycle from a zero guess).
    pub(super) fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        self.levels[0].b.copy_from_slice(r);
        self.levels[0].x.fill(0.0);
        self.cycle(0);
        z.copy_from_slice(&self.levels[0].x);
    }

    fn cycle(&mut self, l: usize) {
        if l + 1 == self.levels.len() {
            let lv = &mut self.levels[l];
            cholesky_solve(&self.chol, &lv.b, &mut lv.x);
            return;
        }
        {
            let lv = &mut self.levels[l];
            for _ in 0..Multigrid::SWEEPS {
                gs(&lv.a, &lv.colours[0], &lv.b, &mut lv.x);
                gs(&lv.a, &lv.colours[1], &lv.b, &mut lv.x);
            }
            lv.a.apply(&lv.x, &mut lv.r);
            for (r, b) in lv.r.iter_mut().zip(&lv.b) {
                *r = b - *r;
            }
        }
        let (fine, coarse) = self.levels.split_at_mut(l + 1);
        let (f, c) = (&mut fine[l], &mut coarse[0]);
        c.b.fill(0.0);
        for (&p, &r) in f.parent.iter().zip(&f.r) {
            c.b[p as usize] += r;
        }
        c.x.fill(0.0);
        for _ in 0..2 {
            self.cycle(l + 1);
        }
        let (fine, coarse) = self.levels.split_at_mut(l + 1);
        let (f, c) = (&mut fine[l], &coarse[0]);
        for (x, &p) in f.x.iter_mut().zip(&f.parent) {
            *x += Multigrid::OVERCORRECTION * c.x[p as usize];
        }
        for _ in 0..Multigrid::SWEEPS {
            gs(&f.a, &f.colours[1], &f.b, &mut f.x);
            gs(&f.a, &f.colours[0], &f.b, &mut f.x);
        }
    }
}

/// One Gauss-Seidel half-sweep over `rows` (one lattice parity, so they do not couple).
fn gs(a: &CellOp, rows: &[u32], b: &[f64], x: &mut [f64]) {
    for &k in rows {
        let k = k as usize;
        let (s, e) = (a.start[k] as usize, a.start[k + 1] as usize);
        let mut v = b[k];
        for (&j, &g) in a.col[s..e].iter().zip(&a.val[s..e]) {
            v += g * x[j as usize];
        }
        x[k] = v / a.diag[k];
    }
}

/// Solves `(A + outlet) x = b` by PCG from the guess in `x` (cells, then the outlet node if
/// any) with the multigrid on the cells (Jacobi on the node) or Jacobi. `ritz_floor`: the
/// smallest Ritz value an earlier solve with the same operator and preconditioner found (an upper
/// bound on `lambda_min` too, so it only tightens the stop rule's error bound).
pub(super) fn solve(
    a: &CellOp,
    outlet: Option<&OutletNode>,
    mg: Option<&mut CellMultigrid>,
    b: &[f64],
    x: &mut [f64],
    rule: StopRule,
    ritz_floor: f64,
) -> SolveStats {
    let mut mg_apply = mg.map(|m| move |r: &[f64], z: &mut [f64]| m.apply(r, z));
    pressure::pcg_cells(
        &a.diag,
        &|v, y| a.apply(v, y),
        outlet,
        mg_apply.as_mut().map(|f| f as pressure::CellPrecond<'_>),
        b,
        x,
        rule,
        ritz_floor,
    )
}
