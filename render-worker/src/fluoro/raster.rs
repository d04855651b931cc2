//! The geometric L-buffer pass on the CPU (see the module map in `fluoro`): the same sums as
//! `lbuffer.wgsl`'s `fs_anatomy` and `fs_anatomy_scalar`, rasterised by the worker's own cores
//! from the scene's f64 triangles and uploaded into the geometric targets, for adapters whose
//! rasteriser is itself software (lavapipe: its geometry stage sets up every triangle on one
//! thread, about 200 ns each, so a C-arm-moved frame of the default phantom spent about 225 of
//! its 260 ms on the 1.1 M triangles that reach the image).
//!
//! # What it computes
//! For each sample of the target (pixel centres, or the supersampled region's sub-pixel
//! centres) and each anatomy triangle covering it, the triangle's axial depth
//! `w = row_w . (point - source)` at the sample's ray, minus the mesh's reference depth, signed
//! (`-` entering, `+` leaving) and times the mesh's geometric weights: the GPU pass's fragment,
//! but in f64 from the f64 triangles (the GPU reads f32 vertices and blends in f32). Summed over
//! a closed mesh the signed depths give its chord times `(row_w . d) / |d|`, as on the GPU.
//!
//! # Coverage rule (why each closed mesh's entering and leaving samples pair up)
//! Vertices are snapped to 1/256 of a sample (as a GPU rasteriser does), so every edge test is
//! exact integer arithmetic, and two triangles sharing an edge snap it to the same two points. A
//! sample is covered when it is strictly inside all three edges, or on an edge that the rule
//! "the edge runs downwards, or horizontally leftwards" (in the triangle's counter-clockwise
//! order) claims. The rule is antisymmetric, so of two triangles on opposite sides of a shared
//! edge exactly one takes a sample on it; two triangles on the same side (a silhouette fold)
//! face opposite ways and take it together. Either way the signed counts stay balanced.
//! Entering or leaving is the sign of the snapped screen area (what the coverage used) times
//! the sign of the projection's determinant: `det[P0 P1 P2] = det(M) det[v0-s, v1-s, v2-s]`
//! and `det[v0-s, v1-s, v2-s] = (v0 - s) . ((v1 - v0) x (v2 - v0))`, negative for a triangle
//! whose outward normal faces the source.
//!
//! # Depth at a sample
//! A point of the triangle's plane on the ray of sample `(x, y)` has
//! `w = n.(v0 - s) / n.(M^-1 (x, y, 1))` (the ray's direction `M^-1 (x, y, 1)` has unit axial
//! depth), so `1 / w` is affine in the sample coordinates: one division per covered sample, no
//! barycentric interpolation, and no loss on triangles whose snapped corners moved.
//!
//! # Order
//! Every sample belongs to one band of rows; a band's thread visits the chunks in drawing order,
//! so each sample sums its triangles in drawing order whatever the number of threads: the
//! result does not depend on the machine's core count.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use glam::{DMat3, DVec3};
use sim_core::fluoro::Scene;
use sim_core::fluoro::nesting::NestedMesh;

/// Triangles per culling chunk of the CPU pass. Simulator choice: large enough that projecting
/// the chunks' box corners (eight per chunk) stays a few percent of the pass, small enough that
/// a band or the needle's box skips most of the anatomy.
const CHUNK_TRIANGLES: usize = 64;

/// Rows per band. Simulator choice: a band's f64 sums at 1024 samples across (40 bytes per
/// sample, 1.3 MB) stay within a core's second-level cache.
const BAND_ROWS: usize = 32;

/// Sub-sample precision of snapped vertices, bits (GPU rasterisers use 8).
const SUBSAMPLE_BITS: u32 = 8;

/// Snapped coordinates beyond this many samples from the target's origin are refused (the frame
/// falls back to the GPU pass): with 8 fractional bits, edge products then stay below 2^62.
/// Simulator choice: 2^20 samples is a hundred times any detector.
const MAX_SAMPLE_COORDINATE: f64 = (1u64 << 20) as f64;

/// Triangles with a corner nearer than this to the source plane (axial depth, mm) are refused:
/// the GPU clips them, this pass does not. Simulator choice: no anatomy comes within a
/// millimetre of the focal spot.
const MIN_AXIAL_DEPTH_MM: f64 = 1.0;

/// The anatomy as the CPU pass reads it: the scene (shared, never copied) and chunks of each
/// drawn mesh's triangles in the GPU's drawing order.
pub(super) struct CpuGeometry {
    scene: Arc<Scene>,
    chunks: Vec<Chunk>,
}

struct Chunk {
    /// Index of the drawn mesh (in the anatomy's drawing order).
    mesh: u32,
    /// Triangles `first..first + count` of the mesh's scene entry.
    first: u32,
    count: u32,
    lo: [f64; 3],
    hi: [f64; 3],
}

/// A band's first row and its rows of the two outputs.
type BandOut<'a> = (usize, &'a mut [f32], &'a mut [f32]);

/// One drawn mesh's weights in the pass: geometric weights (`f32`, the GPU's), its reference
/// axial depth (mm) and whether it goes to the one-channel target.
#[derive(Debug, Clone, Copy)]
pub(super) struct MeshWeights {
    pub(super) g: [f32; 4],
    pub(super) wref: f32,
    pub(super) scalar: bool,
}

/// Why the CPU pass refused a frame (the GPU pass draws it instead).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Refused;

/// The target's projection: rows giving `(x w, y w, w)` of a point (sample coordinates `x, y`;
/// `w` its axial depth, mm), size in samples.
#[derive(Debug, Clone, Copy)]
pub(super) struct SampleProjection {
    pub(super) rows: [[f64; 4]; 3],
    pub(super) size: [u32; 2],
}

/// The geometric L-buffer of a target: `a` four channels per sample (row-major), `s` one.
pub(super) struct GeometrySums {
    pub(super) a: Vec<f32>,
    pub(super) s: Vec<f32>,
}

impl CpuGeometry {
    /// The chunks of `meshes` (the anatomy's drawn meshes, in drawing order) in `scene`.
    pub(super) fn new(scene: Arc<Scene>, meshes: &[NestedMesh]) -> CpuGeometry {
        let entries = scene.entries();
        let mut chunks = Vec::new();
        for (id, mesh) in meshes.iter().enumerate() {
            let tris = entries[mesh.entry].bvh.triangles_mm();
            for (k, c) in tris.chunks(CHUNK_TRIANGLES).enumerate() {
                let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                for v in c.iter().flatten() {
                    for a in 0..3 {
                        lo[a] = lo[a].min(v[a]);
                        hi[a] = hi[a].max(v[a]);
                    }
                }
                chunks.push(Chunk {
                    mesh: id as u32,
                    first: (k * CHUNK_TRIANGLES) as u32,
                    count: c.len() as u32,
                    lo,
                    hi,
                });
            }
        }
        CpuGeometry { scene, chunks }
    }

    /// The geometric L-buffer of `meshes` (in drawing order, as given to [`CpuGeometry::new`])
    /// with `weights` under `p`, on `threads` threads (0: every core). `Refused` when a triangle
    /// that may reach the target comes within [`MIN_AXIAL_DEPTH_MM`] of the source plane or
    /// projects too far away to snap.
    pub(super) fn rasterise(
        &self,
        meshes: &[NestedMesh],
        weights: &[MeshWeights],
        p: &SampleProjection,
        threads: usize,
    ) -> Result<GeometrySums, Refused> {
        let [w, h] = p.size.map(|x| x as usize);
        let m = DMat3::from_cols(
            DVec3::new(p.rows[0][0], p.rows[1][0], p.rows[2][0]),
            DVec3::new(p.rows[0][1], p.rows[1][1], p.rows[2][1]),
            DVec3::new(p.rows[0][2], p.rows[1][2], p.rows[2][2]),
        );
        let det = m.determinant();
        if !det.is_finite() || det == 0.0 {
            return Err(Refused);
        }
        let inv_t = m.inverse().transpose();
        let source = -(m.inverse() * DVec3::new(p.rows[0][3], p.rows[1][3], p.rows[2][3]));
        let threads = if threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            threads
        }
        .clamp(1, h.max(1));
        let boxes = self.chunk_boxes(p, threads);
        let frame = Frame {
            rows: p.rows,
            inv_t,
            source,
            det_positive: det > 0.0,
        };
        let entries = self.scene.entries();
        let tris: Vec<&[[[f64; 3]; 3]]> = meshes
            .iter()
            .map(|mesh| entries[mesh.entry].bvh.triangles_mm())
            .collect();
        let mut a = vec![0f32; 4 * w * h];
        let mut s = vec![0f32; w * h];
        let refused = AtomicBool::new(false);
        // Bands of a few rows, so that a band's sums stay in the core's cache while its
        // triangles are added; thread `k` takes bands `k`, `k + threads`, ...
        let rows_per = BAND_ROWS.min(h.max(1));
        let mut bands: Vec<Vec<BandOut<'_>>> = (0..threads).map(|_| Vec::new()).collect();
        for (band, (a_band, s_band)) in a
            .chunks_mut(4 * w * rows_per)
            .zip(s.chunks_mut(w * rows_per))
            .enumerate()
        {
            bands[band % threads].push((band * rows_per, a_band, s_band));
        }
        std::thread::scope(|scope| {
            for mine in bands {
                let (frame, boxes, tris, refused) = (&frame, &boxes, &tris, &refused);
                scope.spawn(move || {
                    let mut acc = Band::new(w, 0..rows_per);
                    for (first_row, a_band, s_band) in mine {
                        acc.reset(first_row..first_row + s_band.len() / w.max(1));
                        for (chunk, b) in self.chunks.iter().zip(boxes) {
                            if !acc.meets(*b) {
                                continue;
                            }
                            let mw = &weights[chunk.mesh as usize];
                            let mesh_tris = tris[chunk.mesh as usize];
                            let range = chunk.first as usize..(chunk.first + chunk.count) as usize;
                            for t in &mesh_tris[range] {
                                if acc.triangle(frame, t, mw).is_err() {
                                    refused.store(true, Ordering::Relaxed);
                                    return;
                                }
                            }
                        }
                        if refused.load(Ordering::Relaxed) {
                            return;
                        }
                        for (o, v) in a_band.iter_mut().zip(&acc.a) {
                            *o = *v as f32;
                        }
                        for (o, v) in s_band.iter_mut().zip(&acc.s) {
                            *o = *v as f32;
                        }
                    }
                });
            }
        });
        if refused.load(Ordering::Relaxed) {
            return Err(Refused);
        }
        Ok(GeometrySums { a, s })
    }

    /// Each chunk's box in sample coordinates `(x0, y0, x1, y1)` (its eight corners projected;
    /// the whole plane when a corner is within [`MIN_AXIAL_DEPTH_MM`] of the source plane, so
    /// that its triangles are looked at and refused).
    fn chunk_boxes(&self, p: &SampleProjection, threads: usize) -> Vec<[f64; 4]> {
        let mut boxes = vec![[0.0; 4]; self.chunks.len()];
        let per = self.chunks.len().div_ceil(threads).max(1);
        std::thread::scope(|scope| {
            for (out, chunks) in boxes.chunks_mut(per).zip(self.chunks.chunks(per)) {
                scope.spawn(move || {
                    for (o, c) in out.iter_mut().zip(chunks) {
                        *o = chunk_box(p, c);
                    }
                });
            }
        });
        boxes
    }
}

fn chunk_box(p: &SampleProjection, c: &Chunk) -> [f64; 4] {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for corner in 0..8 {
        let v: [f64; 3] = std::array::from_fn(|a| {
            if corner & (1 << a) == 0 {
                c.lo[a]
            } else {
                c.hi[a]
            }
        });
        let [x, y, w] = project(&p.rows, &v);
        if w.is_nan() || w < MIN_AXIAL_DEPTH_MM {
            return [
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::INFINITY,
            ];
        }
        let (x, y) = (x / w, y / w);
        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
    }
    b
}

/// `v` rounded to the nearest integer, halves away from zero (as `f64::round`, which is a libm
/// call on baseline x86-64); `|v|` is at most 2^28 here.
#[inline(always)]
fn snap(v: f64) -> i64 {
    (v + 0.5f64.copysign(v)) as i64
}

#[inline(always)]
fn project(rows: &[[f64; 4]; 3], v: &[f64; 3]) -> [f64; 3] {
    rows.map(|r| r[0] * v[0] + r[1] * v[1] + r[2] * v[2] + r[3])
}

/// The sample box of one triangle and its edge functions and depth plane there.
struct Span {
    rows: std::ops::RangeInclusive<i64>,
    cols: std::ops::RangeInclusive<usize>,
    /// Edge values at the box's first sample, and their steps per column and per row.
    e_row: [i64; 3],
    step_x: [i64; 3],
    step_y: [i64; 3],
    /// `w = k / (q.x x + q.y y + q.z)` at sample coordinates `(x, y)`.
    q: DVec3,
    k: f64,
    /// The mesh's reference axial depth, mm.
    wref: f64,
}

/// What every triangle of a frame needs.
struct Frame {
    rows: [[f64; 4]; 3],
    /// `(M^-1)^T` of the rows' 3 x 3 part.
    inv_t: DMat3,
    /// The focal spot, mm (where the rows give zero).
    source: DVec3,
    det_positive: bool,
}

/// One thread's rows of the target, summed in f64.
struct Band {
    width: usize,
    rows: std::ops::Range<usize>,
    a: Vec<f64>,
    s: Vec<f64>,
}

const ONE: i64 = 1 << SUBSAMPLE_BITS;
const HALF: i64 = ONE / 2;

impl Band {
    fn new(width: usize, rows: std::ops::Range<usize>) -> Band {
        let n = width * rows.len();
        Band {
            width,
            rows,
            a: vec![0.0; 4 * n],
            s: vec![0.0; n],
        }
    }

    /// Whether a chunk's sample box can reach a sample centre of this band (a sample `(i, j)`
    /// sits at `(i + 0.5, j + 0.5)`; a sample on the box's edge still counts).
    /// Adds `g (w - w_ref)` at every sample of `span` inside the triangle's three edges, into
    /// the four-channel sums (`C = 4`) or the one-channel sums (`C = 1`).
    #[inline(always)]
    fn add<const C: usize>(&mut self, span: &Span, g: [f64; 4]) {
        let sums = if C == 1 { &mut self.s } else { &mut self.a };
        let mut e_row = span.e_row;
        let (q, k, wref) = (span.q, span.k, span.wref);
        let (i0, i1) = (*span.cols.start(), *span.cols.end());
        for j in span.rows.clone() {
            let y = j as f64 + 0.5;
            let row_base = (j as usize - self.rows.start) * self.width;
            let row = &mut sums[C * (row_base + i0)..C * (row_base + i1 + 1)];
            let mut ev = e_row;
            let qy = q.y * y + q.z;
            for (i, o) in (i0..=i1).zip(row.chunks_exact_mut(C)) {
                // All three edge values non-negative: their bitwise or is.
                if (ev[0] | ev[1] | ev[2]) >= 0 {
                    let x = i as f64 + 0.5;
                    let d = k / (q.x * x + qy) - wref;
                    for c in 0..C {
                        o[c] += g[c] * d;
                    }
                }
                // The box's edge values stay within 2^62 (`MAX_SAMPLE_COORDINATE`).
                for (v, step) in ev.iter_mut().zip(span.step_x) {
                    *v = v.wrapping_add(step);
                }
            }
            for (v, step) in e_row.iter_mut().zip(span.step_y) {
                *v = v.wrapping_add(step);
            }
        }
    }

    /// Zeroes the sums for `rows` (at most as many rows as the band was made for).
    fn reset(&mut self, rows: std::ops::Range<usize>) {
        let n = self.width * rows.len();
        self.a.clear();
        self.a.resize(4 * n, 0.0);
        self.s.clear();
        self.s.resize(n, 0.0);
        self.rows = rows;
    }

    fn meets(&self, b: [f64; 4]) -> bool {
        let (y0, y1) = (self.rows.start as f64 + 0.5, self.rows.end as f64 - 0.5);
        let (x0, x1) = (0.5, self.width as f64 - 0.5);
        // One sample of slack each side for the snapping (1/512 of a sample at most).
        b[3] >= y0 - 1.0 && b[1] <= y1 + 1.0 && b[2] >= x0 - 1.0 && b[0] <= x1 + 1.0
    }

    /// Adds one triangle's signed, weighted axial depths at the samples it covers.
    #[inline]
    fn triangle(&mut self, f: &Frame, t: &[[f64; 3]; 3], mw: &MeshWeights) -> Result<(), Refused> {
        let mut fx = [0i64; 3];
        let mut fy = [0i64; 3];
        for (k, v) in t.iter().enumerate() {
            let [xw, yw, w] = project(&f.rows, v);
            if w.is_nan() || w < MIN_AXIAL_DEPTH_MM {
                return Err(Refused);
            }
            let scale = ONE as f64 / w;
            let (x, y) = (xw * scale, yw * scale);
            if !(x.abs() <= MAX_SAMPLE_COORDINATE * ONE as f64
                && y.abs() <= MAX_SAMPLE_COORDINATE * ONE as f64)
            {
                return Err(Refused);
            }
            fx[k] = snap(x);
            fy[k] = snap(y);
        }
        // Sample rows and columns whose centres lie in the snapped box.
        let lo_y = fy[0].min(fy[1]).min(fy[2]);
        let hi_y = fy[0].max(fy[1]).max(fy[2]);
        let j0 = (lo_y - HALF).div_euclid(ONE) + i64::from((lo_y - HALF).rem_euclid(ONE) != 0);
        let j1 = (hi_y - HALF).div_euclid(ONE);
        let j0 = j0.max(self.rows.start as i64);
        let j1 = j1.min(self.rows.end as i64 - 1);
        if j0 > j1 {
            return Ok(());
        }
        let lo_x = fx[0].min(fx[1]).min(fx[2]);
        let hi_x = fx[0].max(fx[1]).max(fx[2]);
        let i0 = (lo_x - HALF).div_euclid(ONE) + i64::from((lo_x - HALF).rem_euclid(ONE) != 0);
        let i1 = (hi_x - HALF).div_euclid(ONE);
        let i0 = i0.max(0);
        let i1 = i1.min(self.width as i64 - 1);
        if i0 > i1 {
            return Ok(());
        }
        let area2 = (fx[1] - fx[0]) * (fy[2] - fy[0]) - (fx[2] - fx[0]) * (fy[1] - fy[0]);
        if area2 == 0 {
            return Ok(());
        }
        let entering = (area2 > 0) != f.det_positive;
        if area2 < 0 {
            fx.swap(1, 2);
            fy.swap(1, 2);
        }
        // The plane's 1 / w at sample (x, y): (q . (x, y, 1)) / k.
        let v0 = DVec3::from(t[0]);
        let normal = (DVec3::from(t[1]) - v0).cross(DVec3::from(t[2]) - v0);
        let k = normal.dot(v0 - f.source);
        let q = f.inv_t * normal;
        let sign = if entering { -1.0 } else { 1.0 };
        let wref = f64::from(mw.wref);
        let g = mw.g.map(|x| sign * f64::from(x));
        // Edge functions E(p) = (b - a) x (p - a) at the first sample of the box, their steps,
        // and the tie rule's bias (-1: a sample on the edge is not taken).
        let mut e_row = [0i64; 3];
        let mut step_x = [0i64; 3];
        let mut step_y = [0i64; 3];
        let px0 = i0 * ONE + HALF;
        let py0 = j0 * ONE + HALF;
        for e in 0..3 {
            let (a, b) = (e, (e + 1) % 3);
            let (dx, dy) = (fx[b] - fx[a], fy[b] - fy[a]);
            let takes_ties = dy > 0 || (dy == 0 && dx < 0);
            e_row[e] = dx * (py0 - fy[a]) - dy * (px0 - fx[a]) - i64::from(!takes_ties);
            step_x[e] = -dy * ONE;
            step_y[e] = dx * ONE;
        }
        let span = Span {
            rows: j0..=j1,
            cols: i0 as usize..=i1 as usize,
            e_row,
            step_x,
            step_y,
            q,
            k,
            wref,
        };
        if mw.scalar {
            self.add::<1>(&span, [g[0], 0.0, 0.0, 0.0]);
        } else {
            self.add::<4>(&span, g);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;
    use sim_core::fluoro::{FluoroMaterial, Projection};
    use sim_core::material::MaterialClass;
    use sim_core::mesh::TriMesh;
    use sim_core::rng::SplitMix64;

    /// A closed box `[-half, half]^3` with each face cut into `n x n` squares (two triangles
    /// each, diagonals alternating), rotated by `rot` about its centre and moved to `centre`,
    /// outward counter-clockwise. Shared corners are computed by one expression, so faces
    /// meet exactly.
    fn grid_box(n: u32, half: f64, rot: DQuat, centre: DVec3) -> TriMesh {
        let at = |k: u32| -half + 2.0 * half * f64::from(k) / f64::from(n);
        let mut mesh = TriMesh {
            vertices_mm: Vec::new(),
            triangles: Vec::new(),
        };
        for axis in 0..3 {
            for side in [0, n] {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let point = |a: u32, b: u32| {
                    let mut p = DVec3::ZERO;
                    p[axis] = at(side);
                    p[u] = at(a);
                    p[v] = at(b);
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
            size: [20, 20],
        }
    }

    /// The CPU pass over a scene of `mesh` alone, drawn with `weights`.
    fn one_mesh(
        mesh: &TriMesh,
        p: &SampleProjection,
        weights: MeshWeights,
        threads: usize,
    ) -> Result<GeometrySums, Refused> {
        let material = FluoroMaterial::Tissue(MaterialClass::CorticalBone);
        let mut scene = Scene::new();
        scene.add("box", material, mesh);
        let meshes = [NestedMesh {
            entry: 0,
            name: "box".into(),
            effective: material,
            container: None,
            centre_mm: [0.0; 3],
        }];
        CpuGeometry::new(Arc::new(scene), &meshes).rasterise(&meshes, &[weights], p, threads)
    }

    /// The CPU pass over one mesh with weights `(1, 0, 0, 0)` (four-channel target) and
    /// reference depth `wref`: channel 0 of every sample.
    fn axial_chords(mesh: &TriMesh, p: &SampleProjection, wref: f32, threads: usize) -> Vec<f64> {
        let weights = MeshWeights {
            g: [1.0, 0.0, 0.0, 0.0],
            wref,
            scalar: false,
        };
        let sums = one_mesh(mesh, p, weights, threads).expect("in front of the source");
        assert!(
            sums.s.iter().all(|&v| v == 0.0),
            "nothing in the scalar target"
        );
        sums.a.chunks_exact(4).map(|c| f64::from(c[0])).collect()
    }

    /// Exact axial extent `w_exit - w_enter` of the box on the ray of sample `(x, y)`: the ray's
    /// points are `source + w M^-1 (x, y, 1)`; the slab method in the box's own frame.
    fn exact_axial_chord(
        p: &SampleProjection,
        half: f64,
        rot: DQuat,
        centre: DVec3,
        x: f64,
        y: f64,
    ) -> f64 {
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
                if start[a].abs() > half {
                    return 0.0;
                }
                continue;
            }
            let (t0, t1) = ((-half - start[a]) / dir[a], (half - start[a]) / dir[a]);
            lo = lo.max(t0.min(t1));
            hi = hi.min(t0.max(t1));
        }
        (hi - lo).max(0.0)
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
        let mesh = grid_box(7, half, DQuat::IDENTITY, centre);
        for threads in [1, 3] {
            let got = axial_chords(&mesh, &p, 103.0, threads);
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
            let projection = Projection {
                detector_pixels: [64, 48],
                pixel_pitch_mm: [1.5, 1.5],
                orbital_deg: 180.0 * r() - 90.0,
                angular_deg: 60.0 * r() - 30.0,
                ..Projection::default()
            };
            let m = projection.projection_matrix();
            let (n, x0, y0) = if trial % 2 == 0 {
                (1.0, 0.0, 0.0)
            } else {
                (2.0, 10.0 + 20.0 * r(), 5.0 + 20.0 * r())
            };
            let row = |k: usize, o: f64| -> [f64; 4] {
                std::array::from_fn(|c| n * (m[k][c] - o * m[2][c]))
            };
            let p = SampleProjection {
                rows: [row(0, x0), row(1, y0), m[2]],
                size: [64, 48],
            };
            let rot = DQuat::from_euler(glam::EulerRot::XYZ, 6.0 * r(), 6.0 * r(), 6.0 * r());
            let centre = DVec3::new(40.0 * r() - 20.0, 40.0 * r() - 20.0, 40.0 * r() - 20.0);
            let half = 10.0 + 20.0 * r();
            let mesh = grid_box(3 + trial as u32 % 4, half, rot, centre);
            let got = axial_chords(&mesh, &p, 500.0, 2);
            assert_eq!(
                got,
                axial_chords(&mesh, &p, 500.0, 1),
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
        let mesh = grid_box(2, 200.0, DQuat::IDENTITY, DVec3::ZERO);
        let weights = MeshWeights {
            g: [1.0; 4],
            wref: 0.0,
            scalar: true,
        };
        assert_eq!(one_mesh(&mesh, &p, weights, 2).err(), Some(Refused));
    }
}
