//! The explicit transport update of one pressure step: upwind advection on the solved face flows,
//! diffusion with the harmonic `phi D` transmissibility, drains, the outlet's inflow and
//! clearance, all as pairwise exchanges over the live cells only (see [`super::model`] for the
//! step bound).
//!
//! # Sub-cycling
//! The face flows of a pressure step are constant over it (the backward-Euler pressure holds for
//! the whole step), so the fluid update is linear in time, and the iodine update is split into
//! as many equal substeps as the bound needs: each substep lets at most [`super::ModelConfig::cfl`]
//! of any cell's current fluid leave it, so each keeps the concentration a convex combination of
//! the old ones and the injected one. The fluid at the end of the step is the same (to round-off)
//! as one unsplit update; only the iodine, which the bound protects, is advanced in pieces. A
//! step whose bound would need more than [`MAX_SUBSTEPS`] pieces is refused (and halved by the
//! model).

use super::grid::{ContrastGrid, Domain, Faces};
use super::ledger::Ledger;

/// Most transport substeps under one pressure step.
pub(super) const MAX_SUBSTEPS: u32 = 4096;

/// One open face between live cells (compressed indices, `a < b` in lattice order).
#[derive(Debug, Clone, PartialEq)]
struct Face {
    a: u32,
    b: u32,
    conductance: f64,
    transmissibility: f64,
}

/// The live cells (full-grid indices, ascending) and everything the update reads about them.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct LiveSet {
    pub(super) cells: Vec<usize>,
    /// Faces with a non-zero conductance or transmissibility, axis by axis, by lower cell.
    faces: Vec<Face>,
    sink: Vec<f64>,
    clearance: Vec<f64>,
    domain: Vec<u8>,
}

impl LiveSet {
    /// The live set of `cells` (ascending; every open face of a live cell joins two live cells).
    pub(super) fn new(g: &ContrastGrid, faces: &Faces, cells: Vec<usize>) -> LiveSet {
        let [nx, ny, _] = g.grid.dims;
        let strides = [1, nx, nx * ny];
        let mut list = Vec::new();
        for (a, &s) in strides.iter().enumerate() {
            let (gc, tc) = (&faces.conductance[a], &faces.transmissibility[a]);
            for (k, &c) in cells.iter().enumerate() {
                if gc[c] == 0.0 && tc[c] == 0.0 {
                    continue;
                }
                let b = cells
                    .binary_search(&(c + s))
                    .unwrap_or_else(|_| panic!("face of live cell {c} leaves the live cells"));
                list.push(Face {
                    a: k as u32,
                    b: b as u32,
                    conductance: gc[c],
                    transmissibility: tc[c],
                });
            }
        }
        LiveSet {
            sink: cells.iter().map(|&c| faces.sink[c]).collect(),
            clearance: cells.iter().map(|&c| g.props[c].clearance_per_s).collect(),
            domain: cells
                .iter()
                .map(|&c| g.domain[c].map_or(0, Domain::index) as u8)
                .collect(),
            faces: list,
            cells,
        }
    }
}

/// Result of an accepted step.
pub(super) struct StepOut {
    pub(super) ledger: Ledger,
    /// Transport substeps taken.
    pub(super) substeps: u32,
}

/// Applies one pressure step of `dt` with pressures `p` (live cells, then the outlet node if
/// any) to the full-grid `iodine` and `fluid`; `contacts` are the outlet's (live index,
/// conductance) and the injected stock fraction. `None` (and no change) if the bound cannot be
/// kept (a cell without fluid would lose some, NaN, or too many substeps).
pub(super) fn step(
    live: &LiveSet,
    p: &[f64],
    contacts: Option<(&[(usize, f64)], f64)>,
    cfl: f64,
    dt: f64,
    iodine: &mut [f64],
    fluid: &mut [f64],
) -> Option<StepOut> {
    let n = live.cells.len();
    let mut m: Vec<f64> = live.cells.iter().map(|&c| iodine[c]).collect();
    let mut v: Vec<f64> = live.cells.iter().map(|&c| fluid[c]).collect();
    let flow: Vec<f64> = live
        .faces
        .iter()
        .map(|f| f.conductance * (p[f.a as usize] - p[f.b as usize]))
        .collect();
    let sink_flow: Vec<f64> = (0..n).map(|k| live.sink[k] * p[k]).collect();
    let contact_flow: Vec<(usize, f64)> = contacts.map_or(Vec::new(), |(cs, _)| {
        cs.iter().map(|&(c, gk)| (c, gk * (p[n] - p[c]))).collect()
    });
    // Outgoing transport rate per cell (fluid-volume units per second), clearance aside: fixed
    // over the step, since the flows are.
    let mut out = vec![0.0; n];
    for (f, &q) in live.faces.iter().zip(&flow) {
        let (a, b) = (f.a as usize, f.b as usize);
        if q > 0.0 {
            out[a] += q;
        } else {
            out[b] -= q;
        }
        out[a] += f.transmissibility;
        out[b] += f.transmissibility;
    }
    for (k, o) in out.iter_mut().enumerate() {
        *o += live.sink[k] * p[k].max(0.0);
    }
    for &(c, f) in &contact_flow {
        if f < 0.0 {
            out[c] -= f;
        }
    }
    let stock = contacts.map_or(0.0, |c| c.1);
    let mut led = Ledger::default();
    let mut conc = vec![0.0; n];
    let mut substeps = 0u32;
    let mut left = dt;
    while left > 0.0 {
        // The largest outgoing rate per unit fluid.
        let mut worst: f64 = 0.0;
        for k in 0..n {
            let rate = out[k] + live.clearance[k] * v[k];
            if rate > 0.0 {
                // A cell without fluid cannot lose any (NaN fails this test too).
                if v[k].is_nan() || v[k] <= 0.0 {
                    return None;
                }
                worst = worst.max(rate / v[k]);
            }
        }
        // NaN (from a failed solve) rejects the step as well.
        if worst.is_nan() {
            return None;
        }
        let pieces = (left * worst / cfl).ceil().max(1.0);
        if substeps as f64 + pieces > MAX_SUBSTEPS as f64 {
            return None;
        }
        let mut h = if pieces <= 1.0 { left } else { left / pieces };
        if h * worst > cfl {
            h = left / (pieces + 1.0);
        }
        substep(
            live,
            &flow,
            &sink_flow,
            &contact_flow,
            stock,
            h,
            &mut m,
            &mut v,
            &mut conc,
            &mut led,
        );
        substeps += 1;
        left = if h >= left { 0.0 } else { left - h };
    }
    for (k, &c) in live.cells.iter().enumerate() {
        iodine[c] = m[k];
        fluid[c] = v[k];
    }
    Some(StepOut {
        ledger: led,
        substeps,
    })
}

/// One transport substep of `h` under the step's flows.
#[expect(
    clippy::too_many_arguments,
    reason = "the step's frozen flows and the state"
)]
fn substep(
    live: &LiveSet,
    flow: &[f64],
    sink_flow: &[f64],
    contact_flow: &[(usize, f64)],
    stock: f64,
    h: f64,
    m: &mut [f64],
    v: &mut [f64],
    conc: &mut [f64],
    led: &mut Ledger,
) {
    let dom = |k: usize| live.domain[k] as usize;
    for k in 0..m.len() {
        conc[k] = if v[k] > 0.0 { m[k] / v[k] } else { 0.0 };
        // Clearance of the iodine the substep starts with.
        let cleared = h * live.clearance[k] * m[k];
        m[k] -= cleared;
        led.cleared += cleared;
        led.cleared_by_domain[dom(k)] += cleared;
    }
    for (f, &q) in live.faces.iter().zip(flow) {
        let (a, b) = (f.a as usize, f.b as usize);
        let upwind = if q > 0.0 { conc[a] } else { conc[b] };
        // Iodine moved from a to b: advection plus diffusion.
        let moved = h * (q * upwind + f.transmissibility * (conc[a] - conc[b]));
        m[a] -= moved;
        m[b] += moved;
        v[a] -= h * q;
        v[b] += h * q;
        let (da, db) = (dom(a), dom(b));
        if da != db {
            led.exchanged[da][db] += moved;
            led.exchanged[db][da] -= moved;
        }
    }
    for (k, &f) in sink_flow.iter().enumerate() {
        if f != 0.0 {
            // Outflow carries the cell's iodine; inflow from a drain is plain fluid.
            let moved = if f > 0.0 { h * f * conc[k] } else { 0.0 };
            m[k] -= moved;
            v[k] -= h * f;
            led.escaped += moved;
            led.escaped_by_domain[dom(k)] += moved;
            led.fluid_escaped_mm3 += h * f;
        }
    }
    for &(c, f) in contact_flow {
        if f >= 0.0 {
            let moved = h * f * stock;
            m[c] += moved;
            led.injected += moved;
            led.injected_by_domain[dom(c)] += moved;
            led.fluid_injected_mm3 += h * f;
        } else {
            // Backflow into the needle leaves the tissue.
            let moved = -h * f * conc[c];
            m[c] -= moved;
            led.escaped += moved;
            led.escaped_by_domain[dom(c)] += moved;
            led.fluid_escaped_mm3 -= h * f;
        }
        v[c] += h * f;
    }
    // Round-off can leave -1e-20 where a cell was emptied exactly; the bound guarantees the exact
    // value is >= 0, so clamp those (and book the difference as cleared to keep the balance).
    for (k, x) in m.iter_mut().enumerate() {
        if *x < 0.0 {
            led.cleared += *x;
            led.cleared_by_domain[dom(k)] += *x;
            *x = 0.0;
        }
    }
}
