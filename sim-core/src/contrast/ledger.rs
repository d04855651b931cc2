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

#[cfg(test)]
mod tests {
    use super::Ledger;

    /// The mass-balance figure every transport test bounds is itself right: hand-computed
    /// imbalances, never negative, and 0 only for a balanced or empty ledger.
    #[test]
    fn the_balance_error_is_the_relative_imbalance() {
        let l = Ledger {
            injected: 10.0,
            escaped: 2.0,
            cleared: 1.0,
            ..Ledger::default()
        };
        assert_eq!(l.expected_retained(), 7.0);
        assert_eq!(l.balance_error(7.0), 0.0);
        // |7 - 6.5| / max(10, 6.5) and |7 - 12| / max(10, 12).
        assert!((l.balance_error(6.5) - 0.05).abs() < 1e-15);
        assert!((l.balance_error(12.0) - 5.0 / 12.0).abs() < 1e-15);
        // Nothing injected but iodine found: all of it is error.
        assert_eq!(Ledger::default().balance_error(5.0), 1.0);
        assert_eq!(Ledger::default().balance_error(-5.0), 1.0);
        // Empty and balanced.
        assert_eq!(Ledger::default().balance_error(0.0), 0.0);
    }

    /// Adding a step's ledger to the totals adds every field, the per-domain ones included.
    #[test]
    fn adding_ledgers_adds_every_total() {
        let n = super::Domain::COUNT;
        let step = |k: f64| {
            let mut l = Ledger {
                injected: 1.0 * k,
                escaped: 2.0 * k,
                cleared: 3.0 * k,
                fluid_injected_mm3: 4.0 * k,
                fluid_escaped_mm3: 5.0 * k,
                ..Ledger::default()
            };
            for a in 0..n {
                let a_k = k * (a as f64 + 1.0);
                l.injected_by_domain[a] = 6.0 * a_k;
                l.escaped_by_domain[a] = 7.0 * a_k;
                l.cleared_by_domain[a] = 8.0 * a_k;
                for b in 0..n {
                    l.exchanged[a][b] = a_k * (b as f64 - a as f64);
                }
            }
            l
        };
        let mut total = step(2.0);
        total.add(&step(3.0));
        assert_eq!(total, step(5.0));
    }
}
