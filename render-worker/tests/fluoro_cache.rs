//! The GPU fluoroscopy renderer's caches (geometric L-buffer per projection, incremental resolve
//! of the needle's rows, whole-frame reuse): a frame from a renderer that kept its caches
//! through a sequence of changes equals, bit for bit, the frame of a renderer that renders every
//! frame from scratch. Equality is exact by construction (see `render_worker::fluoro`): outside
//! the needle's old and new pixel boxes every input of the resolve is unchanged.

use render_worker::fluoro::{GpuFluoroRenderer, GpuTransmission};
use render_worker::gpu::context_for_tests;
use sim_core::fluoro::analytic::SpherePhantom;
use sim_core::fluoro::{EnergyModel, IodineField, Projection, RenderSettings};
use sim_core::geom::{capped_cylinder, equal_area_vertex_radius};
use sim_core::mesh::TriMesh;
use sim_core::volume::{Volume, VolumeGrid};

fn needle(base: [f64; 3], tip: [f64; 3]) -> TriMesh {
    capped_cylinder(base, tip, equal_area_vertex_radius(0.36, 16), 16)
}

/// One step of the sequence: what changes before the frame.
enum Step {
    Needle(TriMesh),
    NoNeedle,
    Pose(Projection),
    Settings(RenderSettings),
    Iodine(bool),
    Chords,
    Nothing,
}

/// The analytic sphere phantom the cache tests render.
fn sphere_scene() -> sim_core::fluoro::Scene {
    SpherePhantom {
        subdivisions: 3,
        volume_matched: true,
        needle_segments: 16,
    }
    .build()
    .0
}

/// A small AP view of it (160 x 128 pixels of 1.2 mm).
fn small_ap() -> Projection {
    Projection {
        detector_pixels: [160, 128],
        pixel_pitch_mm: [1.2, 1.2],
        ..Projection::default()
    }
}

/// A renderer that keeps its caches and one that renders every frame from scratch, of
/// [`sphere_scene`].
fn cached_and_scratch(
    ctx: &render_worker::gpu::GpuContext,
) -> (GpuFluoroRenderer, GpuFluoroRenderer) {
    let scene = sphere_scene();
    let cached = GpuFluoroRenderer::new(ctx, &scene).expect("renderer");
    let mut scratch = GpuFluoroRenderer::new(ctx, &scene).expect("renderer");
    scratch.caching = false;
    (cached, scratch)
}

/// A uniform iodine field, 0.2 of the stock, over the middle of the scene.
fn iodine_field() -> IodineField {
    IodineField {
        volume: Volume {
            grid: VolumeGrid {
                dims: [8, 8, 8],
                spacing_mm: [4.0; 3],
                origin_mm: [-14.0, -14.0, -14.0],
            },
            data: vec![0.2; 512],
        },
    }
}

fn frame(
    r: &mut GpuFluoroRenderer,
    p: &Projection,
    s: &RenderSettings,
    iodine: Option<&IodineField>,
) -> GpuTransmission {
    r.render_transmission_supersampled(p, s, iodine)
        .expect("frame")
}

#[test]
fn cached_and_incremental_frames_equal_frames_from_scratch() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let (mut cached, mut scratch) = cached_and_scratch(&ctx);
    let ap = small_ap();
    let oblique = Projection {
        orbital_deg: -25.0,
        angular_deg: 10.0,
        ..ap
    };
    let poly = RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 2,
        ..RenderSettings::default()
    };
    let field = iodine_field();
    // A needle feed (same line, deeper), a roll-free sideways move, a withdrawal.
    let (a, b) = ([-40.0, -60.0, 10.0], [-5.0, -15.0, 15.0]);
    let deeper = [10.0, 5.0, 17.0];
    let steps = vec![
        Step::Needle(needle(a, b)),
        Step::Needle(needle(a, deeper)),
        Step::Nothing,
        Step::Needle(needle([-38.0, -60.0, 12.0], [-2.0, -14.0, 16.0])),
        Step::NoNeedle,
        Step::Nothing,
        Step::Needle(needle(a, b)),
        Step::Pose(oblique),
        Step::Needle(needle(a, deeper)),
        Step::Settings(RenderSettings {
            energy: EnergyModel::Spectral { kvp: 100 },
            ..poly
        }),
        Step::Needle(needle(a, b)),
        Step::Settings(RenderSettings {
            energy: EnergyModel::Mono60,
            ..poly
        }),
        Step::Iodine(true),
        Step::Needle(needle(a, deeper)),
        Step::Iodine(false),
        Step::Chords,
        Step::Needle(needle(a, b)),
        Step::Pose(ap),
        Step::Needle(needle(a, deeper)),
    ];
    let (mut p, mut s, mut iodine) = (ap, poly, false);
    let mut reused_geometry = 0;
    let mut partial_resolves = 0;
    let mut reused_frames = 0;
    let mut geometry_kept = false;
    for (k, step) in steps.iter().enumerate() {
        let mut needle_only = false;
        match step {
            Step::Needle(m) => {
                cached.update_needle(m);
                scratch.update_needle(m);
                needle_only = true;
            }
            Step::NoNeedle => {
                cached.clear_needle();
                scratch.clear_needle();
                needle_only = true;
            }
            Step::Pose(q) => p = *q,
            Step::Settings(t) => s = *t,
            Step::Iodine(on) => iodine = *on,
            Step::Chords => {
                // The validation path overwrites the L-buffer with other channels.
                let _ = cached.render_chords(&p).expect("chords");
            }
            Step::Nothing => {}
        }
        let field = iodine.then_some(&field);
        let c = frame(&mut cached, &p, &s, field);
        let t = cached.last_timings();
        let f = frame(&mut scratch, &p, &s, field);
        assert_eq!((c.width, c.height), (f.width, f.height));
        let differ = c
            .transmission
            .iter()
            .zip(&f.transmission)
            .enumerate()
            .filter(|(_, (x, y))| x.to_bits() != y.to_bits())
            .map(|(q, (x, y))| format!("pixel {q}: {x} vs {y}"))
            .collect::<Vec<_>>();
        assert!(
            differ.is_empty(),
            "step {k}: {} pixels differ from the frame from scratch, first {:?}",
            differ.len(),
            differ.first()
        );
        assert!(!scratch.last_timings().geometry_reused);
        if matches!(step, Step::Nothing) && !iodine {
            assert!(
                t.frame_reused,
                "step {k}: nothing changed, nothing re-rendered"
            );
            reused_frames += 1;
        }
        if needle_only && geometry_kept && !iodine {
            // Same projection: the anatomy's geometric pass is kept.
            assert!(t.geometry_reused, "step {k}");
            reused_geometry += 1;
            // Only the needle's rows (plus the supersampled region) were resolved.
            if t.resolved_samples < u64::from(p.detector_pixels[0] * p.detector_pixels[1]) {
                partial_resolves += 1;
            }
        }
        // The next needle-only frame may keep the geometry unless this step replaced it.
        geometry_kept = !matches!(step, Step::Chords);
    }
    eprintln!(
        "{reused_geometry} needle-only frames reused the geometry, {partial_resolves} resolved \
         only part of the image, {reused_frames} frames were reused whole"
    );
    assert!(reused_geometry >= 6 && partial_resolves >= 3 && reused_frames == 2);
}

/// Drawing only the anatomy triangles whose pixel box meets the needle's box (or the
/// supersampled region) gives the same frame, bit for bit, as drawing every triangle: the
/// others produce no fragment there, and the rest blend in the same order.
#[test]
fn culled_needle_passes_equal_full_draws() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let scene = sphere_scene();
    let mut culled = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    let mut full = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
    full.culling = false;
    let settings = RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 4,
        ..RenderSettings::default()
    };
    for (orbital_deg, tip) in [(0.0, [-5.0, -15.0, 15.0]), (30.0, [10.0, 5.0, 17.0])] {
        let p = Projection {
            orbital_deg,
            detector_pixels: [160, 128],
            pixel_pitch_mm: [1.2, 1.2],
            ..Projection::default()
        };
        let m = needle([-40.0, -60.0, 10.0], tip);
        culled.update_needle(&m);
        full.update_needle(&m);
        let a = frame(&mut culled, &p, &settings, None);
        let b = frame(&mut full, &p, &settings, None);
        let same = a
            .transmission
            .iter()
            .zip(&b.transmission)
            .filter(|(x, y)| x.to_bits() == y.to_bits())
            .count();
        assert_eq!(same, a.transmission.len(), "orbital {orbital_deg}");
        // The chords (validation path) too.
        let (ca, cb) = (
            culled.render_chords(&p).unwrap(),
            full.render_chords(&p).unwrap(),
        );
        assert!(
            ca.iter().zip(&cb).all(|(x, y)| x == y),
            "orbital {orbital_deg}"
        );
    }
}

/// A frame after [`GpuFluoroRenderer::prefetch`] of its view (what a session does before its
/// first shot) reuses the prefetched transmission (no GPU work: `frame_reused`) and is, bit for
/// bit, the frame of a renderer that never prefetched; with noise on, whatever its seed. A
/// prefetch of another view changes nothing either (positive control: that frame is rendered).
#[test]
fn a_prefetched_frame_is_the_frame_from_scratch_without_gpu_work() {
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let scene = sphere_scene();
    let ap = small_ap();
    let oblique = Projection {
        orbital_deg: -25.0,
        ..ap
    };
    let shot = |seed: u64| RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 2,
        noise: Some(sim_core::fluoro::QuantumNoise {
            photons_per_pixel: 2000.0,
            seed,
        }),
        ..RenderSettings::default()
    };
    let shaft = needle([-30.0, -60.0, 5.0], [2.0, -4.0, 1.0]);
    for (prefetched, shown, reused) in [(ap, ap, true), (oblique, ap, false)] {
        let mut scratch = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
        scratch.caching = false;
        scratch.update_needle(&shaft);
        let expected = scratch.render_frame(&shown, &shot(7), None).expect("frame");
        let mut r = GpuFluoroRenderer::new(&ctx, &scene).expect("renderer");
        r.update_needle(&shaft);
        // The prefetch knows no noise seed: it is not part of what is kept.
        r.prefetch(&prefetched, &shot(0)).expect("prefetch");
        let frame = r.render_frame(&shown, &shot(7), None).expect("frame");
        assert_eq!(
            r.last_timings().frame_reused,
            reused,
            "prefetched {prefetched:?}"
        );
        assert!(
            frame == expected,
            "prefetched {prefetched:?}: the frame differs"
        );
    }
}

/// Displayed frames with scatter and a receptor profile (a session's defaults): a new shot of
/// an unchanged view reuses the kept detector signal (only the noise and the display are
/// redone) and equals the frame of a renderer without caches bit for bit; after a needle move,
/// a technique change, iodine or another air gap the signal is made again, and those frames
/// equal too.
#[test]
fn new_shots_reuse_the_detector_signal_and_equal_frames_from_scratch() {
    use sim_core::fluoro::QuantumNoise;
    use sim_core::fluoro::receptor::{ReceptorKind, ReceptorSettings};
    use sim_core::fluoro::scatter::superposition::ScatterSettings;
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let (mut cached, mut scratch) = cached_and_scratch(&ctx);
    let p = small_ap();
    let shot = |kvp: u32, seed: u64| RenderSettings {
        energy: EnergyModel::Spectral { kvp },
        supersample: 2,
        noise: Some(QuantumNoise {
            photons_per_pixel: 1500.0 + 100.0 * seed as f64,
            seed,
        }),
        scatter: Some(ScatterSettings {
            kvp,
            grid: true,
            air_gap_mm: 150.0,
            pixel_pitch_mm: p.pixel_pitch_mm[0],
        }),
        receptor: Some(ReceptorSettings {
            kind: ReceptorKind::ImageIntensifier,
            pixel_pitch_mm: p.pixel_pitch_mm[0],
        }),
        ..RenderSettings::default()
    };
    let field = iodine_field();
    let wider = |s: RenderSettings| RenderSettings {
        scatter: s.scatter.map(|c| ScatterSettings {
            air_gap_mm: 120.0,
            ..c
        }),
        ..s
    };
    let (a, b) = ([-40.0, -60.0, 10.0], [-5.0, -15.0, 15.0]);
    cached.update_needle(&needle(a, b));
    scratch.update_needle(&needle(a, b));
    // (settings, iodine, move the needle first, the signal may be reused)
    let steps = [
        (shot(80, 1), false, false, false),
        (shot(80, 2), false, false, true),
        (shot(80, 3), false, false, true),
        (shot(80, 4), false, true, false),
        (shot(80, 5), false, false, true),
        (shot(95, 6), false, false, false),
        (shot(95, 7), true, false, false),
        (shot(95, 8), true, false, false),
        (shot(95, 9), false, false, false),
        (shot(95, 10), false, false, true),
        // Another air gap at the same view and technique: a new signal, then kept.
        (wider(shot(95, 11)), false, false, false),
        (wider(shot(95, 12)), false, false, true),
    ];
    let mut reused = 0;
    for (k, (s, iodine, moved, reusable)) in steps.into_iter().enumerate() {
        if moved {
            cached.update_needle(&needle(a, [10.0, 5.0, 17.0]));
            scratch.update_needle(&needle(a, [10.0, 5.0, 17.0]));
        }
        let field = iodine.then_some(&field);
        let c = cached.render_frame(&p, &s, field).expect("frame");
        let t = cached.last_timings();
        let f = scratch.render_frame(&p, &s, field).expect("frame");
        assert!(
            c == f,
            "step {k}: the frame differs from the frame from scratch"
        );
        assert_eq!(t.signal_reused, reusable, "step {k}");
        reused += usize::from(t.signal_reused);
    }
    assert_eq!(reused, 5);
}

/// A frame whose CPU geometric pass is stopped by newer input (the thread's watched flag
/// raised, see `render_worker::interrupt`) ends with `Interrupted` and keeps nothing: the
/// renderer's next frames, of the stopped view and of the one before, equal frames from
/// scratch bit for bit. A frame whose geometry is kept needs no geometric pass and is not
/// stopped.
#[test]
fn an_interrupted_frame_keeps_nothing_and_the_next_frames_equal_frames_from_scratch() {
    use render_worker::fluoro::FluoroGpuError;
    use render_worker::interrupt::watching;
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;
    let Some(ctx) = context_for_tests() else {
        return;
    };
    let (mut cached, mut scratch) = cached_and_scratch(&ctx);
    if !cached.cpu_geometry() {
        // A real GPU draws the geometric pass itself: nothing on the CPU to stop.
        return;
    }
    let shaft = needle([-30.0, -60.0, 5.0], [2.0, -4.0, 1.0]);
    cached.update_needle(&shaft);
    scratch.update_needle(&shaft);
    let s = RenderSettings {
        energy: EnergyModel::Spectral { kvp: 80 },
        supersample: 2,
        ..RenderSettings::default()
    };
    let ap = small_ap();
    let oblique = Projection {
        orbital_deg: 20.0,
        ..ap
    };
    let raised = Arc::new(AtomicBool::new(true));
    frame(&mut cached, &ap, &s, None);
    {
        let _w = watching(&raised);
        let stopped = cached.render_transmission_supersampled(&oblique, &s, None);
        assert!(
            matches!(stopped, Err(FluoroGpuError::Interrupted)),
            "a new view's pass under a raised flag: {:?}",
            stopped.err()
        );
    }
    for p in [oblique, ap, oblique] {
        let a = frame(&mut cached, &p, &s, None);
        let b = frame(&mut scratch, &p, &s, None);
        assert!(
            a.transmission == b.transmission,
            "{p:?} after a stopped frame"
        );
    }
    let moved = needle([-28.0, -60.0, 5.0], [3.0, -4.0, 1.0]);
    cached.update_needle(&moved);
    scratch.update_needle(&moved);
    let a = {
        let _w = watching(&raised);
        cached
            .render_transmission_supersampled(&oblique, &s, None)
            .expect("a needle step in the kept view is not stopped")
    };
    assert!(cached.last_timings().geometry_reused);
    let b = frame(&mut scratch, &oblique, &s, None);
    assert!(a.transmission == b.transmission);
}
