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
    // A failed solve (NaN or infinite pressure) rejects the step before anything moves.
    if p.iter().any(|x| !x.is_finite()) {
        return None;
    }
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
            // A NaN rate (NaN fluid) rejects the step: `f64::max` below would skip it and the
            // substep would spread it.
            if rate.is_nan() {
                return None;
            }
            if rate > 0.0 {
                // A cell without fluid cannot lose any.
                if v[k] <= 0.0 {
                    return None;
                }
                worst = worst.max(rate / v[k]);
            }
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
    use super::{Face, LiveSet, MAX_SUBSTEPS, StepOut, step};
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

    /// A hand-made live set of `case`: faces `(a, b, conductance, transmissibility)`, one sink,
    /// clearance and domain index per cell.
    fn live_set(case: &Case) -> LiveSet {
        let Case {
            n,
            faces,
            sink,
            clearance,
            domain,
            ..
        } = case;
        LiveSet {
            cells: (0..*n).collect(),
            faces: faces
                .iter()
                .map(|&(a, b, g, t)| Face {
                    a,
                    b,
                    conductance: g,
                    transmissibility: t,
                })
                .collect(),
            sink: sink.to_vec(),
            clearance: clearance.to_vec(),
            domain: domain.clone(),
        }
    }

    /// One scene for [`step`] and for the reference below.
    struct Case {
        n: usize,
        faces: Vec<(u32, u32, f64, f64)>,
        sink: Vec<f64>,
        clearance: Vec<f64>,
        /// Domain index of each cell (for the per-domain ledger).
        domain: Vec<u8>,
        /// Outlet contacts (cell, conductance) and the stock fraction; the outlet's pressure is
        /// the last entry of `p`.
        contacts: Option<(Vec<(usize, f64)>, f64)>,
        p: Vec<f64>,
        fluid: Vec<f64>,
        iodine: Vec<f64>,
        cfl: f64,
        dt: f64,
    }

    impl Case {
        fn run(&self) -> (Option<StepOut>, Vec<f64>, Vec<f64>) {
            let live = live_set(self);
            let (mut iodine, mut fluid) = (self.iodine.clone(), self.fluid.clone());
            let contacts = self.contacts.as_ref().map(|(c, s)| (c.as_slice(), *s));
            let out = step(
                &live,
                &self.p,
                contacts,
                self.cfl,
                self.dt,
                &mut iodine,
                &mut fluid,
            );
            (out, iodine, fluid)
        }

        /// What leaves each cell for each other cell and out of the live set (last column),
        /// per second, built as a dense matrix (advection on the face flow `G (p_i - p_j)` out
        /// of the upstream cell, diffusion `T` out of both, the outflowing part of a drain,
        /// backflow into the outlet), and each cell's net fluid gain, mm^3/s.
        fn rates(&self) -> (Vec<Vec<f64>>, Vec<f64>) {
            let n = self.n;
            let mut leaving = vec![vec![0.0f64; n + 1]; n];
            let mut net = vec![0.0f64; n];
            for &(a, b, g, t) in &self.faces {
                let (a, b) = (a as usize, b as usize);
                let q_ab = g * (self.p[a] - self.p[b]);
                leaving[a][b] += q_ab.max(0.0) + t;
                leaving[b][a] += (-q_ab).max(0.0) + t;
                net[a] -= q_ab;
                net[b] += q_ab;
            }
            for k in 0..n {
                let drain = self.sink[k] * self.p[k];
                // Column n: out of the live set (drain or needle).
                leaving[k][n] += drain.max(0.0);
                net[k] -= drain;
            }
            if let Some((contacts, _)) = &self.contacts {
                for &(c, g) in contacts {
                    let inflow = g * (self.p[n] - self.p[c]);
                    leaving[c][n] += (-inflow).max(0.0);
                    net[c] += inflow;
                }
            }
            (leaving, net)
        }

        /// The substep count that the documented bound asks for, from the rates of
        /// [`Case::rates`] (clearance `k v` added per cell). The fluid of each cell changes
        /// linearly over the step by its net gain. The policy (module doc): split what is left
        /// of the step into the fewest equal pieces that keep `h * rate / fluid <= cfl` for
        /// every cell with fluid at the piece's start, take one piece, look again. `None` where
        /// a cell with a positive rate has no fluid or the count passes [`MAX_SUBSTEPS`].
        fn reference_substeps(&self) -> Option<u32> {
            let (leaving, net) = self.rates();
            let n = self.n;
            let mut fluid = self.fluid.clone();
            let (mut left, mut count) = (self.dt, 0u32);
            while left > 0.0 {
                let mut worst = 0.0f64;
                for k in 0..n {
                    let rate = leaving[k].iter().sum::<f64>() + self.clearance[k] * fluid[k];
                    if rate > 0.0 {
                        if fluid[k] <= 0.0 {
                            return None;
                        }
                        worst = worst.max(rate / fluid[k]);
                    }
                }
                let pieces = (left * worst / self.cfl).ceil().max(1.0) as u32;
                if count + pieces > MAX_SUBSTEPS {
                    return None;
                }
                let h = left / f64::from(pieces);
                for k in 0..n {
                    fluid[k] += h * net[k];
                }
                count += 1;
                left = if pieces == 1 { 0.0 } else { left - h };
            }
            Some(count)
        }
    }

    /// A small deterministic generator (64-bit LCG, Knuth's constants) for the property test.
    struct Lcg(u64);

    impl Lcg {
        /// Uniform in [0, 1).
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }

        /// With probability `p`, uniform in [0, `scale`); else 0 (one draw, two when drawn).
        fn sometimes(&mut self, p: f64, scale: f64) -> f64 {
            if self.next() < p {
                scale * self.next()
            } else {
                0.0
            }
        }
    }

    fn total(x: &[f64]) -> f64 {
        x.iter().sum()
    }

    /// Random chains and rings of 2-6 cells with flows both ways along faces, drains at positive
    /// and negative pressure, an outlet that injects or takes fluid back, clearance, and steps
    /// from one substep to hundreds: the substep count equals the reference's, the bound keeps
    /// every concentration between 0 and the largest of the old ones and the stock (no cell
    /// emptied below zero: nothing booked as negative clearance), and iodine and fluid balance
    /// to round-off (1e-12 relative: a few hundred substeps of sums over a handful of terms).
    #[test]
    fn the_substep_count_is_the_bound_and_keeps_concentrations_convex() {
        let mut rng = Lcg(0x5eed_0033);
        let mut kinds = [0usize; 4];
        for case_no in 0..800 {
            let n = 2 + (rng.next() * 5.0) as usize;
            let mut faces: Vec<(u32, u32, f64, f64)> = (0..n - 1)
                .map(|a| (a as u32, a as u32 + 1, 0.0, 0.0))
                .collect();
            if n > 2 && rng.next() < 0.5 {
                faces.push((0, n as u32 - 1, 0.0, 0.0));
            }
            for f in &mut faces {
                f.2 = rng.sometimes(0.8, 0.03);
                f.3 = rng.sometimes(0.8, 2.0);
            }
            let sink: Vec<f64> = (0..n).map(|_| rng.sometimes(0.3, 0.03)).collect();
            let clearance: Vec<f64> = (0..n).map(|_| rng.sometimes(0.3, 0.2)).collect();
            let mut p: Vec<f64> = (0..n).map(|_| 2.0 * rng.next() - 0.5).collect();
            let contacts = (rng.next() < 0.6).then(|| {
                let c = (rng.next() * n as f64) as usize;
                p.push(2.0 * rng.next() - 0.5);
                (vec![(c, 0.5 + rng.next())], 0.5 + 0.5 * rng.next())
            });
            if contacts.is_none() {
                p.push(0.0);
            }
            // Fluid from a tenth of the largest rates to well above them, so that a step
            // takes one substep, a few, or hundreds.
            let fluid: Vec<f64> = (0..n).map(|_| 0.01 * 300f64.powf(rng.next())).collect();
            let iodine: Vec<f64> = fluid.iter().map(|v| v * rng.next()).collect();
            let domain: Vec<u8> = (0..n).map(|_| (rng.next() * 3.0) as u8).collect();
            let case = Case {
                n,
                faces,
                sink,
                clearance,
                domain,
                contacts,
                p,
                fluid,
                iodine,
                cfl: [0.2, 0.5, 1.0][case_no % 3],
                dt: 0.02 + 0.5 * rng.next(),
            };
            let expected = case.reference_substeps();
            let (out, iodine, fluid) = case.run();
            let Some(out) = out else {
                assert_eq!(
                    expected, None,
                    "case {case_no}: step refused, reference did not"
                );
                kinds[3] += 1;
                continue;
            };
            assert_eq!(
                Some(out.substeps),
                expected,
                "case {case_no}: substep count"
            );
            kinds[(out.substeps > 1) as usize + (out.substeps > 20) as usize] += 1;
            let stock = case.contacts.as_ref().map_or(0.0, |c| c.1);
            let top = case
                .iodine
                .iter()
                .zip(&case.fluid)
                .map(|(m, v)| m / v)
                .fold(stock, f64::max);
            for k in 0..n {
                // At a bound of 1 a donor may be emptied exactly, of fluid and iodine alike.
                assert!(
                    fluid[k] >= 0.0,
                    "case {case_no}: cell {k} fluid {}",
                    fluid[k]
                );
                if fluid[k] == 0.0 {
                    assert_eq!(iodine[k], 0.0, "case {case_no}: iodine in an empty cell");
                    continue;
                }
                let c = iodine[k] / fluid[k];
                assert!(
                    (0.0..=top * (1.0 + 1e-12)).contains(&c),
                    "case {case_no}: cell {k} concentration {c} outside [0, {top}]"
                );
            }
            // A cell emptied below zero by more than round-off would show as negative
            // clearance (the clamp books it there); round-off is ulps of the iodine moved.
            assert!(
                out.ledger.cleared >= -1e-15 * total(&case.iodine).max(1.0),
                "case {case_no}: a cell was emptied below zero ({} booked)",
                out.ledger.cleared
            );
            let led = &out.ledger;
            let iodine_gap =
                total(&iodine) - (total(&case.iodine) + led.injected - led.escaped - led.cleared);
            assert!(
                iodine_gap.abs() <= 1e-12 * total(&case.iodine).max(1.0),
                "case {case_no}: iodine off by {iodine_gap}"
            );
            let fluid_gap = total(&fluid)
                - (total(&case.fluid) + led.fluid_injected_mm3 - led.fluid_escaped_mm3);
            assert!(
                fluid_gap.abs() <= 1e-12 * total(&case.fluid),
                "case {case_no}: fluid off by {fluid_gap}"
            );
            // The fluid is linear in time over the step: each cell ends at its start plus dt
            // times its net gain, whatever the split.
            let (_, net) = case.rates();
            for k in 0..n {
                let expected = case.fluid[k] + case.dt * net[k];
                assert!(
                    (fluid[k] - expected).abs() <= 1e-12 * case.fluid[k].max(1.0),
                    "case {case_no}: cell {k} fluid {} not {expected}",
                    fluid[k]
                );
            }
            // Per domain: the totals split, exchanges are antisymmetric, and each domain's
            // iodine changes by what entered, left and moved across its boundary.
            let by = |f: &[f64; Domain::COUNT]| f.iter().sum::<f64>();
            for (split, whole, what) in [
                (by(&led.injected_by_domain), led.injected, "injected"),
                (by(&led.escaped_by_domain), led.escaped, "escaped"),
                (by(&led.cleared_by_domain), led.cleared, "cleared"),
            ] {
                assert!(
                    (split - whole).abs() <= 1e-13 * whole.abs().max(1.0),
                    "case {case_no}: {what} {split} by domain, {whole} in all"
                );
            }
            for d in 0..Domain::COUNT {
                let held = |m: &[f64]| {
                    m.iter()
                        .zip(&case.domain)
                        .filter(|(_, x)| usize::from(**x) == d)
                        .map(|(m, _)| m)
                        .sum::<f64>()
                };
                let out_of_d: f64 = led.exchanged[d].iter().sum();
                let expected = held(&case.iodine) + led.injected_by_domain[d]
                    - led.escaped_by_domain[d]
                    - led.cleared_by_domain[d]
                    - out_of_d;
                assert!(
                    (held(&iodine) - expected).abs() <= 1e-12 * total(&case.iodine).max(1.0),
                    "case {case_no}: domain {d} holds {} not {expected}",
                    held(&iodine)
                );
                for e in 0..Domain::COUNT {
                    assert_eq!(
                        led.exchanged[d][e], -led.exchanged[e][d],
                        "case {case_no}: exchange {d}->{e}"
                    );
                }
            }
        }
        // The draw covers one substep, a few, many, and refusals.
        assert!(kinds.iter().all(|&k| k > 10), "{kinds:?}");
    }

    /// Two cells exchanging by diffusion only (fluid constant): the count is
    /// `ceil(dt * worst / cfl)` with worst = T / min fluid, exactly at an integer here
    /// (`1.0 * 2.0 / 0.5 = 4`, each piece at the bound exactly), so 4 and not 5; one piece is
    /// refused past [`MAX_SUBSTEPS`] and taken at it.
    #[test]
    fn a_step_at_the_bound_takes_the_exact_count_and_the_limit_holds() {
        let case = |dt: f64| Case {
            n: 2,
            faces: vec![(0, 1, 0.0, 1.0)],
            sink: vec![0.0; 2],
            clearance: vec![0.0; 2],
            domain: vec![0; 2],
            contacts: None,
            p: vec![0.0; 2],
            fluid: vec![0.5, 4.0],
            iodine: vec![0.5, 0.0],
            cfl: 0.5,
            dt,
        };
        assert_eq!(case(1.0).run().0.map(|o| o.substeps), Some(4));
        assert_eq!(case(0.125).run().0.map(|o| o.substeps), Some(1));
        let limit = f64::from(MAX_SUBSTEPS) / 4.0;
        assert_eq!(case(limit).run().0.map(|o| o.substeps), Some(MAX_SUBSTEPS));
        let (out, iodine, fluid) = case(limit * (1.0 + 1e-9)).run();
        assert!(out.is_none(), "one piece past the limit is refused");
        assert_eq!(
            (iodine, fluid),
            (vec![0.5, 0.0], vec![0.5, 4.0]),
            "a refused step changes nothing"
        );
    }

    /// A way to break a scene, named.
    type Breakage = (&'static str, fn(&mut Case));

    /// A failed solve or broken state never spreads: a NaN or infinite pressure anywhere
    /// (even in a cell with no face), NaN fluid, or a cell without fluid that something would
    /// leave, refuses the step and leaves the state as it was. A dry cell that nothing leaves
    /// (positive control) is fine.
    #[test]
    fn nan_pressure_nan_fluid_and_dry_donors_refuse_the_step() {
        let base = || Case {
            n: 3,
            faces: vec![(0, 1, 1.0, 0.1)],
            sink: vec![0.0; 3],
            clearance: vec![0.0; 3],
            domain: vec![0; 3],
            contacts: None,
            p: vec![1.0, 0.0, 0.0, 0.0],
            fluid: vec![1.0, 1.0, 0.0],
            iodine: vec![0.5, 0.0, 0.0],
            cfl: 0.2,
            dt: 0.1,
        };
        assert_eq!(
            base().run().0.map(|o| o.substeps),
            Some(1),
            "a dry cell that nothing leaves"
        );
        // A dry cell that advection fills (nothing leaves it) takes the upstream
        // concentration: 0.5 of stock-equivalent per mm^3 at 1 mm^3/s for 0.1 s.
        let mut filling = base();
        filling.faces.push((1, 2, 1.0, 0.0));
        filling.p = vec![2.0, 1.0, 0.0, 0.0];
        filling.iodine = vec![0.5, 0.5, 0.0];
        let (out, iodine, fluid) = filling.run();
        assert!(out.is_some(), "a dry cell may fill");
        assert!(
            (fluid[2] - 0.1).abs() < 1e-15 && (iodine[2] - 0.05).abs() < 1e-15,
            "{iodine:?} {fluid:?}"
        );
        let broken: [Breakage; 5] = [
            ("NaN pressure in a cell with no face", |c| c.p[2] = f64::NAN),
            ("infinite pressure", |c| c.p[0] = f64::INFINITY),
            ("NaN outlet pressure", |c| c.p[3] = f64::NAN),
            ("NaN fluid", |c| c.fluid[1] = f64::NAN),
            ("a dry donor", |c| c.fluid[0] = 0.0),
        ];
        for (what, breaks) in broken {
            let mut c = base();
            breaks(&mut c);
            let (out, iodine, fluid) = c.run();
            assert!(out.is_none(), "{what} accepted");
            let same =
                |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits());
            assert!(
                same(&iodine, &c.iodine) && same(&fluid, &c.fluid),
                "{what} changed the state"
            );
        }
    }

    /// Where `ceil(left * worst / cfl)` equal pieces would still overstep the bound by
    /// round-off (the division rounds down onto an integer, the piece times the rate rounds
    /// up), the step takes one piece more, and no piece oversteps. Such steps are found by
    /// search among steps of about a whole number of pieces.
    #[test]
    fn a_bound_missed_by_round_off_takes_one_more_piece() {
        let mut rng = Lcg(0x0b0d_0033);
        let mut found = 0;
        for _ in 0..200_000 {
            // A step of about a whole number of pieces at the bound: the count's division
            // lands on that number, and the piece times the rate lands on either side of cfl.
            let (worst, cfl, whole) = (
                0.5 + 20.0 * rng.next(),
                [0.2, 0.5, 1.0][(rng.next() * 3.0) as usize],
                1.0 + (rng.next() * 50.0).floor(),
            );
            let dt = whole * cfl / worst;
            let pieces = (dt * worst / cfl).ceil().max(1.0);
            if (dt / pieces) * worst <= cfl {
                continue;
            }
            // Diffusion only out of a cell of 1 mm^3 into a large one: worst = T exactly.
            let case = Case {
                n: 2,
                faces: vec![(0, 1, 0.0, worst)],
                sink: vec![0.0; 2],
                clearance: vec![0.0; 2],
                domain: vec![0; 2],
                contacts: None,
                p: vec![0.0; 3],
                fluid: vec![1.0, 1e9],
                iodine: vec![1.0, 0.0],
                cfl,
                dt,
            };
            let (out, iodine, _) = case.run();
            let out = out.expect("a step within the limit");
            assert_eq!(
                f64::from(out.substeps),
                pieces + 1.0,
                "dt {dt:e}, worst {worst:e}, cfl {cfl}"
            );
            assert!(iodine[0] > 0.0 && iodine[0] < 1.0, "{iodine:?}");
            found += 1;
            if found == 20 {
                return;
            }
        }
        panic!("only {found} triples found");
    }

    /// A donor that a substep empties exactly can keep a round-off negative of iodine: all its
    /// fluid leaves through two faces at a bound of one, and `m - h q1 c - h q2 c` with
    /// `h (q1 + q2) = v` and `c = m / v` lands an ulp either side of 0. The step clamps it to 0
    /// and books it as a negative clearance, in all and in the donor's domain, so that the
    /// balance stays exact; nothing negative is left. Such donors are found by search (about
    /// one draw in three).
    #[test]
    fn round_off_below_zero_is_clamped_and_booked() {
        let mut rng = Lcg(0xc1a3_0033);
        let mut found = 0;
        for _ in 0..10_000 {
            let v0 = 0.1 + rng.next();
            let m0 = v0 * rng.next();
            let (q1, q2) = (0.05 + rng.next(), 0.05 + rng.next());
            let case = Case {
                n: 3,
                faces: vec![(0, 1, q1, 0.0), (0, 2, q2, 0.0)],
                sink: vec![0.0; 3],
                clearance: vec![0.0; 3],
                domain: vec![2, 0, 0],
                contacts: None,
                p: vec![1.0, 0.0, 0.0, 0.0],
                fluid: vec![v0, 1.0, 1.0],
                iodine: vec![m0, 0.0, 0.0],
                cfl: 1.0,
                // All of the donor's fluid leaves.
                dt: v0 / (q1 + q2),
            };
            let (out, iodine, fluid) = case.run();
            // Where the count's rounding asks for two pieces, the second finds the donor
            // all but dry and the step is refused (the model halves it): not this case.
            let Some(out) = out else { continue };
            let led = out.ledger;
            assert!(
                iodine.iter().all(|m| *m >= 0.0),
                "left below zero: {iodine:?}"
            );
            assert!(fluid[0].abs() < 1e-15, "the donor is emptied: {fluid:?}");
            if led.cleared < 0.0 {
                assert_eq!(iodine[0], 0.0);
                assert!(led.cleared > -1e-15, "round-off only: {}", led.cleared);
                assert_eq!(
                    led.cleared_by_domain[2], led.cleared,
                    "booked in the donor's domain"
                );
                assert_eq!(led.cleared_by_domain.iter().sum::<f64>(), led.cleared);
                found += 1;
            } else {
                assert_eq!(led.cleared, 0.0, "no clearance in this scene");
            }
        }
        assert!(
            found >= 100,
            "only {found} round-off negatives in 10,000 draws"
        );
    }
}
