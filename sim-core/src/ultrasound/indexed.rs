//! A [`CtMedium`] with its properties looked up once per distinct tissue instead of once per
//! point: each voxel holds the index of its (label, HU) pair in a palette of
//! [`AcousticProps`], computed by the same functions [`CtMedium::props`] calls. Every lookup
//! returns what `CtMedium` returns, bit for bit (tested), at a fraction of the cost: the scatter
//! deposit asks the medium for every lattice scatterer (millions per frame; a column at a time,
//! `AcousticMedium::scatter_along`), and the HU mapping interpolates seven fields per call.
//! The index takes one byte per voxel plus the padding of the grid's partial bricks (a grid
//! whose sides are multiples of 4 voxels has none).
//!
//! Painted volumes (a region's structures, one CT number and label per structure) hold a dozen
//! pairs; a volume with more than [`MAX_TISSUES`] (a real CT's continuum of HU) is refused, and
//! its caller keeps the `CtMedium`.

use std::collections::HashMap;

use glam::DVec3;

use super::tissue::{AIR, AcousticMedium, AcousticProps, CtMedium, LatticeColumn, ScatterProps};
use crate::volume::{VolumeGrid, round_in};

/// Most distinct (label, HU) pairs a palette holds: a one-byte index.
pub const MAX_TISSUES: usize = 256;

/// Side of a brick of the index volume, voxels: a brick of `4^3` one-byte indices is one
/// 64-byte cache line.
const BRICK: usize = 4;

/// A voxel volume of palette indices and the palette (see the module docs).
///
/// The indices are stored in bricks of `4 x 4 x 4` voxels (x fastest within a brick, bricks x
/// fastest), so that a lookup's cache line holds its neighbours along every axis: the deposit
/// walks lattice columns along whichever axis is closest to the slice normal, and with rows of
/// x the lookups of a column along z touched a new line every voxel.
#[derive(Debug, Clone)]
pub struct IndexedMedium {
    grid: VolumeGrid,
    /// Bricks per axis.
    bricks: [usize; 3],
    /// Palette index per voxel, in bricks (see [`slot`]).
    index: Vec<u8>,
    palette: Vec<AcousticProps>,
    /// What the scatter deposit reads of each palette entry.
    scatter: Vec<ScatterProps>,
}

impl IndexedMedium {
    /// The palette form of `ct`, or `None` where it holds more than [`MAX_TISSUES`] distinct
    /// (label, HU) pairs. HU are told apart by their bits, so `-0.0` and `0.0` (equal
    /// properties) take two entries and NaN ones are kept as they are.
    pub fn from_ct(ct: &CtMedium<'_>) -> Option<IndexedMedium> {
        let grid = ct.hu.grid;
        let n = grid
            .dims
            .iter()
            .try_fold(1usize, |n, &d| n.checked_mul(d))?;
        if ct.hu.data.len() != n
            || ct
                .labels
                .is_some_and(|l| l.data.len() != n || l.grid != grid)
        {
            return None;
        }
        let mut palette = Vec::new();
        let mut seen: HashMap<(u8, u32), u8> = HashMap::new();
        let bricks = grid.dims.map(|d| d.div_ceil(BRICK));
        // A grid too large to index is refused (its voxel count would wrap).
        let slots = bricks
            .iter()
            .try_fold(BRICK.pow(3), |n, &b| n.checked_mul(b))?;
        let mut index = vec![0u8; slots];
        // Painted volumes come in long runs of one tissue: the last pair short-cuts the map.
        let mut last: Option<((u8, u32), u8)> = None;
        let [nx, ny, nz] = grid.dims;
        let mut i = 0;
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    let label = ct.labels.map_or(0, |l| l.data[i]);
                    let key = (label, ct.hu.data[i].to_bits());
                    let k = match last {
                        Some((lk, lv)) if lk == key => lv,
                        _ => {
                            let k = match seen.get(&key) {
                                Some(&k) => k,
                                None => {
                                    if palette.len() == MAX_TISSUES {
                                        return None;
                                    }
                                    let k = palette.len() as u8;
                                    palette.push(ct.voxel_props(i));
                                    seen.insert(key, k);
                                    k
                                }
                            };
                            last = Some((key, k));
                            k
                        }
                    };
                    index[slot(bricks, x, y, z)] = k;
                    i += 1;
                }
            }
        }
        Some(IndexedMedium {
            grid,
            bricks,
            index,
            scatter: palette.iter().map(ScatterProps::from).collect(),
            palette,
        })
    }

    /// Distinct tissues in the palette.
    pub fn tissues(&self) -> usize {
        self.palette.len()
    }
}

/// Position of voxel `(x, y, z)` in a bricked index of `bricks` bricks per axis.
#[inline]
fn slot(bricks: [usize; 3], x: usize, y: usize, z: usize) -> usize {
    let brick = x / BRICK + bricks[0] * (y / BRICK + bricks[1] * (z / BRICK));
    brick * BRICK.pow(3) + x % BRICK + BRICK * (y % BRICK + BRICK * (z % BRICK))
}

impl AcousticMedium for IndexedMedium {
    #[inline]
    fn props(&self, p_mm: DVec3) -> AcousticProps {
        match self.grid.nearest_ijk(p_mm.to_array()) {
            Some([x, y, z]) => self.palette[usize::from(self.index[slot(self.bricks, x, y, z)])],
            None => AIR,
        }
    }

    fn lookups_by_column(&self) -> bool {
        true
    }

    /// The two fixed coordinates are rounded once, and along the column only `axis` is, by the
    /// same arithmetic as [`props`](AcousticMedium::props) (the grid's axes are independent).
    fn scatter_along(&self, column: &LatticeColumn, out: &mut Vec<ScatterProps>) {
        let LatticeColumn {
            base_mm,
            axis,
            h_mm,
            ref ks,
        } = *column;
        out.clear();
        let g = &self.grid;
        // Any coordinate of the grid on the column's axis: the others decide whether the
        // column meets the grid at all.
        let mut probe = base_mm.to_array();
        probe[axis] = g.origin_mm[axis];
        let air = ScatterProps::from(&AIR);
        let Some(mut ijk) = g.nearest_ijk(probe) else {
            out.extend(ks.clone().map(|_| air));
            return;
        };
        let (o, s, n) = (g.origin_mm[axis], g.spacing_mm[axis], g.dims[axis]);
        // The slot of voxel 0 on the axis, and its step per brick and within a brick.
        ijk[axis] = 0;
        let [x, y, z] = ijk;
        let first = slot(self.bricks, x, y, z);
        let per_brick = [1, self.bricks[0], self.bricks[0] * self.bricks[1]][axis] * BRICK.pow(3);
        let within = [1, BRICK, BRICK * BRICK][axis];
        out.extend(
            ks.clone()
                .map(|k| match round_in((k as f64 * h_mm - o) / s, n) {
                    Some(i) => {
                        let at = first + (i / BRICK) * per_brick + (i % BRICK) * within;
                        self.scatter[usize::from(self.index[at])]
                    }
                    None => air,
                }),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::MaterialClass;
    use crate::volume::Volume;

    /// A small CT of `values` HU (cycled with a stride that mixes them) and some labelled
    /// voxels, on a grid with unequal spacings and an off-integer origin.
    fn ct_volumes(values: &[f32]) -> (Volume<f32>, Volume<u8>) {
        let grid = VolumeGrid {
            dims: [13, 9, 7],
            spacing_mm: [0.5, 0.7, 1.3],
            origin_mm: [-3.1, 2.25, -4.0],
        };
        let mut hu = Volume::filled(grid, 0.0f32);
        let mut labels = Volume::filled(grid, 0u8);
        for i in 0..grid.len() {
            hu.data[i] = values[(i * 7) % values.len()];
            if i % 5 == 0 {
                labels.data[i] = MaterialClass::ALL[i % MaterialClass::ALL.len()].label();
            }
        }
        (hu, labels)
    }

    /// Every lookup equals `CtMedium`'s bit for bit: random points inside and around the grid,
    /// points on the half-voxel boundaries where the nearest voxel changes (and a hair either
    /// side), the grid's faces, and non-finite points; with and without labels.
    #[test]
    fn lookups_equal_the_ct_medium_bit_for_bit() {
        let values = [
            -1000.0, -400.0, -399.5, -100.0, -60.0, -0.0, 0.0, 20.0, 35.5, 50.0, 299.0, 1000.0,
            1500.0,
        ];
        let (hu, labels) = ct_volumes(&values);
        let g = hu.grid;
        let mut rand = crate::rng::uniform_stream(7);
        for with_labels in [false, true] {
            let ct = CtMedium {
                hu: &hu,
                labels: with_labels.then_some(&labels),
            };
            let indexed = IndexedMedium::from_ct(&ct).expect("13 HU values and 12 labels fit");
            let mut points: Vec<[f64; 3]> = Vec::new();
            for _ in 0..20_000 {
                points.push(std::array::from_fn(|a| {
                    let extent = g.dims[a] as f64 * g.spacing_mm[a];
                    g.origin_mm[a] + (1.4 * rand() - 0.2) * extent
                }));
            }
            for _ in 0..5_000 {
                // Half-voxel boundaries and their neighbours, per axis.
                let mut p: [f64; 3] = std::array::from_fn(|a| {
                    g.origin_mm[a] + rand() * g.dims[a] as f64 * g.spacing_mm[a]
                });
                let a = (rand() * 3.0) as usize;
                let j = (rand() * (g.dims[a] as f64 + 2.0)) as i64 - 1;
                let b = g.origin_mm[a] + (j as f64 + 0.5) * g.spacing_mm[a];
                for d in [-1i64, 0, 1] {
                    p[a] = f64::from_bits((b.to_bits() as i64 + d) as u64);
                    points.push(p);
                }
            }
            for special in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300] {
                points.push([special, 3.0, 0.0]);
                points.push([0.0, special, 0.0]);
                points.push([0.0, 3.0, special]);
            }
            for p in points {
                let (a, b) = (
                    ct.props(DVec3::from_array(p)),
                    indexed.props(DVec3::from_array(p)),
                );
                assert!(
                    a == b
                        && a.impedance_mrayl.to_bits() == b.impedance_mrayl.to_bits()
                        && a.echogenicity_db.to_bits() == b.echogenicity_db.to_bits(),
                    "labels {with_labels}, {p:?}: {a:?} against {b:?}"
                );
            }
        }
    }

    /// Lookups along lattice columns (every axis, columns inside, grazing and outside the
    /// grid, fixed coordinates on half-voxel boundaries, grids whose sides are not a multiple
    /// of a brick) equal point lookups bit for bit, for the palette and for the trait's
    /// default (the CT medium).
    #[test]
    fn column_lookups_equal_point_lookups() {
        let values = [-1000.0, -100.0, 20.0, 35.5, 50.0, 299.0, 1000.0];
        let (hu, labels) = ct_volumes(&values);
        let g = hu.grid;
        let ct = CtMedium {
            hu: &hu,
            labels: Some(&labels),
        };
        let indexed = IndexedMedium::from_ct(&ct).expect("fits");
        let mut rand = crate::rng::uniform_stream(19);
        let mut out = Vec::new();
        let mut meeting = 0;
        for trial in 0..3_000 {
            let axis = trial % 3;
            let h = [0.2, 0.34, 0.5, 1.1][trial % 4];
            let mut base: [f64; 3] = std::array::from_fn(|a| {
                let extent = g.dims[a] as f64 * g.spacing_mm[a];
                g.origin_mm[a] + (1.4 * rand() - 0.2) * extent
            });
            if trial % 5 == 0 {
                // A fixed coordinate on a half-voxel boundary.
                let a = (axis + 1) % 3;
                let j = (rand() * g.dims[a] as f64) as i64 as f64;
                base[a] = g.origin_mm[a] + (j + 0.5) * g.spacing_mm[a];
            }
            let lo = ((g.origin_mm[axis] - 3.0) / h) as i64 - (rand() * 5.0) as i64;
            let ks = lo..lo + (rand() * 60.0) as i64;
            for medium in [&indexed as &dyn AcousticMedium, &ct] {
                let column = LatticeColumn {
                    base_mm: DVec3::from_array(base),
                    axis,
                    h_mm: h,
                    ks: ks.clone(),
                };
                medium.scatter_along(&column, &mut out);
                assert_eq!(out.len(), ks.clone().count());
                for (k, got) in ks.clone().zip(&out) {
                    let mut p = base;
                    p[axis] = k as f64 * h;
                    let want = ScatterProps::from(&ct.props(DVec3::from_array(p)));
                    assert_eq!(*got, want, "axis {axis}, k {k}, {p:?}");
                }
            }
            meeting += usize::from(out.iter().any(|p| *p != ScatterProps::from(&AIR)));
        }
        assert!(meeting > 1_000, "most columns meet the grid ({meeting})");
    }

    /// A volume with more distinct tissues than a palette holds is refused, one with exactly
    /// that many is taken, and so is a volume of one tissue.
    #[test]
    fn more_tissues_than_the_palette_holds_are_refused() {
        let values: Vec<f32> = (0..=MAX_TISSUES as i32).map(|v| v as f32).collect();
        let grid = VolumeGrid {
            dims: [values.len(), 1, 1],
            spacing_mm: [1.0; 3],
            origin_mm: [0.0; 3],
        };
        let hu = Volume {
            grid,
            data: values.clone(),
        };
        assert!(
            IndexedMedium::from_ct(&CtMedium {
                hu: &hu,
                labels: None
            })
            .is_none()
        );
        let hu = Volume {
            grid: VolumeGrid {
                dims: [MAX_TISSUES, 1, 1],
                ..grid
            },
            data: values[..MAX_TISSUES].to_vec(),
        };
        let m = IndexedMedium::from_ct(&CtMedium {
            hu: &hu,
            labels: None,
        })
        .expect("fits");
        assert_eq!(m.tissues(), MAX_TISSUES);
        let one = Volume::filled(grid, 40.0f32);
        let m = IndexedMedium::from_ct(&CtMedium {
            hu: &one,
            labels: None,
        })
        .expect("fits");
        assert_eq!(m.tissues(), 1);
        // A grid whose voxel count would wrap: refused, not indexed out of bounds.
        let huge = Volume {
            grid: VolumeGrid {
                dims: [1 << 40, 1 << 40, 1],
                ..grid
            },
            data: vec![0.0f32; 4],
        };
        assert!(
            IndexedMedium::from_ct(&CtMedium {
                hu: &huge,
                labels: None
            })
            .is_none()
        );
        // Labels on another grid than the HU: refused, not misread.
        let labels = Volume::filled(
            VolumeGrid {
                dims: [2, 1, 1],
                ..grid
            },
            0u8,
        );
        assert!(
            IndexedMedium::from_ct(&CtMedium {
                hu: &one,
                labels: Some(&labels)
            })
            .is_none()
        );
    }
}
