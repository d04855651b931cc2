//! Build time of the procedural lumbosacral phantom against grid spacing.
//!
//! For each voxel size: time to voxelize (paint labels, blur, noise), time of the whole build
//! (voxelize + mesh every structure from its level set through the shared pipeline), triangle
//! count, and the worst relative difference between a structure's mesh volume and its analytic
//! volume (the octree integral of its solids, `phantom::level_set`), over every structure; then
//! that difference per structure. The goals: within 5 % on the default 1.5 mm grid and 10 % at
//! 3 mm. `BENCH_QUICK=1` runs only the coarse grids (CI runs it in the dev profile).

use std::time::Instant;

use sim_core::anatomy::phantom::{self, PhantomParams, level_set};

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

/// Per structure: name, analytic volume and mesh volume, mm^3.
type Rows = Vec<(String, f64, f64)>;

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    // (voxel mm, meshed from level sets): mask meshes and the level-set meshes (the 1.5 mm
    // level-set row is the shipped phantom).
    let sizes: &[(f64, bool)] = if quick {
        &[(4.0, false), (3.0, false), (3.0, true)]
    } else {
        &[
            (3.0, false),
            (2.0, false),
            (1.5, false),
            (3.0, true),
            (1.5, true),
        ]
    };
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
        "| voxel mm | meshing | grid | mesh lattice mm | voxelize s | build s (wall) | build CPU s | write s | cache-hit load s | structures | triangles | analytic volumes s | worst mesh/analytic volume error |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut per_structure: Vec<(f64, &str, Rows)> = Vec::new();
    for &(voxel, level_sets) in sizes {
        let (params, meshing) = if level_sets {
            (PhantomParams::level_set_meshed(voxel), "level sets")
        } else {
            (PhantomParams::with_voxel_mm(voxel), "masks")
        };
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
                    "| {voxel} | {meshing} | {:?} | | {t_vox:.2} | failed: {e} | | | | | | | |",
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
        // Analytic volumes on the octree (see `level_set::reference_leaf_mm`).
        let t4 = Instant::now();
        let exact = level_set::structure_volumes_mm3(&phantom::anatomy(&params), &params.grid());
        let t_exact = t4.elapsed().as_secs_f64();
        let rows: Rows = exact
            .into_iter()
            .zip(&region.structures)
            .map(|((name, v), s)| (name, v, s.mesh.signed_volume_mm3()))
            .collect();
        let worst = rows.iter().map(|(n, v, m)| ((m - v) / v, n.clone())).fold(
            (0.0f64, String::new()),
            |a, b| {
                if b.0.abs() > a.0.abs() { b } else { a }
            },
        );
        println!(
            "| {voxel} | {meshing} | {:?} | {:.2} | {t_vox:.2} | {t_build:.2} | {cpu} | {t_write:.2} | {t_load} | {} | {tris} | {t_exact:.1} | {:+.2} % ({}) |",
            params.grid().dims,
            voxel / f64::from(params.pipeline.upsample.max(1)),
            region.structures.len(),
            100.0 * worst.0,
            worst.1
        );
        per_structure.push((voxel, meshing, rows));
    }
    for (voxel, meshing, rows) in per_structure {
        println!();
        println!("Mesh volume against analytic volume, {voxel} mm grid, meshed from {meshing}:");
        println!();
        println!("| structure | analytic ml | mesh ml | error |");
        println!("|---|---:|---:|---:|");
        for (name, v, m) in rows {
            println!(
                "| {name} | {:.2} | {:.2} | {:+.2} % |",
                v / 1000.0,
                m / 1000.0,
                100.0 * (m - v) / v
            );
        }
    }
}
