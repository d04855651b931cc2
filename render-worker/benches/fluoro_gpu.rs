//! GPU fluoroscopy: frame time against error on the lumbar phantom.
//!
//! For several phantom mesh resolutions (CT voxel size of the procedural phantom, which sets the
//! marching-tetrahedra and decimation scale) it builds the scene once, uploads it, and prints:
//! - the GPU time of a polychromatic (80 kVp) transmission frame at 512 x 512 and 1024 x 1024
//!   (needle pass, L-buffer, resolve, read-back; mean of several frames after a warm-up), and of
//!   the displayed 8-bit frame (plus sim-core's automatic brightness and log mapping on the CPU);
//! - the error against the CPU reference on the same meshes (centre-sampled, so both sample the
//!   same rays), over pixels away from silhouette edges (3 x 3 neighbourhood with one CPU hit
//!   signature): median and p99 of |ln T_gpu - ln T_cpu| against the CPU evaluation of the
//!   L-buffer's own linear nesting rule (the implementation error; pixels off the needle) and
//!   against the CPU priority rule (adds the phantom's touching-mesh overlaps, which the L-buffer
//!   counts twice), and the largest 8-bit grey difference;
//! - the mesh's own error: median |ln T| difference of the GPU frame against the CPU frame of the
//!   finest mesh of the run (same pixels), i.e. what a coarser mesh costs in fidelity.
//!
//! Then, per mesh and image size, the phases of a session's displayed frame (80 kVp, 2 x 2
//! supersampling at the needle, quantum noise) in five cases: from scratch (caches off: every
//! pass, the whole resolve and read-back, as every frame was rendered before the caches), after
//! a C-arm move (geometry redrawn), after a needle-only move (the common case: feed, roll,
//! withdraw; only the needle, the anatomy under its pixel box and its rows are redone), with
//! nothing changed (a new shot at the same pose: only the noise and display), and the same new
//! shot with a session's detector (scatter behind the grid and the flat panel's profile, whose
//! signal the renderer keeps for new shots). Each cached frame is checked bit for bit against
//! the frame from scratch.
//!
//! `BENCH_QUICK=1`: two coarse meshes, GPU at both sizes, CPU reference at 512 x 512 only (under a
//! minute on 2 cores in the dev profile). Without it: three meshes, CPU reference at both sizes.

#[allow(dead_code)]
mod common;

use std::time::Instant;

use render_worker::fluoro::{FrameTimings, GpuFluoroRenderer};
use render_worker::gpu::GpuContext;
use sim_core::anatomy::phantom::{self, PhantomParams};
use sim_core::compare::Compare;
use sim_core::fluoro::attenuation::basis_depths;
use sim_core::fluoro::receptor::{ReceptorKind, ReceptorSettings};
use sim_core::fluoro::render::to_display;
use sim_core::fluoro::scatter::superposition::ScatterSettings;
use sim_core::fluoro::{
    EnergyModel, FluoroMaterial, Projection, QuantumNoise, RenderSettings, Scene, SpectralModel,
    render_chords, render_transmission,
};
use sim_core::geom::{capped_cylinder, equal_area_vertex_radius};
use sim_core::stats::percentile;

/// The phantom with a needle, the needle's entry and tip, and the build time (s).
fn phantom_scene(voxel_mm: f64) -> (Scene, [f64; 3], [f64; 3], f64) {
    let t = Instant::now();
    let params = PhantomParams::with_voxel_mm(voxel_mm);
    let region = phantom::build(&params, &mut |_| {}).expect("phantom builds");
    let mut scene = Scene::new();
    for s in &region.structures {
        scene.add(s.name.clone(), FluoroMaterial::Tissue(s.material), &s.mesh);
    }
    // A 22 G needle from the skin of the left back towards the left L4 transforaminal target.
    let target = phantom::landmark(&params, "L4_transforaminal_target_left")
        .map_or([-30.0, 0.0, -40.0], |l| l.position_mm);
    let entry = [target[0] - 60.0, target[1] - 90.0, target[2] + 10.0];
    let r = equal_area_vertex_radius(0.36, 16);
    scene.add(
        "needle",
        FluoroMaterial::Steel,
        &capped_cylinder(entry, target, r, 16),
    );
    (scene, entry, target, t.elapsed().as_secs_f64())
}

/// Mean phases of `frames` displayed frames; `prepare(k)` makes frame `k`'s change. Also returns
/// whether every frame's transmission equalled `reference(k)`'s bit for bit.
fn phases(
    gpu: &mut GpuFluoroRenderer,
    frames: usize,
    mut change: impl FnMut(&mut GpuFluoroRenderer, usize) -> (Projection, RenderSettings),
    mut reference: impl FnMut(usize, &Projection, &RenderSettings) -> Vec<f32>,
) -> (FrameTimings, f64, bool) {
    let mut sum = FrameTimings::default();
    let mut wall = 0.0;
    let mut exact = true;
    for k in 0..frames {
        let (p, settings) = change(gpu, k);
        let t = Instant::now();
        let _ = gpu.render_frame(&p, &settings, None).expect("frame");
        wall += t.elapsed().as_secs_f64() * 1e3;
        let f = gpu.last_timings();
        sum.encode_ms += f.encode_ms;
        sum.gpu_ms += f.gpu_ms;
        sum.readback_ms += f.readback_ms;
        sum.supersample_ms += f.supersample_ms;
        sum.finish_ms += f.finish_ms;
        sum.resolved_samples += f.resolved_samples;
        let mine = gpu
            .render_transmission_supersampled(&p, &settings, None)
            .expect("frame")
            .transmission;
        let want = reference(k, &p, &settings);
        exact &= mine.len() == want.len()
            && mine
                .iter()
                .zip(&want)
                .all(|(a, b)| a.to_bits() == b.to_bits());
    }
    let n = frames as f64;
    let mean = FrameTimings {
        encode_ms: sum.encode_ms / n,
        gpu_ms: sum.gpu_ms / n,
        readback_ms: sum.readback_ms / n,
        supersample_ms: sum.supersample_ms / n,
        finish_ms: sum.finish_ms / n,
        resolved_samples: sum.resolved_samples / frames as u64,
        ..FrameTimings::default()
    };
    (mean, wall / n, exact)
}

fn view(n: u32) -> Projection {
    // AP, isocentre at L4 level, a 300 mm flat panel.
    Projection {
        isocentre_mm: [0.0, 0.0, -40.0],
        detector_pixels: [n, n],
        pixel_pitch_mm: [300.0 / f64::from(n); 2],
        ..Projection::default()
    }
}

/// `ln T` at pixels `qs` with chords from the renderer's linear nesting rule (own chord to the
/// effective material, minus it from the container's) applied to sim-core's exact raw per-mesh
/// chords, and the GPU's pixel-total cancellous clamp; f64, two threads.
fn linear_rule_ln_t(
    scene: &Scene,
    gpu: &GpuFluoroRenderer,
    p: &Projection,
    model: &SpectralModel,
    qs: &[usize],
) -> Vec<f64> {
    let w = p.detector_pixels[0] as usize;
    let cort = FluoroMaterial::Tissue(sim_core::material::MaterialClass::CorticalBone).index();
    let canc = FluoroMaterial::Tissue(sim_core::material::MaterialClass::Cancellous).index();
    let one = |q: usize| {
        let ray = p.pixel_ray([(q % w) as f64 + 0.5, (q / w) as f64 + 0.5]);
        let raw = scene.ray_entry_chords(ray.origin_mm, ray.dir, ray.detector_t_mm);
        let mut lin = [0f64; FluoroMaterial::COUNT];
        for d in gpu.drawn() {
            lin[d.effective.index()] += raw[d.entry];
            if let Some(c) = d.container {
                lin[c.index()] -= raw[d.entry];
            }
        }
        let total = (lin[cort] + lin[canc]).max(0.0);
        lin[canc] = lin[canc].clamp(0.0, (total - 2.0 * scene.cortical_shell_mm).max(0.0));
        lin[cort] = total - lin[canc];
        for l in &mut lin {
            *l = l.max(0.0);
        }
        model.transmission(&basis_depths(&lin, 0.0)).ln()
    };
    let mut out = vec![0.0; qs.len()];
    let half = qs.len().div_ceil(2);
    std::thread::scope(|s| {
        for (chunk, qc) in out.chunks_mut(half.max(1)).zip(qs.chunks(half.max(1))) {
            s.spawn(move || {
                for (o, &q) in chunk.iter_mut().zip(qc) {
                    *o = one(q);
                }
            });
        }
    });
    out
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let Some(ctx) = common::gpu_or_skip() else {
        return;
    };
    let voxels: &[f64] = if quick { &[5.0, 3.5] } else { &[5.0, 3.0, 2.0] };
    let cpu_sizes: &[u32] = if quick { &[512] } else { &[512, 1024] };
    let frames = if quick { 3 } else { 10 };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "GPU fluoroscopy, lumbar phantom + 22 G needle, 80 kVp, adapter: {} ({}, {}), {threads} CPU threads",
        ctx.summary.name, ctx.summary.backend, ctx.summary.device_type
    );
    println!();
    println!(
        "| phantom voxel (mm) | triangles | image | GPU T (ms) | GPU 8-bit frame (ms) | CPU T (ms) | median / p99 abs. ln T err vs CPU, linear nesting | median / p99 abs. ln T err vs CPU, priority rule | max grey diff | interior px | median abs. ln T err vs finest mesh |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let energy = EnergyModel::Spectral { kvp: 80 };
    let model = SpectralModel::new(energy).expect("80 kVp is tabulated");
    let settings = RenderSettings {
        energy,
        supersample: 1,
        ..RenderSettings::default()
    };
    // The finest mesh's CPU ln T per image size (filled by the last, finest voxel size first).
    let mut finest: std::collections::HashMap<u32, Vec<f64>> = Default::default();
    let mut rows = Vec::new();
    let mut phase_rows = Vec::new();
    for &voxel in voxels.iter().rev() {
        let (scene, entry, tip, build_s) = phantom_scene(voxel);
        let tris = scene.triangle_count();
        let t = Instant::now();
        let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
        // The run-time-against-error table times frames from scratch.
        gpu.caching = false;
        eprintln!(
            "voxel {voxel} mm: {tris} triangles, phantom build {build_s:.1} s, upload {:.2} s",
            t.elapsed().as_secs_f64()
        );
        for n in [512u32, 1024] {
            let p = view(n);
            let _ = gpu
                .render_transmission(&p, &energy, None)
                .expect("gpu frame");
            let t = Instant::now();
            let mut g = None;
            for _ in 0..frames {
                g = Some(
                    gpu.render_transmission(&p, &energy, None)
                        .expect("gpu frame"),
                );
            }
            let gpu_ms = t.elapsed().as_secs_f64() * 1e3 / frames as f64;
            let g = g.expect("frames > 0");
            let t = Instant::now();
            for _ in 0..frames {
                let _ = gpu.render_frame(&p, &settings, None).expect("gpu frame");
            }
            let frame_ms = t.elapsed().as_secs_f64() * 1e3 / frames as f64;
            let gpu_img = gpu.render_frame(&p, &settings, None).expect("gpu frame");
            let (mut cpu_ms, mut vs_cpu, mut grey, mut interior_n, mut vs_finest) = (
                f64::NAN,
                String::from("-"),
                String::from("-"),
                0usize,
                String::from("-"),
            );
            let mut vs_linear = String::from("-");
            if cpu_sizes.contains(&n) {
                let [w, h] = p.detector_pixels.map(|x| x as usize);
                let t = Instant::now();
                let cpu = render_transmission(&scene, None, &p, &settings).expect("cpu");
                cpu_ms = t.elapsed().as_secs_f64() * 1e3;
                // No noise: the CPU frame is the display mapping of this transmission.
                let cpu_img = to_display(&cpu, &settings.exposure, settings.invert, None);
                let sig = render_chords(&scene, &p, 0);
                let interior: Vec<usize> = (0..w * h)
                    .filter(|&q| {
                        let (i, j) = (q % w, q / w);
                        (j.saturating_sub(1)..(j + 2).min(h)).all(|jj| {
                            (i.saturating_sub(1)..(i + 2).min(w))
                                .all(|ii| sig[jj * w + ii].signature == sig[q].signature)
                        })
                    })
                    .collect();
                interior_n = interior.len();
                let ln = |x: f64| x.max(1e-30).ln();
                let gpu_ln: Vec<f64> = g.transmission.iter().map(|&x| ln(f64::from(x))).collect();
                let cpu_ln: Vec<f64> = cpu.transmission.iter().map(|&x| ln(x)).collect();
                let image = Compare::image(w, h);
                let d = image
                    .at(&gpu_ln, &cpu_ln, interior.iter().copied())
                    .expect("ln T of the view");
                vs_cpu = format!("{:.1e} / {:.1e}", d.median_abs, d.p99_abs);
                // The same rays under the L-buffer's linear nesting rule, evaluated on the CPU
                // from exact raw per-mesh chords (pixels off the needle).
                let off_needle: Vec<usize> = interior
                    .iter()
                    .copied()
                    .filter(|&q| sig[q].chords_mm[FluoroMaterial::Steel.index()] == 0.0)
                    .collect();
                let lin = linear_rule_ln_t(&scene, &gpu, &p, &model, &off_needle);
                let e: Vec<f64> = off_needle
                    .iter()
                    .zip(&lin)
                    .map(|(&q, l)| (gpu_ln[q] - l).abs())
                    .collect();
                vs_linear = format!(
                    "{:.1e} / {:.1e}",
                    percentile(&e, 50.0),
                    percentile(&e, 99.0)
                );
                grey = image
                    .at(&gpu_img.pixels, &cpu_img.pixels, interior.iter().copied())
                    .expect("frames of the view")
                    .max_abs
                    .to_string();
                let reference = finest.entry(n).or_insert_with(|| cpu_ln.clone());
                let d = image
                    .at(&gpu_ln, reference, interior.iter().copied())
                    .expect("ln T of the view");
                vs_finest = format!("{:.1e}", d.median_abs);
            }
            // "-": the CPU reference was not run at this size (quick mode).
            let cpu = if cpu_ms.is_nan() {
                String::from("-")
            } else {
                format!("{cpu_ms:.0}")
            };
            rows.push(format!(
                "| {voxel} | {tris} | {n} x {n} | {gpu_ms:.1} | {frame_ms:.1} | {cpu} | {vs_linear} | {vs_cpu} | {grey} | {interior_n} | {vs_finest} |"
            ));
            // Progress on stderr (a full run takes minutes); the tables follow on stdout.
            eprintln!("progress: {}", rows.last().expect("row"));
        }
        if !quick || voxel == voxels[voxels.len() - 1] {
            phase_rows.extend(phase_table(&ctx, &scene, entry, tip, voxel, frames));
        }
    }
    for r in rows {
        println!("{r}");
    }
    println!();
    println!(
        "Phases of a session's displayed frame (80 kVp, 2 x 2 supersampling at the needle, noise), mean ms per frame; 'exact' = transmission bit-identical to the frame from scratch"
    );
    println!();
    println!(
        "| phantom voxel (mm) | triangles | image | case | encode | GPU (submit to mapped) | read-back | supersample (CPU) | noise + display (CPU) | frame wall (ms) | resolved samples | exact |"
    );
    println!("|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---|");
    for r in phase_rows {
        println!("{r}");
    }
}

/// Rows of the phase table for one mesh: from scratch, C-arm move, needle-only move, nothing
/// changed, at 512 and 1024 pixels.
fn phase_table(
    ctx: &GpuContext,
    scene: &Scene,
    entry: [f64; 3],
    tip: [f64; 3],
    voxel: f64,
    frames: usize,
) -> Vec<String> {
    let r = equal_area_vertex_radius(0.36, 16);
    // Needle k: fed k x 1 mm further along its line (alternating 0 and 1 mm).
    let dir = {
        let d = [tip[0] - entry[0], tip[1] - entry[1], tip[2] - entry[2]];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|x| x / l)
    };
    let needle = |k: usize| {
        let f = (k % 2) as f64;
        capped_cylinder(entry, std::array::from_fn(|a| tip[a] + f * dir[a]), r, 16)
    };
    let settings = |k: usize| RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 2,
        // Simulator's session default (3000 quanta at 2 mA), a new seed per frame.
        noise: Some(QuantumNoise {
            photons_per_pixel: 3000.0,
            seed: k as u64,
        }),
        ..RenderSettings::default()
    };
    let mut out = Vec::new();
    let tris = scene.triangle_count();
    let mut scratch = GpuFluoroRenderer::new(ctx, scene).expect("renderer");
    scratch.caching = false;
    for n in [512u32, 1024] {
        let ap = view(n);
        let pose = |k: usize| Projection {
            orbital_deg: (k % 2) as f64 * 2.0,
            ..ap
        };
        let mut reference = |needle_k: usize, p: &Projection, s: &RenderSettings| {
            scratch.update_needle(&needle(needle_k));
            scratch
                .render_transmission_supersampled(p, s, None)
                .expect("frame")
                .transmission
        };
        let mut gpu = GpuFluoroRenderer::new(ctx, scene).expect("renderer");
        gpu.update_needle(&needle(0));
        // Warm-up (pipelines, tables, targets).
        let _ = gpu.render_frame(&ap, &settings(0), None).expect("frame");
        // A session's detector: scatter behind the grid and the flat panel's profile, with the
        // air gap of the default C-arm's AP view of L4 (606 mm: the brightness bench's table).
        let session = |k: usize| RenderSettings {
            scatter: Some(ScatterSettings {
                kvp: 80,
                grid: true,
                air_gap_mm: 606.0,
                pixel_pitch_mm: ap.pixel_pitch_mm[0],
            }),
            receptor: Some(ReceptorSettings {
                kind: ReceptorKind::FlatPanel,
                pixel_pitch_mm: ap.pixel_pitch_mm[0],
            }),
            ..settings(k)
        };
        let cases: [(&str, bool); 5] = [
            ("from scratch (caches off)", false),
            ("C-arm moved", true),
            ("needle moved 1 mm, same pose", true),
            ("nothing changed (new shot)", true),
            ("new shot, scatter and flat panel (a session's)", true),
        ];
        for (case, (name, caching)) in cases.into_iter().enumerate() {
            gpu.caching = caching;
            if case == 4 {
                // The shot that makes the detector signal the timed ones reuse.
                let _ = gpu
                    .render_frame(&ap, &session(frames + 1), None)
                    .expect("frame");
            }
            let (t, wall, exact) = phases(
                &mut gpu,
                frames,
                |g, k| match case {
                    0 | 1 => (pose(k + 1), settings(k)),
                    2 => {
                        g.update_needle(&needle(k + 1));
                        (ap, settings(k))
                    }
                    3 => (ap, settings(k)),
                    _ => (ap, session(k)),
                },
                |k, p, s| match case {
                    0 | 1 => reference(0, p, s),
                    2 => reference(k + 1, p, s),
                    _ => reference(frames, p, s),
                },
            );
            if case == 1 {
                // Back to the AP pose with needle 0 before the needle and shot cases.
                gpu.update_needle(&needle(0));
                let _ = gpu.render_frame(&ap, &settings(0), None).expect("frame");
            }
            out.push(format!(
                "| {voxel} | {tris} | {n} x {n} | {name} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {wall:.1} | {} | {} |",
                t.encode_ms,
                t.gpu_ms,
                t.readback_ms,
                t.supersample_ms,
                t.finish_ms,
                t.resolved_samples,
                if exact { "yes" } else { "NO" }
            ));
            eprintln!("progress: {}", out.last().expect("row"));
        }
    }
    out
}
