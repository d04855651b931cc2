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

impl CellOp {
    /// Unknowns.
    pub(super) fn len(&self) -> usize {
        self.diag.len()
    }

    /// An operator from per-cell neighbour slots (`nb[k][s]` with coupling `g[k][s]`, slots -z,
    /// -y, -x, +x, +y, +z, which is ascending lattice order; absent where the coupling is 0) and
    /// diagonals.
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
        let lo = cells.first().copied().unwrap_or(0);
        let mut map = vec![u32::MAX; cells.last().map_or(0, |&c| c + 1 - lo)];
        for (k, &c) in cells.iter().enumerate() {
            map[c - lo] = k as u32;
        }
        let index = |c: usize| -> u32 {
            let k = map.get(c - lo).copied().unwrap_or(u32::MAX);
            assert!(k != u32::MAX, "cell {c} couples outside the live cells");
            k
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

    /// Galerkin coarsening by aggregates: the cells of one 2 x 2 x 2 lattice block that are
    /// joined through couplings inside the block (cells of one block that do not couple, such as
    /// two compartments a membrane separates, stay apart: a constant across them is no smooth
    /// error of the operator). Returns the coarse operator and the coarse unknown of each fine
    /// one; coarse unknowns are ordered by block (lattice order), then by their first cell.
    fn coarsen(&self) -> (CellOp, Vec<u32>) {
        let n = self.len();
        let key = |k: usize| self.coords[k].map(|v| v / 2);
        // Union-find of the couplings inside blocks.
        let mut root: Vec<u32> = (0..n as u32).collect();
        fn find(root: &mut [u32], mut k: u32) -> u32 {
            while root[k as usize] != k {
                let up = root[root[k as usize] as usize];
                root[k as usize] = up;
                k = up;
            }
            k
        }
        for k in 0..n {
            for t in self.start[k] as usize..self.start[k + 1] as usize {
                let j = self.col[t] as usize;
                if j > k && key(j) == key(k) {
                    let (a, b) = (find(&mut root, k as u32), find(&mut root, j as u32));
                    // The smaller index is the root, so roots are each aggregate's first cell.
                    root[a.max(b) as usize] = a.min(b);
                }
            }
        }
        // The cells block by block (a counting sort, stable, so by index within a block).
        let mut cdims = [1u32; 3];
        for c in &self.coords {
            for a in 0..3 {
                cdims[a] = cdims[a].max(c[a] / 2 + 1);
            }
        }
        let block = |k: usize| {
            let c = self.coords[k];
            (c[0] / 2 + cdims[0] * (c[1] / 2 + cdims[1] * (c[2] / 2))) as usize
        };
        let order = counting_sort(n, (cdims[0] * cdims[1] * cdims[2]) as usize, block);
        const NONE: u32 = u32::MAX;
        let mut id = vec![NONE; n];
        let mut coords = Vec::new();
        let mut parent = vec![0u32; n];
        for &k in &order {
            let r = find(&mut root, k) as usize;
            if id[r] == NONE {
                id[r] = coords.len() as u32;
                coords.push(self.coords[k as usize].map(|v| v / 2));
            }
            parent[k as usize] = id[r];
        }
        let nc = coords.len();
        // Rows of the coarse operator, aggregate by aggregate (members in the order above), with
        // a marker per coarse column: each coarse coupling sums its fine ones in a fixed order.
        let members = counting_sort(n, nc, |k| parent[k] as usize);
        let mut diag = vec![0.0; nc];
        let mut start = Vec::with_capacity(nc + 1);
        let (mut col, mut val): (Vec<u32>, Vec<f64>) = (Vec::new(), Vec::new());
        let (mut marker, mut pos) = (vec![NONE; nc], vec![0usize; nc]);
        start.push(0u32);
        let mut m = 0;
        for (p, dp) in diag.iter_mut().enumerate() {
            while m < n && parent[members[m] as usize] as usize == p {
                let k = members[m] as usize;
                m += 1;
                *dp += self.diag[k];
                for t in self.start[k] as usize..self.start[k + 1] as usize {
                    let q = parent[self.col[t] as usize] as usize;
                    if q == p {
                        // A coupling inside the aggregate (met from both of its cells) cancels.
                        *dp -= self.val[t];
                    } else if marker[q] == p as u32 {
                        val[pos[q]] += self.val[t];
                    } else {
                        marker[q] = p as u32;
                        pos[q] = col.len();
                        col.push(q as u32);
                        val.push(self.val[t]);
                    }
                }
            }
            start.push(col.len() as u32);
        }
        let op = CellOp {
            coords,
            diag,
            start,
            col,
            val,
        };
        (op, parent)
    }

    /// The operator with unknown `order[i]` at position `i` (`new_index` the inverse).
    fn permuted(&self, order: &[u32], new_index: &[u32]) -> CellOp {
        let mut start = Vec::with_capacity(self.start.len());
        let (mut col, mut val) = (Vec::with_capacity(self.col.len()), Vec::new());
        start.push(0);
        for &k in order {
            let (s, e) = (
                self.start[k as usize] as usize,
                self.start[k as usize + 1] as usize,
            );
            col.extend(self.col[s..e].iter().map(|&j| new_index[j as usize]));
            val.extend_from_slice(&self.val[s..e]);
            start.push(col.len() as u32);
        }
        CellOp {
            coords: order.iter().map(|&k| self.coords[k as usize]).collect(),
            diag: order.iter().map(|&k| self.diag[k as usize]).collect(),
            start,
            col,
            val,
        }
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

/// The unknowns of `a` with even lattice parity, then the odd ones (each ascending), and the
/// number of even ones.
fn parity_order(a: &CellOp) -> (Vec<u32>, usize) {
    let odd = |c: &[u32; 3]| (c[0] + c[1] + c[2]) % 2 == 1;
    let mut order: Vec<u32> = (0..a.len() as u32)
        .filter(|&k| !odd(&a.coords[k as usize]))
        .collect();
    let split = order.len();
    order.extend((0..a.len() as u32).filter(|&k| odd(&a.coords[k as usize])));
    (order, split)
}

/// Indices `0..n` ordered by `bucket(k) < buckets`, stably.
fn counting_sort(n: usize, buckets: usize, bucket: impl Fn(usize) -> usize) -> Vec<u32> {
    let mut first = vec![0u32; buckets + 1];
    for k in 0..n {
        first[bucket(k) + 1] += 1;
    }
    for b in 0..buckets {
        first[b + 1] += first[b];
    }
    let mut out = vec![0u32; n];
    for k in 0..n {
        let b = bucket(k);
        out[first[b] as usize] = k as u32;
        first[b] += 1;
    }
    out
}

/// Largest coarsest level solved by a dense factorisation. Aggregates never join cells that do
/// not couple, so a level made of many separate pockets stops shrinking above
/// [`COARSEST_CELLS`]; beyond this size (a 1000^2 factor is 8 MB) the coarsest level
/// is only smoothed, which keeps the cycle symmetric and positive definite.
const DENSE_LIMIT: usize = 1000;

#[derive(Debug, Clone)]
struct Level {
    a: CellOp,
    /// The unknowns are ordered by lattice parity: `0..split` even, `split..` odd.
    split: usize,
    /// Coarse unknown of each unknown (empty on the coarsest level).
    parent: Vec<u32>,
    x: Vec<f64>,
    b: Vec<f64>,
    r: Vec<f64>,
}

/// Coarsening stops once a level has at most this many cells.
pub const COARSEST_CELLS: usize = 125;
/// Default scale of the coarse correction (see `multigrid`'s module docs). Measured on the tests'
/// 1000x-contrast grid (`contrast_grid`, 1e-6) at 64^3: 7 PCG iterations at 1.6, 12 at 1.0
/// (at 32^3: 7 and 10), 1.6 also the shortest time.
pub const OVERCORRECTION: f64 = 1.6;
/// Red-black sweeps before and after the correction: two instead of one cut the PCG
/// iterations at 64^3 from 10 to 7 for the same time (same measurement; with the earlier
/// aggregates that ignored membranes, from 49 to 31). The W-cycle (`gamma` 2) instead of a
/// V-cycle: 7 instead of 11 iterations, 20 % less time.
pub const SWEEPS: usize = 2;

/// The multigrid hierarchy of a [`CellOp`] (see the module docs).
#[derive(Debug, Clone)]
pub(super) struct CellMultigrid {
    levels: Vec<Level>,
    /// The operator's unknown at each position of the finest level.
    order: Vec<u32>,
    /// Dense Cholesky factor of the coarsest level (empty when that level is too large, see
    /// [`DENSE_LIMIT`]).
    chol: Vec<f64>,
    /// Smoothing sweeps before and after the coarse correction.
    pub(super) sweeps: usize,
    /// Coarse visits per level.
    pub(super) gamma: usize,
    /// Coarse-correction scale.
    pub(super) alpha: f64,
}

impl CellMultigrid {
    pub(super) fn new(a: &CellOp) -> CellMultigrid {
        let mut levels: Vec<Level> = Vec::new();
        let mut order0 = Vec::new();
        let mut cur = a.clone();
        loop {
            // Each level's unknowns in parity order, so a half-sweep streams one contiguous half.
            let (order, split) = parity_order(&cur);
            let mut new_index = vec![0u32; order.len()];
            for (i, &k) in order.iter().enumerate() {
                new_index[k as usize] = i as u32;
            }
            let op = cur.permuted(&order, &new_index);
            match levels.last_mut() {
                Some(prev) => {
                    for q in prev.parent.iter_mut() {
                        *q = new_index[*q as usize];
                    }
                }
                None => order0 = order,
            }
            let n = op.len();
            let next = (n > COARSEST_CELLS).then(|| op.coarsen());
            // Coarsening that no longer shrinks the level (cells far apart) ends the hierarchy;
            // the dense solve then takes the whole level.
            let next = next.filter(|(c, _)| c.len() < n);
            let (next, parent) = match next {
                Some((c, p)) => (Some(c), p),
                None => (None, Vec::new()),
            };
            levels.push(Level {
                a: op,
                split,
                parent,
                x: vec![0.0; n],
                b: vec![0.0; n],
                r: vec![0.0; n],
            });
            match next {
                Some(c) => cur = c,
                None => break,
            }
        }
        let last = &levels[levels.len() - 1].a;
        let chol = if last.len() <= DENSE_LIMIT {
            cholesky_factor(last.dense(), last.len())
        } else {
            Vec::new()
        };
        CellMultigrid {
            levels,
            order: order0,
            chol,
            sweeps: SWEEPS,
            gamma: 2,
            alpha: OVERCORRECTION,
        }
    }

    /// Number of levels.
    pub(super) fn depth(&self) -> usize {
        self.levels.len()
    }

    /// `z = M^-1 r` (one cycle from a zero guess).
    pub(super) fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        let lv = &mut self.levels[0];
        for (b, &k) in lv.b.iter_mut().zip(&self.order) {
            *b = r[k as usize];
        }
        lv.x.fill(0.0);
        self.cycle(0);
        for (&x, &k) in self.levels[0].x.iter().zip(&self.order) {
            z[k as usize] = x;
        }
    }

    fn cycle(&mut self, l: usize) {
        if l + 1 == self.levels.len() {
            let lv = &mut self.levels[l];
            if self.chol.is_empty() {
                // Symmetric smoothing only (see `DENSE_LIMIT`).
                for _ in 0..self.sweeps {
                    gs(&lv.a, 0..lv.split, &lv.b, &mut lv.x);
                    gs(&lv.a, lv.split..lv.a.len(), &lv.b, &mut lv.x);
                }
                for _ in 0..self.sweeps {
                    gs(&lv.a, lv.split..lv.a.len(), &lv.b, &mut lv.x);
                    gs(&lv.a, 0..lv.split, &lv.b, &mut lv.x);
                }
            } else {
                cholesky_solve(&self.chol, &lv.b, &mut lv.x);
            }
            return;
        }
        {
            let lv = &mut self.levels[l];
            for _ in 0..self.sweeps {
                gs(&lv.a, 0..lv.split, &lv.b, &mut lv.x);
                gs(&lv.a, lv.split..lv.a.len(), &lv.b, &mut lv.x);
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
        for _ in 0..self.gamma {
            self.cycle(l + 1);
        }
        let (fine, coarse) = self.levels.split_at_mut(l + 1);
        let (f, c) = (&mut fine[l], &coarse[0]);
        for (x, &p) in f.x.iter_mut().zip(&f.parent) {
            *x += self.alpha * c.x[p as usize];
        }
        for _ in 0..self.sweeps {
            gs(&f.a, f.split..f.a.len(), &f.b, &mut f.x);
            gs(&f.a, 0..f.split, &f.b, &mut f.x);
        }
    }
}

/// Dense Cholesky factorisation in place of the row-major symmetric `m` (`n` x `n`); returns the
/// lower triangle.
fn cholesky_factor(mut m: Vec<f64>, n: usize) -> Vec<f64> {
    for j in 0..n {
        let mut d = m[j * n + j];
        for k in 0..j {
            d -= m[j * n + k] * m[j * n + k];
        }
        let d = d.max(f64::MIN_POSITIVE).sqrt();
        m[j * n + j] = d;
        for i in j + 1..n {
            let mut v = m[i * n + j];
            for k in 0..j {
                v -= m[i * n + k] * m[j * n + k];
            }
            m[i * n + j] = v / d;
        }
    }
    m
}

fn cholesky_solve(l: &[f64], b: &[f64], x: &mut [f64]) {
    let n = b.len();
    for i in 0..n {
        let mut v = b[i];
        for k in 0..i {
            v -= l[i * n + k] * x[k];
        }
        x[i] = v / l[i * n + i];
    }
    for i in (0..n).rev() {
        let mut v = x[i];
        for k in i + 1..n {
            v -= l[k * n + i] * x[k];
        }
        x[i] = v / l[i * n + i];
    }
}

/// One Gauss-Seidel half-sweep over `rows` (one lattice parity, so they do not couple).
fn gs(a: &CellOp, rows: std::ops::Range<usize>, b: &[f64], x: &mut [f64]) {
    for k in rows {
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
