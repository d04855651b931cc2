//! The L-buffer passes on the CPU (see the module map in `fluoro`): the same sums as
//! `lbuffer.wgsl`'s `fs_anatomy` and `fs_anatomy_scalar` (here) and `fs_needle` and
//! `fs_displaced` (`needle.rs`), rasterised by the worker's own cores from the scene's f64
//! triangles and uploaded into the targets the resolve reads, for adapters whose rasteriser is
//! itself software (lavapipe: its geometry stage sets up every triangle on one thread, about
//! 200 ns each, so a C-arm-moved frame of the default phantom spent about 225 of its 260 ms on
//! the 1.1 M triangles that reach the image, and a needle-moved frame most of its 32 ms on the
//! few passes over the needle's box). Here: the anatomy's chunks and the bands; `span.rs`: the
//! sample grid and one triangle's set-up over it (the coverage rule and the depth below).
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

mod needle;
mod span;
#[cfg(test)]
mod tests;

use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};

use rustc_hash::FxHashMap;

use crate::interrupt::Interrupt;
use crate::priority::Priority;
use sim_core::fluoro::Scene;
use sim_core::fluoro::nesting::{NestedMesh, soup_box};

pub(super) use needle::NeedleTriangles;
use span::{Frame, MIN_AXIAL_DEPTH_MM, Span, project, setup, setup_snapped};
pub(super) use span::{NotDrawn, Refused, SampleProjection, SampleRect};

/// Triangles per culling chunk of the CPU pass. Simulator choice: large enough that projecting
/// the chunks' box corners (eight per chunk) stays a few percent of the pass, small enough that
/// a band or the needle's box skips most of the anatomy.
const CHUNK_TRIANGLES: usize = 64;

/// Chunks between two looks at the render's interrupt flag (see `crate::interrupt`). Our
/// choice: 256 chunks are 16k triangles, well under a millisecond of a band's work, while one
/// relaxed load per 256 chunks costs nothing measurable.
const INTERRUPT_CHUNKS: usize = 256;

/// Most rows per band. Simulator choice: a band's f64 sums at 1024 samples across (40 bytes per
/// sample, 5 MB) still mostly stay in cache, while a triangle is set up once per band its
/// chunk meets (each set-up reads its 72 bytes from memory): the CPU passes of C-arm-moved
/// frames of `PhantomParams::with_voxel_mm(1.5)` (a lighter mesh set than the default) took
/// 72 / 70 / 65 ms at 512^2 and 162 / 138 / 136 ms at 1024^2 with bands of 32, 64 and 128
/// rows.
const BAND_ROWS: usize = 128;

/// The anatomy as the CPU pass reads it: chunks of each drawn mesh's triangles in the GPU's
/// drawing order, each chunk as its distinct corners (the scene's values, bit for bit) and its
/// triangles as three indices into them. A chunk's corners are projected and snapped once per
/// band it meets, not once per triangle corner (a chunk of 64 triangles of the default phantom
/// has about 53 distinct corners instead of 192), and the pass reads about 13 bytes per
/// triangle of the default phantom instead of the scene's 72 (its set-up was bound by those
/// reads).
pub(super) struct CpuGeometry {
    chunks: Vec<Chunk>,
    /// Every chunk's distinct corners, chunk after chunk.
    corners: Corners,
    /// Every chunk's triangles, each as indices into its chunk's corners, chunk after chunk.
    triangles: Vec<[u8; 3]>,
}

/// Consecutive chunks of [`CpuGeometry`], their ranges counted from the part's start.
struct Part {
    chunks: Vec<Chunk>,
    corners: Vec<[f64; 3]>,
    triangles: Vec<[u8; 3]>,
}

impl Part {
    /// The chunks of `jobs` (drawn mesh index, the chunk's triangles).
    fn of(jobs: &[(u32, &[[[f64; 3]; 3]])]) -> Part {
        let mut part = Part {
            chunks: Vec::with_capacity(jobs.len()),
            corners: Vec::new(),
            triangles: Vec::new(),
        };
        // A chunk's corner index by its coordinates' bits (the same f64 values share a corner).
        let mut seen: FxHashMap<[u64; 3], u8> =
            FxHashMap::with_capacity_and_hasher(3 * CHUNK_TRIANGLES, Default::default());
        for &(mesh, c) in jobs {
            let (lo, hi) = soup_box(c);
            seen.clear();
            let first_corner = part.corners.len();
            let first_triangle = part.triangles.len();
            for t in c {
                let corners = &mut part.corners;
                let index = t.map(|v| {
                    *seen.entry(v.map(f64::to_bits)).or_insert_with(|| {
                        corners.push(v);
                        // At most 3 x CHUNK_TRIANGLES = 192 corners: a u8.
                        (corners.len() - 1 - first_corner) as u8
                    })
                });
                part.triangles.push(index);
            }
            part.chunks.push(Chunk {
                mesh,
                corners: first_corner as u32..part.corners.len() as u32,
                triangles: first_triangle as u32..part.triangles.len() as u32,
                lo,
                hi,
            });
        }
        part
    }
}

/// Corners, mm: `f32` when every corner of the scene is an `f32` value (a region asset's
/// meshes are stored in `f32`, so the scene's f64 corners all are: the same values in half the
/// memory and reads), else `f64`.
enum Corners {
    F32(Vec<[f32; 3]>),
    F64(Vec<[f64; 3]>),
}

/// A stored corner.
trait Corner: Copy {
    /// Its coordinates, mm (exactly the scene's).
    fn mm(self) -> [f64; 3];
}

impl Corner for [f32; 3] {
    #[inline(always)]
    fn mm(self) -> [f64; 3] {
        self.map(f64::from)
    }
}

impl Corner for [f64; 3] {
    #[inline(always)]
    fn mm(self) -> [f64; 3] {
        self
    }
}

#[derive(Clone)]
struct Chunk {
    /// Index of the drawn mesh (in the anatomy's drawing order).
    mesh: u32,
    /// Its corners `corners.start..` and triangles `triangles.start..` in [`CpuGeometry`].
    corners: Range<u32>,
    triangles: Range<u32>,
    lo: [f64; 3],
    hi: [f64; 3],
}

impl Chunk {
    fn corners(&self) -> Range<usize> {
        self.corners.start as usize..self.corners.end as usize
    }

    fn triangles(&self) -> Range<usize> {
        self.triangles.start as usize..self.triangles.end as usize
    }
}

/// One drawn mesh's weights in the pass: geometric weights (`f32`, the GPU's), its reference
/// axial depth (mm) and whether it goes to the one-channel target.
#[derive(Debug, Clone, Copy)]
pub(super) struct MeshWeights {
    pub(super) g: [f32; 4],
    pub(super) wref: f32,
    pub(super) scalar: bool,
}

/// Each chunk's full-image pixel box `(x0, y0, x1, y1)` under one projection (its eight corners
/// projected; everywhere when a corner is within [`MIN_AXIAL_DEPTH_MM`] of the source plane, so
/// that its triangles are looked at and refused). A renderer keeps them while its projection
/// stays: a needle-moved frame culls with them again.
pub(super) struct ChunkBoxes {
    matrix: [[f64; 4]; 3],
    boxes: Vec<[f32; 4]>,
}

impl ChunkBoxes {
    /// Whether these are the boxes under `matrix` (the projection's, bit for bit).
    pub(super) fn under(&self, matrix: &[[f64; 4]; 3]) -> bool {
        same_matrix(&self.matrix, matrix)
    }
}

/// Whether two projection matrices are the same bit for bit (what decides that work done under
/// one serves the other).
pub(super) fn same_matrix(a: &[[f64; 4]; 3], b: &[[f64; 4]; 3]) -> bool {
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

/// The geometric L-buffer of a target: `a` four channels per sample (row-major), `s` one.
pub(super) struct GeometrySums {
    pub(super) a: Vec<f32>,
    pub(super) s: Vec<f32>,
}

impl GeometrySums {
    /// The sums of `part`, a rectangle within `whole` (the rectangle these sums cover).
    pub(super) fn crop(&self, whole: &SampleRect, part: &SampleRect) -> GeometrySums {
        debug_assert!(whole.contains(part), "{part:?} within {whole:?}");
        let (mut a, mut s) = (
            Vec::with_capacity(4 * part.len()),
            Vec::with_capacity(part.len()),
        );
        for j in part.rows.clone() {
            let first = whole.index(part.cols.start, j);
            let cols = first..first + part.cols.len();
            a.extend_from_slice(&self.a[4 * cols.start..4 * cols.end]);
            s.extend_from_slice(&self.s[cols]);
        }
        GeometrySums { a, s }
    }
}

impl CpuGeometry {
    /// The chunks of `meshes` (the anatomy's drawn meshes, in drawing order) in `scene`, made
    /// on every core (in parts of consecutive chunks, joined in order: the result does not
    /// depend on the number of cores).
    pub(super) fn new(scene: &Scene, meshes: &[NestedMesh]) -> CpuGeometry {
        let entries = scene.entries();
        let jobs: Vec<(u32, &[[[f64; 3]; 3]])> = meshes
            .iter()
            .enumerate()
            .flat_map(|(id, mesh)| {
                let tris = entries[mesh.entry].bvh.triangles_mm();
                tris.chunks(CHUNK_TRIANGLES).map(move |c| (id as u32, c))
            })
            .collect();
        let per = jobs.len().div_ceil(thread_count(0)).max(1);
        let parts: Vec<Part> = std::thread::scope(|scope| {
            let handles: Vec<_> = jobs
                .chunks(per)
                .map(|jobs| scope.spawn(move || Part::of(jobs)))
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("chunking thread"))
                .collect()
        });
        let mut chunks = Vec::with_capacity(jobs.len());
        let mut corners: Vec<[f64; 3]> = Vec::new();
        let mut triangles = Vec::new();
        for part in parts {
            let (c0, t0) = (corners.len() as u32, triangles.len() as u32);
            chunks.extend(part.chunks.into_iter().map(|c| Chunk {
                corners: c.corners.start + c0..c.corners.end + c0,
                triangles: c.triangles.start + t0..c.triangles.end + t0,
                ..c
            }));
            corners.extend(part.corners);
            triangles.extend(part.triangles);
        }
        let in_f32 = corners
            .iter()
            .flatten()
            .all(|&v| f64::from(v as f32).to_bits() == v.to_bits());
        let corners = if in_f32 {
            Corners::F32(corners.iter().map(|v| v.map(|x| x as f32)).collect())
        } else {
            Corners::F64(corners)
        };
        CpuGeometry {
            chunks,
            corners,
            triangles,
        }
    }

    /// Triangles kept, of every drawn mesh.
    pub(super) fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Calls `f(mesh, corners)` for every triangle in drawing order (each mesh's in its scene
    /// order), with its corners' exact values (mm).
    pub(super) fn for_each_triangle(&self, mut f: impl FnMut(u32, [[f64; 3]; 3])) {
        fn each<C: Corner>(g: &CpuGeometry, corners: &[C], f: &mut impl FnMut(u32, [[f64; 3]; 3])) {
            for chunk in &g.chunks {
                let c = &corners[chunk.corners()];
                for t in &g.triangles[chunk.triangles()] {
                    f(chunk.mesh, t.map(|k| c[usize::from(k)].mm()));
                }
            }
        }
        match &self.corners {
            Corners::F32(c) => each(self, c, &mut f),
            Corners::F64(c) => each(self, c, &mut f),
        }
    }

    /// The chunks' pixel boxes under the projection `matrix` (rows giving `(x w, y w, w)` in
    /// full-image pixel coordinates), on `threads` threads (0: every core).
    pub(super) fn chunk_boxes(&self, matrix: &[[f64; 4]; 3], threads: usize) -> ChunkBoxes {
        let mut boxes = vec![[0.0; 4]; self.chunks.len()];
        let per = self.chunks.len().div_ceil(thread_count(threads)).max(1);
        let priority = Priority::of_this_thread();
        std::thread::scope(|scope| {
            for (out, chunks) in boxes.chunks_mut(per).zip(self.chunks.chunks(per)) {
                scope.spawn(move || {
                    priority.enter();
                    for (o, c) in out.iter_mut().zip(chunks) {
                        *o = projected_box(matrix, c.lo, c.hi);
                    }
                });
            }
        });
        ChunkBoxes {
            matrix: *matrix,
            boxes,
        }
    }

    /// The geometric L-buffer of the meshes (each with its `weights`, in the drawing order given
    /// to [`CpuGeometry::new`]) under `p` at the samples of `rect` (row-major over it), culled with
    /// `boxes` (under `p`'s projection), on `threads` threads (0: every core). `Refused` when
    /// a triangle that may reach the rectangle comes within [`MIN_AXIAL_DEPTH_MM`] of the
    /// source plane or projects too far away to snap. Each sample's sums do not depend on the
    /// rectangle: a rectangle cut from a larger one's sums ([`GeometrySums::crop`]) equals
    /// its own, bit for bit. `Interrupted` once the flag this thread watches is raised (see
    /// `crate::interrupt`; asked between chunks of triangles).
    pub(super) fn rasterise_rect(
        &self,
        weights: &[MeshWeights],
        p: &SampleProjection,
        boxes: &ChunkBoxes,
        rect: &SampleRect,
        threads: usize,
    ) -> Result<GeometrySums, NotDrawn> {
        let n = rect.len();
        let mut a = vec![0f32; 4 * n];
        let mut s = vec![0f32; n];
        self.banded(
            p,
            boxes,
            rect,
            (&mut a, Some(&mut s)),
            (threads, &Interrupt::of_this_thread()),
            |band, span, mesh| {
                let mw = &weights[mesh];
                let g = mw.g.map(|x| span.sign() * f64::from(x));
                let wref = f64::from(mw.wref);
                if mw.scalar {
                    band.add::<1>(span, [g[0], 0.0, 0.0, 0.0], wref);
                } else {
                    band.add::<4>(span, g, wref);
                }
            },
        )?;
        Ok(GeometrySums { a, s })
    }

    /// Adds every anatomy triangle that can reach `rect` (in drawing order, culled with
    /// `boxes`) to bands of `rect`'s rows with `add(band, span, mesh)`, on `threads` threads,
    /// then writes the bands' four-channel sums (and one-channel sums, if asked) into `out`
    /// (row-major over `rect`); gives up once `interrupt` is raised.
    fn banded(
        &self,
        p: &SampleProjection,
        boxes: &ChunkBoxes,
        rect: &SampleRect,
        (out4, out1): (&mut [f32], Option<&mut [f32]>),
        (threads, interrupt): (usize, &Interrupt),
        add: impl Fn(&mut Band, &Span, usize) + Sync,
    ) -> Result<(), NotDrawn> {
        let frame = Frame::new(p)?;
        let w = rect.cols.len();
        let h = rect.rows.len();
        if w == 0 || h == 0 {
            return Ok(());
        }
        let refused = AtomicBool::new(false);
        let interrupted = AtomicBool::new(false);
        // Bands of rows, at least one per thread (a needle's box is a few dozen rows), at most
        // `BAND_ROWS`; thread `k` takes bands `k`, `k + threads`, ...
        let threads = thread_count(threads).min(h);
        let rows_per = h.div_ceil(threads).min(BAND_ROWS);
        let bands_n = h.div_ceil(rows_per);
        let threads = threads.min(bands_n);
        let mut bands: Vec<Vec<BandOut<'_>>> = (0..threads).map(|_| Vec::new()).collect();
        let mut ones = out1.map(|o| o.chunks_mut(w * rows_per));
        for (band, a_band) in out4.chunks_mut(4 * w * rows_per).enumerate() {
            let s_band = ones.as_mut().and_then(Iterator::next);
            bands[band % threads].push((band * rows_per, a_band, s_band));
        }
        let priority = Priority::of_this_thread();
        std::thread::scope(|scope| {
            for mine in bands {
                let (frame, refused, add) = (&frame, &refused, &add);
                let interrupted = &interrupted;
                scope.spawn(move || {
                    priority.enter();
                    let mut acc = Band::default();
                    let mut snapped = [[0i64; 2]; 3 * CHUNK_TRIANGLES];
                    for (first, a_band, s_band) in mine {
                        let first_row = rect.rows.start + first;
                        let rows = first_row..first_row + a_band.len() / (4 * w);
                        acc.reset(SampleRect {
                            cols: rect.cols.clone(),
                            rows,
                        });
                        match self.draw_band(
                            frame,
                            p,
                            boxes,
                            (&mut acc, &mut snapped),
                            add,
                            interrupt,
                        ) {
                            Ok(()) => {}
                            Err(NotDrawn::Refused) => {
                                refused.store(true, Ordering::Relaxed);
                                return;
                            }
                            Err(NotDrawn::Interrupted) => {
                                interrupted.store(true, Ordering::Relaxed);
                                return;
                            }
                        }
                        if refused.load(Ordering::Relaxed) || interrupted.load(Ordering::Relaxed) {
                            return;
                        }
                        for (o, v) in a_band.iter_mut().zip(&acc.a) {
                            *o = *v as f32;
                        }
                        if let Some(s_band) = s_band {
                            for (o, v) in s_band.iter_mut().zip(&acc.s) {
                                *o = *v as f32;
                            }
                        }
                    }
                });
            }
        });
        if refused.load(Ordering::Relaxed) {
            return Err(NotDrawn::Refused);
        }
        if interrupted.load(Ordering::Relaxed) {
            return Err(NotDrawn::Interrupted);
        }
        Ok(())
    }

    /// Adds every anatomy triangle that can reach `acc`'s rectangle (in drawing order, culled
    /// with `boxes`) to it with `add(band, span, mesh)`, snapping each chunk's corners into
    /// `snapped`; `Refused` as [`Frame::snap`], `Interrupted` once `interrupt` is raised
    /// (asked every [`INTERRUPT_CHUNKS`] chunks).
    fn draw_band(
        &self,
        frame: &Frame,
        p: &SampleProjection,
        boxes: &ChunkBoxes,
        (acc, snapped): (&mut Band, &mut [[i64; 2]]),
        add: &(impl Fn(&mut Band, &Span, usize) + Sync),
        interrupt: &Interrupt,
    ) -> Result<(), NotDrawn> {
        let px = p.pixel_box(&acc.rect);
        for (k, (chunk, b)) in self.chunks.iter().zip(&boxes.boxes).enumerate() {
            if k % INTERRUPT_CHUNKS == 0 && interrupt.is_raised() {
                return Err(NotDrawn::Interrupted);
            }
            // One pixel of slack each side for the snapping (1/512 of a sample) and the boxes'
            // f32 rounding.
            let b = b.map(f64::from);
            if b[2] < px[0] - 1.0 || b[0] > px[2] + 1.0 || b[3] < px[1] - 1.0 || b[1] > px[3] + 1.0
            {
                continue;
            }
            let tris = &self.triangles[chunk.triangles()];
            let mut add = |acc: &mut Band, span: &Span| add(acc, span, chunk.mesh as usize);
            let corners = chunk.corners();
            match &self.corners {
                Corners::F32(c) => draw_chunk(frame, &c[corners], tris, snapped, acc, &mut add),
                Corners::F64(c) => draw_chunk(frame, &c[corners], tris, snapped, acc, &mut add),
            }?;
        }
        Ok(())
    }
}

/// Adds the triangles of one chunk (`corners`, and `triangles` indexing them) to `acc` with
/// `add`, snapping the corners into `snapped` first; `Refused` as [`Frame::snap`].
#[inline(always)]
fn draw_chunk<C: Corner>(
    frame: &Frame,
    corners: &[C],
    triangles: &[[u8; 3]],
    snapped: &mut [[i64; 2]],
    acc: &mut Band,
    add: &mut impl FnMut(&mut Band, &Span),
) -> Result<(), Refused> {
    for (s, v) in snapped.iter_mut().zip(corners) {
        *s = frame.snap(&v.mm())?;
    }
    for t in triangles {
        let t = t.map(usize::from);
        let at = t.map(|k| snapped[k]);
        let tri = t.map(|k| corners[k].mm());
        if let Some(span) = setup_snapped(frame, &tri, at, &acc.rect) {
            add(acc, &span);
        }
    }
    Ok(())
}

/// A band's first row (from the rectangle's first) and its rows of the two outputs.
type BandOut<'a> = (usize, &'a mut [f32], Option<&'a mut [f32]>);

/// `threads`, or every core for 0.
fn thread_count(threads: usize) -> usize {
    if threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        threads
    }
}

/// The full-image pixel box `(x0, y0, x1, y1)` of the axis-aligned box `lo..hi` (mm) under the
/// projection `matrix` (rows giving `(x w, y w, w)`): its eight corners projected; everywhere
/// when a corner is within [`MIN_AXIAL_DEPTH_MM`] of the source plane (or the projection is
/// not a number), so that what it bounds is looked at. Culls the chunks of both the CPU passes
/// and the adapter's (`LBuffer::culled`).
pub(super) fn projected_box(matrix: &[[f64; 4]; 3], lo: [f64; 3], hi: [f64; 3]) -> [f32; 4] {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for corner in 0..8 {
        let v: [f64; 3] =
            std::array::from_fn(|a| if corner & (1 << a) == 0 { lo[a] } else { hi[a] });
        let [x, y, w] = project(matrix, &v);
        if w.is_nan() || w < MIN_AXIAL_DEPTH_MM {
            return [
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
                f32::INFINITY,
                f32::INFINITY,
            ];
        }
        let (x, y) = (x / w, y / w);
        b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
    }
    b.map(|v| v as f32)
}

/// One thread's band of rows of a rectangle, summed in f64.
#[derive(Default)]
struct Band {
    rect: SampleRect,
    a: Vec<f64>,
    s: Vec<f64>,
}

impl Band {
    /// Zeroes the sums for `rect`.
    fn reset(&mut self, rect: SampleRect) {
        let n = rect.len();
        self.a.clear();
        self.a.resize(4 * n, 0.0);
        self.s.clear();
        self.s.resize(n, 0.0);
        self.rect = rect;
    }

    /// Adds `g (w - wref)` at every sample `span` covers, into the four-channel sums (`C = 4`)
    /// or the one-channel sums (`C = 1`). (The geometric pass's inner loop: each covered run
    /// of a row is sliced once, so each sample costs no bounds check and no coverage test.)
    #[inline(always)]
    fn add<const C: usize>(&mut self, span: &Span, g: [f64; 4], wref: f64) {
        let rect = &self.rect;
        let sums = if C == 1 { &mut self.s } else { &mut self.a };
        span.for_each_row(|j, cols| {
            let base = rect.index(cols.start, j);
            let row = &mut sums[C * base..C * (base + cols.len())];
            let qy = span.q.y * (j as f64 + 0.5) + span.q.z;
            for (i, o) in cols.zip(row.chunks_exact_mut(C)) {
                let d = span.k / (span.q.x * (i as f64 + 0.5) + qy) - wref;
                for c in 0..C {
                    o[c] += g[c] * d;
                }
            }
        });
    }
}
