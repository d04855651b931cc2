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

use render_worker::fluoro::{CHANNELS, GpuAnatomy, GpuFluoroRenderer};
use render_worker::gpu::context_for_tests;
use sim_core::compare::{Compare, Diff, Tolerance};
use sim_core::fluoro::analytic::SpherePhantom;
use sim_core::fluoro::{
    EnergyModel, FluoroMaterial, IodineField, Projection, RayChords, RenderSettings, Scene,
    render_chords, render_frame, render_transmission,
};
use sim_core::geom::{capped_cylinder, equal_area_vertex_radius};
use sim_core::material::MaterialClass;
use sim_core::volume::{Volume, VolumeGrid};

/// Per-channel path-length tolerance: 0.1 mm or 0.5 %, whichever is larger. Simulator choice:
/// 0.1 mm of cortical bone (0.52 per cm at 60 keV, methods page) moves -ln T by 0.005, a small
/// fraction of one 8-bit grey level; 0.5 % keeps long chords, whose f32 sums of signed distances
/// lose absolute precision, to the same relative accuracy.
const CHORD_TOLERANCE: Tolerance = Tolerance::absolute_or_relative(0.1, 0.005);

/// GPU against CPU chords of a `w` x `h` view, per channel within [`CHORD_TOLERANCE`].
fn chord_comparison(w: usize, h: usize) -> Compare {
    Compare::image(w, h)
        .channels(CHANNELS)
        .tolerance(CHORD_TOLERANCE)
}

/// The CPU chords as one row-major image of `CHANNELS` values per pixel.
fn cpu_chord_image(cpu: &[RayChords]) -> Vec<f64> {
    cpu.iter().flat_map(|r| r.chords_mm).collect()
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
    steel_pixels: usize,
    diff: Diff,
}

impl ChordReport {
    /// Where the chords are furthest outside [`CHORD_TOLERANCE`] (or closest to it).
    fn worst(&self) -> String {
        self.diff.worst.map(|s| s.to_string()).unwrap_or_default()
    }
}

/// Compares GPU and CPU chords at interior pixels; `diff.values_over` counts channel values
/// outside [`CHORD_TOLERANCE`].
fn compare_chords(gpu: &[[f32; CHANNELS]], cpu: &[RayChords], w: usize, h: usize) -> ChordReport {
    let interior = interior_pixels(cpu, w, h);
    let steel = FluoroMaterial::Steel.index();
    ChordReport {
        steel_pixels: interior
            .iter()
            .filter(|&&p| cpu[p].chords_mm[steel] > 0.0)
            .count(),
        diff: chord_comparison(w, h)
            .at(gpu.as_flattened(), &cpu_chord_image(cpu), interior)
            .expect("chord images of the view's size"),
    }
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
            r.diff.pixels,
            r.steel_pixels,
            r.diff.worst_excess,
            r.worst()
        );
        // Most of the image is interior (edges are a thin band), so the comparison is not empty.
        assert!(r.diff.pixels > w * h / 2, "{} of {}", r.diff.pixels, w * h);
        r.diff.check().unwrap_or_else(|e| panic!("view {k}: {e}"));
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
        rep.diff.pixels,
        rep.steel_pixels,
        rep.diff.worst_excess,
        rep.worst()
    );
    assert!(rep.steel_pixels > 100 && rep.diff.pixels > 160 * 160 / 2);
    rep.diff
        .check()
        .unwrap_or_else(|e| panic!("moved needle: {e}"));
    // And clearing it removes all steel.
    gpu.clear_needle();
    let g = gpu.render_chords(&p).expect("gpu chords");
    assert!(g.iter().all(|c| c[FluoroMaterial::Steel.index()] == 0.0));
}

/// `ln T` of each pixel's transmission.
fn ln_of<T: Copy + Into<f64>>(transmission: &[T]) -> Vec<f64> {
    transmission.iter().map(|&t| t.into().ln()).collect()
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
        let worst = Compare::image(w, h)
            .at(
                &ln_of(&g.transmission),
                &ln_of(&cpu.transmission),
                interior.iter().copied(),
            )
            .expect("transmissions of the view's size")
            .max_abs;
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
    let frame = Compare::image(w, h)
        .at(&gpu_img.pixels, &cpu_img.pixels, interior.iter().copied())
        .expect("frames of the view's size");
    assert!(frame.max_abs <= 1.0, "{frame}");
    // Every interior difference is 0 or 1, so the pixels that differ at all are off by one.
    let off_by_one = frame.pixels_over;
    // And the grey levels are not all equal by accident (the view spans tissue, bone, steel).
    let (lo, hi) = gpu_img
        .pixels
        .iter()
        .fold((255, 0), |(l, h), &g| (g.min(l), g.max(h)));
    eprintln!("frame: {off_by_one} interior pixels off by one level; grey range {lo}..{hi}");
    assert!(hi - lo > 50);
}

/// Two renderers of `scene` with its steel entries as the needle: one drawing the L-buffer
/// passes on the CPU (`raster`, whatever the adapter), one leaving them to the adapter.
fn cpu_and_adapter_renderers(
    ctx: &render_worker::gpu::GpuContext,
    scene: &Scene,
) -> (GpuFluoroRenderer, GpuFluoroRenderer) {
    let renderer = |cpu: bool| {
        let a = if cpu {
            GpuAnatomy::with_cpu_geometry(ctx, scene)
        } else {
            GpuAnatomy::new(ctx, scene)
        };
        let mut r = GpuFluoroRenderer::with_anatomy(a.expect("anatomy"));
        let steel: Vec<[f64; 3]> = scene
            .entries()
            .iter()
            .filter(|e| e.material == FluoroMaterial::Steel)
            .flat_map(|e| e.bvh.triangles_mm().iter().flatten().copied())
            .collect();
        r.update_needle(&sim_core::mesh::TriMesh {
            triangles: (0..steel.len() as u32 / 3)
                .map(|t| [3 * t, 3 * t + 1, 3 * t + 2])
                .collect(),
            vertices_mm: steel,
        });
        r.set_cpu_geometry(cpu);
        r
    };
    let (on_cpu, on_adapter) = (renderer(true), renderer(false));
    assert!(on_cpu.cpu_geometry() && !on_adapter.cpu_geometry());
    (on_cpu, on_adapter)
}

/// A mesh reaching behind the focal spot's plane (a cylinder around the whole C-arm, which the
/// adapter clips) is refused by the CPU passes, which then leave every pass to the adapter:
/// the frames equal those of a renderer that never uses them, bit for bit, needle and
/// supersampled region included.
#[test]
fn frames_the_cpu_passes_refuse_are_the_adapters() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let mut scene = sphere_scene();
    let room = capped_cylinder([0.0, -3000.0, 0.0], [0.0, 3000.0, 0.0], 3000.0, 16);
    scene.add("room", FluoroMaterial::Tissue(MaterialClass::Fat), &room);
    let (mut on_cpu, mut on_adapter) = cpu_and_adapter_renderers(&ctx, &scene);
    let settings = RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 2,
        ..RenderSettings::default()
    };
    for p in sphere_views() {
        let a = on_cpu.render_frame(&p, &settings, None).unwrap();
        let b = on_adapter.render_frame(&p, &settings, None).unwrap();
        assert_eq!(a, b);
        assert!(on_cpu.last_timings().resolved_samples > 0);
    }
}

/// The L-buffer passes drawn by the worker's cores (`raster`: f64 sums of the f64 triangles,
/// what a software adapter gets) and by the adapter's rasteriser (f32 sums of f32 vertices)
/// give the same transmission as the CPU reference at interior pixels, within the tolerance of
/// `polychromatic_transmission_and_frame_match_the_cpu` (2e-3 in ln T), the CPU's at least as
/// close, and frames with the needle's supersampled region within a grey level of each other.
#[test]
fn the_cpu_passes_match_the_adapters_and_the_cpu_reference() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let scene = sphere_scene();
    let (mut on_cpu, mut on_adapter) = cpu_and_adapter_renderers(&ctx, &scene);
    // A software adapter (lavapipe, as in CI) gets the CPU pass by default; a GPU does not.
    assert_eq!(
        GpuFluoroRenderer::new(&ctx, &scene)
            .expect("renderer")
            .cpu_geometry(),
        ctx.summary.is_software
    );
    let energy = EnergyModel::Spectral { kvp: 80 };
    for (k, p) in sphere_views().iter().enumerate() {
        let [w, h] = p.detector_pixels.map(|x| x as usize);
        let interior = interior_pixels(&render_chords(&scene, p, 0), w, h);
        let reference = ln_of(
            &render_transmission(&scene, None, p, &centre_settings(energy))
                .unwrap()
                .transmission,
        );
        let against_reference = |t: &[f32]| {
            Compare::image(w, h)
                .at(&ln_of(t), &reference, interior.iter().copied())
                .expect("transmissions of the view's size")
        };
        let cpu_t = on_cpu.render_transmission(p, &energy, None).unwrap();
        let adapter_t = on_adapter.render_transmission(p, &energy, None).unwrap();
        let (cpu_d, adapter_d) = (
            against_reference(&cpu_t.transmission),
            against_reference(&adapter_t.transmission),
        );
        eprintln!(
            "view {k}, |ln T| against the CPU reference at {} interior pixels: CPU pass worst {:.2e}, mean {:.2e}; adapter worst {:.2e}, mean {:.2e}",
            interior.len(),
            cpu_d.max_abs,
            cpu_d.mean_abs,
            adapter_d.max_abs,
            adapter_d.mean_abs
        );
        assert!(
            cpu_d.max_abs < 2e-3 && adapter_d.max_abs < 2e-3,
            "{cpu_d} / {adapter_d}"
        );
        // f64 sums of f64 triangles, and the needle's distances in f64: the worst pixel is no
        // worse than the adapter's (whose f32 needle pass is off by 2e-4 at the zoomed view's
        // needle edge; the rest of both errors is the resolve's, which they share).
        assert!(cpu_d.max_abs <= adapter_d.max_abs, "{cpu_d} / {adapter_d}");
        // The supersampled needle region (its geometric pass is the CPU's too): the two
        // renderers' frames agree to within one grey level at interior pixels.
        let settings = RenderSettings {
            energy,
            supersample: 2,
            ..RenderSettings::default()
        };
        let a = on_cpu.render_frame(p, &settings, None).unwrap();
        let b = on_adapter.render_frame(p, &settings, None).unwrap();
        let frame = Compare::image(w, h)
            .at(&a.pixels, &b.pixels, interior.iter().copied())
            .expect("frames of the view's size");
        eprintln!("view {k}: supersampled frames, CPU pass against adapter: {frame}");
        assert!(frame.max_abs <= 1.0, "view {k}: {frame}");
    }
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
    let gpu_cols: Vec<f64> = (0..64 * 64)
        .map(|q| (f64::from(without.transmission[q]) / f64::from(with.transmission[q])).ln() / k)
        .collect();
    let cpu_cols: Vec<f64> = (0..64 * 64)
        .map(|q| {
            let ray = p.pixel_ray([(q % 64) as f64 + 0.5, (q / 64) as f64 + 0.5]);
            field.column_stock_mm(frame.source_mm, ray.dir, 0.0, ray.detector_t_mm)
        })
        .collect();
    let max_col = cpu_cols.iter().fold(0f64, |m, &c| m.max(c));
    let worst = Compare::image(64, 64)
        .all(&gpu_cols, &cpu_cols)
        .expect("64 x 64 columns")
        .max_abs;
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
///    GPU implementation and must meet [`CHORD_TOLERANCE`] at every interior pixel.
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
    // The linear rule on the CPU at the interior pixels (zero elsewhere, where nothing is
    // compared).
    let mut linear = vec![0f64; w * h * CHANNELS];
    for &q in &interior {
        let ray = p.pixel_ray([(q % w) as f64 + 0.5, (q / w) as f64 + 0.5]);
        let raw = scene.ray_entry_chords(ray.origin_mm, ray.dir, ray.detector_t_mm);
        let lin = &mut linear[q * CHANNELS..(q + 1) * CHANNELS];
        for d in gpu.drawn() {
            lin[d.effective.index()] += raw[d.entry];
            if let Some(c) = d.container {
                lin[c.index()] -= raw[d.entry];
            }
        }
        let total = (lin[cort] + lin[canc]).max(0.0);
        lin[canc] = lin[canc].clamp(0.0, (total - 2.0 * scene.cortical_shell_mm).max(0.0));
        lin[cort] = total - lin[canc];
    }
    let chords = chord_comparison(w, h);
    let vs_linear = chords
        .at(g.as_flattened(), &linear, interior.iter().copied())
        .expect("chord images of the view's size");
    let vs_priority = chords
        .at(
            g.as_flattened(),
            &cpu_chord_image(&cpu),
            interior.iter().copied(),
        )
        .expect("chord images of the view's size");
    let frac = vs_priority.fraction_within();
    eprintln!(
        "phantom: {} interior pixels ({} without a change of signature, less those at folds); GPU vs linear rule worst excess {:.2e} mm; \
         GPU vs priority rule: median {:.1e} mm, p99 {:.2} mm, max {:.2} mm, {:.2} % of pixels within tolerance",
        interior.len(),
        outline_interior.len(),
        vs_linear.worst_excess,
        vs_priority.median_abs,
        vs_priority.p99_abs,
        vs_priority.max_abs,
        100.0 * frac
    );
    vs_linear
        .check()
        .unwrap_or_else(|e| panic!("GPU vs linear rule: {e}"));
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
    let cpu_ln = ln_of(&cpu.transmission);
    let worst = |t: &[f32], pixels: &[usize]| {
        Compare::image(w, h)
            .at(&ln_of(t), &cpu_ln, pixels.iter().copied())
            .expect("transmissions of the view's size")
            .max_abs
    };
    let worst_flagged = worst(&g.transmission, &flagged);
    let worst_plain = worst(&g.transmission, &plain);
    let centre_flagged = worst(&centre.transmission, &flagged);
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
