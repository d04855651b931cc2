//! What the deposit of one lattice column needs, whichever way it crosses the slice: the
//! frame's shared context and reach, the column itself, and the scatterer of one of its cells.

use glam::DVec3;

use super::super::probe::ScanGeometry;
use super::super::tissue::{AcousticMedium, LatticeColumn, ScatterProps};
use super::lookup::EXP_LEN;
use super::tables::BeamTables;
use crate::rng::splitmix64;

/// The in-plane reach of the scatter sum: line index and depth (mm) ranges.
pub(super) struct Reach {
    pub u: (f64, f64),
    pub z: (f64, f64),
}

impl Reach {
    /// Whether line index `u` and depth `z` (mm) are within reach.
    #[inline]
    pub fn contains(&self, u: f64, z: f64) -> bool {
        u >= self.u.0 && u <= self.u.1 && z >= self.z.0 && z <= self.z.1
    }
}

/// What every column of one deposit shares.
pub(super) struct ScatterContext<'a> {
    pub geo: &'a ScanGeometry,
    pub tables: &'a BeamTables,
    pub medium: &'a dyn AcousticMedium,
    pub exp_tab: &'a [f64; EXP_LEN],
    pub reach: Reach,
    /// Wavenumber, rad/mm.
    pub k0: f64,
    /// Lattice cell, mm.
    pub h: f64,
    /// Amplitude scale (see `deposit::amplitude_norm`).
    pub norm: f64,
    pub seed: u64,
    /// `medium.lookups_by_column()`, asked once.
    pub by_column: bool,
}

/// One lattice column: its cells `k` along axis `AM`, the probe-frame point of the first
/// and the step between cells, the other two indices (in `p`), the hash levels that do not
/// depend on `k` (axis 2) or on the column (axes 0 and 1, per row), and the region point with
/// the fixed coordinates set.
pub(super) struct Column<'a> {
    pub k: std::ops::Range<i64>,
    pub q: DVec3,
    pub step: DVec3,
    pub p: [i64; 3],
    /// For `AM` 2: the hash's first two levels.
    pub prefix: u64,
    /// For `AM` 0 or 1: the hash's first two levels for every `k` of the row, from `k_first`.
    pub row_hash: &'a [u64],
    pub k_first: i64,
    pub pos: DVec3,
}

impl Column<'_> {
    /// Where the medium looks up by column ([`ScatterContext::by_column`]), the tissue of cells
    /// `ks` of this column (along axis `AM`) into `out`, one call to the medium per column;
    /// else nothing (see [`Column::tissue_at`]).
    #[inline(always)]
    pub(super) fn tissue<const AM: usize>(
        &self,
        cx: &ScatterContext<'_>,
        ks: std::ops::Range<i64>,
        out: &mut Vec<ScatterProps>,
    ) {
        if !cx.by_column {
            return;
        }
        let column = LatticeColumn {
            base_mm: self.pos,
            axis: AM,
            h_mm: cx.h,
            ks,
        };
        cx.medium.scatter_along(&column, out);
    }

    /// The tissue of cell `k`, the `i`-th of the range [`Column::tissue`] was given: from
    /// `tissues` where the medium looks up by column, else from the medium at the cell's point.
    #[inline(always)]
    pub(super) fn tissue_at<const AM: usize>(
        &self,
        cx: &ScatterContext<'_>,
        (i, k): (usize, i64),
        tissues: &[ScatterProps],
    ) -> ScatterProps {
        if cx.by_column {
            tissues[i]
        } else {
            let mut p = self.pos;
            p[AM] = k as f64 * cx.h;
            ScatterProps::from(&cx.medium.props(p))
        }
    }

    /// The hash of the scatterer of cell `k` (along axis `AM`; `pos` gets its region point),
    /// whose tissue [`Column::tissue`] gave, `None` where the tissue's scatter density leaves
    /// the cell empty; `echo` gets the tissue's amplitude.
    #[inline(always)]
    pub(super) fn scatterer<const AM: usize>(
        &self,
        cx: &ScatterContext<'_>,
        k: i64,
        tissue: &ScatterProps,
        pos: &mut DVec3,
        echo: &mut EchoCache,
    ) -> Option<u64> {
        let hsh = match AM {
            0 | 1 => splitmix64(self.row_hash[(k - self.k_first) as usize] ^ self.p[2] as u64),
            _ => splitmix64(self.prefix ^ k as u64),
        };
        pos[AM] = k as f64 * cx.h;
        if tissue.scatter_density < 1.0 {
            let keep = crate::rng::unit_f64(splitmix64(hsh));
            if keep >= tissue.scatter_density {
                return None;
            }
        }
        if tissue.echogenicity_db != echo.db {
            echo.db = tissue.echogenicity_db;
            echo.amp = cx.norm * 10f64.powf(echo.db / 20.0);
        }
        Some(hsh)
    }
}

/// The last echogenicity seen (dB) and its amplitude (the `powf` is done on change only).
pub(super) struct EchoCache {
    pub db: f64,
    pub amp: f64,
}

/// What the tests of the deposits' clips share.
#[cfg(test)]
pub(super) mod test_frames {
    use super::*;
    use crate::ultrasound::probe::{ProbeKind, ProbePose};

    /// Uniform numbers in `[0, 1)` from `seed` (SplitMix64).
    pub fn uniform(seed: u64) -> impl FnMut() -> f64 {
        let mut state = seed;
        move || {
            state = splitmix64(state);
            crate::rng::unit_f64(state)
        }
    }

    /// A 128-line scan 60 mm deep by `kind` at `pose`, and its reach (4 lines and 1.5 mm of
    /// padding).
    pub fn scan_at(kind: ProbeKind, pose: ProbePose) -> (ScanGeometry, Reach) {
        let geo = ScanGeometry {
            spec: kind.spec(),
            frame: pose.frame().unwrap(),
            lines: 128,
            depth_mm: 60.0,
        };
        let reach = Reach {
            u: (-4.0, 127.0 + 4.0),
            z: (-1.5, 60.0 + 1.5),
        };
        (geo, reach)
    }

    /// Whether the in-plane point `(x, y)` is within `reach`.
    pub fn in_reach(geo: &ScanGeometry, reach: &Reach, x: f64, y: f64) -> bool {
        let (u, z) = geo.plane_to_line(x, y);
        reach.contains(u, z)
    }
}
