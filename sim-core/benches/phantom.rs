//! Build time of the procedural lumbosacral phantom against grid spacing.
//!
//! For each voxel size: time to voxelize (paint labels, blur, noise), time of the whole build
//! (voxelize + mesh every structure through the shared pipeline), triangle count, and the worst
//! relative difference between a structure's mesh volume and its mask volume (structures of at
//! least 5 ml). `BENCH_QUICK=1` runs only the coarse grids (CI runs it in the dev profile).

use std::time::Instant;

use sim_core::anatomy::phantom::{self, PhantomParams};

/// CPU seconds used by this process so far (all threads), from `/proc/self/stat` (Linux; utime +
/// stime in clock ticks of 1/100 s, the Linux USER_HZ). `None` elsewhere.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let sizes: &[f64] = if quick { &[4.0, 3.0] } else { &[3.0, 2.0, 1.5] };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "Phantom build, {threads} hardware threads, profile {}",
        if cfg!(debug_assertions) {
            "dev"
        } else {
            "release"
        }
    );
    println!();
    println!(
        "Wall times include any load from other processes; CPU s is this process's own CPU time (all threads)."
    );
    println!();
    println!(
        "| voxel mm | grid | voxelize s | build s (wall) | build CPU s | write s | cache-hit load s | structures | triangles | worst mesh/mask volume error (>= 5 ml) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for &voxel in sizes {
        let params = PhantomParams::with_voxel_mm(voxel);
        let t0 = Instant::now();
        let vols = phantom::voxelize(&params);
        let t_vox = t0.elapsed().as_secs_f64();
        drop(vols);
        let t1 = Instant::now();
        let c1 = cpu_seconds();
        let region = match phantom::build(&params, &mut |_| {}) {
            Ok(r) => r,
            Err(e) => {
                println!(
                    "| {voxel} | {:?} | {t_vox:.2} | failed: {e} | | | | | | |",
                    params.grid().dims
                );
                continue;
            }
        };
        let t_build = t1.elapsed().as_secs_f64();
        let cpu = match (c1, cpu_seconds()) {
            (Some(a), Some(b)) => format!("{:.1}", b - a),
            _ => "n/a".to_string(),
        };
        // Writing the region folder, then what a cache hit costs: reading it back with every
        // file's SHA-256 verified.
        let dir = tempfile::tempdir().expect("temporary folder");
        let t2 = Instant::now();
        region
            .write_to(&dir.path().join("lumbar-phantom"))
            .expect("write region");
        let t_write = t2.elapsed().as_secs_f64();
        let t3 = Instant::now();
        let t_load = match phantom::ensure_built_with(
            &dir.path().join("lumbar-phantom"),
            &params,
            &mut |_| {},
        ) {
            Ok(_) => format!("{:.2}", t3.elapsed().as_secs_f64()),
            Err(e) => format!("failed: {e}"),
        };
        let tris: usize = region
            .structures
            .iter()
            .map(|s| s.mesh.triangle_count())
            .sum();
        let worst = region
            .structures
            .iter()
            .filter(|s| s.mask_volume_mm3 >= 5000.0)
            .map(|s| {
                (
                    (s.mesh.signed_volume_mm3() - s.mask_volume_mm3).abs() / s.mask_volume_mm3,
                    s.name.clone(),
                )
            })
            .fold(
                (0.0f64, String::new()),
                |a, b| if b.0 > a.0 { b } else { a },
            );
        println!(
            "| {voxel} | {:?} | {t_vox:.2} | {t_build:.2} | {cpu} | {t_write:.2} | {t_load} | {} | {tris} | {:.2} % ({}) |",
            params.grid().dims,
            region.structures.len(),
            100.0 * worst.0,
            worst.1
        );
    }
}
