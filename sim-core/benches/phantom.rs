//! Build time of the procedural lumbosacral phantom against grid spacing.
//!
//! For each voxel size: time to voxelize (paint labels, blur, noise), time of the whole build
//! (voxelize + mesh every structure through the shared pipeline), triangle count, and the worst
//! relative difference between a structure's mesh volume and its mask volume (structures of at
//! least 1 ml). `BENCH_QUICK=1` runs only the coarse grids (CI runs it in the dev profile).

use std::time::Instant;

use sim_core::anatomy::phantom::{self, PhantomParams};

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let sizes: &[f64] = if quick { &[4.0, 3.0] } else { &[3.0, 2.0, 1.5, 1.0] };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!("Phantom build, {threads} hardware threads, profile {}", if cfg!(debug_assertions) { "dev" } else { "release" });
    println!();
    println!("| voxel mm | grid | voxelize s | build s | structures | triangles | worst mesh/mask volume error (>= 1 ml) |");
    println!("|---|---|---|---|---|---|---|");
    for &voxel in sizes {
        let params = PhantomParams::with_voxel_mm(voxel);
        let t0 = Instant::now();
        let vols = phantom::voxelize(&params);
        let t_vox = t0.elapsed().as_secs_f64();
        drop(vols);
        let t1 = Instant::now();
        let region = match phantom::build(&params, &mut |_| {}) {
            Ok(r) => r,
            Err(e) => {
                println!("| {voxel} | {:?} | {t_vox:.2} | failed: {e} | | | |", params.grid().dims);
                continue;
            }
        };
        let t_build = t1.elapsed().as_secs_f64();
        let tris: usize = region.structures.iter().map(|s| s.mesh.triangle_count()).sum();
        let worst = region
            .structures
            .iter()
            .filter(|s| s.mask_volume_mm3 >= 1000.0)
            .map(|s| (s.mesh.signed_volume_mm3() - s.mask_volume_mm3).abs() / s.mask_volume_mm3)
            .fold(0.0f64, f64::max);
        println!(
            "| {voxel} | {:?} | {t_vox:.2} | {t_build:.2} | {} | {tris} | {:.2} % |",
            params.grid().dims,
            region.structures.len(),
            100.0 * worst
        );
    }
}
