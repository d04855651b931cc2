//! Anatomy pipeline benchmark: meshing time against surface error for an analytic sphere at
//! several up-sampling factors, and the real-CT import time on the TotalSegmentator test CT.
//!
//! `cargo bench -p sim-core --bench anatomy` (add `--profile dev` and `BENCH_QUICK=1` for the
//! quick CI run: one repetition, lumbar structures only).

use std::path::Path;
use std::time::Instant;

use sim_core::anatomy::decimate::DecimationParams;
use sim_core::anatomy::pipeline::{PipelineParams, StructureMask, mesh_structure};
use sim_core::anatomy::smooth::TaubinParams;
use sim_core::anatomy::totalseg::{ImportOptions, MaskSource, import_ct};
use sim_core::material::MaterialClass;
use sim_core::volume::{Volume, VolumeGrid};

/// Partial-volume sphere occupancy by 8^3 supersampling near the surface.
fn sphere_mask(radius_vox: f64) -> StructureMask {
    let n = (2.0 * radius_vox).ceil() as usize + 6;
    let grid = VolumeGrid {
        dims: [n; 3],
        spacing_mm: [1.0; 3],
        origin_mm: [0.0; 3],
    };
    let c = [
        n as f64 / 2.0 + 0.31,
        n as f64 / 2.0 - 0.17,
        n as f64 / 2.0 + 0.23,
    ];
    let sdf = |p: [f64; 3]| {
        ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt() - radius_vox
    };
    let mut v = Volume::filled(grid, 0.0f32);
    const S: usize = 8;
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = grid.voxel_center_mm(i, j, k);
                let d = sdf(p);
                let occ = if d > 0.9 {
                    0.0
                } else if d < -0.9 {
                    1.0
                } else {
                    let mut inside = 0;
                    for a in 0..S {
                        for b in 0..S {
                            for e in 0..S {
                                let q = [
                                    p[0] + (a as f64 + 0.5) / S as f64 - 0.5,
                                    p[1] + (b as f64 + 0.5) / S as f64 - 0.5,
                                    p[2] + (e as f64 + 0.5) / S as f64 - 0.5,
                                ];
                                inside += usize::from(sdf(q) < 0.0);
                            }
                        }
                    }
                    inside as f32 / (S * S * S) as f32
                };
                v.set(i, j, k, occ);
            }
        }
    }
    StructureMask {
        name: format!("sphere_r{radius_vox}"),
        material: MaterialClass::Disc,
        mask: v,
    }
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let reps = if quick { 1 } else { 3 };
    println!("## Analytic sphere (1 mm voxels)\n");
    println!(
        "| radius (voxel) | upsample | smoothing + decimation | time (ms) | triangles | mean |r - R| (voxel) | volume error |"
    );
    println!("|---|---|---|---|---|---|---|");
    for radius in [6.0, 12.0] {
        let mask = sphere_mask(radius);
        let n = mask.mask.grid.dims[0] as f64;
        let c = [n / 2.0 + 0.31, n / 2.0 - 0.17, n / 2.0 + 0.23];
        let exact = 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3);
        for upsample in [1, 2, 3] {
            for post in [false, true] {
                let params = PipelineParams {
                    upsample,
                    smoothing: post.then(TaubinParams::default),
                    decimation: post.then(DecimationParams::default),
                    ..PipelineParams::default()
                };
                let start = Instant::now();
                let mut mesh = None;
                for _ in 0..reps {
                    mesh = Some(mesh_structure(&mask, &params).expect("sphere meshes").0);
                }
                let ms = start.elapsed().as_secs_f64() * 1e3 / reps as f64;
                let mesh = mesh.expect("at least one repetition");
                let mean = mesh
                    .vertices_mm
                    .iter()
                    .map(|p| {
                        (((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2))
                            .sqrt()
                            - radius)
                            .abs()
                    })
                    .sum::<f64>()
                    / mesh.vertices_mm.len() as f64;
                let vol_err = (mesh.signed_volume_mm3() - exact) / exact;
                println!(
                    "| {radius} | {upsample} | {} | {ms:.1} | {} | {mean:.4} | {:+.3}% |",
                    if post { "yes" } else { "no" },
                    mesh.triangles.len(),
                    100.0 * vol_err
                );
            }
        }
    }
    let data = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/anatomy/totalseg_example_abdomen_pelvis");
    if !data.is_dir() {
        println!(
            "\nReal-CT import: SKIPPED, test data not found at {}",
            data.display()
        );
        return;
    }
    println!("\n## Real CT import (abdomen-pelvis, 122 x 101 x 112 at 3 mm, v1 masks)\n");
    println!(
        "| structures | upsample | smoothing + decimation | time (s) | triangles | worst |mesh - mask| volume |"
    );
    println!("|---|---|---|---|---|---|");
    let lumbar: Vec<String> = [
        "vertebrae_L1",
        "vertebrae_L2",
        "vertebrae_L3",
        "vertebrae_L4",
        "vertebrae_L5",
        "sacrum",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let mut runs: Vec<(Option<Vec<String>>, u32, bool)> =
        vec![(Some(lumbar.clone()), 1, false), (Some(lumbar), 2, true)];
    if !quick {
        runs.push((None, 1, false));
        runs.push((None, 1, true));
    }
    for (include, upsample, post) in runs {
        let params = PipelineParams {
            upsample,
            smoothing: post.then(TaubinParams::default),
            decimation: post.then(DecimationParams::default),
            ..PipelineParams::default()
        };
        let options = ImportOptions {
            region_name: "bench".into(),
            params,
            include: include.clone(),
            licence: "Apache-2.0".into(),
            attribution: String::new(),
        };
        let start = Instant::now();
        let region = import_ct(
            &data.join("example_ct.nii.gz"),
            &MaskSource::Folder(data.join("segmentations_v1")),
            &options,
            &mut |_| {},
        )
        .expect("import");
        let secs = start.elapsed().as_secs_f64();
        let tris: usize = region
            .structures
            .iter()
            .map(|s| s.mesh.triangles.len())
            .sum();
        let worst = region
            .structures
            .iter()
            .map(|s| ((s.mesh.signed_volume_mm3() - s.mask_volume_mm3) / s.mask_volume_mm3).abs())
            .fold(0.0, f64::max);
        println!(
            "| {} | {upsample} | {} | {secs:.2} | {tris} | {:.2}% |",
            if include.is_some() {
                "L1-L5 + sacrum".to_string()
            } else {
                format!("all {}", region.structures.len())
            },
            if post { "yes" } else { "no" },
            100.0 * worst
        );
    }
}
