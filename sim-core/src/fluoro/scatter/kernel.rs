//! Pencil-beam scatter kernels of water, tabulated from the Monte Carlo
//! ([`super::monte_carlo::pencil`]) by `cargo run -p sim-core --bin scatter_kernels`, and read
//! back from `sim-core/data/fluoro/scatter_kernels.csv`.
//!
//! A kernel is the scatter that a unit pencil of the tube's spectrum (energy-integrating units:
//! the open field's detector signal is 1) puts within radius `r` of its axis on a detector plane
//! an air gap behind a water slab, without and with the anti-scatter grid: the cumulative
//! `C(r)` at `r = 10, 20, ..., 500` mm.

use std::sync::OnceLock;

use super::AntiScatterGrid;
use super::monte_carlo::{Beam, RING_MM, RINGS, SlabSetup, pencil};
use crate::fluoro::spectrum::{UnknownKvp, parse_csv};

/// Tube voltages of the table, kVp (others are interpolated linearly, clamped at the ends).
pub const KVPS: [u32; 4] = [60, 80, 100, 120];
/// Water thicknesses of the table, mm (a lumbar AP is about 200 mm water-equivalent, a lateral
/// 300 to 400 mm).
pub const WATER_MM: [f64; 9] = [10.0, 25.0, 50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0];
/// Air gaps of the table (exit face to detector), mm: from a detector on the skin to the
/// C-arm's 750 mm from isocentre.
pub const GAPS_MM: [f64; 7] = [0.0, 50.0, 100.0, 200.0, 350.0, 500.0, 700.0];
/// Radial step of the table, mm (two Monte Carlo rings).
pub const STEP_MM: f64 = 10.0;
/// Radii of the table: `STEP_MM, 2 STEP_MM, ..., RADII x STEP_MM` (500 mm).
pub const RADII: usize = 50;
/// Photons per pencil run of the committed table.
pub const PHOTONS: usize = 2_000_000;
/// Seed of the committed table's runs (each run's seed is this plus its index).
pub const SEED: u64 = 0x5CA7_7E12;

const KERNELS_CSV: &str = include_str!("../../../data/fluoro/scatter_kernels.csv");

/// A kernel table that does not parse: what is wrong with it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("scatter kernel table: {0}")]
pub struct KernelTableError(pub String);

/// One tabulated kernel: `C(r)` at the table's radii, without and with the grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Kernel {
    /// Primary transmission of the pencil (energy-integrating).
    pub primary: f64,
    /// Cumulative scatter within each radius, no grid.
    pub cumulative: [f64; RADII],
    /// Cumulative scatter within each radius, behind the grid.
    pub cumulative_grid: [f64; RADII],
}

/// The whole table, indexed `[kvp][water][gap]`.
#[derive(Debug, Clone, PartialEq)]
pub struct KernelTable {
    /// Kernels in `KVPS x WATER_MM x GAPS_MM` order.
    pub kernels: Vec<Kernel>,
}

impl KernelTable {
    /// The committed table (parsed once).
    pub fn get() -> &'static KernelTable {
        static TABLE: OnceLock<KernelTable> = OnceLock::new();
        TABLE.get_or_init(|| KernelTable::from_csv(KERNELS_CSV).expect("committed kernel table"))
    }

    /// Index of `(kvp index, water index, gap index)`.
    pub fn index(k: usize, w: usize, g: usize) -> usize {
        (k * WATER_MM.len() + w) * GAPS_MM.len() + g
    }

    /// The kernel at table point `(k, w, g)`.
    pub fn at(&self, k: usize, w: usize, g: usize) -> &Kernel {
        &self.kernels[Self::index(k, w, g)]
    }

    /// Runs the Monte Carlo for the table point `kvp` x `water_mm` with `photons` photons and
    /// seed `seed`: the kernels at every gap.
    pub fn simulate(
        kvp: u32,
        water_mm: f64,
        photons: usize,
        seed: u64,
    ) -> Result<Vec<Kernel>, UnknownKvp> {
        let score = pencil(&SlabSetup {
            kvp,
            water_mm,
            air_gaps_mm: GAPS_MM.to_vec(),
            beam: Beam::Pencil,
            grid: AntiScatterGrid::FLUOROSCOPY,
            photons,
            seed,
        })?;
        let per = (STEP_MM / RING_MM) as usize;
        debug_assert_eq!(per * RADII, RINGS);
        Ok((0..GAPS_MM.len())
            .map(|g| Kernel {
                primary: score.primary,
                cumulative: std::array::from_fn(|k| score.cumulative[g][(k + 1) * per - 1]),
                cumulative_grid: std::array::from_fn(|k| {
                    score.cumulative_grid[g][(k + 1) * per - 1]
                }),
            })
            .collect())
    }

    /// The table as CSV: one row per `(kvp, water_mm, gap_mm, grid)`.
    pub fn to_csv(&self) -> String {
        let mut out = String::from("kvp,water_mm,gap_mm,grid,primary");
        for k in 1..=RADII {
            out.push_str(&format!(",c{}", k as f64 * STEP_MM));
        }
        out.push('\n');
        for (ki, kvp) in KVPS.iter().enumerate() {
            for (wi, w) in WATER_MM.iter().enumerate() {
                for (gi, g) in GAPS_MM.iter().enumerate() {
                    let kernel = self.at(ki, wi, gi);
                    for (grid, c) in [(0, &kernel.cumulative), (1, &kernel.cumulative_grid)] {
                        out.push_str(&format!("{kvp},{w},{g},{grid},{:.5e}", kernel.primary));
                        for v in c {
                            out.push_str(&format!(",{v:.5e}"));
                        }
                        out.push('\n');
                    }
                }
            }
        }
        out
    }

    /// Parses [`KernelTable::to_csv`]'s format, checking that the rows are the table's points
    /// in order.
    pub fn from_csv(text: &str) -> Result<KernelTable, KernelTableError> {
        let (header, rows) = parse_csv(text);
        if header.len() != 5 + RADII {
            return Err(KernelTableError(format!(
                "{} columns, expected {}",
                header.len(),
                5 + RADII
            )));
        }
        let expected = KVPS.len() * WATER_MM.len() * GAPS_MM.len() * 2;
        if rows.len() != expected {
            return Err(KernelTableError(format!(
                "{} rows, expected {expected}",
                rows.len()
            )));
        }
        let mut kernels = Vec::with_capacity(expected / 2);
        for pair in rows.chunks(2) {
            let i = kernels.len();
            let (k, w, g) = (
                i / (WATER_MM.len() * GAPS_MM.len()),
                i / GAPS_MM.len() % WATER_MM.len(),
                i % GAPS_MM.len(),
            );
            for (grid, r) in pair.iter().enumerate() {
                let key = [KVPS[k] as f64, WATER_MM[w], GAPS_MM[g], grid as f64];
                if r[..4] != key {
                    return Err(KernelTableError(format!(
                        "row {:?} where {key:?} was expected",
                        &r[..4]
                    )));
                }
            }
            kernels.push(Kernel {
                primary: pair[0][4],
                cumulative: std::array::from_fn(|k| pair[0][5 + k]),
                cumulative_grid: std::array::from_fn(|k| pair[1][5 + k]),
            });
        }
        Ok(KernelTable { kernels })
    }
}
