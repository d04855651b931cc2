//! GPU fluoroscopy against sim-core's CPU reference on the same scenes.
//!
//! "Away from silhouette edges" means: pixels whose 3 x 3 neighbourhood has the same CPU hit
//! signature (the set of meshes each centre ray crosses) as the pixel itself. At the other
//! pixels a triangle edge passes within a pixel of the centre, where the GPU rasteriser's
//! fixed-point coverage and the CPU's f64 ray test may legitimately disagree about a hit.
//! On scenes with concave meshes (the phantom) a mesh also has silhouettes inside its own
//! projection, where a ray grazes a fold and the number of times it crosses the mesh changes
//! while the set of meshes does not: there the neighbourhood must also cross every mesh the
//! same number of times ([`fold_free`]).

use render_worker::fluoro::{CHANNELS, GpuFluoroRenderer};
use render_worker::gpu::context_for_tests;
use sim_core::fluoro::analytic::SpherePhantom;
use sim_core::fluoro::{
    EnergyModel, FluoroMaterial, IodineField, Projection, RayChords, RenderSettings, Scene,
    render_chords, render_frame, render_transmission,
};
use sim_core::geom::{capped_cylinder, equal_area_vertex_radius};
use sim_core::material::MaterialClass;
use sim_core::volume::{Volume, VolumeGrid};

/// Per-channel path-length tolerance from the issue: 0.1 mm or 0.5 %, whichever is larger.
fn chord_tolerance_mm(cpu_mm: f64) -> f64 {
    0.1f64.max(0.005 * cpu_mm.abs())
}

/// The pixels of `pixels` whose 3 x 3 neighbourhood (clipped at the image border) has the same
/// `key` as the pixel itself; `key` is indexed by pixel, row-major, `w` x `h`.
fn uniform_neighbourhood<K: PartialEq>(
    pixels: impl IntoIterator<Item = usize>,
    key: &[K],
    w: usize,
    h: usize,
) -> Vec<usize> {
    pixels
        .into_iter()
        .filter(|&p| {
            let (i, j) = (p % w, p / w);
            (j.saturating_sub(1)..(j + 2).min(h)).all(|jj| {
                (i.saturating_sub(1)..(i + 2).min(w)).all(|ii| key[jj * w + ii] == key[p])
            })
        })
        .collect()
}

/// Indices of pixels whose 3 x 3 neighbourhood has one CPU signature.
fn interior_pixels(cpu: &[RayChords], w: usize, h: usize) -> Vec<usize> {
    let signatures: Vec<u64> = cpu.iter().map(|r| r.signature).collect();
    uniform_neighbourhood(0..w * h, &signatures, w, h)
}

/// The pixels of `pixels` whose 3 x 3 neighbourhood's centre rays cross every scene entry the
/// same number of times as the pixel's own ray (CPU f64 hits): no fold of any mesh projects
/// within a pixel of the centre. A grazed fold is a silhouette edge inside the mesh's outline,
/// where a sliver thinner than the rasteriser's sub-pixel grid may be hit by one side only (seen
/// on the phantom: a 0.15 mm sliver of a vertebral body at the edge of a lobe).
fn fold_free(pixels: &[usize], scene: &Scene, p: &Projection, w: usize, h: usize) -> Vec<usize> {
    let mut hits = Vec::new();
    let counts: Vec<Vec<usize>> = (0..w * h)
        .map(|q| {
            let ray = p.pixel_ray([(q % w) as f64 + 0.5, (q / w) as f64 + 0.5]);
            scene
                .entries()
                .iter()
                .map(|e| {
                    e.bvh
                        .all_hits(ray.origin_mm, ray.dir, 0.0, ray.detector_t_mm, &mut hits);
                    hits.len()
                })
                .collect()
        })
        .collect();
    uniform_neighbourhood(pixels.iter().copied(), &counts, w, h)
}

struct ChordReport {
    compared: usize,
    steel_pixels: usize,
    worst_excess_mm: f64,
    worst: String,
    failures: usize,
}

/// Compares GPU and CPU chords at interior pixels; `failures` counts channel values outside
/// [`chord_tolerance_mm`].
fn compare_chords(gpu: &[[f32; CHANNELS]], cpu: &[RayChords], w: usize, h: usize) -> ChordReport {
    let mut r = ChordReport {
        compared: 0,
        steel_pixels: 0,
        worst_excess_mm: f64::NEG_INFINITY,
        worst: String::new(),
        failures: 0,
    };
    for p in interior_pixels(cpu, w, h) {
        r.compared += 1;
        if cpu[p].chords_mm[FluoroMaterial::Steel.index()] > 0.0 {
            r.steel_pixels += 1;
        }
        for (c, (&g, &e)) in gpu[p].iter().zip(&cpu[p].chords_mm).enumerate() {
            let g = f64::from(g);
            let excess = (g - e).abs() - chord_tolerance_mm(e);
            if excess > 0.0 {
                r.failures += 1;
            }
            if excess > r.worst_excess_mm {
                r.worst_excess_mm = excess;
                r.worst = format!("pixel ({}, {}) channel {c}: gpu {g} cpu {e}", p % w, p / w);
            }
        }
    }
    r
}

fn sphere_scene() -> Scene {
    SpherePhantom {
        subdivisions: 5,
        volume_matched: true,
        needle_segments: 16,
    }
    .build()
    .0
}

/// A view of the whole sphere phantom, and a zoomed oblique view of the needle entering the
/// bone (0.4 mm pixels: the 0.72 mm needle is 3.7 pixels wide, so interior pixels exist on it).
fn sphere_views() -> [Projection; 2] {
    [
        Projection {
            detector_pixels: [160, 160],
            pixel_pitch_mm: [2.8, 2.8],
            ..Projection::default()
        },
        Projection {
            orbital_deg: 25.0,
            angular_deg: -12.0,
            isocentre_mm: [5.0, -15.0, 18.0],
            detector_pixels: [192, 160],
            pixel_pitch_mm: [0.4, 0.4],
            ..Projection::default()
        },
    ]
}

#[test]
fn sphere_phantom_chords_match_the_cpu_away_from_edges() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let scene = sphere_scene();
    let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    for (k, p) in sphere_views().iter().enumerate() {
        let [w, h] = p.detector_pixels.map(|x| x as usize);
        let cpu = render_chords(&scene, p, 0);
        let g = gpu.render_chords(p).expect("gpu chords");
        let r = compare_chords(&g, &cpu, w, h);
        eprintln!(
            "view {k}: {} interior pixels ({} on steel), worst excess over tolerance {:.2e} mm at {}",
            r.compared, r.steel_pixels, r.worst_excess_mm, r.worst
        );
        // Most of the image is interior (edges are a thin band), so the comparison is not empty.
        assert!(r.compared > w * h / 2, "{} of {}", r.compared, w * h);
        assert_eq!(r.failures, 0, "worst: {}", r.worst);
        if k == 1 {
            // The zoomed view really checks the needle's subtraction from soft tissue and bone.
            assert!(r.steel_pixels > 100, "{}", r.steel_pixels);
        }
    }
}

#[test]
fn a_moved_needle_matches_the_cpu_scene_with_that_needle() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let (scene, _) = SpherePhantom {
        subdivisions: 4,
        volume_matched: true,
        needle_segments: 16,
    }
    .build();
    let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    // Move the needle: now it runs from the tissue through the whole bone sphere.
    let (base, tip) = ([-40.0, -60.0, 10.0], [30.0, 10.0, 30.0]);
    let r = equal_area_vertex_radius(0.36, 16);
    let needle = capped_cylinder(base, tip, r, 16);
    gpu.update_needle(&needle);
    let mut moved = Scene::new();
    for e in scene
        .entries()
        .iter()
        .filter(|e| e.material != FluoroMaterial::Steel)
    {
        let tris = e.bvh.triangles_mm();
        let mesh = sim_core::mesh::TriMesh {
            vertices_mm: tris.iter().flatten().copied().collect(),
            triangles: (0..tris.len() as u32)
                .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
                .collect(),
        };
        moved.add_with_priority(e.name.clone(), e.material, e.priority, &mesh);
    }
    moved.add("needle", FluoroMaterial::Steel, &needle);
    let p = Projection {
        orbital_deg: -35.0,
        isocentre_mm: [0.0, -20.0, 20.0],
        detector_pixels: [160, 160],
        pixel_pitch_mm: [0.35, 0.35],
        ..Projection::default()
    };
    let cpu = render_chords(&moved, &p, 0);
    let g = gpu.render_chords(&p).expect("gpu chords");
    let rep = compare_chords(&g, &cpu, 160, 160);
    eprintln!(
        "moved needle: {} interior pixels ({} on steel), worst {:.2e} mm at {}",
        rep.compared, rep.steel_pixels, rep.worst_excess_mm, rep.worst
    );
    assert!(rep.steel_pixels > 100 && rep.compared > 160 * 160 / 2);
    assert_eq!(rep.failures, 0, "worst: {}", rep.worst);
    // And clearing it removes all steel.
    gpu.clear_needle();
    let g = gpu.render_chords(&p).expect("gpu chords");
    assert!(g.iter().all(|c| c[FluoroMaterial::Steel.index()] == 0.0));
}

/// Centre-sampled CPU settings (the GPU samples pixel centres only; see the module doc).
fn centre_settings(energy: EnergyModel) -> RenderSettings {
    RenderSettings {
        energy,
        supersample: 1,
        ..RenderSettings::default()
    }
}

#[test]
fn polychromatic_transmission_and_frame_match_the_cpu() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let scene = sphere_scene();
    let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    let p = sphere_views()[1];
    let [w, h] = p.detector_pixels.map(|x| x as usize);
    let cpu_chords = render_chords(&scene, &p, 0);
    let interior = interior_pixels(&cpu_chords, w, h);
    for energy in [EnergyModel::Spectral { kvp: 80 }, EnergyModel::Mono60] {
        let settings = centre_settings(energy);
        let cpu = render_transmission(&scene, None, &p, &settings).unwrap();
        let g = gpu.render_transmission(&p, &energy, None).unwrap();
        // Tolerance on ln T: f32 depths carry ~1e-4 mm per crossing (ulp of ~1 m), a few
        // crossings times steel's 0.96 per mm gives ~5e-4; the f32 spectral sum adds ~1e-5.
        // 2e-3 leaves a factor of 4.
        let mut worst = 0f64;
        for &q in &interior {
            let d = (f64::from(g.transmission[q]).ln() - cpu.transmission[q].ln()).abs();
            worst = worst.max(d);
        }
        eprintln!(
            "{energy:?}: worst |ln T| difference {worst:.2e} over {} pixels",
            interior.len()
        );
        assert!(worst < 2e-3, "{worst}");
    }
    // The 8-bit frame: same automatic brightness and mapping, so interior pixels differ by at
    // most one grey level (2e-3 in ln T is 0.15 level at 3.5 ln units per 255 levels, plus the
    // median's own difference of the same size; rounding can flip one level).
    let settings = centre_settings(EnergyModel::Spectral { kvp: 80 });
    let cpu_img = render_frame(&scene, None, &p, &settings).unwrap();
    let gpu_img = gpu.render_frame(&p, &settings, None).unwrap();
    assert_eq!(
        (gpu_img.width, gpu_img.height),
        (cpu_img.width, cpu_img.height)
    );
    let mut off_by_one = 0;
    for &q in &interior {
        let d = (i32::from(gpu_img.pixels[q]) - i32::from(cpu_img.pixels[q])).abs();
        assert!(
            d <= 1,
            "pixel {q}: gpu {} cpu {}",
            gpu_img.pixels[q],
            cpu_img.pixels[q]
        );
        off_by_one += usize::from(d == 1);
    }
    // And the grey levels are not all equal by accident (the view spans tissue, bone, steel).
    let (lo, hi) = gpu_img
        .pixels
        .iter()
        .fold((255, 0), |(l, h), &g| (g.min(l), g.max(h)));
    eprintln!("frame: {off_by_one} interior pixels off by one level; grey range {lo}..{hi}");
    assert!(hi - lo > 50);
}

#[test]
fn iodine_column_matches_the_exact_cpu_integral() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    // The CPU render test's synthetic pool: 21^3 voxels of 1 mm, 50 % stock in the middle 11^3,
    // plus a smooth gradient so that interpolation matters.
    let grid = VolumeGrid {
        dims: [21, 21, 21],
        spacing_mm: [1.0; 3],
        origin_mm: [-20.0, -10.0, -10.0],
    };
    let mut v = Volume::filled(grid, 0.0f32);
    for k in 0..21 {
        for j in 0..21 {
            for i in 0..21 {
                let inside = (5..16).contains(&i) && (5..16).contains(&j) && (5..16).contains(&k);
                let base = if inside { 0.5 } else { 0.0 };
                v.set(i, j, k, base + 0.01 * i as f32);
            }
        }
    }
    let field = IodineField::new(v);
    let mut scene = Scene::new();
    scene.add(
        "body",
        FluoroMaterial::Tissue(MaterialClass::SoftTissue),
        &sim_core::mesh::TriMesh::icosphere([0.0; 3], 40.0, 3),
    );
    let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    let p = Projection {
        orbital_deg: 20.0,
        angular_deg: 10.0,
        detector_pixels: [64, 64],
        pixel_pitch_mm: [1.2, 1.2],
        ..Projection::default()
    };
    let mono = EnergyModel::Mono60;
    let with = gpu.render_transmission(&p, &mono, Some(&field)).unwrap();
    let without = gpu.render_transmission(&p, &mono, None).unwrap();
    // In the single-energy mode -ln T is linear: the iodine column is the ln-ratio over mu.
    let k = sim_core::fluoro::attenuation::iodine_stock_mu_60kev_per_cm() * 0.1;
    let frame = p.frame();
    let mut worst = 0f64;
    let mut max_col = 0f64;
    for j in 0..64 {
        for i in 0..64 {
            let q = j * 64 + i;
            let gpu_col =
                (f64::from(without.transmission[q]) / f64::from(with.transmission[q])).ln() / k;
            let ray = p.pixel_ray([i as f64 + 0.5, j as f64 + 0.5]);
            let cpu_col = field.column_stock_mm(frame.source_mm, ray.dir, 0.0, ray.detector_t_mm);
            max_col = max_col.max(cpu_col);
            worst = worst.max((gpu_col - cpu_col).abs());
        }
    }
    eprintln!("iodine: worst column error {worst:.2e} mm (largest column {max_col:.2} mm)");
    assert!(max_col > 5.0);
    // Midpoint rule with 0.25-voxel steps: the trilinear field's slope jumps at every plane of
    // voxel centres; each jump of up to 0.5/mm costs at most h^2/8 x 0.5 = 4e-3 mm, and a ray
    // meets a handful of the pool's jumps: 0.03 mm. The f32 ln-ratio adds ~1e-5 mm.
    assert!(worst < 0.03, "{worst}");
}

#[test]
fn the_resolve_without_iodine_equals_the_one_with_an_empty_iodine_field() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    // Frames without a contrast field use a resolve kernel built without the iodine ray march;
    // with a field of zeros the kernel with the march runs and must give the same transmission,
    // bit for bit, on every ray (polychromatic, with bone and a needle: the table path and the
    // spectral sum both run).
    let grid = VolumeGrid {
        dims: [8, 8, 8],
        spacing_mm: [4.0; 3],
        origin_mm: [-14.0; 3],
    };
    let zeros = IodineField::new(Volume::filled(grid, 0.0f32));
    let mut scene = Scene::new();
    scene.add(
        "body",
        FluoroMaterial::Tissue(MaterialClass::SoftTissue),
        &sim_core::mesh::TriMesh::icosphere([0.0; 3], 60.0, 3),
    );
    scene.add(
        "bone",
        FluoroMaterial::Tissue(MaterialClass::CorticalBone),
        &sim_core::mesh::TriMesh::icosphere([5.0, 0.0, 0.0], 20.0, 3),
    );
    let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    gpu.update_needle(&capped_cylinder(
        [-50.0, -40.0, 0.0],
        [0.0, 0.0, 0.0],
        0.36,
        16,
    ));
    let p = Projection {
        orbital_deg: 15.0,
        detector_pixels: [64, 64],
        pixel_pitch_mm: [4.0, 4.0],
        ..Projection::default()
    };
    let poly = EnergyModel::Spectral { kvp: 80 };
    gpu.caching = false;
    let with = gpu.render_transmission(&p, &poly, Some(&zeros)).unwrap();
    let without = gpu.render_transmission(&p, &poly, None).unwrap();
    let differing = (0..with.transmission.len())
        .filter(|&q| with.transmission[q].to_bits() != without.transmission[q].to_bits())
        .count();
    let (lo, hi) = without
        .transmission
        .iter()
        .fold((f32::INFINITY, 0f32), |(l, h), &t| (t.min(l), t.max(h)));
    eprintln!("resolve specialisations: {differing} differing rays; T in {lo:.3e}..{hi:.3e}");
    assert_eq!(differing, 0);
    // The view holds tissue, bone and open field, so both paths of the kernel ran.
    assert!(lo < 0.05 && hi > 0.9, "{lo} {hi}");
}

/// The lumbar phantom (procedural, 5 mm grid: about 184k triangles, a few seconds to build).
///
/// Two comparisons, because where two of the phantom's structures still overlap (touching
/// structures are meshed as laminar families sharing their interfaces, but a few pairs' surfaces
/// cross), the L-buffer's laminar nesting counts the overlap twice where the CPU's priority rule
/// counts it once:
/// 1. The GPU against the same linear rule evaluated on the CPU from sim-core's exact raw
///    per-mesh chords (`Scene::ray_entry_chords`) and the renderer's nesting: this isolates the
///    GPU implementation and must meet the 0.1 mm / 0.5 % at every interior pixel.
/// 2. The GPU against the CPU priority rule: reported, with the fraction of interior pixels
///    within that tolerance asserted at the level measured when this test was written.
#[test]
fn lumbar_phantom_chords_match_the_cpu() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    use sim_core::anatomy::phantom::{self, PhantomParams};
    let params = PhantomParams::with_voxel_mm(5.0);
    let region = phantom::build(&params, &mut |_| {}).expect("phantom");
    let mut scene = Scene::new();
    for s in &region.structures {
        scene.add(s.name.clone(), FluoroMaterial::Tissue(s.material), &s.mesh);
    }
    let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    let p = Projection {
        orbital_deg: 15.0,
        isocentre_mm: [0.0, 0.0, -40.0],
        detector_pixels: [192, 192],
        pixel_pitch_mm: [300.0 / 192.0; 2],
        ..Projection::default()
    };
    let (w, h) = (192usize, 192usize);
    let g = gpu.render_chords(&p).expect("gpu chords");
    let cpu = render_chords(&scene, &p, 0);
    let outline_interior = interior_pixels(&cpu, w, h);
    let interior = fold_free(&outline_interior, &scene, &p, w, h);
    // Measured: 22,951 pixels without a change of signature, 16,907 of them away from folds.
    assert!(interior.len() > w * h / 3, "{}", interior.len());
    let cort = FluoroMaterial::Tissue(MaterialClass::CorticalBone).index();
    let canc = FluoroMaterial::Tissue(MaterialClass::Cancellous).index();
    let (mut linear_worst, mut within, mut priority_errs) = (f64::NEG_INFINITY, 0usize, Vec::new());
    for &q in &interior {
        let ray = p.pixel_ray([(q % w) as f64 + 0.5, (q / w) as f64 + 0.5]);
        let raw = scene.ray_entry_chords(ray.origin_mm, ray.dir, ray.detector_t_mm);
        let mut lin = [0f64; CHANNELS];
        for d in gpu.drawn() {
            lin[d.effective.index()] += raw[d.entry];
            if let Some(c) = d.container {
                lin[c.index()] -= raw[d.entry];
            }
        }
        let total = (lin[cort] + lin[canc]).max(0.0);
        lin[canc] = lin[canc].clamp(0.0, (total - 2.0 * scene.cortical_shell_mm).max(0.0));
        lin[cort] = total - lin[canc];
        let mut ok = true;
        for c in 0..CHANNELS {
            let gq = f64::from(g[q][c]);
            linear_worst = linear_worst.max((gq - lin[c]).abs() - chord_tolerance_mm(lin[c]));
            let e = (gq - cpu[q].chords_mm[c]).abs();
            priority_errs.push(e);
            ok &= e <= chord_tolerance_mm(cpu[q].chords_mm[c]);
        }
        within += usize::from(ok);
    }
    priority_errs.sort_by(f64::total_cmp);
    let n = priority_errs.len();
    let frac = within as f64 / interior.len() as f64;
    eprintln!(
        "phantom: {} interior pixels ({} without a change of signature, less those at folds); GPU vs linear rule worst excess {linear_worst:.2e} mm; \
         GPU vs priority rule: median {:.1e} mm, p99 {:.2} mm, max {:.2} mm, {:.2} % of pixels within tolerance",
        interior.len(),
        outline_interior.len(),
        priority_errs[n / 2],
        priority_errs[n * 99 / 100],
        priority_errs[n - 1],
        100.0 * frac
    );
    assert!(linear_worst <= 0.0, "{linear_worst}");
    // Measured: 99.9 % of interior pixels within tolerance on this 5 mm phantom and view (was
    // 86 % before touching structures were meshed as laminar families sharing their interfaces;
    // the rest see pairs of structures whose surfaces cross, listed in the build's provenance
    // notes). 99 % leaves slack for rounding only.
    assert!(frac > 0.99, "{frac}");
}

/// Needle supersampling: the GPU's `n x n` samples at the CPU's positions near the needle's
/// projected edges (a 1.8-pixel needle here) against the CPU's adaptive supersampling.
#[test]
fn needle_supersampling_matches_the_cpu() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let scene = sphere_scene();
    let anatomy = {
        let mut a = Scene::new();
        for e in scene
            .entries()
            .iter()
            .filter(|e| e.material != FluoroMaterial::Steel)
        {
            let tris = e.bvh.triangles_mm();
            let mesh = sim_core::mesh::TriMesh {
                vertices_mm: tris.iter().flatten().copied().collect(),
                triangles: (0..tris.len() as u32)
                    .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
                    .collect(),
            };
            a.add_with_priority(e.name.clone(), e.material, e.priority, &mesh);
        }
        a
    };
    let mut gpu = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    let p = Projection {
        orbital_deg: 25.0,
        angular_deg: -12.0,
        isocentre_mm: [-10.0, -30.0, 5.0],
        detector_pixels: [128, 128],
        pixel_pitch_mm: [0.8, 0.8],
        ..Projection::default()
    };
    let (w, h) = (128usize, 128usize);
    let settings = RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 4,
        adaptive: true,
        ..RenderSettings::default()
    };
    let cpu = render_transmission(&scene, None, &p, &settings).unwrap();
    let g = gpu
        .render_transmission_supersampled(&p, &settings, None)
        .unwrap();
    let centre = gpu.render_transmission(&p, &settings.energy, None).unwrap();
    let flags = gpu.needle_edge_pixels(&p);
    let full_sig = render_chords(&scene, &p, 0);
    let anat_sig = render_chords(&anatomy, &p, 0);
    let (full_int, anat_int) = (
        interior_pixels(&full_sig, w, h),
        interior_pixels(&anat_sig, w, h),
    );
    let mut in_anat = vec![false; w * h];
    anat_int.iter().for_each(|&q| in_anat[q] = true);
    // Pixels the CPU supersamples exactly where the GPU does: flagged by the steel-edge rule
    // with no anatomy silhouette in the 3 x 3 neighbourhood, or unflagged interior pixels.
    let flagged: Vec<usize> = (0..w * h).filter(|&q| flags[q] && in_anat[q]).collect();
    let plain: Vec<usize> = full_int.into_iter().filter(|&q| !flags[q]).collect();
    let diff = |t: &[f32], q: usize| (f64::from(t[q]).ln() - cpu.transmission[q].ln()).abs();
    let worst_flagged = flagged
        .iter()
        .map(|&q| diff(&g.transmission, q))
        .fold(0.0, f64::max);
    let worst_plain = plain
        .iter()
        .map(|&q| diff(&g.transmission, q))
        .fold(0.0, f64::max);
    let centre_flagged = flagged
        .iter()
        .map(|&q| diff(&centre.transmission, q))
        .fold(0.0, f64::max);
    eprintln!(
        "supersampling: {} flagged pixels, worst |ln T| diff {worst_flagged:.2e} \
         (centre samples only: {centre_flagged:.2e}); {} other pixels, worst {worst_plain:.2e}; \
         CPU supersampled {} pixels",
        flagged.len(),
        plain.len(),
        cpu.supersampled_pixels
    );
    assert!(flagged.len() > 100, "{}", flagged.len());
    // Same 2e-3 as the centre-sampled comparison: each sample is an independent ray with the
    // same f32 error (a sample on the needle's very silhouette may be covered differently by the
    // rasteriser and the CPU's ray test, but its chord there is near zero).
    assert!(worst_flagged < 2e-3 && worst_plain < 2e-3);
    // And the comparison can fail: centre sampling alone misses the needle edges by far more.
    assert!(centre_flagged > 10.0 * 2e-3, "{centre_flagged}");
}
