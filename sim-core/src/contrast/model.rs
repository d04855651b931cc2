//! The transport model: state (iodine and fluid per cell, pressure), injections, punctures and
//! time stepping with the per-step ledger.
//!
//! # One step of length `dt`
//! 1. Pressure, backward Euler in the storage: `sum_j G_ij (p_i - p_j) + s_i p_i
//!    + C_i (p_i - p_i^n) / dt = Q_i`, where `C_i p_i^n` is the cell's current fluid excess over
//!    its pore volume, `s_i` its drains, and `Q_i` comes from the outlet node (see
//!    [`super::pressure`]).
//! 2. Face flows `F_ij = G_ij (p_i - p_j)`; each carries the upwind concentration. Diffusion moves
//!    `T_ij (c_i - c_j)` with the harmonic `phi D` transmissibility; clearance removes `k m_i`.
//!    Every exchange is subtracted from one cell and added to another (or to a ledger entry), so
//!    iodine is conserved to round-off whatever the solver's accuracy.
//! 3. The step is accepted only if every cell's outgoing transport (advective outflow, drains,
//!    all diffusive transmissibilities and clearance) over `dt` is at most [`ModelConfig::cfl`] of
//!    its fluid volume; then the new concentration `m'/V'` is a convex combination of old
//!    concentrations and the injected one, so it stays in `[0, stock]`. Otherwise `dt` is halved
//!    and the step repeated.

use super::ContrastError;
use super::grid::{ContrastGrid, Domain, Faces};
use super::ledger::Ledger;
use super::multigrid::Multigrid;
use super::outlet::{self, Injection, NeedleOutlet};
use super::pressure::{self, OutletNode, SolveStats, Stencil, StopRule, System};
use super::window::{Components, Window};
use crate::volume::Volume;

/// Which preconditioner the pressure solve uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Preconditioner {
    /// Diagonal scaling (the baseline).
    Jacobi,
    /// The symmetric W-cycle of [`Multigrid`].
    Multigrid,
}

/// Numerical settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelConfig {
    /// Pressure stop rule.
    pub stop: StopRule,
    /// Preconditioner.
    pub preconditioner: Preconditioner,
    /// Largest step, s.
    pub dt_max_s: f64,
    /// Largest fraction of a cell's fluid that may leave it in one step (< 1).
    pub cfl: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            stop: StopRule::default(),
            preconditioner: Preconditioner::Multigrid,
            dt_max_s: 0.25,
            cfl: 0.9,
        }
    }
}

/// An injection under way.
#[derive(Debug, Clone, PartialEq)]
struct Running {
    node: OutletNode,
    rate_mm3_s: f64,
    remaining_mm3: f64,
    stock_fraction: f64,
}

#[derive(Debug, Clone)]
struct Cached {
    dt: f64,
    version: u64,
    window: Window,
    stencil: Stencil,
    /// The outlet node with contacts in window indices.
    node: Option<OutletNode>,
    mg: Option<Multigrid>,
}

/// Solver counters since creation.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SolverCounters {
    /// Accepted steps.
    pub steps: u64,
    /// Rejected (halved) steps.
    pub rejected: u64,
    /// Pressure solves.
    pub solves: u64,
    /// PCG iterations over all solves.
    pub iterations: u64,
    /// The last solve.
    pub last: Option<SolveStats>,
    /// Wall time in pressure solves (setup included), s (timing only; never feeds results).
    pub solve_seconds: f64,
    /// Wall time in transport updates, s (timing only).
    pub transport_seconds: f64,
}

/// What one call of [`ContrastModel::advance`] did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepReport {
    /// Simulated time advanced, s.
    pub dt_s: f64,
    /// Substeps taken.
    pub substeps: u32,
    /// The ledger of this call.
    pub ledger: Ledger,
}

/// The contrast transport state on one grid.
#[derive(Debug, Clone)]
pub struct ContrastModel {
    grid: ContrastGrid,
    faces: Faces,
    components: Components,
    window: Option<Window>,
    opened: Vec<(usize, usize)>,
    iodine: Vec<f64>,
    fluid: Vec<f64>,
    pore0: Vec<f64>,
    pressure: Vec<f64>,
    injection: Option<Running>,
    ledger: Ledger,
    time_s: f64,
    dt_try: f64,
    version: u64,
    cache: Vec<Cached>,
    /// Numerical settings.
    pub config: ModelConfig,
    /// Solver counters.
    pub counters: SolverCounters,
}

impl ContrastModel {
    /// A model on `grid`, empty of contrast, at rest.
    pub fn new(grid: ContrastGrid, config: ModelConfig) -> ContrastModel {
        let faces = Faces::new(&grid, &[]);
        let pore0: Vec<f64> = (0..grid.len()).map(|i| grid.pore_volume_mm3(i)).collect();
        ContrastModel {
            components: Components::new(&grid, &faces),
            window: None,
            faces,
            opened: Vec::new(),
            iodine: vec![0.0; grid.len()],
            fluid: pore0.clone(),
            pressure: vec![0.0; grid.len()],
            pore0,
            grid,
            injection: None,
            ledger: Ledger::default(),
            time_s: 0.0,
            dt_try: config.dt_max_s,
            version: 0,
            cache: Vec::new(),
            config,
            counters: SolverCounters::default(),
        }
    }

    /// The grid.
    pub fn grid(&self) -> &ContrastGrid {
        &self.grid
    }

    /// Simulated time, s.
    pub fn time_s(&self) -> f64 {
        self.time_s
    }

    /// Totals since creation.
    pub fn ledger(&self) -> &Ledger {
        &self.ledger
    }

    /// Iodine per cell, stock-equivalent mm^3.
    pub fn iodine_mm3(&self) -> &[f64] {
        &self.iodine
    }

    /// Pore fluid per cell, mm^3.
    pub fn fluid_mm3(&self) -> &[f64] {
        &self.fluid
    }

    /// Pressure per cell from the last solve (uncalibrated potential).
    pub fn pressure(&self) -> &[f64] {
        &self.pressure[..self.grid.len()]
    }

    /// Iodine in the grid, stock-equivalent mm^3.
    pub fn retained_mm3(&self) -> f64 {
        self.iodine.iter().sum()
    }

    /// Pore-fluid concentration of cell `i` as a stock fraction (0 for solid cells).
    pub fn concentration(&self, i: usize) -> f64 {
        if self.fluid[i] > 0.0 {
            self.iodine[i] / self.fluid[i]
        } else {
            0.0
        }
    }

    /// Whole-voxel stock-equivalent density (iodine / cell volume) on the model grid: what the
    /// fluoroscopy renderers integrate (wrap it in `sim_core::fluoro::IodineField`).
    pub fn density_stock(&self) -> Volume<f32> {
        let vc = self.grid.grid.voxel_volume_mm3();
        Volume {
            grid: self.grid.grid,
            data: self.iodine.iter().map(|m| (m / vc) as f32).collect(),
        }
    }

    /// Whether an injection is under way.
    pub fn injecting(&self) -> bool {
        self.injection.is_some()
    }

    /// Volume still to inject, mL.
    pub fn remaining_ml(&self) -> f64 {
        self.injection
            .as_ref()
            .map_or(0.0, |r| r.remaining_mm3 / 1000.0)
    }

    /// Starts an injection through `outlet` (replacing one under way; what it delivered stays).
    pub fn start_injection(
        &mut self,
        outlet: &NeedleOutlet,
        injection: &Injection,
    ) -> Result<(), ContrastError> {
        injection.validate()?;
        let node = outlet::route(&self.grid, outlet)?;
        self.injection = Some(Running {
            node,
            rate_mm3_s: injection.rate_ml_s * 1000.0,
            remaining_mm3: injection.volume_ml * 1000.0,
            stock_fraction: injection.agent.stock_fraction(),
        });
        self.version += 1;
        self.pressure.truncate(self.grid.len());
        Ok(())
    }

    /// Stops the injection under way.
    pub fn stop_injection(&mut self) {
        if self.injection.take().is_some() {
            self.version += 1;
            self.pressure.truncate(self.grid.len());
        }
    }

    /// A dural puncture along the needle's last `depth_mm`: opens the epidural-subdural-intrathecal
    /// faces on its path for good. Returns how many faces it opened.
    pub fn puncture(
        &mut self,
        outlet: &NeedleOutlet,
        depth_mm: f64,
    ) -> Result<usize, ContrastError> {
        outlet.validate()?;
        outlet::check_range("puncture.depth_mm", depth_mm, 0.0, 200.0, "mm")?;
        let mut added = 0;
        for f in outlet::puncture_faces(&self.grid, outlet, depth_mm) {
            if !self.opened.contains(&f) {
                self.opened.push(f);
                added += 1;
            }
        }
        if added > 0 {
            self.faces = Faces::new(&self.grid, &self.opened);
            self.components = Components::new(&self.grid, &self.faces);
            self.version += 1;
        }
        Ok(added)
    }

    /// Advances by `dt_s` seconds in as many substeps as the step bound needs.
    pub fn advance(&mut self, dt_s: f64) -> Result<StepReport, ContrastError> {
        if !(dt_s.is_finite() && (0.0..=3600.0).contains(&dt_s)) {
            return Err(ContrastError::OutOfRange {
                field: "dt_s",
                value: dt_s,
                min: 0.0,
                max: 3600.0,
                unit: "s",
            });
        }
        let mut report = StepReport::default();
        let mut left = dt_s;
        while left > 0.0 {
            let mut dt = self.dt_try.min(left);
            if let Some(r) = &self.injection {
                dt = dt.min(r.remaining_mm3 / r.rate_mm3_s);
            }
            let ledger = loop {
                if let Some(l) = self.try_step(dt) {
                    break l;
                }
                self.counters.rejected += 1;
                dt *= 0.5;
                self.dt_try = dt;
            };
            self.counters.steps += 1;
            report.ledger.add(&ledger);
            report.substeps += 1;
            report.dt_s += dt;
            self.time_s += dt;
            self.ledger.add(&ledger);
            if let Some(r) = &mut self.injection {
                r.remaining_mm3 -= r.rate_mm3_s * dt;
                if r.remaining_mm3 <= 1e-9 * r.rate_mm3_s {
                    self.stop_injection();
                }
            }
            left = if dt >= left { 0.0 } else { left - dt };
        }
        Ok(report)
    }

    /// The pressure solve for a step of `dt` on the live window (see [`super::window`]),
    /// warm-started from the last pressure; zero outside the window.
    fn solve(&mut self, dt: f64) -> Vec<f64> {
        let n = self.grid.len();
        let node_len = usize::from(self.injection.is_some());
        let contacts = self
            .injection
            .iter()
            .flat_map(|r| r.node.contacts.iter().map(|c| c.0));
        let seeds = (0..n)
            .filter(|&i| self.iodine[i] != 0.0 || self.fluid[i] != self.pore0[i])
            .chain(contacts);
        self.window = Window::of_seeds(&self.components, self.grid.grid.dims, seeds);
        let Some(w) = self.window.clone() else {
            return vec![0.0; n + node_len];
        };
        let wd = w.dims();
        let wn = wd[0] * wd[1] * wd[2];
        let to_window = |c: usize| -> usize {
            let [i, j, k] = self.grid.grid.ijk(c);
            (i - w.lo[0]) + wd[0] * ((j - w.lo[1]) + wd[1] * (k - w.lo[2]))
        };
        // Operators (and multigrid hierarchies) of the last few step sizes and windows are kept:
        // steps are halved and doubled, so the same few recur.
        self.cache.retain(|c| c.version == self.version);
        let hit = self.cache.iter().position(|c| c.dt == dt && c.window == w);
        let slot = match hit {
            Some(i) => i,
            None => {
                let vc = self.grid.grid.voxel_volume_mm3();
                let mut extra = vec![0.0; wn];
                let mut active = vec![false; wn];
                let mut off = [vec![0.0; wn], vec![0.0; wn], vec![0.0; wn]];
                for k in 0..wd[2] {
                    for j in 0..wd[1] {
                        for i in 0..wd[0] {
                            let c = w.full_index(i, j, k);
                            if !w.is_live(&self.components, c) {
                                continue;
                            }
                            let wi = i + wd[0] * (j + wd[1] * k);
                            active[wi] = true;
                            extra[wi] =
                                self.faces.sink[c] + self.grid.props[c].compliance * vc / dt;
                            let ijk = [i, j, k];
                            for a in 0..3 {
                                // Live cells couple only to live cells, all inside the window.
                                if ijk[a] + 1 < wd[a] {
                                    off[a][wi] = self.faces.conductance[a][c];
                                } else {
                                    debug_assert!(self.faces.conductance[a][c] == 0.0);
                                }
                            }
                        }
                    }
                }
                let node = self.injection.as_ref().map(|r| OutletNode {
                    contacts: r
                        .node
                        .contacts
                        .iter()
                        .map(|&(c, g)| (to_window(c), g))
                        .collect(),
                });
                if let Some(o) = &node {
                    for &(c, g) in &o.contacts {
                        extra[c] += g;
                    }
                }
                let stencil = Stencil::from_couplings(wd, off, &extra, active);
                let mg = (self.config.preconditioner == Preconditioner::Multigrid)
                    .then(|| Multigrid::new(&stencil));
                if self.cache.len() >= 4 {
                    self.cache.remove(0);
                }
                self.cache.push(Cached {
                    dt,
                    version: self.version,
                    window: w.clone(),
                    stencil,
                    node,
                    mg,
                });
                self.cache.len() - 1
            }
        };
        let cache = &mut self.cache[slot];
        let sys = System {
            stencil: &cache.stencil,
            outlet: cache.node.as_ref(),
        };
        let mut b = vec![0.0; wn];
        let mut x = vec![0.0; wn];
        for k in 0..wd[2] {
            for j in 0..wd[1] {
                for i in 0..wd[0] {
                    let c = w.full_index(i, j, k);
                    if !cache.stencil.active[i + wd[0] * (j + wd[1] * k)] {
                        continue;
                    }
                    let wi = i + wd[0] * (j + wd[1] * k);
                    if self.grid.props[c].compliance > 0.0 {
                        b[wi] = (self.fluid[c] - self.pore0[c]) / dt;
                    }
                    x[wi] = self.pressure.get(c).copied().unwrap_or(0.0);
                }
            }
        }
        if let Some(r) = &self.injection {
            b.push(r.rate_mm3_s);
            x.push(self.pressure.get(n).copied().unwrap_or(0.0));
        }
        let stats = solve_system(&sys, cache.mg.as_mut(), &b, &mut x, self.config.stop);
        self.counters.solves += 1;
        self.counters.iterations += stats.iterations as u64;
        self.counters.last = Some(stats);
        let mut p = vec![0.0; n + node_len];
        for k in 0..wd[2] {
            for j in 0..wd[1] {
                for i in 0..wd[0] {
                    p[w.full_index(i, j, k)] = x[i + wd[0] * (j + wd[1] * k)];
                }
            }
        }
        if node_len == 1 {
            p[n] = x[wn];
        }
        p
    }

    /// One step of `dt`, or `None` if it would break the step bound (nothing changed then).
    fn try_step(&mut self, dt: f64) -> Option<Ledger> {
        let t0 = std::time::Instant::now();
        let p = self.solve(dt);
        let t1 = std::time::Instant::now();
        let out = super::transport::step(self, &p, dt);
        self.counters.solve_seconds += (t1 - t0).as_secs_f64();
        self.counters.transport_seconds += t1.elapsed().as_secs_f64();
        let out = out?;
        self.pressure = p;
        // Grow the step again once it is comfortably inside the bound.
        if out.max_ratio < 0.25 * self.config.cfl {
            self.dt_try = (2.0 * dt).min(self.config.dt_max_s);
        }
        Some(out.ledger)
    }

    pub(super) fn parts(&self) -> super::transport::Parts<'_> {
        super::transport::Parts {
            grid: &self.grid,
            faces: &self.faces,
            iodine: &self.iodine,
            fluid: &self.fluid,
            live: self
                .window
                .as_ref()
                .map(|w| w.live_cells(&self.components).collect())
                .unwrap_or_default(),
            contacts: self
                .injection
                .as_ref()
                .map(|r| (r.node.contacts.as_slice(), r.stock_fraction)),
            cfl: self.config.cfl,
        }
    }

    pub(super) fn commit(&mut self, iodine: Vec<f64>, fluid: Vec<f64>) {
        self.iodine = iodine;
        self.fluid = fluid;
    }

    /// Retained iodine per domain, stock-equivalent mm^3.
    pub fn retained_by_domain(&self) -> [f64; Domain::COUNT] {
        let mut out = [0.0; Domain::COUNT];
        for (m, d) in self.iodine.iter().zip(&self.grid.domain) {
            if let Some(d) = d {
                out[d.index()] += m;
            }
        }
        out
    }
}

/// Solves `sys x = b` by PCG from the guess in `x` with the multigrid (if given, on the cells;
/// Jacobi on the outlet node) or Jacobi.
pub fn solve_system(
    sys: &System<'_>,
    mg: Option<&mut Multigrid>,
    b: &[f64],
    x: &mut [f64],
    rule: StopRule,
) -> SolveStats {
    let n = sys.stencil.len();
    let jac = pressure::jacobi_diagonal(sys);
    let mut apply = |v: &[f64], y: &mut [f64]| sys.apply(v, y);
    match mg {
        Some(mg) => {
            let mut pc = |r: &[f64], z: &mut [f64]| {
                mg.apply(&r[..n], &mut z[..n]);
                for i in n..r.len() {
                    z[i] = r[i] * jac[i];
                }
            };
            pressure::pcg(&mut apply, &mut pc, b, x, rule)
        }
        None => {
            let mut pc = |r: &[f64], z: &mut [f64]| {
                for i in 0..r.len() {
                    z[i] = r[i] * jac[i];
                }
            };
            pressure::pcg(&mut apply, &mut pc, b, x, rule)
        }
    }
}

/// Steady pressure with drains only (no storage, no outlet): `sum_j G_ij (p_i - p_j) + s_i p_i =
/// q_i`, where `q` is in mm^3/s per cell. For tests and benchmarks of the solver.
pub fn steady_pressure(
    grid: &ContrastGrid,
    q: &[f64],
    preconditioner: Preconditioner,
    rule: StopRule,
) -> (Vec<f64>, SolveStats) {
    let faces = Faces::new(grid, &[]);
    let stencil = steady_stencil(grid, &faces);
    let mut mg = (preconditioner == Preconditioner::Multigrid).then(|| Multigrid::new(&stencil));
    let sys = System {
        stencil: &stencil,
        outlet: None,
    };
    let mut x = vec![0.0; q.len()];
    let stats = solve_system(&sys, mg.as_mut(), q, &mut x, rule);
    (x, stats)
}

/// The steady operator of a grid (face conductances plus drains).
pub fn steady_stencil(grid: &ContrastGrid, faces: &Faces) -> Stencil {
    Stencil::from_couplings(
        grid.grid.dims,
        faces.conductance.clone(),
        &faces.sink,
        grid.domain.iter().map(Option::is_some).collect(),
    )
}
