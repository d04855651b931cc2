//! A lumbar region from a real CT and its TotalSegmentator masks: landmarks computed from the
//! vertebra masks, and the tissues the masks lack, authored and marked as such.
//!
//! # Landmarks ([`spine_landmarks`], a pure function of the masks)
//! - The **canal** of every axial slice is the enclosed hole of the vertebral ring: the pixels
//!   of the slice that are not bone (any vertebra or the sacrum) and cannot be reached from the
//!   slice border through non-bone pixels (4-connected); of several holes the largest is the
//!   canal. Where the ring is open (between the laminae of two vertebrae, at the disc) the canal
//!   is the nearest closed slice's canal, shifted by the linearly interpolated centroid
//!   ([`canal`]).
//! - `{V}_body_centre`: centroid of the voxel centres of vertebra `V` anterior to the anterior
//!   wall of its canal (the vertebral body); `{V}_canal_centre`: centroid of its canal voxels.
//! - `{U}_{L}_posterior_epidural_space` (and `_interlaminar_window_centre` one voxel behind it,
//!   in the ligamentum flavum): between the body centres of `U` and `L`, the slice where the
//!   midline posterior to the canal is free of bone the longest way back (the interlaminar
//!   window), the most posterior canal voxel of the midline column there (the authored epidural
//!   layer, see below).
//!
//! # Authored tissues ([`authored_structures`])
//! All of them are our construction at the CT's voxel size, listed in the provenance notes with
//! the word "authored"; mask voxels (bone first) are never given to them:
//! - `dural_sac` (dura and CSF): the canal eroded by one pixel in plane; `epidural_space`: the
//!   rest of the canal (a one-voxel layer); `ligamentum_flavum`: the first non-bone voxel behind
//!   the canal in every column, between the body centres of two adjacent levels (so it fills
//!   the gaps between the laminae); `interspinous_ligament`: the midline column behind the
//!   flavum, in soft tissue, at the lumbar levels.
//! - From the CT by HU (bands of [`super::labels`], after Kalender, *Computed Tomography*):
//!   `skin` = the body (the largest connected component above [`BODY_FROM_HU`], holes filled per
//!   slice), meshed whole; `deep_soft_tissue` = the body less its outer voxel layer (the skin,
//!   one voxel thick), meshed whole; `subcutaneous_fat` = fat voxels (-190..-30 HU) connected
//!   through fat to the skin layer; `muscle_other` = soft-tissue voxels (-30..150 HU) posterior
//!   to the canal centre (paraspinal and quadratus muscles beyond the autochthon masks; organs
//!   lie anterior). Components under [`MIN_COMPONENT_VOXELS`] are dropped.

use std::collections::{BTreeMap, VecDeque};

use super::asset::Landmark;
use super::error::AnatomyError;
use super::mask::{StructureMask, crop_box as crop, mask_offset};
use crate::material::MaterialClass;
use crate::volume::{Volume, VolumeGrid};

/// Body outline threshold, HU: half-way between air (-1000 HU) and fat (about -100 HU); our
/// choice.
pub const BODY_FROM_HU: f32 = -500.0;
/// Fat band, HU: about -190 to -30 HU (Kalender, *Computed Tomography*, 3rd ed., Fig. 1.8).
pub const FAT_HU: (f32, f32) = (-190.0, -30.0);
/// Muscle and soft tissue band, HU: -30 to 150 HU (the soft-tissue band of
/// [`super::labels`]; skeletal muscle is about 40 HU).
pub const MUSCLE_HU: (f32, f32) = (-30.0, 150.0);
/// Connected components of an HU-derived tissue smaller than this are dropped (noise and
/// partial volumes; 8 voxels of 3 mm are 0.2 ml); our choice.
pub const MIN_COMPONENT_VOXELS: usize = 8;
/// Smallest hole counted as a canal, pixels (a lumbar canal is about 200 mm^2, 22 pixels of
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

/// A boolean volume on the region grid.
#[derive(Debug, Clone, PartialEq)]
pub struct BoolVolume {
    /// The grid.
    pub grid: VolumeGrid,
    /// One flag per voxel, x fastest.
    pub data: Vec<bool>,
}

impl BoolVolume {
    /// All false.
    pub fn empty(grid: VolumeGrid) -> BoolVolume {
        BoolVolume {
            grid,
            data: vec![false; grid.len()],
        }
    }

    /// The voxels of a mask (occupancy >= 0.5) placed on `grid`.
    pub fn of_mask(grid: VolumeGrid, mask: &StructureMask) -> Result<BoolVolume, AnatomyError> {
        let off = mask_offset(&grid, mask)?;
        let mut out = BoolVolume::empty(grid);
        let g = mask.mask.grid;
        for k in 0..g.dims[2] {
            for j in 0..g.dims[1] {
                for i in 0..g.dims[0] {
                    if mask.mask.get(i, j, k) >= 0.5 {
                        out.data[grid.index(i + off[0], j + off[1], k + off[2])] = true;
                    }
                }
            }
        }
        Ok(out)
    }

    fn at(&self, i: usize, j: usize, k: usize) -> bool {
        self.data[self.grid.index(i, j, k)]
    }

    /// Number of true voxels.
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&b| b).count()
    }

    /// As an occupancy mask (1 inside) named `name` of class `material`.
    pub fn to_structure(&self, name: &str, material: MaterialClass) -> StructureMask {
        StructureMask {
            name: name.to_string(),
            material,
            mask: Volume {
                grid: self.grid,
                data: self.data.iter().map(|&b| f32::from(u8::from(b))).collect(),
            },
        }
    }
}

/// Connected components (4-connected) of the true pixels of a 2-D slice (`nx` by `ny`, x
/// fastest), largest first.
fn components_2d(px: &[bool], nx: usize, ny: usize) -> Vec<Vec<usize>> {
    let mut seen = vec![false; px.len()];
    let mut out = Vec::new();
    for start in 0..px.len() {
        if !px[start] || seen[start] {
            continue;
        }
        let mut comp = Vec::new();
        let mut queue = VecDeque::from([start]);
        seen[start] = true;
        while let Some(p) = queue.pop_front() {
            comp.push(p);
            let (i, j) = (p % nx, p / nx);
            let mut push = |q: usize| {
                if px[q] && !seen[q] {
                    seen[q] = true;
                    queue.push_back(q);
                }
            };
            if i > 0 {
                push(p - 1);
            }
            if i + 1 < nx {
                push(p + 1);
            }
            if j > 0 {
                push(p - nx);
            }
            if j + 1 < ny {
                push(p + nx);
            }
        }
        out.push(comp);
    }
    out.sort_by_key(|c| std::cmp::Reverse(c.len()));
    out
}

/// The holes of a 2-D slice: false pixels not reachable from the border through false pixels.
fn holes_2d(solid: &[bool], nx: usize, ny: usize) -> Vec<bool> {
    let open: Vec<bool> = solid.iter().map(|&b| !b).collect();
    let mut hole = open.clone();
    for comp in components_2d(&open, nx, ny) {
        let touches = comp.iter().any(|&p| {
            let (i, j) = (p % nx, p / nx);
            i == 0 || j == 0 || i + 1 == nx || j + 1 == ny
        });
        if touches {
            for p in comp {
                hole[p] = false;
            }
        }
    }
    hole
}

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
fn posterior_canal_voxel(canal: &BoolVolume, k: usize) -> Option<[usize; 3]> {
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

/// A volume on `v`'s grid whose voxel `(i, j, k)` is `f(v, i, j, k)`.
fn map_voxels(v: &BoolVolume, f: impl Fn(&BoolVolume, usize, usize, usize) -> bool) -> BoolVolume {
    let g = v.grid;
    let mut out = BoolVolume::empty(g);
    for (idx, o) in out.data.iter_mut().enumerate() {
        let [i, j, k] = g.ijk(idx);
        *o = f(v, i, j, k);
    }
    out
}

/// Morphological erosion in plane (4-neighbours), pixels at the slice border erode.
fn erode_2d(v: &BoolVolume) -> BoolVolume {
    let [nx, ny, _] = v.grid.dims;
    map_voxels(v, |v, i, j, k| {
        v.at(i, j, k)
            && i > 0
            && j > 0
            && i + 1 < nx
            && j + 1 < ny
            && v.at(i - 1, j, k)
            && v.at(i + 1, j, k)
            && v.at(i, j - 1, k)
            && v.at(i, j + 1, k)
    })
}

/// The 6-connected components of the true voxels.
fn components_3d(v: &BoolVolume) -> Vec<Vec<usize>> {
    let g = v.grid;
    let dims = g.dims;
    let mut seen = vec![false; v.data.len()];
    let mut out = Vec::new();
    for start in 0..v.data.len() {
        if !v.data[start] || seen[start] {
            continue;
        }
        let mut comp = vec![start];
        seen[start] = true;
        let mut q = 0;
        while q < comp.len() {
            let ijk = g.ijk(comp[q]);
            q += 1;
            for d in 0..3 {
                for nc in [ijk[d].wrapping_sub(1), ijk[d] + 1] {
                    if nc < dims[d] {
                        let mut n3 = ijk;
                        n3[d] = nc;
                        let n = g.index(n3[0], n3[1], n3[2]);
                        if v.data[n] && !seen[n] {
                            seen[n] = true;
                            comp.push(n);
                        }
                    }
                }
            }
        }
        out.push(comp);
    }
    out
}

/// Drops 6-connected components smaller than `min` voxels.
fn drop_small(v: &mut BoolVolume, min: usize) {
    for comp in components_3d(v) {
        if comp.len() < min {
            for c in comp {
                v.data[c] = false;
            }
        }
    }
}

/// The body: voxels above [`BODY_FROM_HU`], largest 6-connected component, holes filled per slice.
pub fn body_mask(ct_hu: &Volume<f32>) -> BoolVolume {
    let g = ct_hu.grid;
    let [nx, ny, nz] = g.dims;
    let above = BoolVolume {
        grid: g,
        data: ct_hu.data.iter().map(|&h| h > BODY_FROM_HU).collect(),
    };
    let mut v = BoolVolume::empty(g);
    if let Some(largest) = components_3d(&above).into_iter().max_by_key(Vec::len) {
        for c in largest {
            v.data[c] = true;
        }
    }
    for k in 0..nz {
        let slice = v.data[k * nx * ny..(k + 1) * nx * ny].to_vec();
        let holes = holes_2d(&slice, nx, ny);
        for (p, h) in holes.into_iter().enumerate() {
            if h {
                v.data[k * nx * ny + p] = true;
            }
        }
    }
    v
}

/// 3 x 3 x 3 majority filter (a voxel is kept when at least 14 of the 27 voxels of its
/// neighbourhood, counting those outside the grid as false, are set): removes the speckle of
/// HU thresholding at this voxel size, which would otherwise cost hundreds of thousands of
/// triangles; our choice.
fn majority(v: &BoolVolume) -> BoolVolume {
    let [nx, ny, nz] = v.grid.dims;
    map_voxels(v, |v, i, j, k| {
        let mut n = 0;
        for kk in k.saturating_sub(1)..=(k + 1).min(nz - 1) {
            for jj in j.saturating_sub(1)..=(j + 1).min(ny - 1) {
                for ii in i.saturating_sub(1)..=(i + 1).min(nx - 1) {
                    n += usize::from(v.at(ii, jj, kk));
                }
            }
        }
        n >= 14
    })
}

/// Depth of the subcutaneous fat layer at most, voxels below the skin layer (10 of 3 mm: lumbar
/// subcutaneous fat is up to a few centimetres thick); our choice.
pub const SUBCUTANEOUS_MAX_DEPTH_VOXELS: usize = 10;

/// The authored structures, in painting order, and the notes that mark them as authored (see
/// the module docs). `masks` are the imported structures (none of their voxels is given to an
/// authored tissue); `canal` comes from [`canal`]; `landmarks` from [`spine_landmarks`].
pub fn authored_structures(
    ct_hu: &Volume<f32>,
    masks: &[StructureMask],
    canal: &BoolVolume,
    landmarks: &[Landmark],
) -> Result<(Vec<StructureMask>, Vec<String>), AnatomyError> {
    let g = ct_hu.grid;
    let [nx, ny, nz] = g.dims;
    let mut claimed = BoolVolume::empty(g);
    let mut bone = BoolVolume::empty(g);
    for m in masks {
        let b = BoolVolume::of_mask(g, m)?;
        for (idx, &x) in b.data.iter().enumerate() {
            if x {
                claimed.data[idx] = true;
                if m.material.is_bone() {
                    bone.data[idx] = true;
                }
            }
        }
    }
    let mut notes = Vec::new();
    let z_of = |name: &str| {
        landmarks
            .iter()
            .find(|l| l.name == name)
            .map(|l| g.world_to_voxel(l.position_mm)[2].round().max(0.0) as usize)
    };
    let lumbar_z: Vec<usize> = LEVELS
        .iter()
        .filter_map(|(l, _)| z_of(&format!("{l}_body_centre")))
        .collect();
    let (z_lo, z_hi) = (
        lumbar_z.iter().copied().min().unwrap_or(0),
        lumbar_z.iter().copied().max().unwrap_or(0),
    );
    // Canal contents.
    let canal_free = BoolVolume {
        grid: g,
        data: canal
            .data
            .iter()
            .zip(&claimed.data)
            .map(|(&c, &m)| c && !m)
            .collect(),
    };
    let sac = {
        let mut s = erode_2d(&canal_free);
        drop_small(&mut s, MIN_COMPONENT_VOXELS);
        s
    };
    let mut epidural = BoolVolume::empty(g);
    for idx in 0..g.len() {
        epidural.data[idx] = canal_free.data[idx] && !sac.data[idx];
    }
    // Body envelope: the skin is its outer voxel layer.
    let mut body = body_mask(ct_hu);
    for idx in 0..g.len() {
        body.data[idx] |= claimed.data[idx] || canal.data[idx];
    }
    let deep0 = erode_2d(&body);
    let mut flavum = BoolVolume::empty(g);
    let mut interspinous = BoolVolume::empty(g);
    for k in z_lo..=z_hi.min(nz - 1) {
        for i in 0..nx {
            let Some(j) = (0..ny).find(|&j| canal.at(i, j, k)) else {
                continue;
            };
            if j > 0 && !claimed.at(i, j - 1, k) && !canal.at(i, j - 1, k) {
                flavum.data[g.index(i, j - 1, k)] = true;
            }
        }
        if let Some(p) = posterior_canal_voxel(canal, k) {
            for j in (0..p[1].saturating_sub(1)).rev() {
                let idx = g.index(p[0], j, k);
                if claimed.data[idx] {
                    continue;
                }
                if !deep0.data[idx] || ct_hu.data[idx] < FAT_HU.1 {
                    break;
                }
                interspinous.data[idx] = true;
            }
        }
    }
    let mut deep = deep0;
    for idx in 0..g.len() {
        deep.data[idx] |=
            claimed.data[idx] || canal.data[idx] || flavum.data[idx] || interspinous.data[idx];
    }
    let taken = |idx: usize| {
        claimed.data[idx] || canal.data[idx] || flavum.data[idx] || interspinous.data[idx]
    };
    let in_band = |h: f32, band: (f32, f32)| h >= band.0 && h < band.1;
    // Fat (majority-filtered) within the outer layer, connected through fat to the skin layer,
    // per slice.
    let mut outer = deep.clone();
    for _ in 0..SUBCUTANEOUS_MAX_DEPTH_VOXELS {
        outer = erode_2d(&outer);
    }
    let fat_hu = majority(&BoolVolume {
        grid: g,
        data: (0..g.len())
            .map(|idx| deep.data[idx] && !taken(idx) && in_band(ct_hu.data[idx], FAT_HU))
            .collect(),
    });
    let mut subcut = BoolVolume::empty(g);
    for k in 0..nz {
        let off = k * nx * ny;
        let fat: Vec<bool> = (0..nx * ny)
            .map(|p| fat_hu.data[off + p] && !taken(off + p) && !outer.data[off + p])
            .collect();
        for comp in components_2d(&fat, nx, ny) {
            let at_skin = comp.iter().any(|&p| {
                let (i, j) = (p % nx, p / nx);
                [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)]
                    .iter()
                    .any(|(di, dj)| {
                        let (a, b) = (i as i64 + di, j as i64 + dj);
                        a >= 0
                            && b >= 0
                            && (a as usize) < nx
                            && (b as usize) < ny
                            && !deep.data[off + b as usize * nx + a as usize]
                    })
            });
            if at_skin {
                for p in comp {
                    subcut.data[off + p] = true;
                }
            }
        }
        // Septa and speckle enclosed by the layer are part of it (fewer, smoother surfaces).
        let layer = subcut.data[off..off + nx * ny].to_vec();
        for (p, h) in holes_2d(&layer, nx, ny).into_iter().enumerate() {
            if h && !taken(off + p) && deep.data[off + p] {
                subcut.data[off + p] = true;
            }
        }
    }
    drop_small(&mut subcut, MIN_COMPONENT_VOXELS);
    let canal_y = |k: usize| posterior_canal_voxel(canal, k).map(|p| p[1]);
    let mut muscle = BoolVolume::empty(g);
    for k in 0..nz {
        let Some(cy) = canal_y(k) else { continue };
        for j in 0..cy {
            for i in 0..nx {
                let idx = g.index(i, j, k);
                muscle.data[idx] = deep.data[idx]
                    && !taken(idx)
                    && !subcut.data[idx]
                    && in_band(ct_hu.data[idx], MUSCLE_HU);
            }
        }
    }
    let mut muscle = majority(&muscle);
    for idx in 0..g.len() {
        muscle.data[idx] &= !taken(idx) && !subcut.data[idx];
    }
    drop_small(&mut muscle, MIN_COMPONENT_VOXELS);
    let out = vec![
        body.to_structure("skin", MaterialClass::SoftTissue),
        deep.to_structure("deep_soft_tissue", MaterialClass::SoftTissue),
        subcut.to_structure("subcutaneous_fat", MaterialClass::Fat),
        muscle.to_structure("muscle_other", MaterialClass::Muscle),
        interspinous.to_structure("interspinous_ligament", MaterialClass::SoftTissue),
        flavum.to_structure("ligamentum_flavum", MaterialClass::LigamentumFlavum),
        epidural.to_structure("epidural_space", MaterialClass::EpiduralSpace),
        sac.to_structure("dural_sac", MaterialClass::DuraCsf),
    ];
    for s in &out {
        let n = s.mask.data.iter().filter(|&&v| v >= 0.5).count();
        notes.push(format!(
            "{}: authored ({} voxels; {})",
            s.name,
            n,
            match s.name.as_str() {
                "skin" => "body outline above -500 HU, holes filled per slice, meshed whole",
                "deep_soft_tissue" => "body less its outer voxel layer, meshed whole",
                "subcutaneous_fat" => "-190..-30 HU, majority-filtered, within 30 mm of and connected to the skin layer",
                "muscle_other" => "-30..150 HU, majority-filtered, posterior to the canal, outside every mask",
                "interspinous_ligament" => "midline column behind the flavum, lumbar levels",
                "ligamentum_flavum" => "first non-bone voxel behind the canal, lumbar levels",
                "epidural_space" => "canal less the dural sac (one voxel layer)",
                _ => "canal eroded by one pixel in plane",
            }
        ));
    }
    Ok((out, notes))
}

/// Voxels of margin kept behind the body's back when the region is cropped; our choice.
pub const CROP_MARGIN_VOXELS: usize = 2;
/// Half width of the crop, either side of the spine's centre, mm: takes in the paraspinal
/// muscles, the psoas and the posterior iliac crests that a lumbar fluoroscopy field shows; our
/// choice.
pub const SPINE_HALF_WIDTH_MM: f64 = 90.0;
/// How far the crop reaches below the lowest voxel of L5, mm: S1 to S3 and the posterior iliac
/// crests; our choice.
pub const BELOW_L5_MM: f64 = 60.0;
/// How far the crop reaches in front of the vertebral bodies, mm: the aorta and the inferior
/// vena cava lie directly in front of them; our choice.
pub const ANTERIOR_MARGIN_MM: f64 = 45.0;

/// A real-CT lumbar region: the TotalSegmentator import ([`super::totalseg::read_ct_and_masks`]),
/// cropped in plane to the body's box, with landmarks from the vertebra masks and the authored
/// tissues of the module docs, meshed by [`super::pipeline::build_region`].
pub fn import_lumbar_ct(
    ct_path: &std::path::Path,
    masks: &super::totalseg::MaskSource,
    options: &super::totalseg::ImportOptions,
    progress: &mut dyn FnMut(&super::pipeline::Progress),
) -> Result<super::asset::RegionAsset, AnatomyError> {
    let imported = super::totalseg::read_ct_and_masks(ct_path, masks, options, progress)?;
    let full = imported.ct_hu.grid;
    // In-plane crop around the spine (z is kept whole): see [`SPINE_HALF_WIDTH_MM`].
    let body = body_mask(&imported.ct_hu);
    let mut spine_lo = [usize::MAX; 3];
    let mut spine_hi = [0usize; 3];
    let mut l5_bottom = None;
    for st in &imported.structures {
        if st.name == "vertebrae_L5" {
            let b = BoolVolume::of_mask(full, st)?;
            l5_bottom = (0..full.len()).find(|&i| b.data[i]).map(|i| full.ijk(i)[2]);
        }
        if st.name.starts_with("vertebrae_") || st.name == "sacrum" {
            let b = BoolVolume::of_mask(full, st)?;
            for (idx, &x) in b.data.iter().enumerate() {
                if x {
                    let ijk = full.ijk(idx);
                    for a in 0..3 {
                        spine_lo[a] = spine_lo[a].min(ijk[a]);
                        spine_hi[a] = spine_hi[a].max(ijk[a]);
                    }
                }
            }
        }
    }
    if spine_lo[0] == usize::MAX {
        return Err(AnatomyError::invalid(
            &options.region_name,
            "no vertebra or sacrum mask among the structures",
        ));
    }
    let body_back = (0..full.len())
        .filter(|&i| body.data[i])
        .map(|i| full.ijk(i)[1])
        .min()
        .unwrap_or(0);
    let h = full.spacing_mm;
    let mid_i = 0.5 * (spine_lo[0] + spine_hi[0]) as f64;
    let half_i = SPINE_HALF_WIDTH_MM / h[0];
    let lo = [
        (mid_i - half_i).max(0.0).round() as usize,
        body_back.saturating_sub(CROP_MARGIN_VOXELS),
        l5_bottom.map_or(0, |k| {
            (k as f64 - BELOW_L5_MM / full.spacing_mm[2])
                .max(0.0)
                .round() as usize
        }),
    ];
    let hi = [
        ((mid_i + half_i).round() as usize).min(full.dims[0] - 1),
        ((spine_hi[1] as f64 + ANTERIOR_MARGIN_MM / h[1]).round() as usize).min(full.dims[1] - 1),
        full.dims[2] - 1,
    ];
    let ct_hu = crop(&imported.ct_hu, lo, hi);
    let g = ct_hu.grid;
    let mut notes = imported.source.notes.clone();
    notes.push(format!(
        "cropped around the spine (from {BELOW_L5_MM} mm below L5 up, {SPINE_HALF_WIDTH_MM} mm either side of its centre, \
         {ANTERIOR_MARGIN_MM} mm in front of it, the body's back plus {CROP_MARGIN_VOXELS} voxels): \
         voxels {lo:?}..={hi:?} of the resampled grid, dims {:?}",
        g.dims
    ));
    let mut structures = Vec::new();
    for s in imported.structures {
        let full_mask = BoolVolume::of_mask(full, &s)?;
        let cropped = BoolVolume {
            grid: g,
            data: crop(
                &Volume {
                    grid: full,
                    data: full_mask.data,
                },
                lo,
                hi,
            )
            .data,
        };
        match cropped.to_structure(&s.name, s.material).cropped() {
            Some(c) => structures.push(c),
            None => notes.push(format!("{}: outside the crop; skipped", s.name)),
        }
    }
    let mut vertebrae = BTreeMap::new();
    let mut bone = BoolVolume::empty(g);
    for s in &structures {
        if s.name.starts_with("vertebrae_") || s.name == "sacrum" {
            let b = BoolVolume::of_mask(g, s)?;
            for (x, &y) in bone.data.iter_mut().zip(&b.data) {
                *x |= y;
            }
            if let Some((level, _)) = LEVELS.iter().find(|(_, n)| *n == s.name) {
                vertebrae.insert(level.to_string(), b);
            }
        }
    }
    let canal_mask = canal(&bone);
    let landmarks = spine_landmarks(&vertebrae, &bone, &canal_mask);
    let (mut all, authored_notes) =
        authored_structures(&ct_hu, &structures, &canal_mask, &landmarks)?;
    notes.extend(authored_notes);
    notes.push(format!(
        "{} landmarks computed from the vertebra masks (canal = enclosed hole of the bone ring)",
        landmarks.len()
    ));
    all.extend(structures);
    let source = super::pipeline::SourceInfo {
        notes,
        ..imported.source
    };
    let mut region = super::pipeline::build_region(
        &options.region_name,
        &ct_hu,
        all,
        &options.params,
        source,
        progress,
    )?;
    region.landmarks = landmarks;
    Ok(region)
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
