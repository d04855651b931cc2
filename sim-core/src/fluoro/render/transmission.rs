//! Transmission per pixel: exact chords along each ray through the scene, the spectral model,
//! and supersampling where a pixel straddles an edge or a thin steel instrument.

use crate::fluoro::rows::{par_rows, thread_count};
use super::settings::{RenderSettings, TransmissionImage};
use crate::fluoro::attenuation::{FluoroMaterial, MaterialChords, SpectralModel, basis_depths};
use crate::fluoro::contrast::IodineField;
use crate::fluoro::geometry::{DetectorFrame, Projection, ray_through};
use crate::fluoro::scene::{ChordScratch, RayChords, SceneRef};
use crate::fluoro::spectrum::UnknownKvp;

struct Ctx<'a> {
    scene: SceneRef<'a>,
    iodine: Option<&'a IodineField>,
    projection: &'a Projection,
    frame: DetectorFrame,
    model: SpectralModel,
}

impl Ctx<'_> {
    fn sample(&self, px: [f64; 2], scratch: &mut ChordScratch) -> (f64, u64) {
        let ray = ray_through(&self.frame, self.projection, px);
        let r = self
            .scene
            .ray_chords(ray.origin_mm, ray.dir, ray.detector_t_mm, scratch);
        let iodine = self.iodine.map_or(0.0, |f| {
            f.column_stock_mm(ray.origin_mm, ray.dir, 0.0, ray.detector_t_mm)
        });
        (
            self.model.transmission(&basis_depths(&r.chords_mm, iodine)),
            r.signature,
        )
    }

    fn supersampled(&self, i: usize, j: usize, n: u32, scratch: &mut ChordScratch) -> f64 {
        let mut acc = 0.0;
        for b in 0..n {
            for a in 0..n {
                let px = [
                    i as f64 + (a as f64 + 0.5) / n as f64,
                    j as f64 + (b as f64 + 0.5) / n as f64,
                ];
                acc += self.sample(px, scratch).0;
            }
        }
        acc / f64::from(n * n)
    }
}

/// Exact per-material chords at every pixel centre (no supersampling): what the GPU's path-length
/// pass must reproduce. Pixels outside the collimator get chords too (geometry only). `scene` is
/// a [`Scene`](crate::fluoro::Scene) or a [`SceneRef`] (a scene with an overlay).
pub fn render_chords<'a>(
    scene: impl Into<SceneRef<'a>>,
    projection: &Projection,
    threads: usize,
) -> Vec<RayChords> {
    let scene = scene.into();
    let frame = projection.frame();
    let [w, h] = projection.detector_pixels.map(|x| x as usize);
    let empty = RayChords {
        chords_mm: [0.0; FluoroMaterial::COUNT],
        signature: 0,
    };
    let mut out = vec![empty; w * h];
    par_rows(&mut out, w, thread_count(threads), |j, row| {
        let mut scratch = ChordScratch::default();
        for (i, o) in row.iter_mut().enumerate() {
            let ray = ray_through(&frame, projection, [i as f64 + 0.5, j as f64 + 0.5]);
            *o = scene.ray_chords(ray.origin_mm, ray.dir, ray.detector_t_mm, &mut scratch);
        }
    });
    out
}

/// Transmission per pixel: centre samples, then `n x n` supersampling where needed. `scene` is a
/// [`Scene`](crate::fluoro::Scene) or a [`SceneRef`] (a scene with an overlay).
pub fn render_transmission<'a>(
    scene: impl Into<SceneRef<'a>>,
    iodine: Option<&IodineField>,
    projection: &Projection,
    settings: &RenderSettings,
) -> Result<TransmissionImage, UnknownKvp> {
    let scene = scene.into();
    let ctx = Ctx {
        scene,
        iodine,
        projection,
        frame: projection.frame(),
        model: SpectralModel::new(settings.energy)?,
    };
    let [w, h] = projection.detector_pixels.map(|x| x as usize);
    let threads = thread_count(settings.threads);
    let exposed: Vec<bool> = (0..w * h)
        .map(|p| projection.is_exposed([(p % w) as f64 + 0.5, (p / w) as f64 + 0.5]))
        .collect();
    // Pass 1: pixel centres.
    let mut centre = vec![(0.0f64, 0u64); w * h];
    par_rows(&mut centre, w, threads, |j, row| {
        let mut scratch = ChordScratch::default();
        for (i, o) in row.iter_mut().enumerate() {
            if exposed[j * w + i] {
                *o = ctx.sample([i as f64 + 0.5, j as f64 + 0.5], &mut scratch);
            }
        }
    });
    // Pass 2: which pixels need supersampling.
    let n = settings.supersample.max(1);
    let mut flag = vec![false; w * h];
    if n > 1 {
        if settings.adaptive {
            for j in 0..h {
                for i in 0..w {
                    let s = centre[j * w + i].1;
                    let differs = (j.saturating_sub(1)..(j + 2).min(h)).any(|jj| {
                        (i.saturating_sub(1)..(i + 2).min(w)).any(|ii| centre[jj * w + ii].1 != s)
                    });
                    flag[j * w + i] = differs;
                }
            }
            mark_steel_edges(scene, projection, &mut flag, w, h);
        } else {
            flag.fill(true);
        }
    }
    // Pass 3: supersample flagged pixels.
    let mut transmission: Vec<f64> = centre.iter().map(|c| c.0).collect();
    par_rows(&mut transmission, w, threads, |j, row| {
        let mut scratch = ChordScratch::default();
        for (i, t) in row.iter_mut().enumerate() {
            let p = j * w + i;
            if flag[p] && exposed[p] {
                *t = ctx.supersampled(i, j, n, &mut scratch);
            }
        }
    });
    let supersampled_pixels = flag
        .iter()
        .zip(&exposed)
        .filter(|(f, e)| **f && **e)
        .count();
    Ok(TransmissionImage {
        width: w as u32,
        height: h as u32,
        transmission,
        exposed,
        supersampled_pixels,
    })
}

/// Flags every pixel within 1.5 pixels of a projected edge of a steel mesh, so an instrument
/// thinner than a pixel (which centre rays can miss entirely) is still supersampled.
fn mark_steel_edges(
    scene: SceneRef<'_>,
    projection: &Projection,
    flag: &mut [bool],
    w: usize,
    h: usize,
) {
    for entry in scene
        .entries()
        .filter(|e| e.material == FluoroMaterial::Steel)
    {
        mark_projected_edges(
            projection,
            entry.bvh.triangles_mm().iter().copied(),
            flag,
            w,
            h,
        );
    }
}

/// The steel-edge rule shared by the CPU reference and the GPU renderer: every pixel within
/// `1.5` pixels of a projected triangle edge is flagged, walking each edge in 0.5-pixel steps
/// with the f64 projection. `flag` is row-major, `w x h`.
pub fn mark_projected_edges(
    projection: &Projection,
    triangles_mm: impl IntoIterator<Item = [[f64; 3]; 3]>,
    flag: &mut [bool],
    w: usize,
    h: usize,
) {
    // 1.5 px covers the 3x3 neighbourhood of any pixel a sub-pixel needle edge passes through;
    // 0.5 px steps cannot skip a pixel (simulator choice, tested through needle supersampling).
    const RADIUS_PX: f64 = 1.5;
    let edges = triangles_mm
        .into_iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])]);
    for (a, b) in edges {
        let (Some(pa), Some(pb)) = (projection.project_point(a), projection.project_point(b))
        else {
            continue;
        };
        let len = ((pb[0] - pa[0]).powi(2) + (pb[1] - pa[1]).powi(2)).sqrt();
        let steps = (len / 0.5).ceil().max(1.0) as usize;
        for k in 0..=steps {
            let f = k as f64 / steps as f64;
            let (x, y) = (pa[0] + f * (pb[0] - pa[0]), pa[1] + f * (pb[1] - pa[1]));
            let (x0, x1) = (
                (x - RADIUS_PX).floor().max(0.0),
                (x + RADIUS_PX).floor().min(w as f64 - 1.0),
            );
            let (y0, y1) = (
                (y - RADIUS_PX).floor().max(0.0),
                (y + RADIUS_PX).floor().min(h as f64 - 1.0),
            );
            if x1 < x0 || y1 < y0 {
                continue;
            }
            for jj in y0 as usize..=y1 as usize {
                for ii in x0 as usize..=x1 as usize {
                    flag[jj * w + ii] = true;
                }
            }
        }
    }
}

/// Chord channels of one pixel-centre ray (a convenience for tests and picking overlays).
pub fn pixel_chords<'a>(
    scene: impl Into<SceneRef<'a>>,
    projection: &Projection,
    px: [f64; 2],
) -> MaterialChords {
    let ray = projection.pixel_ray(px);
    scene
        .into()
        .ray_chords(
            ray.origin_mm,
            ray.dir,
            ray.detector_t_mm,
            &mut ChordScratch::default(),
        )
        .chords_mm
}
