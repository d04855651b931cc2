//! Tests of the CPU passes against exact chords.

use super::span::NARROW_SPAN;
use super::*;
use glam::{DMat3, DQuat, DVec3};
use sim_core::fluoro::{FluoroMaterial, Projection};
use sim_core::material::MaterialClass;
use sim_core::mesh::TriMesh;
use sim_core::rng::SplitMix64;

/// A closed box `[-half[0], half[0]] x [-half[1], half[1]] x [-half[2], half[2]]` with each
/// face cut into `n x n` rectangles (two triangles
/// each, diagonals alternating), rotated by `rot` about its centre and moved to `centre`,
/// outward counter-clockwise. Shared corners are computed by one expression, so faces
/// meet exactly.
fn grid_box(n: u32, half: [f64; 3], rot: DQuat, centre: DVec3) -> TriMesh {
    let at = |k: u32, a: usize| -half[a] + 2.0 * half[a] * f64::from(k) / f64::from(n);
    let mut mesh = TriMesh {
        vertices_mm: Vec::new(),
        triangles: Vec::new(),
    };
    for axis in 0..3 {
        for side in [0, n] {
            let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
            let point = |a: u32, b: u32| {
                let mut p = DVec3::ZERO;
                p[axis] = at(side, axis);
                p[u] = at(a, u);
                p[v] = at(b, v);
                (centre + rot * p).to_array()
            };
            let mut outward = DVec3::ZERO;
            outward[axis] = if side == 0 { -1.0 } else { 1.0 };
            for a in 0..n {
                for b in 0..n {
                    let base = mesh.vertices_mm.len() as u32;
                    mesh.vertices_mm.extend([
                        point(a, b),
                        point(a + 1, b),
                        point(a + 1, b + 1),
                        point(a, b + 1),
                    ]);
                    let quad = if (a + b) % 2 == 0 {
                        [[0, 1, 2], [0, 2, 3]]
                    } else {
                        [[0, 1, 3], [1, 2, 3]]
                    };
                    for t in quad {
                        let [p0, p1, p2] =
                            t.map(|k| DVec3::from(mesh.vertices_mm[(base + k) as usize]));
                        let facing = (p1 - p0).cross(p2 - p0).dot(rot * outward);
                        let t = if facing > 0.0 { t } else { [t[0], t[2], t[1]] };
                        mesh.triangles.push(t.map(|k| base + k));
                    }
                }
            }
        }
    }
    mesh
}

/// A 20 x 20 target whose source is 100 mm before the plane Z = 0, which it maps to the
/// samples at `(X + 10, Y + 10)` exactly: `x = (100 X + 10 W) / W` with `W = Z + 100`.
fn face_on_samples() -> SampleProjection {
    SampleProjection {
        rows: [
            [100.0, 0.0, 10.0, 1000.0],
            [0.0, 100.0, 10.0, 1000.0],
            [0.0, 0.0, 1.0, 100.0],
        ],
        origin_px: [0.0, 0.0],
        per_px: 1.0,
    }
}

/// A 64 x 48 target of the default C-arm at `pitch_mm` and the given angles: the full image,
/// or with `region = Some(origin)` the supersampled region (2 x 2 samples per pixel) whose
/// first sample is at that pixel coordinate.
fn c_arm_view(
    pitch_mm: f64,
    orbital_deg: f64,
    angular_deg: f64,
    region: Option<[f64; 2]>,
) -> SampleProjection {
    let m = Projection {
        detector_pixels: [64, 48],
        pixel_pitch_mm: [pitch_mm; 2],
        orbital_deg,
        angular_deg,
        ..Projection::default()
    }
    .projection_matrix();
    let (n, [x0, y0]) = region.map_or((1.0, [0.0, 0.0]), |o| (2.0, o));
    let row =
        |k: usize, o: f64| -> [f64; 4] { std::array::from_fn(|c| n * (m[k][c] - o * m[2][c])) };
    SampleProjection {
        rows: [row(0, x0), row(1, y0), m[2]],
        origin_px: [x0, y0],
        per_px: n,
    }
}

/// Every sample of a `w` x `h` target.
fn whole(w: usize, h: usize) -> SampleRect {
    SampleRect {
        cols: 0..w,
        rows: 0..h,
    }
}

/// The full-image rows of `p`'s target (pixel = origin + sample / per_px).
fn pixel_matrix(p: &SampleProjection) -> [[f64; 4]; 3] {
    let [rx, ry, rw] = p.rows;
    let pixel =
        |r: [f64; 4], o: f64| -> [f64; 4] { std::array::from_fn(|k| r[k] / p.per_px + o * rw[k]) };
    [pixel(rx, p.origin_px[0]), pixel(ry, p.origin_px[1]), rw]
}

/// A scene of `meshes` (each of its own material, in this order) as the CPU passes read it.
fn scene_of(meshes: &[&TriMesh]) -> CpuGeometry {
    let material = FluoroMaterial::Tissue(MaterialClass::CorticalBone);
    let mut scene = Scene::new();
    let nested = meshes
        .iter()
        .enumerate()
        .map(|(k, mesh)| {
            scene.add(format!("box {k}"), material, mesh);
            NestedMesh {
                entry: k,
                name: format!("box {k}"),
                effective: material,
                container: None,
                centre_mm: [0.0; 3],
            }
        })
        .collect::<Vec<_>>();
    CpuGeometry::new(&scene, &nested)
}

/// The CPU pass over a scene of `mesh` alone, drawn with `weights`.
fn one_mesh(
    mesh: &TriMesh,
    p: &SampleProjection,
    rect: &SampleRect,
    weights: MeshWeights,
    threads: usize,
) -> Result<GeometrySums, NotDrawn> {
    let cpu = scene_of(&[mesh]);
    let boxes = cpu.chunk_boxes(&pixel_matrix(p), threads);
    cpu.rasterise_rect(&[weights], p, &boxes, rect, threads)
}

/// The CPU pass over one mesh with weights `(1, 0, 0, 0)` (four-channel target) and
/// reference depth `wref`: channel 0 of every sample.
fn axial_chords(
    mesh: &TriMesh,
    p: &SampleProjection,
    rect: &SampleRect,
    wref: f32,
    threads: usize,
) -> Vec<f64> {
    let weights = MeshWeights {
        g: [1.0, 0.0, 0.0, 0.0],
        wref,
        scalar: false,
    };
    let sums = one_mesh(mesh, p, rect, weights, threads).expect("in front of the source");
    assert!(
        sums.s.iter().all(|&v| v == 0.0),
        "nothing in the scalar target"
    );
    sums.a.chunks_exact(4).map(|c| f64::from(c[0])).collect()
}

/// Exact axial extent `w_exit - w_enter` of the box on the ray of sample `(x, y)` (see
/// [`exact_interval`]).
fn exact_axial_chord(
    p: &SampleProjection,
    half: f64,
    rot: DQuat,
    centre: DVec3,
    x: f64,
    y: f64,
) -> f64 {
    exact_interval(p, [half; 3], rot, centre, x, y).map_or(0.0, |(lo, hi)| hi - lo)
}

/// The axial depths `(w_enter, w_exit)` at which the ray of sample `(x, y)` is inside the box
/// of half-sides `half` (rotated by `rot`, centred at `centre`), if it meets it: the ray's
/// points are `source + w M^-1 (x, y, 1)`; the slab method in the box's own frame.
fn exact_interval(
    p: &SampleProjection,
    half: [f64; 3],
    rot: DQuat,
    centre: DVec3,
    x: f64,
    y: f64,
) -> Option<(f64, f64)> {
    let m = DMat3::from_cols(
        DVec3::new(p.rows[0][0], p.rows[1][0], p.rows[2][0]),
        DVec3::new(p.rows[0][1], p.rows[1][1], p.rows[2][1]),
        DVec3::new(p.rows[0][2], p.rows[1][2], p.rows[2][2]),
    );
    let inv = m.inverse();
    let source = -(inv * DVec3::new(p.rows[0][3], p.rows[1][3], p.rows[2][3]));
    let dir = rot.inverse() * (inv * DVec3::new(x, y, 1.0));
    let start = rot.inverse() * (source - centre);
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    for a in 0..3 {
        if dir[a] == 0.0 {
            if start[a].abs() > half[a] {
                return None;
            }
            continue;
        }
        let (t0, t1) = (
            (-half[a] - start[a]) / dir[a],
            (half[a] - start[a]) / dir[a],
        );
        lo = lo.max(t0.min(t1));
        hi = hi.min(t0.max(t1));
    }
    (hi > lo).then_some((lo, hi))
}

/// Every vertex of the face towards the source, and so every edge of its triangles, lies
/// on sample centres: each of those samples is on an edge or a corner of up to six
/// triangles, and must still be taken by exactly one triangle of each face it crosses. The
/// sums equal the exact chords to round-off (an unpaired crossing would be off by about
/// the 100 mm depth).
#[test]
fn samples_on_shared_edges_and_corners_pair_up() {
    let p = face_on_samples();
    let (half, centre) = (3.5, DVec3::new(0.0, 0.0, 3.5));
    let mesh = grid_box(7, [half; 3], DQuat::IDENTITY, centre);
    for threads in [1, 3] {
        let got = axial_chords(&mesh, &p, &whole(20, 20), 103.0, threads);
        let mut inside = 0;
        for j in 0..20 {
            for i in 0..20 {
                let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
                let want = exact_axial_chord(&p, half, DQuat::IDENTITY, centre, x, y);
                let g = got[j * 20 + i];
                assert!(
                    (g - want).abs() < 1e-9,
                    "sample ({i}, {j}): {g} against {want}"
                );
                inside += usize::from(want > 0.0);
            }
        }
        assert_eq!(inside, 36, "the 6 x 6 samples strictly inside the face");
    }
}

/// Boxes in random poses under C-arm projections at random angles, full images and
/// supersampled regions: away from silhouettes (where a 1/512-sample snap may move a
/// sample in or out), every sample's sum is the exact axial chord rounded to f32,
/// whatever the number of threads (bit for bit).
#[test]
fn random_boxes_match_their_exact_chords() {
    let mut rng = SplitMix64::new(0x5eed_2811);
    let mut r = move || rng.next_f64();
    let mut checked = 0usize;
    for trial in 0..12 {
        let region = (trial % 2 == 1).then(|| [10.0 + 20.0 * r(), 5.0 + 20.0 * r()]);
        let p = c_arm_view(1.5, 180.0 * r() - 90.0, 60.0 * r() - 30.0, region);
        let rot = DQuat::from_euler(glam::EulerRot::XYZ, 6.0 * r(), 6.0 * r(), 6.0 * r());
        let centre = DVec3::new(40.0 * r() - 20.0, 40.0 * r() - 20.0, 40.0 * r() - 20.0);
        let half = 10.0 + 20.0 * r();
        let mesh = grid_box(3 + trial as u32 % 4, [half; 3], rot, centre);
        let got = axial_chords(&mesh, &p, &whole(64, 48), 500.0, 2);
        assert_eq!(
            got,
            axial_chords(&mesh, &p, &whole(64, 48), 500.0, 1),
            "trial {trial}: threads"
        );
        for j in 0..48 {
            for i in 0..64 {
                let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
                let want = exact_axial_chord(&p, half, rot, centre, x, y);
                let near: Vec<f64> = [(0.01, 0.0), (-0.01, 0.0), (0.0, 0.01), (0.0, -0.01)]
                    .map(|(dx, dy)| exact_axial_chord(&p, half, rot, centre, x + dx, y + dy))
                    .into();
                if near
                    .iter()
                    .any(|c| (c - want).abs() > 1e-3 || (*c > 0.0) != (want > 0.0))
                {
                    continue;
                }
                let g = got[j * 64 + i];
                // The f32 target rounds to 2^-24 relative; the f64 sums add about 1e-12 mm.
                assert!(
                    (g - want).abs() <= want * f64::from(f32::EPSILON) / 2.0 + 1e-10,
                    "trial {trial}, sample ({i}, {j}): {g} against {want}"
                );
                checked += usize::from(want > 0.0);
            }
        }
    }
    assert!(checked > 5000, "{checked} samples inside boxes");
}

/// A corner behind the focal spot's plane is refused (the GPU pass, which clips, draws
/// that frame).
#[test]
fn a_triangle_behind_the_source_is_refused() {
    let p = face_on_samples();
    let mesh = grid_box(2, [200.0; 3], DQuat::IDENTITY, DVec3::ZERO);
    let weights = MeshWeights {
        g: [1.0; 4],
        wref: 0.0,
        scalar: true,
    };
    assert_eq!(
        one_mesh(&mesh, &p, &whole(20, 20), weights, 2).err(),
        Some(NotDrawn::Refused)
    );
}

/// The needle's passes against exact intervals: a thin box (the needle) through a larger
/// rotated box (the anatomy) under oblique C-arm views, full images and supersampled regions,
/// over a box of samples. Away from either box's silhouette, the needle's chord is its exact
/// length along each ray and the displaced sum is the exact length of the anatomy the needle
/// occupies there (the overlap of the two intervals), to f32 rounding; 1 and 2 threads agree
/// bit for bit.
#[test]
fn needle_passes_match_exact_overlaps() {
    let mut rng = SplitMix64::new(0x6e65_6564_6c65);
    let mut r = move || rng.next_f64();
    let (mut overlapping, mut needle_first) = (0usize, 0usize);
    for trial in 0..16 {
        let region = (trial % 2 == 1).then(|| [5.0 + 10.0 * r(), 5.0 + 10.0 * r()]);
        let p = c_arm_view(0.8, 60.0 * r() - 30.0, 40.0 * r() - 20.0, region);
        let (a_rot, a_half) = (
            DQuat::from_euler(glam::EulerRot::XYZ, 6.0 * r(), 6.0 * r(), 6.0 * r()),
            [8.0 + 4.0 * r(), 6.0 + 4.0 * r(), 7.0 + 4.0 * r()],
        );
        let a_centre = DVec3::new(4.0 * r() - 2.0, 4.0 * r() - 2.0, 4.0 * r() - 2.0);
        // The needle: 3 x 4 x 30 mm, one end inside the anatomy box, the other out of it: in
        // half the trials pointing at the source along the central ray (so that rays meet it
        // before the anatomy), in the others in any direction.
        let n_rot = if trial % 4 < 2 {
            let f = Frame::new(&p).expect("a projection");
            let towards_source = -(f.inv * DVec3::new(32.0, 24.0, 1.0)).normalize();
            let tilt =
                DQuat::from_euler(glam::EulerRot::XYZ, 0.2 * r() - 0.1, 0.2 * r() - 0.1, r());
            tilt * DQuat::from_rotation_arc(DVec3::Z, towards_source)
        } else {
            DQuat::from_euler(glam::EulerRot::XYZ, 6.0 * r(), 6.0 * r(), 6.0 * r())
        };
        let n_half = [1.5, 2.0, 15.0];
        let n_centre = a_centre + n_rot * DVec3::new(0.0, 0.0, 12.0);
        let anatomy = grid_box(4, a_half, a_rot, a_centre);
        let needle_mesh = grid_box(2, n_half, n_rot, n_centre);
        let cpu = scene_of(&[&anatomy]);
        let boxes = cpu.chunk_boxes(&pixel_matrix(&p), 1);
        let tris: Vec<[[f64; 3]; 3]> = needle_mesh
            .triangles
            .iter()
            .map(|t| t.map(|k| needle_mesh.vertices_mm[k as usize]))
            .collect();
        let reference_mm = 900.0;
        let needle = NeedleTriangles {
            triangles: &tris,
            reference_mm,
        };
        let rect = SampleRect {
            cols: 3..61,
            rows: 2..47,
        };
        let weights = [[1.0, 0.0, 0.0, 0.0]];
        let got = cpu
            .needle_passes(&needle, &weights, &p, &boxes, &rect, 2)
            .expect("in front of the source");
        let again = cpu
            .needle_passes(&needle, &weights, &p, &boxes, &rect, 1)
            .expect("in front of the source");
        assert!(
            got.d == again.d && got.chord == again.chord,
            "trial {trial}: threads"
        );
        let f = Frame::new(&p).expect("a projection");
        for j in rect.rows.clone() {
            for i in rect.cols.clone() {
                let at = |x: f64, y: f64| {
                    let per = f.distance_per_depth(x, y);
                    let length = |iv: Option<(f64, f64)>| iv.map(|(lo, hi)| (lo * per, hi * per));
                    let a = length(exact_interval(&p, a_half, a_rot, a_centre, x, y));
                    let nd = length(exact_interval(&p, n_half, n_rot, n_centre, x, y));
                    let chord = nd.map_or(0.0, |(lo, hi)| hi - lo);
                    let overlap = match (a, nd) {
                        (Some(a), Some(nd)) => (a.1.min(nd.1) - a.0.max(nd.0)).max(0.0),
                        _ => 0.0,
                    };
                    // Whether the needle begins before the anatomy on this ray.
                    let first = matches!((a, nd), (Some(a), Some(nd)) if nd.0 < a.0);
                    (chord, overlap, first)
                };
                let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
                let want = at(x, y);
                let steady = [(0.01, 0.0), (-0.01, 0.0), (0.0, 0.01), (0.0, -0.01)]
                    .into_iter()
                    .map(|(dx, dy)| at(x + dx, y + dy))
                    .all(|c| {
                        (c.0 - want.0).abs() < 1e-3
                            && (c.1 - want.1).abs() < 1e-3
                            && (c.0 > 0.0) == (want.0 > 0.0)
                    });
                if !steady {
                    continue;
                }
                let k = (j - rect.rows.start) * rect.cols.len() + (i - rect.cols.start);
                let (chord, displaced) = (f64::from(got.chord[k]), f64::from(got.d[4 * k]));
                // f32 rounding of the sums (2^-24 relative) and the needle's chord summed as
                // distances from the 900 mm reference (f64 round-off of about 1e-13 mm).
                let tol = |v: f64| v * f64::from(f32::EPSILON) / 2.0 + 1e-9;
                assert!(
                    (chord - want.0).abs() <= tol(want.0),
                    "trial {trial}, sample ({i}, {j}): chord {chord} against {}",
                    want.0
                );
                assert!(
                    (displaced - want.1).abs() <= tol(want.1),
                    "trial {trial}, sample ({i}, {j}): displaced {displaced} against {}",
                    want.1
                );
                overlapping += usize::from(want.1 > 0.0);
                needle_first += usize::from(want.2);
            }
        }
    }
    assert!(
        overlapping > 500,
        "{overlapping} samples where the needle is in the anatomy"
    );
    assert!(
        needle_first > 100,
        "{needle_first} samples where the needle comes before the anatomy"
    );
}

/// Four unequal channel weights and a reference depth near the samples' own (so that a channel
/// mixed up with another, or a depth with its reference, shows), on the one-channel target if
/// `scalar`.
fn unequal_weights(scalar: bool) -> MeshWeights {
    MeshWeights {
        g: [1.0, 0.5, 0.25, 2.0],
        wref: 800.0,
        scalar,
    }
}

/// A rectangle cut from the sums of a larger one equals the sums drawn for it alone, bit for
/// bit (what lets a renderer keep a supersampled region's sums for a padded box), in the full
/// image's grid and a supersampled one, on 1 and 2 threads.
#[test]
fn a_cut_rectangle_equals_its_own_sums() {
    let mut rng = SplitMix64::new(0x6375_7473);
    let mut r = move || rng.next_f64();
    for trial in 0..6 {
        let region = (trial % 2 == 1).then_some([0.0, 0.0]);
        let p = c_arm_view(1.2, 60.0 * r() - 30.0, 40.0 * r() - 20.0, region);
        let rot = DQuat::from_euler(glam::EulerRot::XYZ, 6.0 * r(), 6.0 * r(), 6.0 * r());
        let mesh = grid_box(
            5,
            [12.0, 15.0, 9.0],
            rot,
            DVec3::new(r() - 0.5, r() - 0.5, 0.0),
        );
        let cpu = scene_of(&[&mesh]);
        let boxes = cpu.chunk_boxes(&pixel_matrix(&p), 1);
        let weights = [unequal_weights(trial % 3 == 0)];
        let big = SampleRect {
            cols: 3..61,
            rows: 1..47,
        };
        let part = SampleRect {
            cols: 10 + trial..40 + trial,
            rows: 7..30 + trial,
        };
        let cut = cpu
            .rasterise_rect(&weights, &p, &boxes, &big, 2)
            .expect("in front of the source")
            .crop(&big, &part);
        let own = cpu
            .rasterise_rect(&weights, &p, &boxes, &part, 1)
            .expect("in front of the source");
        assert!(cut.a == own.a && cut.s == own.s, "trial {trial}");
        assert!(
            own.a.iter().chain(&own.s).any(|&v| v != 0.0),
            "trial {trial}: the box reaches the part"
        );
    }
}

/// A scene whose corners are all `f32` values (as a region asset's) keeps them in `f32`; its
/// sums equal those of the same corners kept in `f64`, bit for bit, and each chunk keeps each
/// distinct corner once.
#[test]
fn corners_kept_in_f32_give_the_f64_sums() {
    let mut rng = SplitMix64::new(0x0f32_c0de);
    let mut r = move || rng.next_f64();
    for trial in 0..4 {
        let p = c_arm_view(1.3, 40.0 * r() - 20.0, 30.0 * r() - 15.0, None);
        let rot = DQuat::from_euler(glam::EulerRot::XYZ, 6.0 * r(), 6.0 * r(), 6.0 * r());
        let mut mesh = grid_box(6, [14.0, 11.0, 9.0], rot, DVec3::new(r(), r(), r()));
        let exact = scene_of(&[&mesh]);
        assert!(matches!(exact.corners, Corners::F64(_)), "trial {trial}");
        for v in &mut mesh.vertices_mm {
            *v = v.map(|x| f64::from(x as f32));
        }
        let in_f32 = scene_of(&[&mesh]);
        let Corners::F32(kept) = &in_f32.corners else {
            panic!("trial {trial}: f32 corners kept in f64");
        };
        // A 6 x 6 grid box has 6 x 36 quads of four corners each, one distinct corner per
        // quad corner (`grid_box` writes every quad's own), fewer where quads meet exactly.
        assert!(kept.len() < 3 * in_f32.triangles.len(), "trial {trial}");
        let as_f64 = CpuGeometry {
            chunks: in_f32.chunks.clone(),
            corners: Corners::F64(kept.iter().map(|v| v.map(f64::from)).collect()),
            triangles: in_f32.triangles.clone(),
        };
        let boxes = in_f32.chunk_boxes(&pixel_matrix(&p), 2);
        let weights = [unequal_weights(false)];
        let rect = whole(64, 48);
        let got = in_f32
            .rasterise_rect(&weights, &p, &boxes, &rect, 2)
            .expect("in front of the source");
        let want = as_f64
            .rasterise_rect(&weights, &p, &boxes, &rect, 2)
            .expect("in front of the source");
        assert!(got.a == want.a && got.s == want.s, "trial {trial}");
        assert!(got.a.iter().any(|&v| v != 0.0), "trial {trial}: drawn");
    }
}

/// A span's covered runs are exactly the samples the per-sample edge test takes, for narrow
/// and wide spans, and for samples on edges (corners on a quarter-sample lattice put many
/// sample centres exactly on edges).
#[test]
fn covered_runs_are_the_per_sample_edge_test() {
    let p = face_on_samples();
    let frame = Frame::new(&p).expect("projection");
    let rect = whole(20, 20);
    let mut rng = SplitMix64::new(0x0c0f_e4ed);
    let (mut wide, mut on_edges) = (0usize, 0usize);
    for trial in 0..4000 {
        // Corners in the plane Z = 0, which the target maps to samples at (X + 10, Y + 10).
        let mut corner = || {
            let mut q = || (rng.next_f64() * 96.0).floor() / 4.0 - 12.0;
            [q(), q(), 0.0]
        };
        let t = [corner(), corner(), corner()];
        let Some(span) = setup(&frame, &t, &rect).expect("in front of the source") else {
            continue;
        };
        let mut runs = Vec::new();
        span.for_each_row(|j, cols| runs.extend(cols.map(|i| (i, j))));
        let mut want = Vec::new();
        let mut e_row = span.e_row;
        for j in span.rows.clone() {
            let mut ev = e_row;
            for i in span.cols.clone() {
                if (ev[0] | ev[1] | ev[2]) >= 0 {
                    want.push((i, j));
                }
                on_edges += usize::from(ev.iter().any(|&v| v == 0 || v == -1));
                for (v, s) in ev.iter_mut().zip(span.step_x) {
                    *v += s;
                }
            }
            for (v, s) in e_row.iter_mut().zip(span.step_y) {
                *v += s;
            }
        }
        assert_eq!(runs, want, "trial {trial}: {t:?}");
        wide += usize::from(span.cols.clone().count() as i64 > NARROW_SPAN && !want.is_empty());
    }
    assert!(
        wide > 500 && on_edges > 500,
        "{wide} wide spans, {on_edges} samples on edges"
    );
}
