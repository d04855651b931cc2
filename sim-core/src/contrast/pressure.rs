//! The pressure system `sum_j G_ij (p_i - p_j) + s_i p_i = Q_i` on a masked box grid (a 7-point
//! stencil; `s_i` gathers drains, open crop faces and storage), an optional needle-outlet node
//! coupled to the cells it touches, and preconditioned conjugate gradients.
//!
//! # Stop criterion
//! PCG stops on an estimate of the relative error of the pressure in the energy norm
//! `||e||_A / ||p||_A` (the norm of the flux field's dissipation, so the flux error is bounded by
//! it). With `M` the preconditioner, `r` the residual and `z = M^-1 r`, the identity
//! `r.z = e^T A M^-1 A e >= lambda_min(M^-1 A) ||e||_A^2` bounds the error by
//! `sqrt(r.z / lambda_min)`; `||p||_A^2 = p.b` at the solution, estimated by the current iterate's
//! `x.b`. `lambda_min` is estimated by the smallest Ritz value of the Lanczos tridiagonal that CG
//! builds for free (it converges from above, so early on the bound is optimistic; the tests check
//! the delivered error against a reference solution). PCG stops when
//! `sqrt(r.z / (theta_min x.b)) <= tol`.

/// A symmetric 7-point operator on a box: `y_i = diag_i x_i - sum off * x_neighbour`.
#[derive(Debug, Clone, PartialEq)]
pub struct Stencil {
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    /// Diagonal per cell (1 on inactive cells, which are identity rows decoupled from the rest).
    pub diag: Vec<f64>,
    /// Coupling of cell `i` with its `+axis` neighbour (the negative off-diagonal), per axis.
    pub off: [Vec<f64>; 3],
    /// Whether a cell takes part (inactive cells keep value 0).
    pub active: Vec<bool>,
}

impl Stencil {
    /// Number of cells.
    pub fn len(&self) -> usize {
        self.diag.len()
    }

    /// True without cells.
    pub fn is_empty(&self) -> bool {
        self.diag.is_empty()
    }

    /// Strides of the axes.
    pub fn strides(&self) -> [usize; 3] {
        [1, self.dims[0], self.dims[0] * self.dims[1]]
    }

    /// A stencil from face couplings and a per-cell diagonal addition (`extra`: sinks, storage),
    /// with `active` cells; the diagonal is the sum of the couplings plus `extra`.
    pub fn from_couplings(
        dims: [usize; 3],
        off: [Vec<f64>; 3],
        extra: &[f64],
        active: Vec<bool>,
    ) -> Stencil {
        let n = dims[0] * dims[1] * dims[2];
        let strides = [1, dims[0], dims[0] * dims[1]];
        let mut diag = extra.to_vec();
        for a in 0..3 {
            let s = strides[a];
            for i in 0..n {
                let g = off[a][i];
                if g != 0.0 {
                    diag[i] += g;
                    diag[i + s] += g;
                }
            }
        }
        for (d, &on) in diag.iter_mut().zip(&active) {
            if !on {
                *d = 1.0;
            }
        }
        Stencil {
            dims,
            diag,
            off,
            active,
        }
    }

    /// `y = A x`.
    pub fn apply(&self, x: &[f64], y: &mut [f64]) {
        let n = self.len();
        let [sx, sy, sz] = self.strides();
        let [ox, oy, oz] = [&self.off[0], &self.off[1], &self.off[2]];
        let row = |i: usize| -> f64 {
            let mut v = self.diag[i] * x[i];
            if i + sx < n {
                v -= ox[i] * x[i + sx];
            }
            if i >= sx {
                v -= ox[i - sx] * x[i - sx];
            }
            if i + sy < n {
                v -= oy[i] * x[i + sy];
            }
            if i >= sy {
                v -= oy[i - sy] * x[i - sy];
            }
            if i + sz < n {
                v -= oz[i] * x[i + sz];
            }
            if i >= sz {
                v -= oz[i - sz] * x[i - sz];
            }
            v
        };
        if n <= 2 * sz {
            for (i, yi) in y.iter_mut().enumerate().take(n) {
                *yi = row(i);
            }
            return;
        }
        for (i, yi) in y.iter_mut().enumerate().take(sz) {
            *yi = row(i);
        }
        // Interior planes: every neighbour index is in range, and couplings that would wrap are 0.
        for i in sz..n - sz {
            y[i] = self.diag[i] * x[i]
                - ox[i] * x[i + sx]
                - ox[i - sx] * x[i - sx]
                - oy[i] * x[i + sy]
                - oy[i - sy] * x[i - sy]
                - oz[i] * x[i + sz]
                - oz[i - sz] * x[i - sz];
        }
        for (i, yi) in y.iter_mut().enumerate().take(n).skip(n - sz) {
            *yi = row(i);
        }
    }
}

/// A needle outlet as one extra unknown (the pressure in the lumen) joined to the cells it opens
/// into by conductances: the injected rate goes where the pressure and conductances send it.
#[derive(Debug, Clone, PartialEq)]
pub struct OutletNode {
    /// (cell, conductance mm^3/(s pu)) of each contact.
    pub contacts: Vec<(usize, f64)>,
}

impl OutletNode {
    /// Sum of the contact conductances.
    pub fn total(&self) -> f64 {
        self.contacts.iter().map(|c| c.1).sum()
    }

    /// Completes `y = A x` for the node, unknown `n` after `n` cells whose rows `y` already hold
    /// the cell operator: the contacts' couplings to the node, and the node's row.
    pub fn apply(&self, x: &[f64], y: &mut [f64], n: usize) {
        let xn = x[n];
        let mut yn = 0.0;
        for &(c, g) in &self.contacts {
            y[c] -= g * xn;
            yn += g * (xn - x[c]);
        }
        y[n] = yn;
    }
}

/// The full operator: the stencil (whose diagonal already includes the contact conductances) and
/// an optional outlet node stored after the cells.
pub struct System<'a> {
    /// The cell operator.
    pub stencil: &'a Stencil,
    /// The outlet node, if an injection is running.
    pub outlet: Option<&'a OutletNode>,
}

impl System<'_> {
    /// Unknowns: cells plus one for an outlet.
    pub fn len(&self) -> usize {
        self.stencil.len() + usize::from(self.outlet.is_some())
    }

    /// True without unknowns.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `y = A x`.
    pub fn apply(&self, x: &[f64], y: &mut [f64]) {
        let n = self.stencil.len();
        self.stencil.apply(&x[..n], &mut y[..n]);
        if let Some(o) = self.outlet {
            o.apply(x, y, n);
        }
    }
}

/// When PCG stops (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StopRule {
    /// Target relative energy-norm pressure error.
    pub rel_error: f64,
    /// Iteration cap.
    pub max_iter: usize,
}

impl Default for StopRule {
    fn default() -> Self {
        StopRule {
            rel_error: 1e-6,
            max_iter: 2000,
        }
    }
}

/// What a solve did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveStats {
    /// PCG iterations.
    pub iterations: usize,
    /// Final estimated relative energy-norm error.
    pub est_rel_error: f64,
    /// Smallest Ritz value of the preconditioned operator (the `lambda_min` estimate).
    pub ritz_min: f64,
    /// Largest Ritz value.
    pub ritz_max: f64,
    /// Whether the estimate reached the target.
    pub converged: bool,
}

/// Number of eigenvalues of the symmetric tridiagonal (`d`, squared off-diagonal `e2`) below `x`
/// (Sturm sequence).
fn sturm_count(d: &[f64], e2: &[f64], x: f64) -> usize {
    let mut count = 0;
    let mut q = 1.0;
    for i in 0..d.len() {
        let sub = if i == 0 { 0.0 } else { e2[i - 1] / q };
        q = d[i] - x - sub;
        if q == 0.0 {
            q = -1e-300;
        }
        if q < 0.0 {
            count += 1;
        }
    }
    count
}

/// Extreme eigenvalues (min, max) of a symmetric tridiagonal by bisection.
pub fn tridiagonal_extremes(d: &[f64], e2: &[f64]) -> (f64, f64) {
    let n = d.len();
    if n == 0 {
        return (0.0, 0.0);
    }
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..n {
        let r = (if i > 0 { e2[i - 1].sqrt() } else { 0.0 })
            + (if i + 1 < n { e2[i].sqrt() } else { 0.0 });
        lo = lo.min(d[i] - r);
        hi = hi.max(d[i] + r);
    }
    let find = |target: usize| {
        let (mut a, mut b) = (lo, hi);
        for _ in 0..100 {
            let m = 0.5 * (a + b);
            if m <= a || m >= b {
                break;
            }
            if sturm_count(d, e2, m) >= target {
                b = m;
            } else {
                a = m;
            }
        }
        0.5 * (a + b)
    };
    (find(1), find(n))
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Preconditioned conjugate gradients for `A x = b` from the initial guess in `x`; `precond`
/// computes `z = M^-1 r` and must be symmetric positive definite.
pub fn pcg(
    apply: &mut dyn FnMut(&[f64], &mut [f64]),
    precond: &mut dyn FnMut(&[f64], &mut [f64]),
    b: &[f64],
    x: &mut [f64],
    rule: StopRule,
) -> SolveStats {
    pcg_floor(apply, precond, b, x, rule, f64::INFINITY)
}

/// [`pcg`] that also knows `ritz_floor`, the smallest Ritz value an earlier solve with the same
/// operator and preconditioner reached. Every Ritz value lies in the spectrum, so it is an upper
/// bound on `lambda_min` like the solve's own estimate, and the smaller of the two is used: a
/// warm-started solve that stops after a few iterations (whose own Lanczos tridiagonal is too
/// short to have found `lambda_min`) still bounds its error with the better estimate.
pub fn pcg_floor(
    apply: &mut dyn FnMut(&[f64], &mut [f64]),
    precond: &mut dyn FnMut(&[f64], &mut [f64]),
    b: &[f64],
    x: &mut [f64],
    rule: StopRule,
    ritz_floor: f64,
) -> SolveStats {
    let n = b.len();
    let mut r = vec![0.0; n];
    apply(x, &mut r);
    for (ri, bi) in r.iter_mut().zip(b) {
        *ri = bi - *ri;
    }
    let mut z = vec![0.0; n];
    precond(&r, &mut z);
    let mut p = z.clone();
    let mut q = vec![0.0; n];
    let mut rz = dot(&r, &z);
    let (mut td, mut te2) = (Vec::new(), Vec::new());
    let (mut prev_alpha, mut prev_beta) = (0.0f64, 0.0f64);
    let mut stats = SolveStats {
        iterations: 0,
        est_rel_error: f64::INFINITY,
        ritz_min: 1.0,
        ritz_max: 1.0,
        converged: false,
    };
    if b.iter().all(|&v| v == 0.0) {
        x.fill(0.0);
        stats.est_rel_error = 0.0;
        stats.converged = true;
        return stats;
    }
    for it in 0..rule.max_iter {
        if rz <= 0.0 {
            stats.est_rel_error = 0.0;
            stats.converged = true;
            break;
        }
        apply(&p, &mut q);
        let pq = dot(&p, &q);
        if pq <= 0.0 {
            break;
        }
        let alpha = rz / pq;
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
        }
        precond(&r, &mut z);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        // Lanczos tridiagonal of the preconditioned operator from the CG coefficients.
        td.push(1.0 / alpha + if it > 0 { prev_beta / prev_alpha } else { 0.0 });
        te2.push(beta / (alpha * alpha));
        prev_alpha = alpha;
        prev_beta = beta;
        stats.iterations = it + 1;
        if it < 64 || it % 8 == 0 {
            let (lo, hi) = tridiagonal_extremes(&td, &te2[..td.len() - 1]);
            stats.ritz_min = lo.min(ritz_floor).max(f64::MIN_POSITIVE);
            stats.ritz_max = hi;
        }
        let xb = dot(x, b);
        stats.est_rel_error = if xb > 0.0 {
            (rz_new.max(0.0) / (stats.ritz_min * xb)).sqrt()
        } else {
            f64::INFINITY
        };
        rz = rz_new;
        if stats.est_rel_error <= rule.rel_error {
            stats.converged = true;
            break;
        }
        for i in 0..n {
            p[i] = z[i] + beta * p[i];
        }
    }
    stats
}

/// The Jacobi preconditioner of a system: `z = r / diag`.
pub fn jacobi_diagonal(sys: &System<'_>) -> Vec<f64> {
    let mut d: Vec<f64> = sys.stencil.diag.iter().map(|&v| 1.0 / v).collect();
    if let Some(o) = sys.outlet {
        d.push(1.0 / o.total());
    }
    d
}

/// A preconditioner of the cell unknowns: `z = M^-1 r`.
pub(super) type CellPrecond<'a> = &'a mut dyn FnMut(&[f64], &mut [f64]);

/// PCG ([`pcg_floor`]) on `diag.len()` cells plus an optional outlet node after them: `cells`
/// applies the cell operator (diagonal `diag`), `precond` preconditions the cells (Jacobi when
/// `None`); the node is always Jacobi-scaled.
#[expect(
    clippy::too_many_arguments,
    reason = "the operator's parts and PCG's own arguments"
)]
pub(super) fn pcg_cells(
    diag: &[f64],
    cells: &dyn Fn(&[f64], &mut [f64]),
    outlet: Option<&OutletNode>,
    precond: Option<CellPrecond<'_>>,
    b: &[f64],
    x: &mut [f64],
    rule: StopRule,
    ritz_floor: f64,
) -> SolveStats {
    let n = diag.len();
    let mut apply = |v: &[f64], y: &mut [f64]| {
        cells(&v[..n], &mut y[..n]);
        if let Some(o) = outlet {
            o.apply(v, y, n);
        }
    };
    let mut jac: Vec<f64> = diag.iter().map(|&v| 1.0 / v).collect();
    if let Some(o) = outlet {
        jac.push(1.0 / o.total());
    }
    let mut precond = precond;
    let mut pc = |r: &[f64], z: &mut [f64]| {
        let from = match precond.as_mut() {
            Some(m) => {
                m(&r[..n], &mut z[..n]);
                n
            }
            None => 0,
        };
        for i in from..r.len() {
            z[i] = r[i] * jac[i];
        }
    };
    pcg_floor(&mut apply, &mut pc, b, x, rule, ritz_floor)
}
