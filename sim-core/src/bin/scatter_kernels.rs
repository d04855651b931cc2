//! `scatter_kernels`: regenerates `sim-core/data/fluoro/scatter_kernels.csv`, the pencil-beam
//! scatter kernels of water, from the crate's Monte Carlo (`sim_core::fluoro::scatter`).
//!
//! ```text
//! cargo run -p sim-core --bin scatter_kernels -- sim-core/data/fluoro/scatter_kernels.csv
//! ```
//!
//! Every table point runs `kernel::PHOTONS` photons with seed `kernel::SEED` plus the point's
//! index, so the file is reproducible bit for bit.

use std::process::ExitCode;
use std::time::Instant;

use sim_core::fluoro::scatter::kernel::{GAPS_MM, KVPS, KernelTable, PHOTONS, SEED, WATER_MM};

fn main() -> ExitCode {
    let Some(out) = std::env::args().nth(1) else {
        eprintln!("usage: scatter_kernels OUT.csv");
        return ExitCode::from(2);
    };
    let start = Instant::now();
    let mut kernels = Vec::with_capacity(KVPS.len() * WATER_MM.len() * GAPS_MM.len());
    for (ki, &kvp) in KVPS.iter().enumerate() {
        for (wi, &w) in WATER_MM.iter().enumerate() {
            let point = (ki * WATER_MM.len() + wi) as u64;
            match KernelTable::simulate(kvp, w, PHOTONS, SEED + point) {
                Ok(k) => kernels.extend(k),
                Err(e) => {
                    eprintln!("scatter_kernels: {e}");
                    return ExitCode::FAILURE;
                }
            }
            eprintln!(
                "{kvp} kVp, {w} mm water: {:.1} s",
                start.elapsed().as_secs_f64()
            );
        }
    }
    let table = KernelTable { kernels };
    if let Err(e) = std::fs::write(&out, table.to_csv()) {
        eprintln!("scatter_kernels: cannot write {out}: {e}");
        return ExitCode::FAILURE;
    }
    eprintln!("wrote {out} in {:.1} s", start.elapsed().as_secs_f64());
    ExitCode::SUCCESS
}
