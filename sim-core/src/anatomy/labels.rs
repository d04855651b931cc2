//! The categorical label volume: one [`MaterialClass`] label per voxel of the CT grid.
//!
//! Rules, in order (later rules overwrite earlier ones):
//! 1. **HU fallback** for every voxel: below -300 HU air/lung (label 0); -300..-30 HU fat (fat is
//!    about -190..-30 HU, e.g. Kalender, *Computed Tomography*, 3rd ed., Fig. 1.8; the band down to
//!    -300 takes fat/air partial volumes, our assumption); -30..150 HU soft tissue (muscle and
//!    unenhanced blood are 30-60 HU); 150 HU and above is "dense", resolved by rule 3.
//! 2. **Masks**, in the order given: voxels with occupancy >= 0.5 take the mask's class. A mask of
//!    class `CorticalBone` is split by an exact Euclidean distance transform: voxels whose centre
//!    lies within the cortical shell thickness of the mask surface (taken half a voxel outside the
//!    last inside centre) are cortical, deeper ones cancellous.
//! 3. **Bone versus contrast-enhanced vessel** for dense voxels no mask claims (contrast-enhanced
//!    blood, 150-500 HU, overlaps cancellous bone): a dense voxel is bone when it can be reached
//!    from cortical bone through dense, unmasked voxels within a path length of 10 mm ("cortical
//!    proximity and connectivity"); cortical bone here means mask-labelled bone or voxels of at
//!    least 600 HU. Reached voxels of 600 HU and more are cortical, the rest cancellous; dense
//!    voxels not reached are vessel. This is our heuristic, not a validated segmentation: it fails
//!    where an enhanced vessel touches bone without a vessel mask between them (the vessel is then
//!    labelled bone up to 10 mm from the contact), and for dense calcifications far from bone (then
//!    called vessel). The notes of the provenance record how many voxels each branch took.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use super::error::AnatomyError;
use super::mask::{StructureMask, mask_offset};
use crate::material::MaterialClass;
use crate::volume::{Volume, VolumeGrid};

/// Below this, air or lung (label 0).
pub const AIR_BELOW_HU: f32 = -300.0;
/// Below this (and above [`AIR_BELOW_HU`]), fat.
pub const FAT_BELOW_HU: f32 = -30.0;
/// At or above this, dense: bone or contrast-enhanced blood (rule 3).
pub const DENSE_FROM_HU: f32 = 150.0;
/// At or above this, an unmasked voxel counts as cortical bone (enhanced blood in portal-venous or
/// arterial phase stays below about 500 HU; our assumption with margin).
pub const CORTICAL_FROM_HU: f32 = 600.0;
/// Path length through dense voxels within which a voxel counts as bone interior (a vertebral
/// body's half-width is about 20 mm, so 10 mm from the cortex reaches well inside; our assumption).
pub const BONE_PROXIMITY_MM: f64 = 10.0;

/// Squared-distance transform of one line (Felzenszwalb & Huttenlocher, "Distance transforms of
/// sampled functions", Theory of Computing 8, 2012): `out[q] = min_p (f[p] + ((q - p) h)^2)`.
fn edt_1d(f: &[f64], h: f64, out: &mut [f64]) {
    let n = f.len();
    let mut v = vec![0usize; n];
    let mut z = vec![0f64; n + 1];
    let mut k = 0usize;
    let mut first = None;
    for (q, &fq) in f.iter().enumerate() {
        if fq.is_finite() {
            first = Some(q);
            break;
        }
    }
    let Some(first) = first else {
        out.fill(f64::INFINITY);
        return;
    };
    v[0] = first;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in first + 1..n {
        if !f[q].is_finite() {
            continue;
        }
        loop {
            let p = v[k];
            let (xq, xp) = (q as f64 * h, p as f64 * h);
            let s = ((f[q] + xq * xq) - (f[p] + xp * xp)) / (2.0 * (xq - xp));
            if s <= z[k] && k > 0 {
                k -= 1;
                continue;
            }
            if s <= z[k] {
                // k == 0 and the new parabola dominates everywhere.
                v[0] = q;
                z[1] = f64::INFINITY;
                break;
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f64::INFINITY;
            break;
        }
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        let x = q as f64 * h;
        while z[k + 1] < x {
            k += 1;
        }
        let p = v[k];
        let d = x - p as f64 * h;
        *o = d * d + f[p];
    }
}

/// Euclidean distance (mm) from each voxel centre to the nearest voxel centre where `source` is
/// true; infinite if there is none.
pub(crate) fn distance_to_mm(grid: &VolumeGrid, source: &[bool]) -> Vec<f64> {
    let [nx, ny, nz] = grid.dims;
    let mut d: Vec<f64> = source
        .iter()
        .map(|&s| if s { 0.0 } else { f64::INFINITY })
        .collect();
    let dims = [nx, ny, nz];
    let strides = [1, nx, nx * ny];
    for axis in 0..3 {
        let n = dims[axis];
        let stride = strides[axis];
        let (o1, o2) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let mut line = vec![0f64; n];
        let mut out = vec![0f64; n];
        for b in 0..dims[o2] {
            for a in 0..dims[o1] {
                let base = a * strides[o1] + b * strides[o2];
                for (t, l) in line.iter_mut().enumerate() {
                    *l = d[base + t * stride];
                }
                edt_1d(&line, grid.spacing_mm[axis], &mut out);
                for (t, &o) in out.iter().enumerate() {
                    d[base + t * stride] = o;
                }
            }
        }
    }
    d.iter().map(|x| x.sqrt()).collect()
}

/// Builds the label volume on the CT grid (rules in the module doc) and notes on what it did.
pub fn label_volume(
    ct_hu: &Volume<f32>,
    structures: &[StructureMask],
    cortical_shell_mm: f64,
) -> Result<(Volume<u8>, Vec<String>), AnatomyError> {
    let grid = ct_hu.grid;
    let mut labels = Volume::filled(grid, 0u8);
    let mut masked = vec![false; grid.len()];
    let mut mask_bone = vec![false; grid.len()];
    // Rule 1.
    for (l, &hu) in labels.data.iter_mut().zip(&ct_hu.data) {
        *l = if hu < AIR_BELOW_HU || hu.is_nan() {
            0
        } else if hu < FAT_BELOW_HU {
            MaterialClass::Fat.label()
        } else if hu < DENSE_FROM_HU {
            MaterialClass::SoftTissue.label()
        } else {
            0 // decided by rule 3 unless a mask claims it
        };
    }
    // Rule 2.
    let h_min = grid.min_spacing_mm();
    for s in structures {
        let off = mask_offset(&grid, s)?;
        let mg = s.mask.grid;
        let inside: Vec<bool> = s.mask.data.iter().map(|&v| v >= 0.5).collect();
        let split_bone = s.material == MaterialClass::CorticalBone;
        let depth = if split_bone {
            // Pad by one voxel so the mask box's faces count as outside.
            let pg = VolumeGrid {
                dims: mg.dims.map(|n| n + 2),
                ..mg
            };
            let mut outside = vec![true; pg.len()];
            for (idx, &ins) in inside.iter().enumerate() {
                let [i, j, k] = mg.ijk(idx);
                outside[pg.index(i + 1, j + 1, k + 1)] = !ins;
            }
            let d = distance_to_mm(&pg, &outside);
            Some((pg, d))
        } else {
            None
        };
        for (idx, &ins) in inside.iter().enumerate() {
            if !ins {
                continue;
            }
            let [i, j, k] = mg.ijk(idx);
            let g = grid.index(i + off[0], j + off[1], k + off[2]);
            let class = match &depth {
                Some((pg, d)) => {
                    let to_surface = d[pg.index(i + 1, j + 1, k + 1)] - 0.5 * h_min;
                    if to_surface < cortical_shell_mm {
                        MaterialClass::CorticalBone
                    } else {
                        MaterialClass::Cancellous
                    }
                }
                None => s.material,
            };
            labels.data[g] = class.label();
            masked[g] = true;
            mask_bone[g] = class.is_bone();
        }
    }
    // Rule 3: multi-source Dijkstra from cortical seeds through dense unmasked voxels.
    let dense_free = |g: usize| !masked[g] && ct_hu.data[g] >= DENSE_FROM_HU;
    let mut dist = vec![f64::INFINITY; grid.len()];
    let mut heap: BinaryHeap<Reverse<(u64, usize)>> = BinaryHeap::new();
    // Distances are kept as integer micrometres in the heap so it can order them exactly.
    let key = |d: f64| (d * 1000.0).round() as u64;
    for (g, d) in dist.iter_mut().enumerate() {
        if mask_bone[g] || (dense_free(g) && ct_hu.data[g] >= CORTICAL_FROM_HU) {
            *d = 0.0;
            heap.push(Reverse((0, g)));
        }
    }
    let [nx, ny, nz] = grid.dims;
    while let Some(Reverse((dk, g))) = heap.pop() {
        if dk > key(dist[g]) {
            continue;
        }
        let [i, j, k] = grid.ijk(g);
        let steps: [(bool, usize, f64); 6] = [
            (i > 0, g.wrapping_sub(1), grid.spacing_mm[0]),
            (i + 1 < nx, g + 1, grid.spacing_mm[0]),
            (j > 0, g.wrapping_sub(nx), grid.spacing_mm[1]),
            (j + 1 < ny, g + nx, grid.spacing_mm[1]),
            (k > 0, g.wrapping_sub(nx * ny), grid.spacing_mm[2]),
            (k + 1 < nz, g + nx * ny, grid.spacing_mm[2]),
        ];
        for (ok, n, h) in steps {
            if !ok || !dense_free(n) {
                continue;
            }
            let nd = dist[g] + h;
            if nd <= BONE_PROXIMITY_MM && nd < dist[n] {
                dist[n] = nd;
                heap.push(Reverse((key(nd), n)));
            }
        }
    }
    let (mut n_cort, mut n_canc, mut n_vessel) = (0usize, 0usize, 0usize);
    for (g, d) in dist.iter().enumerate() {
        if !dense_free(g) {
            continue;
        }
        labels.data[g] = if d.is_finite() {
            if ct_hu.data[g] >= CORTICAL_FROM_HU {
                n_cort += 1;
                MaterialClass::CorticalBone.label()
            } else {
                n_canc += 1;
                MaterialClass::Cancellous.label()
            }
        } else {
            n_vessel += 1;
            MaterialClass::Vessel.label()
        };
    }
    let notes = vec![format!(
        "labels: unmasked dense voxels (>= {DENSE_FROM_HU} HU): {n_cort} cortical, {n_canc} bone interior \
         (within {BONE_PROXIMITY_MM} mm of cortex), {n_vessel} contrast-enhanced vessel"
    )];
    Ok((labels, notes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edt_matches_brute_force() {
        let grid = VolumeGrid {
            dims: [7, 5, 6],
            spacing_mm: [1.0, 2.0, 0.5],
            origin_mm: [0.0; 3],
        };
        let src: Vec<bool> = (0..grid.len()).map(|i| (i * 7919) % 23 == 0).collect();
        let d = distance_to_mm(&grid, &src);
        for (a, &da) in d.iter().enumerate() {
            let pa = grid.voxel_center_mm(grid.ijk(a)[0], grid.ijk(a)[1], grid.ijk(a)[2]);
            let mut best = f64::INFINITY;
            for b in (0..grid.len()).filter(|&b| src[b]) {
                let [i, j, k] = grid.ijk(b);
                let pb = grid.voxel_center_mm(i, j, k);
                best = best.min(
                    ((pa[0] - pb[0]).powi(2) + (pa[1] - pb[1]).powi(2) + (pa[2] - pb[2]).powi(2))
                        .sqrt(),
                );
            }
            assert!((da - best).abs() < 1e-9, "voxel {a}: {da} vs {best}");
        }
    }

    #[test]
    fn enhanced_vessel_away_from_bone_is_vessel_and_bone_interior_is_bone() {
        let grid = VolumeGrid {
            dims: [40, 20, 20],
            spacing_mm: [1.0; 3],
            origin_mm: [0.0; 3],
        };
        let mut ct = Volume::filled(grid, 40.0f32);
        // A "bone": 8 mm cube with a 1 mm 1000 HU shell and a 300 HU interior, at x 2..10.
        // A "vessel": 6 mm bar of 300 HU at x 25..31, well away from any cortex.
        for k in 0..20 {
            for j in 0..20 {
                for i in 0..40 {
                    let inb = (2..10).contains(&i) && (6..14).contains(&j) && (6..14).contains(&k);
                    let shell = inb && (i == 2 || i == 9 || j == 6 || j == 13 || k == 6 || k == 13);
                    if shell {
                        ct.set(i, j, k, 1000.0);
                    } else if inb || ((25..31).contains(&i) && (7..13).contains(&j)) {
                        ct.set(i, j, k, 300.0);
                    }
                }
            }
        }
        let (l, _) = label_volume(&ct, &[], 1.8).unwrap();
        assert_eq!(l.get(5, 10, 10), MaterialClass::Cancellous.label());
        assert_eq!(l.get(2, 10, 10), MaterialClass::CorticalBone.label());
        assert_eq!(l.get(28, 10, 10), MaterialClass::Vessel.label());
        assert_eq!(l.get(20, 2, 2), MaterialClass::SoftTissue.label());
        // A vessel mask over the bar keeps the class even if HU said otherwise.
        let mut vm = Volume::filled(grid, 0.0f32);
        vm.set(28, 10, 10, 1.0);
        let s = StructureMask {
            name: "v".into(),
            material: MaterialClass::Disc,
            mask: vm,
        };
        let (l2, _) = label_volume(&ct, &[s], 1.8).unwrap();
        assert_eq!(l2.get(28, 10, 10), MaterialClass::Disc.label());
    }
}
