//! Boolean voxel masks of a CT region and the morphology the landmarks and the authored tissues
//! are built with: 2-D and 3-D connected components, holes per slice, in-plane erosion, the
//! majority filter, and the body outline from HU.

use std::collections::VecDeque;

use super::super::error::AnatomyError;
use super::super::mask::{StructureMask, mask_offset};
use crate::material::MaterialClass;
use crate::volume::{Volume, VolumeGrid};

/// Body outline threshold, HU: half-way between air (-1000 HU) and fat (about -100 HU); our
/// choice.
pub const BODY_FROM_HU: f32 = -500.0;

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

    pub(super) fn at(&self, i: usize, j: usize, k: usize) -> bool {
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
pub(super) fn components_2d(px: &[bool], nx: usize, ny: usize) -> Vec<Vec<usize>> {
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
pub(super) fn holes_2d(solid: &[bool], nx: usize, ny: usize) -> Vec<bool> {
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
pub(super) fn erode_2d(v: &BoolVolume) -> BoolVolume {
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
pub(super) fn drop_small(v: &mut BoolVolume, min: usize) {
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
pub(super) fn majority(v: &BoolVolume) -> BoolVolume {
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
