//! The explicit transport update of one step: upwind advection on the solved face flows,
//! diffusion with the harmonic `phi D` transmissibility, drains, the outlet's inflow and
//! clearance, all as pairwise exchanges (see [`super::model`] for the step bound).

use super::grid::{ContrastGrid, Domain, Faces};
use super::ledger::Ledger;
use super::model::ContrastModel;

/// What the update reads from the model.
pub(super) struct Parts<'a> {
    pub(super) grid: &'a ContrastGrid,
    pub(super) faces: &'a Faces,
    pub(super) iodine: &'a [f64],
    pub(super) fluid: &'a [f64],
    /// The cells of the live components (nothing else can change).
    pub(super) live: Vec<usize>,
    /// Outlet contacts and the injected stock fraction.
    pub(super) contacts: Option<(&'a [(usize, f64)], f64)>,
    pub(super) cfl: f64,
}

/// Result of an accepted step.
pub(super) struct StepOut {
    pub(super) ledger: Ledger,
    /// Largest outgoing-transport-to-fluid ratio over the cells.
    pub(super) max_ratio: f64,
}

/// Applies one step of `dt` with pressures `p` (cells, then the outlet node if any); `None`
/// (and no change) if some cell would lose more than the bound allows.
pub(super) fn step(model: &mut ContrastModel, p: &[f64], dt: f64) -> Option<StepOut> {
    let parts = model.parts();
    let g = parts.grid;
    let n = g.len();
    let [nx, ny, _] = g.grid.dims;
    let strides = [1, nx, nx * ny];
    let mut conc = vec![0.0; n];
    for &i in &parts.live {
        if parts.fluid[i] > 0.0 {
            conc[i] = parts.iodine[i] / parts.fluid[i];
        }
    }
    // Outgoing transport rate per cell (fluid-volume units per second).
    let mut out_rate = vec![0.0; n];
    for (a, &s) in strides.iter().enumerate() {
        let gc = &parts.faces.conductance[a];
        let tc = &parts.faces.transmissibility[a];
        for &c in &parts.live {
            if gc[c] == 0.0 && tc[c] == 0.0 {
                continue;
            }
            let f = gc[c] * (p[c] - p[c + s]);
            if f > 0.0 {
                out_rate[c] += f;
            } else {
                out_rate[c + s] -= f;
            }
            out_rate[c] += tc[c];
            out_rate[c + s] += tc[c];
        }
    }
    for &c in &parts.live {
        out_rate[c] +=
            parts.faces.sink[c] * p[c].max(0.0) + g.props[c].clearance_per_s * parts.fluid[c];
    }
    if let Some((contacts, _)) = parts.contacts {
        let pn = p[n];
        for &(c, gk) in contacts {
            let f = gk * (pn - p[c]);
            if f < 0.0 {
                out_rate[c] -= f;
            }
        }
    }
    let mut max_ratio: f64 = 0.0;
    for (&rate, &fl) in out_rate.iter().zip(parts.fluid) {
        if rate > 0.0 {
            // A cell without fluid cannot lose any (NaN fails this test too).
            if fl.is_nan() || fl <= 0.0 {
                return None;
            }
            max_ratio = max_ratio.max(dt * rate / fl);
        }
    }
    // NaN (from a failed solve) rejects the step as well.
    if max_ratio.is_nan() || max_ratio > parts.cfl {
        return None;
    }
    let mut led = Ledger::default();
    let mut iodine = parts.iodine.to_vec();
    let mut fluid = parts.fluid.to_vec();
    let dom = |c: usize| g.domain[c].map_or(0, Domain::index);
    for (a, &s) in strides.iter().enumerate() {
        let gc = &parts.faces.conductance[a];
        let tc = &parts.faces.transmissibility[a];
        for &c in &parts.live {
            if gc[c] == 0.0 && tc[c] == 0.0 {
                continue;
            }
            let nb = c + s;
            let f = gc[c] * (p[c] - p[nb]);
            let upwind = if f > 0.0 { conc[c] } else { conc[nb] };
            // Iodine moved from c to nb: advection plus diffusion.
            let m = dt * (f * upwind + tc[c] * (conc[c] - conc[nb]));
            iodine[c] -= m;
            iodine[nb] += m;
            fluid[c] -= dt * f;
            fluid[nb] += dt * f;
            let (dc, dn) = (dom(c), dom(nb));
            if dc != dn {
                led.exchanged[dc][dn] += m;
                led.exchanged[dn][dc] -= m;
            }
        }
    }
    for &c in &parts.live {
        let f = parts.faces.sink[c] * p[c];
        if f != 0.0 {
            // Outflow carries the cell's iodine; inflow from a drain is plain fluid.
            let m = if f > 0.0 { dt * f * conc[c] } else { 0.0 };
            iodine[c] -= m;
            fluid[c] -= dt * f;
            led.escaped += m;
            led.escaped_by_domain[dom(c)] += m;
            led.fluid_escaped_mm3 += dt * f;
        }
        let cleared = dt * g.props[c].clearance_per_s * parts.iodine[c];
        iodine[c] -= cleared;
        led.cleared += cleared;
        led.cleared_by_domain[dom(c)] += cleared;
    }
    if let Some((contacts, stock)) = parts.contacts {
        let pn = p[n];
        for &(c, gk) in contacts {
            let f = gk * (pn - p[c]);
            if f >= 0.0 {
                let m = dt * f * stock;
                iodine[c] += m;
                led.injected += m;
                led.injected_by_domain[dom(c)] += m;
                led.fluid_injected_mm3 += dt * f;
            } else {
                // Backflow into the needle leaves the tissue.
                let m = -dt * f * conc[c];
                iodine[c] -= m;
                led.escaped += m;
                led.escaped_by_domain[dom(c)] += m;
                led.fluid_escaped_mm3 -= dt * f;
            }
            fluid[c] += dt * f;
        }
    }
    // Round-off can leave -1e-20 where a cell was emptied exactly; the bound guarantees the exact
    // value is >= 0, so clamp those (and book the difference as cleared to keep the balance).
    for (c, m) in iodine.iter_mut().enumerate() {
        if *m < 0.0 {
            led.cleared += *m;
            led.cleared_by_domain[dom(c)] += *m;
            *m = 0.0;
        }
    }
    model.commit(iodine, fluid);
    Some(StepOut {
        ledger: led,
        max_ratio,
    })
}
