//! NIfTI-1 reading (through the `nifti` crate, gzip included) and resampling into world RAS.
//!
//! The model frame of an imported CT is the NIfTI world frame, RAS+ millimetres as nifti1.h
//! defines it: +x towards the patient's right, +y anterior, +z superior (in the test data the
//! right hip lies at positive x). Positions are kept in that frame unchanged.
//!
//! Affine: the sform (`srow_x/y/z`) when `sform_code > 0`, else the qform quaternion when
//! `qform_code > 0`, else the scanner-less fallback `diag(pixdim)` (nifti1.h "method 1"). Any
//! orientation is accepted: the output grid is axis-aligned in world RAS, covering the input
//! voxel centres. When the affine is a scaled signed permutation (RAS, LPS, PIR, ... stored
//! without rotation), every output voxel centre is an input voxel centre and the resampling is an
//! exact re-indexing; an oblique affine is resampled trilinearly at the smallest input spacing.

use std::path::{Path, PathBuf};

use nifti::{Endianness, NiftiObject, NiftiType, ReaderOptions};

use super::error::AnatomyError;
use crate::volume::{Volume, VolumeGrid};

/// A 3D NIfTI image with its voxel-to-world affine.
#[derive(Debug, Clone, PartialEq)]
pub struct NiftiImage {
    /// The file it came from.
    pub path: PathBuf,
    /// Voxel counts along the file's i, j, k axes.
    pub dims: [usize; 3],
    /// Voxel index `(i, j, k)` to world RAS mm: `world = A * [i, j, k] + t`, rows `[A | t]`.
    pub affine: [[f64; 4]; 3],
    /// Values after `scl_slope`/`scl_inter`, i fastest (file order).
    pub data: Vec<f32>,
    /// The stored data type, for messages and provenance.
    pub datatype: String,
}

/// Decodes raw voxel bytes to `f32`, applying `value * slope + inter` (in f64) when `scale`.
fn decode(
    raw: &[u8],
    ty: NiftiType,
    endianness: Endianness,
    scale: Option<(f64, f64)>,
    path: &Path,
) -> Result<Vec<f32>, AnatomyError> {
    let le = matches!(endianness, Endianness::Little);
    let out = |v: f64| match scale {
        Some((slope, inter)) => (v * slope + inter) as f32,
        None => v as f32,
    };
    macro_rules! conv {
        ($t:ty, $n:expr) => {
            raw.chunks_exact($n)
                .map(|c| {
                    let b: [u8; $n] = c.try_into().expect("chunk size");
                    out((if le {
                        <$t>::from_le_bytes(b)
                    } else {
                        <$t>::from_be_bytes(b)
                    }) as f64)
                })
                .collect()
        };
    }
    Ok(match ty {
        NiftiType::Uint8 => raw.iter().map(|&b| out(f64::from(b))).collect(),
        NiftiType::Int8 => raw.iter().map(|&b| out(f64::from(b as i8))).collect(),
        NiftiType::Int16 => conv!(i16, 2),
        NiftiType::Uint16 => conv!(u16, 2),
        NiftiType::Int32 => conv!(i32, 4),
        NiftiType::Uint32 => conv!(u32, 4),
        NiftiType::Int64 => conv!(i64, 8),
        NiftiType::Uint64 => conv!(u64, 8),
        NiftiType::Float32 => conv!(f32, 4),
        NiftiType::Float64 => conv!(f64, 8),
        other => {
            return Err(AnatomyError::bad_file(
                path,
                format!("unsupported NIfTI data type {other:?}"),
            ));
        }
    })
}

/// Reads a `.nii` or `.nii.gz` file (3D, or 4D with one volume).
pub fn read_nifti(path: &Path) -> Result<NiftiImage, AnatomyError> {
    if !path.is_file() {
        return Err(AnatomyError::bad_file(path, "no such file"));
    }
    let obj = ReaderOptions::new().read_file(path).map_err(|e| {
        AnatomyError::bad_file(
            path,
            format!("cannot read NIfTI (truncated or corrupt?): {e}"),
        )
    })?;
    let h = obj.header();
    let ndim = usize::from(h.dim[0]);
    if !(3..=7).contains(&ndim) || h.dim[4..=ndim].iter().any(|&d| d > 1) {
        return Err(AnatomyError::bad_file(
            path,
            format!(
                "expected a 3D volume, header dim is {:?}",
                &h.dim[..=ndim.min(7)]
            ),
        ));
    }
    let dims = [
        usize::from(h.dim[1]),
        usize::from(h.dim[2]),
        usize::from(h.dim[3]),
    ];
    if dims.contains(&0) {
        return Err(AnatomyError::bad_file(
            path,
            format!("zero-sized dimension {dims:?}"),
        ));
    }
    let affine = header_affine(h);
    if affine.iter().flatten().any(|x| !x.is_finite()) {
        return Err(AnatomyError::bad_file(
            path,
            format!("non-finite voxel-to-world affine {affine:?}"),
        ));
    }
    let lin = [
        [affine[0][0], affine[0][1], affine[0][2]],
        [affine[1][0], affine[1][1], affine[1][2]],
        [affine[2][0], affine[2][1], affine[2][2]],
    ];
    if det3(lin).abs() < 1e-9 {
        return Err(AnatomyError::bad_file(
            path,
            format!("singular voxel-to-world affine {affine:?}"),
        ));
    }
    let ty = h
        .data_type()
        .map_err(|e| AnatomyError::bad_file(path, format!("bad data type: {e}")))?;
    let (slope, inter) = (h.scl_slope, h.scl_inter);
    let endianness = h.endianness;
    let volume = obj.into_volume();
    let raw = volume.into_raw_data();
    let n = dims[0] * dims[1] * dims[2];
    // nifti1.h: scl_slope == 0 means "no scaling"; files also carry NaN there (the v1 masks of the
    // test data do), which we read the same way.
    let scale = (slope.is_finite() && slope != 0.0).then(|| {
        (
            f64::from(slope),
            if inter.is_finite() {
                f64::from(inter)
            } else {
                0.0
            },
        )
    });
    let mut data = decode(&raw, ty, endianness, scale, path)?;
    drop(raw);
    if data.len() < n {
        return Err(AnatomyError::bad_file(
            path,
            format!("{} voxels of data, header needs {n}", data.len()),
        ));
    }
    data.truncate(n);
    Ok(NiftiImage {
        path: path.to_path_buf(),
        dims,
        affine,
        data,
        datatype: format!("{ty:?}"),
    })
}

fn header_affine(h: &nifti::NiftiHeader) -> [[f64; 4]; 3] {
    let f = |r: [f32; 4]| r.map(f64::from);
    if h.sform_code > 0 {
        return [f(h.srow_x), f(h.srow_y), f(h.srow_z)];
    }
    let p = h.pixdim.map(f64::from);
    if h.qform_code > 0 {
        // nifti1.h "method 2": rotation from the quaternion (b, c, d), a = sqrt(1 - b^2 - c^2 - d^2),
        // qfac = pixdim[0] (-1 flips k).
        let (b, c, d) = (
            f64::from(h.quatern_b),
            f64::from(h.quatern_c),
            f64::from(h.quatern_d),
        );
        let a = (1.0 - (b * b + c * c + d * d)).max(0.0).sqrt();
        let r = [
            [
                a * a + b * b - c * c - d * d,
                2.0 * (b * c - a * d),
                2.0 * (b * d + a * c),
            ],
            [
                2.0 * (b * c + a * d),
                a * a + c * c - b * b - d * d,
                2.0 * (c * d - a * b),
            ],
            [
                2.0 * (b * d - a * c),
                2.0 * (c * d + a * b),
                a * a + d * d - c * c - b * b,
            ],
        ];
        let qfac = if p[0] < 0.0 { -1.0 } else { 1.0 };
        let s = [p[1], p[2], p[3] * qfac];
        let t = [
            f64::from(h.quatern_x),
            f64::from(h.quatern_y),
            f64::from(h.quatern_z),
        ];
        return std::array::from_fn(|row| {
            [r[row][0] * s[0], r[row][1] * s[1], r[row][2] * s[2], t[row]]
        });
    }
    [
        [p[1], 0.0, 0.0, 0.0],
        [0.0, p[2], 0.0, 0.0],
        [0.0, 0.0, p[3], 0.0],
    ]
}

fn det3(m: [[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

fn inverse3(m: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let d = det3(m);
    let c =
        |r0: usize, c0: usize, r1: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    [
        [c(1, 1, 2, 2) / d, -c(0, 1, 2, 2) / d, c(0, 1, 1, 2) / d],
        [-c(1, 0, 2, 2) / d, c(0, 0, 2, 2) / d, -c(0, 0, 1, 2) / d],
        [c(1, 0, 2, 1) / d, -c(0, 0, 2, 1) / d, c(0, 0, 1, 1) / d],
    ]
}

/// Maps a NIfTI voxel grid onto an axis-aligned world-RAS grid.
#[derive(Debug, Clone, PartialEq)]
pub struct RasResampler {
    /// The output grid (axis-aligned in world RAS, mm).
    pub grid: VolumeGrid,
    /// Input dims.
    in_dims: [usize; 3],
    /// World to input continuous index.
    inv: [[f64; 3]; 3],
    t: [f64; 3],
    /// True when the affine is a scaled signed permutation: exact re-indexing, no interpolation.
    pub exact: bool,
}

impl RasResampler {
    /// Plans the resampling of images with this affine and these dims.
    pub fn new(affine: &[[f64; 4]; 3], in_dims: [usize; 3]) -> RasResampler {
        let lin: [[f64; 3]; 3] =
            std::array::from_fn(|r| [affine[r][0], affine[r][1], affine[r][2]]);
        let t = [affine[0][3], affine[1][3], affine[2][3]];
        let col_norm =
            |c: usize| (lin[0][c].powi(2) + lin[1][c].powi(2) + lin[2][c].powi(2)).sqrt();
        // A column is axis-aligned when all but one of its entries vanish (relative 1e-6).
        let exact = (0..3).all(|c| {
            let n = col_norm(c);
            (0..3).filter(|&r| lin[r][c].abs() > 1e-6 * n).count() == 1
        });
        // World bounding box of the input voxel centres.
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for corner in 0..8 {
            let idx = [0, 1, 2].map(|a| {
                if corner & (1 << a) != 0 {
                    (in_dims[a] - 1) as f64
                } else {
                    0.0
                }
            });
            for r in 0..3 {
                let w = t[r] + lin[r][0] * idx[0] + lin[r][1] * idx[1] + lin[r][2] * idx[2];
                lo[r] = lo[r].min(w);
                hi[r] = hi[r].max(w);
            }
        }
        let spacing: [f64; 3] = if exact {
            // World axis r is carried by the input axis whose column is non-zero in row r.
            std::array::from_fn(|r| (0..3).map(|c| lin[r][c].abs()).fold(0.0, f64::max))
        } else {
            let s = (0..3).map(col_norm).fold(f64::INFINITY, f64::min);
            [s; 3]
        };
        let dims: [usize; 3] =
            std::array::from_fn(|r| ((hi[r] - lo[r]) / spacing[r]).round() as usize + 1);
        RasResampler {
            grid: VolumeGrid {
                dims,
                spacing_mm: spacing,
                origin_mm: lo,
            },
            in_dims,
            inv: inverse3(lin),
            t,
            exact,
        }
    }

    /// Resamples input data (file order, i fastest) onto [`RasResampler::grid`]; samples outside
    /// the input take `fill`.
    pub fn apply(&self, data: &[f32], fill: f32) -> Volume<f32> {
        let g = self.grid;
        let [ni, nj, nk] = self.in_dims;
        let mut out = Vec::with_capacity(g.len());
        for k in 0..g.dims[2] {
            for j in 0..g.dims[1] {
                for i in 0..g.dims[0] {
                    let w = g.voxel_center_mm(i, j, k);
                    let d = [w[0] - self.t[0], w[1] - self.t[1], w[2] - self.t[2]];
                    let x: [f64; 3] = std::array::from_fn(|r| {
                        self.inv[r][0] * d[0] + self.inv[r][1] * d[1] + self.inv[r][2] * d[2]
                    });
                    if self.exact {
                        let idx = x.map(|v| v.round());
                        if idx
                            .iter()
                            .zip(&self.in_dims)
                            .any(|(&v, &n)| v < 0.0 || v > (n - 1) as f64)
                        {
                            out.push(fill);
                        } else {
                            let (a, b, c) = (idx[0] as usize, idx[1] as usize, idx[2] as usize);
                            out.push(data[a + ni * (b + nj * c)]);
                        }
                        continue;
                    }
                    const EDGE: f64 = 1e-6;
                    if x.iter()
                        .zip(&self.in_dims)
                        .any(|(&v, &n)| v < -EDGE || v > (n - 1) as f64 + EDGE)
                    {
                        out.push(fill);
                        continue;
                    }
                    let base: [usize; 3] = std::array::from_fn(|a| {
                        (x[a].max(0.0).floor() as usize).min(self.in_dims[a].saturating_sub(2))
                    });
                    let f: [f64; 3] =
                        std::array::from_fn(|a| (x[a] - base[a] as f64).clamp(0.0, 1.0));
                    let at = |a: usize, b: usize, c: usize| {
                        f64::from(data[a.min(ni - 1) + ni * (b.min(nj - 1) + nj * c.min(nk - 1))])
                    };
                    let mut v = 0.0;
                    for corner in 0..8usize {
                        let (di, dj, dk) = (corner & 1, (corner >> 1) & 1, (corner >> 2) & 1);
                        let wgt = (if di == 1 { f[0] } else { 1.0 - f[0] })
                            * (if dj == 1 { f[1] } else { 1.0 - f[1] })
                            * (if dk == 1 { f[2] } else { 1.0 - f[2] });
                        if wgt > 0.0 {
                            v += wgt * at(base[0] + di, base[1] + dj, base[2] + dk);
                        }
                    }
                    out.push(v as f32);
                }
            }
        }
        Volume { grid: g, data: out }
    }
}

/// Checks that `other` is on exactly the same voxel grid as `reference` (dims and affine within
/// 1e-3 mm, far below any voxel yet above float32 header rounding).
pub fn check_same_grid(reference: &NiftiImage, other: &NiftiImage) -> Result<(), AnatomyError> {
    if reference.dims != other.dims {
        return Err(AnatomyError::bad_file(
            &other.path,
            format!(
                "mask grid {:?} does not match the CT grid {:?} of {}",
                other.dims,
                reference.dims,
                reference.path.display()
            ),
        ));
    }
    let worst = reference
        .affine
        .iter()
        .flatten()
        .zip(other.affine.iter().flatten())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    if worst > 1e-3 {
        return Err(AnatomyError::bad_file(
            &other.path,
            format!(
                "mask affine differs from the CT affine of {} by {worst:.4} mm",
                reference.path.display()
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn qform_quaternion_and_fallback_affines() {
        // 90 degrees about z: quaternion (a, b, c, d) = (cos 45, 0, 0, sin 45); i -> +y, j -> -x.
        let h = nifti::NiftiHeader {
            sform_code: 0,
            qform_code: 1,
            quatern_b: 0.0,
            quatern_c: 0.0,
            quatern_d: std::f32::consts::FRAC_1_SQRT_2,
            quatern_x: 5.0,
            quatern_y: -6.0,
            quatern_z: 7.0,
            // qfac = -1 flips k.
            pixdim: [-1.0, 2.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.0],
            ..Default::default()
        };
        let a = header_affine(&h);
        let expected = [
            [0.0, -3.0, 0.0, 5.0],
            [2.0, 0.0, 0.0, -6.0],
            [0.0, 0.0, -4.0, 7.0],
        ];
        for r in 0..3 {
            for c in 0..4 {
                assert!((a[r][c] - expected[r][c]).abs() < 1e-6, "{a:?}");
            }
        }
        // Neither form: the nifti1.h method-1 diagonal.
        let h = nifti::NiftiHeader {
            sform_code: 0,
            qform_code: 0,
            pixdim: [1.0, 0.5, 0.6, 0.7, 0.0, 0.0, 0.0, 0.0],
            ..Default::default()
        };
        assert_eq!(header_affine(&h)[1][1], f64::from(0.6f32));
        assert_eq!(header_affine(&h)[0][3], 0.0);
    }

    #[test]
    fn pir_affine_is_exact_reindexing_to_ras() {
        // The TPTBox L3 crop's affine (README of the test data).
        let affine = [
            [0.0, 0.0, 1.5, -78.0],
            [-1.5, 0.0, 0.0, -135.0],
            [0.0, -1.5, 0.0, -34.2],
        ];
        let dims = [4, 3, 5];
        let r = RasResampler::new(&affine, dims);
        assert!(r.exact);
        assert_eq!(r.grid.dims, [5, 4, 3]);
        assert_eq!(r.grid.spacing_mm, [1.5; 3]);
        let data: Vec<f32> = (0..60).map(|v| v as f32).collect();
        let out = r.apply(&data, -1.0);
        // Every input voxel lands at its affine world position.
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let w: [f64; 3] = std::array::from_fn(|row| {
                        affine[row][0] * i as f64
                            + affine[row][1] * j as f64
                            + affine[row][2] * k as f64
                            + affine[row][3]
                    });
                    let v = r.grid.world_to_voxel(w).map(|x| x.round() as usize);
                    assert_eq!(out.get(v[0], v[1], v[2]), data[i + 4 * (j + 3 * k)]);
                }
            }
        }
    }

    #[test]
    fn oblique_affine_interpolates_linear_field_exactly() {
        let (c, s) = (0.3f64.cos(), 0.3f64.sin());
        let affine = [
            [2.0 * c, -2.0 * s, 0.0, 10.0],
            [2.0 * s, 2.0 * c, 0.0, -5.0],
            [0.0, 0.0, 3.0, 1.0],
        ];
        let dims = [6, 7, 4];
        let r = RasResampler::new(&affine, dims);
        assert!(!r.exact);
        // A field linear in world coordinates is reproduced by trilinear interpolation.
        let field = |w: [f64; 3]| 0.5 * w[0] - 0.25 * w[1] + 0.125 * w[2];
        let mut data = Vec::new();
        for k in 0..4 {
            for j in 0..7 {
                for i in 0..6 {
                    let w: [f64; 3] = std::array::from_fn(|row| {
                        affine[row][0] * i as f64
                            + affine[row][1] * j as f64
                            + affine[row][2] * k as f64
                            + affine[row][3]
                    });
                    data.push(field(w) as f32);
                }
            }
        }
        let out = r.apply(&data, f32::NAN);
        let mut checked = 0;
        for (idx, &v) in out.data.iter().enumerate() {
            if v.is_nan() {
                continue;
            }
            let [i, j, k] = out.grid.ijk(idx);
            assert!((f64::from(v) - field(out.grid.voxel_center_mm(i, j, k))).abs() < 1e-3);
            checked += 1;
        }
        assert!(checked > 50, "{checked}");
    }
}
