//! Landmarks of the lumbar spine computed from the vertebra masks: the canal as the enclosed hole
//! of the bone ring, the body and canal centres of each level, and the posterior epidural space
//! at each interlaminar window (see the docs of [`super`]).

use std::collections::BTreeMap;

use super::super::asset::Landmark;
use super::masks::{BoolVolume, components_2d, holes_2d};
use crate::volume::VolumeGrid;

/// 3 mm; a hole of 4 pixels is a partial ring); our choice.
pub const MIN_CANAL_PIXELS: usize = 4;

/// How far behind the canal the interlaminar window must be free of bone, voxels (4 voxels of
/// 3 mm: the flavum and the laminae are within 12 mm of the canal); our choice.
pub const WINDOW_DEPTH_VOXELS: usize = 4;

/// The lumbar levels that get landmarks, with the mask names they come from.
pub const LEVELS: [(&str, &str); 5] = [
    ("L1", "vertebrae_L1"),
    ("L2", "vertebrae_L2"),
    ("L3", "vertebrae_L3"),
    ("L4", "vertebrae_L4"),
    ("L5", "vertebrae_L5"),
];

/// The spinal canal on the region grid (see the module docs): the enclosed hole of the bone
/// ring per slice, carried across the open slices between the lowest and the highest closed one.
pub fn canal(bone: &BoolVolume) -> BoolVolume {
    let g = bone.grid;
    let [nx, ny, nz] = g.dims;
    let mut found: Vec<Option<Vec<usize>>> = vec![None; nz];
    for (k, slot) in found.iter_mut().enumerate() {
        let slice = &bone.data[k * nx * ny..(k + 1) * nx * ny];
        if !slice.iter().any(|&b| b) {
            continue;
        }
        let holes = holes_2d(slice, nx, ny);
        let comps = components_2d(&holes, nx, ny);
        if let Some(c) = comps
            .into_iter()
            .next()
            .filter(|c| c.len() >= MIN_CANAL_PIXELS)
        {
            *slot = Some(c);
        }
    }
    let closed: Vec<usize> = (0..nz).filter(|&k| found[k].is_some()).collect();
    let mut out = BoolVolume::empty(g);
    let (Some(&k_lo), Some(&k_hi)) = (closed.first(), closed.last()) else {
        return out;
    };
    let centroid = |c: &[usize]| -> [f64; 2] {
        let n = c.len() as f64;
        [
            c.iter().map(|&p| (p % nx) as f64).sum::<f64>() / n,
            c.iter().map(|&p| (p / nx) as f64).sum::<f64>() / n,
        ]
    };
    for k in k_lo..=k_hi {
        let pixels: Vec<(i64, i64)> = match &found[k] {
            Some(c) => c
                .iter()
                .map(|&p| ((p % nx) as i64, (p / nx) as i64))
                .collect(),
            None => {
                let below = *closed.iter().rev().find(|&&q| q < k).unwrap_or(&k_lo);
                let above = *closed.iter().find(|&&q| q > k).unwrap_or(&k_hi);
                let (cb, ca) = (
                    centroid(found[below].as_deref().unwrap_or(&[])),
                    centroid(found[above].as_deref().unwrap_or(&[])),
                );
                let f = (k - below) as f64 / (above - below).max(1) as f64;
                let target = [cb[0] + f * (ca[0] - cb[0]), cb[1] + f * (ca[1] - cb[1])];
                let near = if k - below <= above - k { below } else { above };
                let nc = found[near].as_deref().unwrap_or(&[]);
                let c = centroid(nc);
                let shift = [
                    (target[0] - c[0]).round() as i64,
                    (target[1] - c[1]).round() as i64,
                ];
                nc.iter()
                    .map(|&p| ((p % nx) as i64 + shift[0], (p / nx) as i64 + shift[1]))
                    .collect()
            }
        };
        for (i, j) in pixels {
            if i >= 0 && j >= 0 && (i as usize) < nx && (j as usize) < ny {
                let idx = g.index(i as usize, j as usize, k);
                if !bone.data[idx] {
                    out.data[idx] = true;
                }
            }
        }
    }
    out
}

fn landmark(name: String, p: [f64; 3], description: &str, inside: Option<&str>) -> Landmark {
    Landmark {
        name,
        position_mm: p,
        description: description.to_string(),
        inside_structure: inside.map(str::to_string),
    }
}

/// Centroid (mm) of the voxel centres of the voxels `pick` accepts, or `None` when none does.
fn centroid_mm(
    g: VolumeGrid,
    mut pick: impl FnMut(usize, usize, usize) -> bool,
) -> Option<[f64; 3]> {
    let mut sum = [0.0; 3];
    let mut n = 0usize;
    for k in 0..g.dims[2] {
        for j in 0..g.dims[1] {
            for i in 0..g.dims[0] {
                if pick(i, j, k) {
                    let c = g.voxel_center_mm(i, j, k);
                    for a in 0..3 {
                        sum[a] += c[a];
                    }
                    n += 1;
                }
            }
        }
    }
    (n > 0).then(|| sum.map(|s| s / n as f64))
}

/// The canal's midline column and most posterior voxel of slice `k` (`None` without canal).
pub(super) fn posterior_canal_voxel(canal: &BoolVolume, k: usize) -> Option<[usize; 3]> {
    let g = canal.grid;
    let [nx, ny, _] = g.dims;
    let mut sx = 0.0;
    let mut n = 0usize;
    for j in 0..ny {
        for i in 0..nx {
            if canal.at(i, j, k) {
                sx += i as f64;
                n += 1;
            }
        }
    }
    if n == 0 {
        return None;
    }
    let i = (sx / n as f64).round() as usize;
    (0..ny).find(|&j| canal.at(i, j, k)).map(|j| [i, j, k])
}

/// The landmarks of the lumbar spine from its masks (see the module docs). `vertebrae` maps
/// level names (`L1`..`L5`, and `S1` for the sacrum) to their masks on `bone`'s grid; `bone` is
/// the union of every vertebra and sacrum mask and `canal` the result of [`canal`].
pub fn spine_landmarks(
    vertebrae: &BTreeMap<String, BoolVolume>,
    bone: &BoolVolume,
    canal: &BoolVolume,
) -> Vec<Landmark> {
    let g = bone.grid;
    let [nx, ny, _] = g.dims;
    let mut out = Vec::new();
    let mut body_z: Vec<(String, f64, usize)> = Vec::new();
    for (level, _) in LEVELS {
        let Some(v) = vertebrae.get(level) else {
            continue;
        };
        // The anterior wall of the canal: the largest canal y index in the vertebra's slices.
        let front = (0..g.dims[2])
            .filter(|&k| (0..ny).any(|j| (0..nx).any(|i| v.at(i, j, k))))
            .flat_map(|k| (0..ny).filter(move |&j| (0..nx).any(|i| canal.at(i, j, k))))
            .max();
        let Some(front) = front else {
            continue;
        };
        let Some(body) = centroid_mm(g, |i, j, k| j > front && v.at(i, j, k)) else {
            continue;
        };
        out.push(landmark(
            format!("{level}_body_centre"),
            body,
            "centroid of the vertebral body (mask voxels anterior to the canal)",
            Some(&format!("vertebrae_{level}")),
        ));
        let kz = g.world_to_voxel(body)[2].round().max(0.0) as usize;
        let in_slice = |i: usize, j: usize, k: usize| k == kz && canal.at(i, j, k);
        if let Some(c) = centroid_mm(g, in_slice) {
            // The canal voxel of that slice nearest to the centroid (inside a concave canal).
            let mut best: Option<(f64, [f64; 3])> = None;
            for j in 0..ny {
                for i in 0..nx {
                    if in_slice(i, j, kz) {
                        let p = g.voxel_center_mm(i, j, kz);
                        let d = (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2);
                        if best.is_none_or(|(bd, _)| d < bd) {
                            best = Some((d, p));
                        }
                    }
                }
            }
            if let Some((_, p)) = best {
                out.push(landmark(
                    format!("{level}_canal_centre"),
                    p,
                    "spinal canal in the slice of the body centre: the canal voxel nearest to \
                     the canal's centroid there (in the dural sac or the epidural space)",
                    None,
                ));
            }
        }
        body_z.push((level.to_string(), body[2], kz));
    }
    for pair in body_z.windows(2) {
        let (upper, lower) = (&pair[0], &pair[1]);
        let (k_lo, k_hi) = (lower.2.min(upper.2), lower.2.max(upper.2));
        // Bone-free run behind the canal's midline, voxels, per slice.
        let mut best: Option<(usize, usize, [usize; 3])> = None;
        for k in k_lo..=k_hi {
            let Some(p) = posterior_canal_voxel(canal, k) else {
                continue;
            };
            let free = (0..p[1])
                .rev()
                .take(WINDOW_DEPTH_VOXELS)
                .take_while(|&j| !bone.at(p[0], j, k))
                .count();
            let mid_dist = (2 * k).abs_diff(k_lo + k_hi);
            if best.is_none_or(|(f, d, _)| free > f || (free == f && mid_dist < d)) {
                best = Some((free, mid_dist, p));
            }
        }
        let Some((_, _, p)) = best else {
            continue;
        };
        let names = format!("{}_{}", upper.0, lower.0);
        out.push(landmark(
            format!("{names}_posterior_epidural_space"),
            g.voxel_center_mm(p[0], p[1], p[2]),
            "midline posterior epidural space just in front of the ligamentum flavum (most \
             posterior canal voxel of the interlaminar window's slice)",
            Some("epidural_space"),
        ));
        if p[1] > 0 {
            out.push(landmark(
                format!("{names}_interlaminar_window_centre"),
                g.voxel_center_mm(p[0], p[1] - 1, p[2]),
                "midline centre of the interlaminar window, in the ligamentum flavum",
                Some("ligamentum_flavum"),
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two box vertebrae of 1 mm voxels: a body (x 10..20, y 18..26) and a ring round a canal
    /// (x 13..17, y 11..15), L4 in slices 10..20 and L5 in 0..10; the ring is open behind the
    /// canal (no lamina) in slices 8..12, the interlaminar window.
    fn spine() -> (BTreeMap<String, BoolVolume>, BoolVolume) {
        let grid = VolumeGrid {
            dims: [30, 30, 20],
            spacing_mm: [1.0; 3],
            origin_mm: [0.0; 3],
        };
        let mut levels = BTreeMap::new();
        let mut bone = BoolVolume::empty(grid);
        for (name, ks) in [("L4", 10..20), ("L5", 0..10)] {
            let mut v = BoolVolume::empty(grid);
            for k in ks {
                for j in 9..26 {
                    for i in 10..20 {
                        let body = j >= 18;
                        let hole = (13..17).contains(&i) && (11..15).contains(&j);
                        let ring = (11..19).contains(&i) && j < 18 && !hole;
                        let window = (8..12).contains(&k) && j < 11;
                        if body || (ring && !window) {
                            v.data[grid.index(i, j, k)] = true;
                            bone.data[grid.index(i, j, k)] = true;
                        }
                    }
                }
            }
            levels.insert(name.to_string(), v);
        }
        (levels, bone)
    }

    fn get<'a>(l: &'a [Landmark], name: &str) -> &'a [f64; 3] {
        &l.iter()
            .find(|x| x.name == name)
            .unwrap_or_else(|| panic!("{name} missing"))
            .position_mm
    }

    #[test]
    fn canal_is_the_enclosed_hole_carried_across_the_window() {
        let (_, bone) = spine();
        let c = canal(&bone);
        // 16 pixels per closed slice; the open slices get the same shape (not leaking out).
        for k in 0..20 {
            let n = (0..30 * 30).filter(|&p| c.data[k * 900 + p]).count();
            assert_eq!(n, 16, "slice {k}");
        }
        assert!(c.at(13, 11, 9) && c.at(16, 14, 9) && !c.at(12, 11, 9));
    }

    #[test]
    fn landmarks_from_masks() {
        let (levels, bone) = spine();
        let c = canal(&bone);
        let l = spine_landmarks(&levels, &bone, &c);
        // Body voxels are j 18..26 (the part in front of the canal's front wall at j = 14, which
        // includes the ring's front row j = 15..18 of x 11..19): centroid by hand.
        let body = get(&l, "L4_body_centre");
        let (mut n, mut sy) = (0.0, 0.0);
        for j in 15..26 {
            let w = if j >= 18 { 10.0 } else { 8.0 };
            n += w;
            sy += w * j as f64;
        }
        assert!((body[0] - 14.5).abs() < 1e-9, "{body:?}");
        assert!((body[1] - sy / n).abs() < 1e-9, "{body:?}");
        assert!((body[2] - 14.5).abs() < 1e-9, "{body:?}");
        let canal_c = get(&l, "L5_canal_centre");
        // The canal voxel nearest to the hole's centroid (14.5, 12.5): one of the four around it.
        assert!((canal_c[0] - 14.5).abs() == 0.5 && (canal_c[1] - 12.5).abs() == 0.5);
        assert!(c.at(
            canal_c[0] as usize,
            canal_c[1] as usize,
            canal_c[2] as usize
        ));
        // The epidural landmark: midline column (x = 14.5 rounds to 14 or 15), the most posterior
        // canal row (j = 11), in the window (slices 8..12), between the body centres (4.5..14.5).
        let e = get(&l, "L4_L5_posterior_epidural_space");
        assert!((e[0] - 14.5).abs() <= 0.5 && e[1] == 11.0, "{e:?}");
        assert!((8.0..12.0).contains(&e[2]), "{e:?}");
        let w = get(&l, "L4_L5_interlaminar_window_centre");
        assert_eq!([w[0], w[1] + 1.0, w[2]], *e);
    }
}
