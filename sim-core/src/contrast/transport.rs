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

#[cfg(test)]
mod tests {
    use super::{LiveSet, step};
    use crate::contrast::grid::{CellProps, ContrastGrid, Domain, Faces};
    use crate::volume::VolumeGrid;

    /// The face-law probe of the integration tests (two 1 mm cubes, `phi D` of 0.2 and
    /// 0.05 mm^2/s, so the harmonic transmissibility is 0.08 mm^3/s) at concentrations 1 and 0
    /// with no flow: one 0.1 s step moves 0.08 * 0.1 * (1 - 0) = 0.008 mm^3 of stock-equivalent
    /// iodine, in one substep (the fastest cell loses 0.08 / 0.2 = 0.4 of its fluid's worth per
    /// second, 0.04 over the step, under the bound of 0.2). The reference's min-based law would
    /// move 0.001. Exact up to a few roundings (1e-15).
    #[test]
    fn the_harmonic_transmissibility_drives_the_diffusive_flux() {
        let grid = VolumeGrid {
            dims: [2, 1, 1],
            spacing_mm: [1.0; 3],
            origin_mm: [0.0; 3],
        };
        let props = CellProps {
            porosity: 1.0,
            mobility: [1.0; 3],
            diffusivity: 0.05,
            clearance_per_s: 0.0,
            compliance: 0.0,
        };
        let mut g = ContrastGrid::uniform(grid, Domain::Epidural, props);
        g.open_at_crop = [false; Domain::COUNT];
        g.props[0].porosity = 0.2;
        g.props[0].diffusivity = 1.0;
        let faces = Faces::new(&g, &[]);
        assert!((faces.transmissibility[0][0] - 0.08).abs() < 1e-15);
        let live = LiveSet::new(&g, &faces, vec![0, 1]);
        // Pore fluid of each cell (porosity times 1 mm^3) at concentrations 1 and 0.
        let mut fluid = vec![0.2, 1.0];
        let mut iodine = vec![0.2, 0.0];
        let out = step(&live, &[0.0, 0.0], None, 0.2, 0.1, &mut iodine, &mut fluid)
            .expect("the step keeps the bound");
        assert_eq!(out.substeps, 1);
        assert!((iodine[1] - 0.008).abs() < 1e-15, "{iodine:?}");
        assert!((iodine[0] - 0.192).abs() < 1e-15, "{iodine:?}");
        assert_eq!(fluid, vec![0.2, 1.0], "no flow moves no fluid");
    }
}
