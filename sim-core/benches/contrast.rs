//! Contrast transport: pressure solve iterations and time to a 1e-6 relative (energy-norm)
//! pressure error with Jacobi-PCG and multigrid-PCG on masked grids with 1000x mobility contrast,
//! time per transport step, and a 3 mL / 10 s epidural injection in the phantom at 1 mm cells.
//!
//! The memory-bandwidth floor of an iteration is the bytes it must stream (a count per cell,
//! stated below) divided by the bandwidth of a STREAM-like triad `a = b + s c` over arrays much
//! larger than the caches, measured here (24 bytes per element, write-allocate not counted).
//!
//! `BENCH_QUICK=1` runs the solvers at 64^3 and multigrid alone at 128^3, the transport at 64^3,
//! fewer repetitions, and a 1 s injection.

use std::hint::black_box;
use std::time::Instant;

use sim_core::anatomy::phantom::{self, PhantomParams};
use sim_core::contrast::benchmark::solver_grid;
use sim_core::contrast::domains::{crop_grid, phantom_grid};
use sim_core::contrast::model::{solve_system, steady_stencil};
use sim_core::contrast::pressure::System;
use sim_core::contrast::{
    Agent, ContrastGrid, ContrastModel, Domain, Faces, Injection, ModelConfig, Multigrid,
    NeedleOutlet, StopRule,
};
use sim_core::stats::median;

/// Bytes per cell of one Jacobi-PCG iteration: matvec 48 (4 stencil arrays, x, y), two updates
/// 48, Jacobi 24, p update 24, three dot products 48.
const JACOBI_BYTES: f64 = 192.0;
/// Bytes per cell of one multigrid-PCG iteration: the CG part 168 plus the W(2,2) cycle: 8
/// red-black half-sweeps reading diag, 3 couplings, b and x and writing x (56 each, 448), the
/// residual 64, restriction and prolongation 32; 544 on the fine level, times 4/3 for the coarse
/// levels of the W-cycle. This is the box stencil's count; the multigrid now stores its levels
/// as compressed rows (a 4-byte column and an 8-byte coupling per neighbour, more bytes than the
/// box's three couplings), and the floor keeps the smaller, box count.
const MG_BYTES: f64 = 168.0 + 544.0 * 4.0 / 3.0;

fn triad_gb_s(n: usize, reps: usize) -> f64 {
    let b = vec![1.0f64; n];
    let c = vec![2.0f64; n];
    let mut a = vec![0.0f64; n];
    let mut best = f64::INFINITY;
    for r in 0..reps {
        let s = 1.0 + r as f64 * 1e-3;
        let t = Instant::now();
        for i in 0..n {
            a[i] = b[i] + s * c[i];
        }
        black_box(&mut a);
        best = best.min(t.elapsed().as_secs_f64());
    }
    24.0 * n as f64 / best / 1e9
}

fn solver_rows(n: usize, reps: usize, triad: f64, jacobi: bool) {
    let (g, q) = solver_grid(n);
    let faces = Faces::new(&g, &[]);
    let st = steady_stencil(&g, &faces);
    let sys = System {
        stencil: &st,
        outlet: None,
    };
    let rule = StopRule {
        rel_error: 1e-6,
        max_iter: 20_000,
    };
    let cells = (n * n * n) as f64;
    for (name, bytes) in [("Jacobi", JACOBI_BYTES), ("multigrid W(2,2)", MG_BYTES)] {
        if name == "Jacobi" && !jacobi {
            continue;
        }
        let mut times = Vec::new();
        let mut setup = Vec::new();
        let mut iters = 0;
        for _ in 0..reps {
            let t0 = Instant::now();
            let mut mg = (name != "Jacobi").then(|| Multigrid::new(&st));
            let t1 = Instant::now();
            let mut x = vec![0.0; q.len()];
            let s = solve_system(&sys, mg.as_mut(), &q, &mut x, rule);
            times.push(t1.elapsed().as_secs_f64());
            setup.push((t1 - t0).as_secs_f64());
            iters = s.iterations;
            assert!(s.converged, "{name} {n}: {s:?}");
        }
        let t = median(&times);
        let per_it = t / iters as f64;
        let floor = bytes * cells / (triad * 1e9);
        println!(
            "| {n}^3 | {name} | {iters} | {:.3} | {:.3} | {:.2} | {:.2} | {:.1} |",
            median(&setup),
            t,
            per_it * 1e3,
            floor * 1e3,
            per_it / floor
        );
    }
}

fn transport_step_row(n: usize) {
    let (mut g, _) = solver_grid(n);
    for p in g.props.iter_mut() {
        p.compliance = 0.02;
    }
    let mut m = ContrastModel::new(g, ModelConfig::default());
    let c = n as f64 / 2.0 + 4.0;
    let out = NeedleOutlet::tuohy([c, c, c], [0.0, 0.0, 1.0]);
    let inj = Injection {
        agent: Agent::CONTRAST,
        volume_ml: 3.0,
        rate_ml_s: 0.3,
    };
    if m.start_injection(&out, &inj).is_err() {
        println!("| {n}^3 | (tip in a solid cell) | | | | | |");
        return;
    }
    let t = Instant::now();
    let r = m.advance(1.0).unwrap_or_default();
    let wall = t.elapsed().as_secs_f64();
    let k = &m.counters;
    println!(
        "| {n}^3 | {} | {} | {:.3} | {:.2} | {:.2} | {:.1} |",
        r.substeps,
        k.transport_substeps,
        k.transport_seconds / k.transport_substeps as f64 * 1e3,
        k.transport_seconds / k.steps as f64 * 1e3,
        k.solve_seconds / k.solves as f64 * 1e3,
        k.iterations as f64 / k.solves as f64
    );
    black_box(wall);
}

/// The cell centre of `domain` nearest `near` whose neighbours within 3 cells along y and 1
/// across are of the same domain (so the Tuohy opening, along y, lies wholly in it).
fn pure_site(g: &ContrastGrid, domain: Domain, near: [f64; 3]) -> [f64; 3] {
    let d = g.grid.dims;
    let mut best = (f64::INFINITY, near);
    for idx in 0..g.len() {
        let ijk = g.grid.ijk(idx);
        let pure = (-3i64..=3).all(|s| {
            (-1i64..=1).all(|t| {
                (-1i64..=1).all(|u| {
                    let q = [ijk[0] as i64 + t, ijk[1] as i64 + s, ijk[2] as i64 + u];
                    (0..3).all(|a| q[a] >= 0 && q[a] < d[a] as i64)
                        && g.domain[g.grid.index(q[0] as usize, q[1] as usize, q[2] as usize)]
                            == Some(domain)
                })
            })
        });
        if pure {
            let p = g.grid.voxel_center_mm(ijk[0], ijk[1], ijk[2]);
            let dist: f64 = (0..3).map(|a| (p[a] - near[a]).powi(2)).sum();
            if dist < best.0 {
                best = (dist, p);
            }
        }
    }
    best.1
}

fn phantom_injection(seconds: f64) {
    let params = PhantomParams::default();
    let c = phantom::landmark(&params, "L4_L5_posterior_epidural_space")
        .map(|l| l.position_mm)
        .unwrap_or([0.0; 3]);
    let t0 = Instant::now();
    let lo = [c[0] - 24.0, c[1] - 24.0, c[2] - 48.0];
    let hi = [c[0] + 24.0, c[1] + 24.0, c[2] + 48.0];
    let g = phantom_grid(&params, crop_grid(lo, hi, 1.0));
    let build = t0.elapsed().as_secs_f64();
    let dims = g.grid.dims;
    let mut m = ContrastModel::new(g, ModelConfig::default());
    let tip = pure_site(m.grid(), Domain::Epidural, c);
    let inj = Injection {
        agent: Agent::CONTRAST,
        volume_ml: 0.3 * seconds,
        rate_ml_s: 0.3,
    };
    if let Err(e) = m.start_injection(&NeedleOutlet::tuohy(tip, [0.0, 1.0, 0.0]), &inj) {
        println!("phantom injection refused: {e}");
        return;
    }
    let t = Instant::now();
    let r = m.advance(seconds).unwrap_or_default();
    let wall = t.elapsed().as_secs_f64();
    let k = &m.counters;
    let fr = sim_core::contrast::classify::retained_fraction_by_domain(&m);
    println!(
        "| {:?} | {:.1} mL / {seconds} s | {:.3} | {:.2} | {} | {} | {:.1} | {:.2} | {:.2} | {:.2} | {:.1e} |",
        dims,
        0.3 * seconds,
        fr[Domain::Epidural.index()],
        build,
        r.substeps,
        k.transport_substeps,
        k.iterations as f64 / k.solves as f64,
        k.solve_seconds,
        k.transport_seconds,
        wall,
        m.ledger().balance_error(m.retained_mm3())
    );
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let (sizes, reps): (&[usize], usize) = if quick { (&[64], 1) } else { (&[64, 128], 3) };
    let triad = triad_gb_s(
        if quick { 1 << 23 } else { 1 << 25 },
        if quick { 3 } else { 10 },
    );
    println!("STREAM-like triad: {triad:.2} GB/s (best of repetitions, 24 B per element)");
    println!();
    println!(
        "Pressure to 1e-6 relative energy-norm error, 1000x mobility contrast (median of {reps} at 64^3, one run at 128^3)"
    );
    println!();
    println!(
        "| grid | preconditioner | iterations | setup (s) | solve (s) | per iteration (ms) | bandwidth floor (ms) | ratio |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for &n in sizes {
        // One repetition at 128^3: a Jacobi solve alone takes a minute or more.
        solver_rows(n, if n > 64 { 1 } else { reps }, triad, true);
    }
    if quick {
        // The multigrid row at 128^3 (a few seconds) is kept in quick mode so every CI log
        // carries the 128^3 iteration count; Jacobi at 128^3 is left to full runs.
        solver_rows(128, 1, triad, false);
    }
    println!();
    println!(
        "Transport (injection at 0.3 mL/s, 1 s simulated, multigrid-PCG warm-started; a pressure step's transport is sub-cycled)"
    );
    println!();
    println!(
        "| grid | pressure steps | transport substeps | transport per substep (ms) | transport per step (ms) | solve per step (ms) | PCG iterations per solve |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|");
    for &n in sizes {
        transport_step_row(n);
    }
    println!();
    println!("Phantom epidural injection at L4-L5, 1 mm cells, Tuohy outlet, 0.3 mL/s");
    println!();
    println!(
        "| crop cells | injection | epidural fraction | domain build (s) | pressure steps | transport substeps | PCG it/solve | solve (s) | transport (s) | wall (s) | balance error |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    phantom_injection(if quick { 1.0 } else { 10.0 });
}
