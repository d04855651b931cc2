//! The transport model: state (iodine and fluid per cell, pressure), injections, punctures and
//! time stepping with the per-step ledger.
//!
//! # One step of length `dt`
//! Only the live cells take part (see [`super::window`]); they are solved and transported as a
//! compressed list ([`super::cells`]), not as the box around them.
//! 1. Pressure, backward Euler in the storage: `sum_j G_ij (p_i - p_j) + s_i p_i
//!    + C_i (p_i - p_i^n) / dt = Q_i`, where `C_i p_i^n` is the cell's current fluid excess over
//!    its pore volume, `s_i` its drains, and `Q_i` comes from the outlet node (see
//!    [`super::pressure`]).
//! 2. Face flows `F_ij = G_ij (p_i - p_j)`; each carries the upwind concentration. Diffusion moves
//!    `T_ij (c_i - c_j)` with the harmonic `phi D` transmissibility; clearance removes `k m_i`.
//!    Every exchange is subtracted from one cell and added to another (or to a ledger entry), so
//!    iodine is conserved to round-off whatever the solver's accuracy.
//! 3. Transport is sub-cycled under the step's flows (see [`super::transport`]): each substep lets
//!    every cell's outgoing transport (advective outflow, drains, all diffusive
//!    transmissibilities and clearance) take at most [`ModelConfig::cfl`] of its fluid volume;
//!    then the new concentration `m'/V'` is a convex combination of old concentrations and the
//!    injected one, so it stays in `[0, stock]`. A step that cannot keep the bound (a cell without
//!    fluid would lose some, NaN, too many substeps) is halved and repeated.
//!
//! # Step sizes and accuracy
//! The pressure step is at most [`ModelConfig::dt_max_s`]; the transport substeps are as long
//! as the bound allows. Measured on the benchmark's phantom injection (3 mL over 10 s at
//! L4-L5, 1 mm cells), as the relative L1 difference of the final iodine field from a reference
//! with 1/256 s steps: 0.33 % for the earlier scheme (one transport step per pressure solve,
//! 320 steps of 1/32 s at a bound of 0.9); with 0.25 s pressure steps, 0.82 % at a bound of 0.9,
//! 0.36 % at 0.3 and 0.28 % at 0.2 (the error is the forward-Euler error of the cells the
//! outlet flushes fastest, so it falls with the bound), and 0.23 % at 0.1.

use super::ContrastError;
use super::cells::{self, CellMultigrid, CellOp};
use super::grid::{ContrastGrid, Domain, Faces};
use super::ledger::Ledger;
use super::multigrid::Multigrid;
use super::outlet::{self, Injection, NeedleOutlet};
use super::pressure::{self, OutletNode, SolveStats, Stencil, StopRule, System};
use super::transport::{self, LiveSet};
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
    /// Largest fraction of a cell's fluid that may leave it in one transport substep (< 1).
    pub cfl: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            stop: StopRule::default(),
            preconditioner: Preconditioner::Multigrid,
            dt_max_s: 0.25,
            // 0.2 rather than the 0.9 positivity allows: accuracy (see "Step sizes and accuracy").
            cfl: 0.2,
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

/// The operator of one step size on one live set, with what the steps on it reuse.
#[derive(Debug, Clone)]
struct Cached {
    dt: f64,
    version: u64,
    window: Window,
    live: LiveSet,
    op: CellOp,
    /// The outlet node with contacts in live-cell indices.
    node: Option<OutletNode>,
    mg: Option<CellMultigrid>,
    /// Smallest Ritz value the solves on this operator have found (see `pressure::pcg_floor`).
    ritz_floor: f64,
}

/// Solver counters since creation.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SolverCounters {
    /// Accepted (pressure) steps.
    pub steps: u64,
    /// Transport substeps of the accepted steps (see `transport`'s sub-cycling).
    pub transport_substeps: u64,
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
    opened: Vec<(usize, usize)>,
    iodine: Vec<f64>,
    fluid: Vec<f64>,
    pore0: Vec<f64>,
    pressure: Vec<f64>,
    /// The pressure before the last accepted step, when that step and the one before it had the
    /// same operator (then the next solve on it starts from the linear extrapolation).
    pressure_prev: Option<Vec<f64>>,
    /// Operator version and step of the last accepted step.
    last_key: Option<(u64, f64)>,
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
            faces,
            opened: Vec::new(),
            iodine: vec![0.0; grid.len()],
            fluid: pore0.clone(),
            pressure: vec![0.0; grid.len()],
            pressure_prev: None,
            last_key: None,
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

    /// The pressure solve for a step of `dt` on the live cells (see [`super::window`]),
    /// warm-started from the last pressure: the cache slot of the operator and the pressures of
    /// its live cells (then the outlet node), or `None` when nothing is live.
    fn solve(&mut self, dt: f64) -> Option<(usize, Vec<f64>)> {
        let n = self.grid.len();
        let contacts = self
            .injection
            .iter()
            .flat_map(|r| r.node.contacts.iter().map(|c| c.0));
        let seeds = (0..n)
            .filter(|&i| self.iodine[i] != 0.0 || self.fluid[i] != self.pore0[i])
            .chain(contacts);
        let w = Window::of_seeds(&self.components, self.grid.grid.dims, seeds)?;
        // Operators (and multigrid hierarchies) of the last few step sizes and windows are kept:
        // steps are halved and doubled, so the same few recur.
        self.cache.retain(|c| c.version == self.version);
        let hit = self.cache.iter().position(|c| c.dt == dt && c.window == w);
        let slot = match hit {
            Some(i) => i,
            None => {
                let entry = self.build(dt, w);
                if self.cache.len() >= 4 {
                    self.cache.remove(0);
                }
                self.cache.push(entry);
                self.cache.len() - 1
            }
        };
        let b = self.rhs(&self.cache[slot].live.cells, dt);
        let cache = &mut self.cache[slot];
        let cells = &cache.live.cells;
        let mut x: Vec<f64> = cells
            .iter()
            .map(|&c| self.pressure.get(c).copied().unwrap_or(0.0))
            .collect();
        if self.injection.is_some() {
            x.push(self.pressure.get(n).copied().unwrap_or(0.0));
        }
        // Warm start: after two steps on this operator, extrapolate the pressure's trend (it
        // changes smoothly while an injection runs); the stop rule does not depend on the guess.
        if let Some(prev) = &self.pressure_prev
            && self.last_key == Some((self.version, dt))
            && prev.len() == self.pressure.len()
        {
            let full = cells
                .iter()
                .copied()
                .chain((x.len() > cells.len()).then_some(n));
            for (xk, c) in x.iter_mut().zip(full) {
                *xk += *xk - prev[c];
            }
        }
        let stats = cells::solve(
            &cache.op,
            cache.node.as_ref(),
            cache.mg.as_mut(),
            &b,
            &mut x,
            self.config.stop,
            cache.ritz_floor,
        );
        if stats.iterations > 0 {
            cache.ritz_floor = cache.ritz_floor.min(stats.ritz_min);
        }
        self.counters.solves += 1;
        self.counters.iterations += stats.iterations as u64;
        self.counters.last = Some(stats);
        Some((slot, x))
    }

    /// The right-hand side of a step of `dt` on `cells` (then the outlet node's rate, if any).
    fn rhs(&self, cells: &[usize], dt: f64) -> Vec<f64> {
        let mut b: Vec<f64> = cells
            .iter()
            .map(|&c| {
                if self.grid.props[c].compliance > 0.0 {
                    (self.fluid[c] - self.pore0[c]) / dt
                } else {
                    0.0
                }
            })
            .collect();
        if let Some(r) = &self.injection {
            b.push(r.rate_mm3_s);
        }
        b
    }

    /// The live cells of window `w`, their operator for steps of `dt` and its preconditioner.
    fn build(&self, dt: f64, w: Window) -> Cached {
        let vc = self.grid.grid.voxel_volume_mm3();
        let cells: Vec<usize> = w.live_cells(&self.components).collect();
        let live = LiveSet::new(&self.grid, &self.faces, cells);
        let cells = &live.cells;
        let node = self.injection.as_ref().map(|r| OutletNode {
            contacts: r
                .node
                .contacts
                .iter()
                .map(|&(c, g)| (cells.binary_search(&c).unwrap_or(0), g))
                .collect(),
        });
        let mut extra: Vec<f64> = cells
            .iter()
            .map(|&c| self.faces.sink[c] + self.grid.props[c].compliance * vc / dt)
            .collect();
        if let Some(o) = &node {
            for &(k, g) in &o.contacts {
                extra[k] += g;
            }
        }
        // Live cells couple only to live cells (components are closed under open faces).
        let op = CellOp::from_cells(
            self.grid.grid.dims,
            cells,
            |a, c| self.faces.conductance[a][c],
            |k| extra[k],
        );
        let mg = (self.config.preconditioner == Preconditioner::Multigrid)
            .then(|| CellMultigrid::new(&op));
        Cached {
            dt,
            version: self.version,
            window: w,
            live,
            op,
            node,
            mg,
            ritz_floor: f64::INFINITY,
        }
    }

    /// One step of `dt`, or `None` if it would break the step bound (nothing changed then).
    fn try_step(&mut self, dt: f64) -> Option<Ledger> {
        let t0 = std::time::Instant::now();
        let Some((slot, x)) = self.solve(dt) else {
            // Nothing live: everything is at rest.
            self.pressure = vec![0.0; self.grid.len()];
            return Some(Ledger::default());
        };
        let t1 = std::time::Instant::now();
        let cache = &self.cache[slot];
        let contacts = self
            .injection
            .as_ref()
            .zip(cache.node.as_ref())
            .map(|(r, o)| (o.contacts.as_slice(), r.stock_fraction));
        let out = transport::step(
            &cache.live,
            &x,
            contacts,
            self.config.cfl,
            dt,
            &mut self.iodine,
            &mut self.fluid,
        );
        self.counters.solve_seconds += (t1 - t0).as_secs_f64();
        self.counters.transport_seconds += t1.elapsed().as_secs_f64();
        let out = out?;
        let n = self.grid.len();
        let mut p = vec![0.0; n + usize::from(self.injection.is_some())];
        for (k, &c) in cache.live.cells.iter().enumerate() {
            p[c] = x[k];
        }
        if self.injection.is_some() {
            p[n] = x[cache.live.cells.len()];
        }
        let key = Some((self.version, dt));
        let before = std::mem::replace(&mut self.pressure, p);
        self.pressure_prev = (self.last_key == key).then_some(before);
        self.last_key = key;
        self.counters.transport_substeps += u64::from(out.substeps);
        // Grow the step again after one that was refused.
        self.dt_try = (2.0 * dt).min(self.config.dt_max_s);
        Some(out.ledger)
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
    let mut mg_apply = mg.map(|m| move |r: &[f64], z: &mut [f64]| m.apply(r, z));
    pressure::pcg_cells(
        &sys.stencil.diag,
        &|v, y| sys.stencil.apply(v, y),
        sys.outlet,
        mg_apply.as_mut().map(|f| f as pressure::CellPrecond<'_>),
        b,
        x,
        rule,
        f64::INFINITY,
    )
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contrast::{Agent, CellProps};
    use crate::volume::VolumeGrid;

    /// The warm-started, extrapolated solves with the carried Ritz floor still deliver the stop
    /// rule's relative energy-norm error (against a 1e-13 solve of the same system from zero).
    #[test]
    fn warm_started_solves_meet_the_stop_rule() {
        let vg = VolumeGrid {
            dims: [16, 8, 8],
            spacing_mm: [1.0; 3],
            origin_mm: [0.0; 3],
        };
        let mut grid =
            ContrastGrid::uniform(vg, Domain::Epidural, Domain::Epidural.default_props());
        // A slow, stiff layer across the channel: a harder operator than the uniform box.
        for k in 0..8 {
            for j in 0..8 {
                grid.props[vg.index(9, j, k)] = CellProps {
                    mobility: [0.001; 3],
                    ..Domain::Epidural.default_props()
                };
            }
        }
        let mut m = ContrastModel::new(grid, ModelConfig::default());
        let dose = Injection {
            agent: Agent::CONTRAST,
            volume_ml: 1.0,
            rate_ml_s: 0.05,
        };
        m.start_injection(
            &NeedleOutlet::tuohy([4.0, 3.5, 3.5], [1.0, 0.0, 0.0]),
            &dose,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let rule = m.config.stop;
        for step in 0..8 {
            m.advance(0.25).unwrap_or_else(|e| panic!("{e}"));
            let dt = m.config.dt_max_s;
            let Some((slot, x)) = m.solve(dt) else {
                panic!("nothing live")
            };
            let its = m.counters.last.map_or(0, |s| s.iterations);
            let c = &m.cache[slot];
            let b = m.rhs(&c.live.cells, dt);
            let mut reference = vec![0.0; b.len()];
            let tight = StopRule {
                rel_error: 1e-13,
                max_iter: 5000,
            };
            let mut mg = CellMultigrid::new(&c.op);
            cells::solve(
                &c.op,
                c.node.as_ref(),
                Some(&mut mg),
                &b,
                &mut reference,
                tight,
                f64::INFINITY,
            );
            let n = c.op.len();
            let energy = |v: &[f64]| {
                let mut y = vec![0.0; v.len()];
                c.op.apply(&v[..n], &mut y[..n]);
                if let Some(o) = &c.node {
                    o.apply(v, &mut y, n);
                }
                v.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>()
            };
            let e: Vec<f64> = x.iter().zip(&reference).map(|(a, b)| a - b).collect();
            let rel = (energy(&e) / energy(&reference)).sqrt();
            println!("step {step}: {its} iterations, relative energy error {rel:.2e}");
            assert!(
                rel <= rule.rel_error,
                "step {step}: {rel} after {its} iterations"
            );
        }
    }
}
