//! Where a structure lies in a fluoroscopy image: the pixels its closed mesh covers when
//! projected through a [`Projection`] (its footprint), and the footprint's outline as runs of
//! pixels, for drawing a structure's silhouette over the image (the debrief's reveal view).
//!
//! A pixel belongs to the footprint when its centre lies inside the projection of any triangle
//! of the mesh (a closed surface projects onto the whole silhouette of the solid it bounds, so
//! the union of its triangles' projections is the silhouette). Pixel centres on an edge shared
//! by two triangles count once; the top-left rule is not needed because the footprint is a set.

use super::geometry::Projection;

/// One horizontal run of outline pixels: row, first column, last column (inclusive).
pub type Run = [u32; 3];

/// The footprint of `triangles_mm` in the image of `projection`: `width * height` flags,
/// row-major from the top-left pixel. Triangles with a corner at or behind the focal spot are
/// skipped (no anatomy lies there).
pub fn footprint(triangles_mm: &[[[f64; 3]; 3]], projection: &Projection) -> Vec<bool> {
    let [w, h] = projection.detector_pixels;
    let (w, h) = (w as usize, h as usize);
    let mut mask = vec![false; w * h];
    for t in triangles_mm {
        let Some(p) = t
            .iter()
            .map(|c| projection.project_point(*c))
            .collect::<Option<Vec<[f64; 2]>>>()
        else {
            continue;
        };
        let area =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if area == 0.0 {
            continue;
        }
        // Pixel centres (i + 0.5, j + 0.5) inside the triangle's bounding box.
        let lo = |a: usize| p.iter().map(|q| q[a]).fold(f64::INFINITY, f64::min);
        let hi = |a: usize| p.iter().map(|q| q[a]).fold(f64::NEG_INFINITY, f64::max);
        let first = |v: f64| (v - 0.5).ceil().max(0.0) as usize;
        let last = |v: f64, n: usize| ((v - 0.5).floor().min(n as f64 - 1.0)).max(-1.0) as i64;
        let (x0, y0) = (first(lo(0)), first(lo(1)));
        let (x1, y1) = (last(hi(0), w), last(hi(1), h));
        for j in y0 as i64..=y1 {
            let y = j as f64 + 0.5;
            for i in x0 as i64..=x1 {
                let x = i as f64 + 0.5;
                let e = |a: [f64; 2], b: [f64; 2]| {
                    ((b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])) * area.signum()
                };
                if e(p[0], p[1]) >= 0.0 && e(p[1], p[2]) >= 0.0 && e(p[2], p[0]) >= 0.0 {
                    mask[j as usize * w + i as usize] = true;
                }
            }
        }
    }
    mask
}

/// The outline of a footprint: its pixels with a 4-neighbour outside it (or on the image's
/// edge), as runs per row, top to bottom.
pub fn outline_runs(mask: &[bool], width: u32, height: u32) -> Vec<Run> {
    let (w, h) = (width as usize, height as usize);
    let inside = |i: isize, j: isize| {
        i >= 0
            && j >= 0
            && (i as usize) < w
            && (j as usize) < h
            && mask[j as usize * w + i as usize]
    };
    let mut runs = Vec::new();
    for j in 0..h {
        let mut open: Option<u32> = None;
        for i in 0..=w {
            let (ii, jj) = (i as isize, j as isize);
            let edge = i < w
                && inside(ii, jj)
                && !(inside(ii - 1, jj)
                    && inside(ii + 1, jj)
                    && inside(ii, jj - 1)
                    && inside(ii, jj + 1));
            match (edge, open) {
                (true, None) => open = Some(i as u32),
                (false, Some(s)) => {
                    runs.push([j as u32, s, i as u32 - 1]);
                    open = None;
                }
                _ => {}
            }
        }
    }
    runs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::TriMesh;

    fn tris(m: &TriMesh) -> Vec<[[f64; 3]; 3]> {
        (0..m.triangle_count()).map(|i| m.triangle(i)).collect()
    }

    #[test]
    fn a_box_in_ap_covers_exactly_the_pixels_inside_its_projected_silhouette() {
        // AP: the beam along +y, so the box's silhouette is the projection of its widest
        // (nearest the source, y = -10) face, a rectangle; every pixel centre inside it, and
        // none outside, is covered.
        let p = Projection::default();
        let m = TriMesh::axis_aligned_box([-20.0, -10.0, -13.0], [30.0, 10.0, 17.0]);
        let mask = footprint(&tris(&m), &p);
        let a = p.project_point([-20.0, -10.0, -13.0]).unwrap();
        let b = p.project_point([30.0, -10.0, 17.0]).unwrap();
        let (xs, ys) = (
            [a[0].min(b[0]), a[0].max(b[0])],
            [a[1].min(b[1]), a[1].max(b[1])],
        );
        let [w, h] = p.detector_pixels;
        let mut covered = 0;
        for j in 0..h {
            for i in 0..w {
                let (x, y) = (f64::from(i) + 0.5, f64::from(j) + 0.5);
                let inside = x >= xs[0] && x <= xs[1] && y >= ys[0] && y <= ys[1];
                assert_eq!(mask[(j * w + i) as usize], inside, "pixel ({i}, {j})");
                covered += usize::from(inside);
            }
        }
        assert!(covered > 1000, "{covered}");
        // The outline is the rectangle's border: two full rows and two pixels on each row between.
        let runs = outline_runs(&mask, w, h);
        let rows: std::collections::BTreeSet<u32> = runs.iter().map(|r| r[0]).collect();
        let span = |j: u32| {
            runs.iter()
                .filter(|r| r[0] == j)
                .map(|r| r[2] - r[1] + 1)
                .sum::<u32>()
        };
        let (top, bottom) = (*rows.first().unwrap(), *rows.last().unwrap());
        let width = (xs[1] - 0.5).floor() as u32 - (xs[0] - 0.5).ceil() as u32 + 1;
        assert_eq!(span(top), width);
        assert_eq!(span(bottom), width);
        assert_eq!(span((top + bottom) / 2), 2);
    }

    #[test]
    fn nothing_behind_the_source_and_nothing_outside_the_image() {
        let p = Projection::default();
        // Entirely outside the field of view (far to the patient's right).
        let m = TriMesh::axis_aligned_box([900.0, -10.0, -10.0], [950.0, 10.0, 10.0]);
        assert!(footprint(&tris(&m), &p).iter().all(|c| !c));
        // Behind the source (the source is 730 mm posterior of the isocentre in AP).
        let m = TriMesh::axis_aligned_box([-10.0, -900.0, -10.0], [10.0, -800.0, 10.0]);
        assert!(footprint(&tris(&m), &p).iter().all(|c| !c));
        assert!(outline_runs(&[false; 4], 2, 2).is_empty());
    }
}
