//! Regular voxel grids in a region's model frame: CT underlays, label volumes, concentration fields.
//!
//! Convention (voxel centres): voxel `(i, j, k)` is the cube of side `spacing_mm` centred at
//! `origin_mm + (i, j, k) * spacing_mm`; the grid axes are the model frame's axes. The volume
//! covered by the grid therefore spans `origin - spacing/2 .. origin + (dims - 1/2) * spacing`.
//! Data are stored x-fastest: `index = i + nx * (j + ny * k)`.

use serde::{Deserialize, Serialize};

/// Geometry of an axis-aligned voxel grid.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VolumeGrid {
    /// Number of voxels along x, y, z.
    pub dims: [usize; 3],
    /// Voxel size along x, y, z in millimetres.
    pub spacing_mm: [f64; 3],
    /// Centre of voxel (0, 0, 0) in the model frame, millimetres.
    pub origin_mm: [f64; 3],
}

impl VolumeGrid {
    /// Total voxel count.
    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// True for a grid without voxels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Linear index of voxel `(i, j, k)` (x fastest).
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    /// Voxel `(i, j, k)` of a linear index.
    pub fn ijk(&self, index: usize) -> [usize; 3] {
        let i = index % self.dims[0];
        let j = (index / self.dims[0]) % self.dims[1];
        let k = index / (self.dims[0] * self.dims[1]);
        [i, j, k]
    }

    /// Centre of voxel `(i, j, k)` in millimetres.
    pub fn voxel_center_mm(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        [
            self.origin_mm[0] + i as f64 * self.spacing_mm[0],
            self.origin_mm[1] + j as f64 * self.spacing_mm[1],
            self.origin_mm[2] + k as f64 * self.spacing_mm[2],
        ]
    }

    /// Continuous voxel coordinates of a point (voxel centres at integers).
    #[inline]
    pub fn world_to_voxel(&self, p_mm: [f64; 3]) -> [f64; 3] {
        [
            (p_mm[0] - self.origin_mm[0]) / self.spacing_mm[0],
            (p_mm[1] - self.origin_mm[1]) / self.spacing_mm[1],
            (p_mm[2] - self.origin_mm[2]) / self.spacing_mm[2],
        ]
    }

    /// Linear index of the voxel whose cube holds `p_mm` (each continuous voxel coordinate of
    /// [`world_to_voxel`](Self::world_to_voxel) rounded half away from zero, as `f64::round`
    /// does), or `None` outside the grid or for a non-finite point. Inline and without a libm
    /// call (the baseline x86-64 target has no rounding instruction): lookups of a medium run
    /// millions of times a frame.
    #[inline]
    pub fn nearest_voxel(&self, p_mm: [f64; 3]) -> Option<usize> {
        let [i, j, k] = self.nearest_ijk(p_mm)?;
        Some(self.index(i, j, k))
    }

    /// The voxel `(i, j, k)` of [`nearest_voxel`](Self::nearest_voxel).
    #[inline]
    pub fn nearest_ijk(&self, p_mm: [f64; 3]) -> Option<[usize; 3]> {
        let v = self.world_to_voxel(p_mm);
        let mut ijk = [0usize; 3];
        for a in 0..3 {
            ijk[a] = round_in(v[a], self.dims[a])?;
        }
        Some(ijk)
    }

    /// A cube of `n` voxels of side `h_mm` per axis, centred on the origin (for tests).
    #[cfg(test)]
    pub(crate) fn centred_cube(n: usize, h_mm: f64) -> VolumeGrid {
        VolumeGrid {
            dims: [n; 3],
            spacing_mm: [h_mm; 3],
            origin_mm: [-(n as f64 - 1.0) * 0.5 * h_mm; 3],
        }
    }

    /// The smallest voxel side, mm.
    pub fn min_spacing_mm(&self) -> f64 {
        self.spacing_mm
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min)
    }

    /// The outer faces of the grid's voxels `(min, max)` in millimetres.
    pub fn extent_mm(&self) -> ([f64; 3], [f64; 3]) {
        let lo = std::array::from_fn(|a| self.origin_mm[a] - 0.5 * self.spacing_mm[a]);
        let hi = std::array::from_fn(|a| {
            self.origin_mm[a] + (self.dims[a] as f64 - 0.5) * self.spacing_mm[a]
        });
        (lo, hi)
    }

    /// Volume of one voxel in mm^3.
    pub fn voxel_volume_mm3(&self) -> f64 {
        self.spacing_mm[0] * self.spacing_mm[1] * self.spacing_mm[2]
    }
}

/// A grid plus one value per voxel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Volume<T> {
    /// Where the voxels are.
    pub grid: VolumeGrid,
    /// One value per voxel, x fastest.
    pub data: Vec<T>,
}

/// `v.round()` as an index below `n`, or `None` where that is negative (`-0.0`, from `v` in
/// `(-0.5, 0)`, counts as 0, as `r >= 0.0` takes it), `n` or more, or NaN. Exact: below 2^52 the
/// fraction `v - trunc(v)` is computed without rounding, and half rounds away from zero.
#[inline]
pub(crate) fn round_in(v: f64, n: usize) -> Option<usize> {
    // NaN fails the comparison; `n as f64 - 0.5` is exact for any grid that fits in memory.
    if !(v > -0.5 && v < n as f64 - 0.5) {
        return None;
    }
    // -0.5 < v < 2^52 here: truncation through i64 is one instruction and exact.
    let t = v as i64;
    let up = v - t as f64 >= 0.5;
    Some(t as usize + usize::from(up))
}

impl<T: Clone> Volume<T> {
    /// A volume filled with `value`.
    pub fn filled(grid: VolumeGrid, value: T) -> Self {
        Volume {
            grid,
            data: vec![value; grid.len()],
        }
    }
}

impl<T: Copy> Volume<T> {
    /// Value of voxel `(i, j, k)`.
    pub fn get(&self, i: usize, j: usize, k: usize) -> T {
        self.data[self.grid.index(i, j, k)]
    }

    /// Sets voxel `(i, j, k)`.
    pub fn set(&mut self, i: usize, j: usize, k: usize, value: T) {
        let idx = self.grid.index(i, j, k);
        self.data[idx] = value;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_voxel_rounds_as_f64_round() {
        let g = VolumeGrid {
            dims: [5, 4, 3],
            spacing_mm: [0.5, 0.7, 1.3],
            origin_mm: [-1.1, 0.25, 3.0],
        };
        let reference = |p: [f64; 3]| {
            let v = g.world_to_voxel(p);
            let mut ijk = [0usize; 3];
            for a in 0..3 {
                let r = v[a].round();
                if !(r >= 0.0 && r < g.dims[a] as f64) {
                    return None;
                }
                ijk[a] = r as usize;
            }
            Some(g.index(ijk[0], ijk[1], ijk[2]))
        };
        // Values a hair around every half-integer voxel coordinate (where rounding turns),
        // around the grid's ends, and the largest double below 0.5.
        let mut coords: Vec<f64> = vec![
            f64::NAN,
            f64::INFINITY,
            -f64::INFINITY,
            1e300,
            -0.0,
            0.49999999999999994,
            -0.49999999999999994,
        ];
        for j in -3..9 {
            let b = j as f64 + 0.5;
            for d in -2i64..=2 {
                coords.push(f64::from_bits((b.to_bits() as i64 + d) as u64));
                coords.push(-f64::from_bits((b.to_bits() as i64 + d) as u64));
            }
            coords.push(j as f64);
        }
        for &c in &coords {
            for a in 0..3 {
                let mut v = [1.0, 1.0, 1.0];
                v[a] = c;
                let p: [f64; 3] = std::array::from_fn(|b| g.origin_mm[b] + v[b] * g.spacing_mm[b]);
                assert_eq!(
                    g.nearest_voxel(p),
                    reference(p),
                    "axis {a}, coordinate {c:e}, {p:?}"
                );
                // And the voxel coordinate itself, as the grid's division gives it.
                assert_eq!(
                    round_in(c, g.dims[a]),
                    {
                        let r = c.round();
                        (r >= 0.0 && r < g.dims[a] as f64).then_some(r as usize)
                    },
                    "{c:e}"
                );
            }
        }
    }

    #[test]
    fn index_round_trip_and_voxel_centres() {
        let g = VolumeGrid {
            dims: [4, 3, 2],
            spacing_mm: [0.5, 1.0, 2.0],
            origin_mm: [10.0, 20.0, 30.0],
        };
        for idx in 0..g.len() {
            let [i, j, k] = g.ijk(idx);
            assert_eq!(g.index(i, j, k), idx);
            let c = g.voxel_center_mm(i, j, k);
            let v = g.world_to_voxel(c);
            assert_eq!(v, [i as f64, j as f64, k as f64]);
        }
        let (lo, hi) = g.extent_mm();
        assert_eq!(lo, [9.75, 19.5, 29.0]);
        assert_eq!(hi, [11.75, 22.5, 33.0]);
    }
}
