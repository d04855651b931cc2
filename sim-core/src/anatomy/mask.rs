//! One structure's occupancy mask, the pipeline's per-structure input, and the lattice checks
//! shared by meshing and labelling.

use super::error::AnatomyError;
use crate::material::MaterialClass;
use crate::volume::{Volume, VolumeGrid};

/// One structure to mesh: a name, its tissue class and its occupancy mask.
#[derive(Debug, Clone, PartialEq)]
pub struct StructureMask {
    /// Unique structure name (becomes the mesh and node name), e.g. `vertebrae_L3`.
    pub name: String,
    /// Tissue class of the structure.
    pub material: MaterialClass,
    /// Occupancy in `0..=1` per voxel (binary masks are 0/1; partial-volume fractions give
    /// sub-voxel accuracy). The grid must have the CT grid's spacing and lie on the CT lattice
    /// inside the CT grid; it may be a sub-box (see [`StructureMask::cropped`]) to save memory.
    pub mask: Volume<f32>,
}

impl StructureMask {
    /// The same mask cropped to the box of its non-zero voxels (`None` if it has none).
    pub fn cropped(&self) -> Option<StructureMask> {
        let (lo, hi) = nonzero_box(&self.mask)?;
        Some(StructureMask {
            name: self.name.clone(),
            material: self.material,
            mask: crop_box(&self.mask, lo, hi),
        })
    }

    /// Mask volume in mm^3: the sum of occupancies (clamped to `0..=1`) times the voxel volume.
    pub fn volume_mm3(&self) -> f64 {
        let s: f64 = self
            .mask
            .data
            .iter()
            .map(|&v| f64::from(v.clamp(0.0, 1.0)))
            .sum();
        s * self.mask.grid.voxel_volume_mm3()
    }
}

/// The voxels of `v` in the inclusive index box `lo..=hi`, on the same lattice.
pub(crate) fn crop_box<T: Copy>(v: &Volume<T>, lo: [usize; 3], hi: [usize; 3]) -> Volume<T> {
    let g = v.grid;
    let grid = VolumeGrid {
        dims: std::array::from_fn(|a| hi[a] - lo[a] + 1),
        spacing_mm: g.spacing_mm,
        origin_mm: g.voxel_center_mm(lo[0], lo[1], lo[2]),
    };
    let mut data = Vec::with_capacity(grid.len());
    for k in lo[2]..=hi[2] {
        for j in lo[1]..=hi[1] {
            for i in lo[0]..=hi[0] {
                data.push(v.get(i, j, k));
            }
        }
    }
    Volume { grid, data }
}

/// Inclusive index box of the voxels with a value above zero.
pub(crate) fn nonzero_box(v: &Volume<f32>) -> Option<([usize; 3], [usize; 3])> {
    let mut lo = [usize::MAX; 3];
    let mut hi = [0usize; 3];
    let mut any = false;
    for (idx, &x) in v.data.iter().enumerate() {
        if x > 0.0 {
            let ijk = v.grid.ijk(idx);
            for a in 0..3 {
                lo[a] = lo[a].min(ijk[a]);
                hi[a] = hi[a].max(ijk[a]);
            }
            any = true;
        }
    }
    any.then_some((lo, hi))
}

/// Checks a mask lies on the CT lattice and returns its voxel offset in the CT grid.
pub(crate) fn mask_offset(
    ct: &VolumeGrid,
    mask: &StructureMask,
) -> Result<[usize; 3], AnatomyError> {
    let g = mask.mask.grid;
    if mask.mask.data.len() != g.len() {
        return Err(AnatomyError::invalid(
            &mask.name,
            "mask data length does not match its grid",
        ));
    }
    let mut off = [0usize; 3];
    for (a, off_a) in off.iter_mut().enumerate() {
        if (g.spacing_mm[a] - ct.spacing_mm[a]).abs() > 1e-6 * ct.spacing_mm[a] {
            return Err(AnatomyError::invalid(
                &mask.name,
                format!(
                    "mask spacing {:?} mm differs from CT spacing {:?} mm",
                    g.spacing_mm, ct.spacing_mm
                ),
            ));
        }
        let x = (g.origin_mm[a] - ct.origin_mm[a]) / ct.spacing_mm[a];
        if !x.is_finite() || (x - x.round()).abs() > 1e-3 || x.round() < 0.0 {
            return Err(AnatomyError::invalid(
                &mask.name,
                format!("mask origin {:?} mm is not on the CT lattice", g.origin_mm),
            ));
        }
        *off_a = x.round() as usize;
        if *off_a + g.dims[a] > ct.dims[a] {
            return Err(AnatomyError::invalid(
                &mask.name,
                format!(
                    "mask grid {:?} extends beyond the CT grid {:?}",
                    g.dims, ct.dims
                ),
            ));
        }
    }
    Ok(off)
}
