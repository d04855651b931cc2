//! The iodine ledger: where the injected stock-equivalent volume went.
//!
//! Iodine is counted as stock-equivalent volume in mm^3 (the iodine in 1 mm^3 of stock contrast);
//! fluid volumes (contrast plus saline) are counted separately in mm^3.

use super::grid::Domain;

/// Running totals since the model was created (and, per step, the same quantities for one call of
/// `advance`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Ledger {
    /// Iodine injected, stock-equivalent mm^3.
    pub injected: f64,
    /// Iodine that left through drains (crop faces, venous return, back into the needle).
    pub escaped: f64,
    /// Iodine removed by clearance.
    pub cleared: f64,
    /// Net iodine moved from domain `a` to domain `b` (`exchanged[a][b] = -exchanged[b][a]`).
    pub exchanged: [[f64; Domain::COUNT]; Domain::COUNT],
    /// Iodine injected into each domain.
    pub injected_by_domain: [f64; Domain::COUNT],
    /// Iodine escaped from each domain.
    pub escaped_by_domain: [f64; Domain::COUNT],
    /// Iodine cleared from each domain.
    pub cleared_by_domain: [f64; Domain::COUNT],
    /// Fluid injected (contrast and saline), mm^3.
    pub fluid_injected_mm3: f64,
    /// Fluid that left through drains, mm^3.
    pub fluid_escaped_mm3: f64,
}

impl Ledger {
    /// Iodine the ledger says should be in the grid: injected - escaped - cleared.
    pub fn expected_retained(&self) -> f64 {
        self.injected - self.escaped - self.cleared
    }

    /// Relative mass-balance error against the iodine actually retained (0 when nothing was
    /// injected and nothing is there).
    pub fn balance_error(&self, retained: f64) -> f64 {
        let scale = self.injected.abs().max(retained.abs());
        if scale == 0.0 {
            0.0
        } else {
            (self.expected_retained() - retained).abs() / scale
        }
    }

    /// Iodine that entered domain `d` so far: injected into it plus net inflow from each other
    /// domain (positive parts only), stock-equivalent mm^3.
    pub fn entered(&self, d: Domain) -> f64 {
        let i = d.index();
        self.injected_by_domain[i]
            + (0..Domain::COUNT)
                .filter(|&e| e != i)
                .map(|e| self.exchanged[e][i].max(0.0))
                .sum::<f64>()
    }

    /// Adds another ledger's totals.
    pub fn add(&mut self, o: &Ledger) {
        self.injected += o.injected;
        self.escaped += o.escaped;
        self.cleared += o.cleared;
        self.fluid_injected_mm3 += o.fluid_injected_mm3;
        self.fluid_escaped_mm3 += o.fluid_escaped_mm3;
        for a in 0..Domain::COUNT {
            self.injected_by_domain[a] += o.injected_by_domain[a];
            self.escaped_by_domain[a] += o.escaped_by_domain[a];
            self.cleared_by_domain[a] += o.cleared_by_domain[a];
            for b in 0..Domain::COUNT {
                self.exchanged[a][b] += o.exchanged[a][b];
            }
        }
    }
}
