//! Pure functions for scorers: where the iodine is and went, how far the epidural spread
//! reaches, and which dangerous compartments it entered.

use super::domains::LevelSpan;
use super::grid::Domain;
use super::ledger::Ledger;
use super::model::ContrastModel;

/// A domain counts as entered (the boolean flags) when at least this fraction of the injected
/// iodine went into it (our choice: 1 % is far above numerical leakage, which is zero between
/// compartments without a puncture or mixed outlet, and about the smallest intrathecal or
/// vascular blush that changes what a clinician does).
pub const FLAG_FRACTION: f64 = 0.01;

/// Stock-equivalent whole-voxel density above which a cell counts as opacified for the spread
/// extent (our choice: 2 % of stock, about the faintest contrast visible on fluoroscopy through
/// a few mm of spread).
pub const VISIBLE_DENSITY: f64 = 0.02;

/// The pattern a scorer reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pattern {
    /// Nothing injected.
    None,
    /// Epidural spread.
    Epidural,
    /// Intrathecal (CSF) spread.
    Intrathecal,
    /// Subdural spread.
    Subdural,
    /// Vascular uptake.
    Vascular,
    /// Intraneural injection.
    Intraneural,
    /// Pooling in muscle, fat or soft tissue.
    Intramuscular,
}

/// Everything a scorer needs from the field and the ledger.
#[derive(Debug, Clone, PartialEq)]
pub struct PatternReport {
    /// Iodine in each domain now, as a fraction of the iodine in the grid.
    pub retained_fraction: [f64; Domain::COUNT],
    /// Iodine that entered each domain, as a fraction of the iodine injected.
    pub entered_fraction: [f64; Domain::COUNT],
    /// Axial (z) extent of the opacified epidural cells, mm.
    pub epidural_extent_mm: Option<(f64, f64)>,
    /// Vertebral levels the epidural extent overlaps.
    pub epidural_levels: Vec<String>,
    /// Intrathecal contrast (critical in epidural and transforaminal stations).
    pub intrathecal: bool,
    /// Vascular uptake.
    pub vascular: bool,
    /// Intraneural injection.
    pub intraneural: bool,
    /// Subdural spread.
    pub subdural: bool,
    /// Fluid injected so far (contrast and saline), mL.
    pub volume_injected_ml: f64,
    /// The domain most of the injected iodine entered.
    pub dominant: Pattern,
}

/// Iodine in each domain now, as a fraction of the iodine in the grid (zeros when empty).
pub fn retained_fraction_by_domain(model: &ContrastModel) -> [f64; Domain::COUNT] {
    let r = model.retained_by_domain();
    let total: f64 = r.iter().sum();
    if total > 0.0 {
        r.map(|v| v / total)
    } else {
        [0.0; Domain::COUNT]
    }
}

/// Iodine that entered each domain as a fraction of the iodine injected (see [`Ledger::entered`]).
pub fn entered_fraction_by_domain(ledger: &Ledger) -> [f64; Domain::COUNT] {
    if ledger.injected <= 0.0 {
        return [0.0; Domain::COUNT];
    }
    Domain::ALL.map(|d| ledger.entered(d) / ledger.injected)
}

/// Axial extent (z of the outer cell faces, mm) of the cells of `domain` whose whole-voxel density
/// is at least `min_density` (stock fraction).
pub fn axial_extent_mm(
    model: &ContrastModel,
    domain: Domain,
    min_density: f64,
) -> Option<(f64, f64)> {
    let g = model.grid();
    let vc = g.grid.voxel_volume_mm3();
    let h = g.grid.spacing_mm[2];
    let mut ext: Option<(f64, f64)> = None;
    for (i, m) in model.iodine_mm3().iter().enumerate() {
        if g.domain[i] != Some(domain) || m / vc < min_density {
            continue;
        }
        let z = g.grid.voxel_center_mm(0, 0, g.grid.ijk(i)[2])[2];
        let (lo, hi) = (z - 0.5 * h, z + 0.5 * h);
        ext = Some(ext.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))));
    }
    ext
}

/// The levels an axial extent overlaps (by more than `min_overlap_mm`), in the order given.
pub fn levels_covered(
    extent: (f64, f64),
    levels: &[LevelSpan],
    min_overlap_mm: f64,
) -> Vec<String> {
    levels
        .iter()
        .filter(|l| extent.1.min(l.z_max_mm) - extent.0.max(l.z_min_mm) > min_overlap_mm)
        .map(|l| l.name.clone())
        .collect()
}

/// The full report (levels from [`super::domains::phantom_levels`] or the region's own).
pub fn classify(model: &ContrastModel, levels: &[LevelSpan]) -> PatternReport {
    let ledger = model.ledger();
    let entered = entered_fraction_by_domain(ledger);
    let extent = axial_extent_mm(model, Domain::Epidural, VISIBLE_DENSITY);
    let flag = |d: Domain| entered[d.index()] >= FLAG_FRACTION;
    let dominant = if ledger.injected <= 0.0 {
        Pattern::None
    } else {
        let (best, _) = entered
            .iter()
            .enumerate()
            .fold(
                (0, f64::NEG_INFINITY),
                |acc, (i, &v)| if v > acc.1 { (i, v) } else { acc },
            );
        match Domain::ALL[best] {
            Domain::Epidural => Pattern::Epidural,
            Domain::Intrathecal => Pattern::Intrathecal,
            Domain::Subdural => Pattern::Subdural,
            Domain::Vascular => Pattern::Vascular,
            Domain::Intraneural => Pattern::Intraneural,
            Domain::Pooling => Pattern::Intramuscular,
        }
    };
    PatternReport {
        retained_fraction: retained_fraction_by_domain(model),
        entered_fraction: entered,
        epidural_extent_mm: extent,
        // A level counts when the spread overlaps it by at least 2 mm (our choice).
        epidural_levels: extent.map_or_else(Vec::new, |e| levels_covered(e, levels, 2.0)),
        intrathecal: flag(Domain::Intrathecal),
        vascular: flag(Domain::Vascular),
        intraneural: flag(Domain::Intraneural),
        subdural: flag(Domain::Subdural),
        volume_injected_ml: ledger.fluid_injected_mm3 / 1000.0,
        dominant,
    }
}
