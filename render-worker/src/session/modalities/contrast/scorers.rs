//! Contrast measurements (rubric keys, unit in the name) from the transport model's field and
//! ledger, by `sim_core::contrast::classify`.
//!
//! Present once iodine was injected (contrast or diluted contrast; saline alone shows nothing):
//! - `iodine_<domain>_fraction`: iodine in each domain now over the iodine in the grid, for
//!   `epidural`, `intrathecal`, `subdural`, `vascular`, `intraneural`, `pooling` (muscle, fat and
//!   soft tissue around the tip);
//! - `iodine_entered_<domain>_fraction`: iodine that ever entered each domain over the iodine
//!   injected (robust to clearance: a vascular blush that washed out still counts);
//! - `epidural_levels_count`: vertebral levels the opacified epidural extent overlaps by at least
//!   2 mm (opacified: whole-voxel density of at least 2 % of stock);
//! - `intrathecal_contrast_bool`, `intravascular_uptake_bool`, `intraneural_contrast_bool`,
//!   `subdural_contrast_bool`: at least 1 % of the injected iodine entered that compartment
//!   (`classify::FLAG_FRACTION`);
//! - `epidural_spread_bool`: the epidural space took at least 1 % of the injected iodine and its
//!   opacified extent covers at least one level;
//! - `perineural_spread_bool`: opacified cells outline a nerve root (at least
//!   [`PERINEURAL_MIN_CELLS`] opacified non-neural cells share a face with root cells), the
//!   contrast also reached the epidural space, and none went into the root;
//! - `contrast_pattern_count`: the dominant pattern as a number (0 none, 1 epidural,
//!   2 intrathecal, 3 subdural, 4 vascular, 5 intraneural, 6 intramuscular), for review.
//!
//! Per injection (the iodine of each injection, from the ledger at its start to the next one's):
//! - `vascular_injections_count`: injections whose iodine entered a vessel (1 % flag);
//! - `last_injection_vascular_bool`: the latest injection's iodine entered a vessel;
//! - `vascular_uptake_managed_bool`: every injection with vascular uptake was followed by a
//!   repositioning (the next injection's tip at least [`REPOSITION_MIN_MM`] away) and the last
//!   injection was free of it (1 when no injection had vascular uptake).
//!
//! `injected_volume_ml` (fluid of every agent delivered so far) is present whenever the station
//! has contrast. Booleans are 1.0 or 0.0. Absent without an injection: the rubric engine then
//! reports the contrast criteria as incomplete rather than scoring a check that never happened.

use sim_core::contrast::classify::{self, Pattern, VISIBLE_DENSITY};
use sim_core::contrast::domains::LevelSpan;
use sim_core::contrast::{ContrastModel, Domain, Ledger};
use sim_core::rubric::Measurements;

/// Opacified cells along a root that make a perineural pattern. Our choice: four 1 mm cells is a
/// few millimetres of outlined root, the least a reader calls a root sleeve.
pub const PERINEURAL_MIN_CELLS: usize = 4;

fn flag(b: bool) -> f64 {
    f64::from(u8::from(b))
}

/// The pattern as a number (see the module docs).
pub fn pattern_number(p: Pattern) -> f64 {
    match p {
        Pattern::None => 0.0,
        Pattern::Epidural => 1.0,
        Pattern::Intrathecal => 2.0,
        Pattern::Subdural => 3.0,
        Pattern::Vascular => 4.0,
        Pattern::Intraneural => 5.0,
        Pattern::Intramuscular => 6.0,
    }
}

/// Opacified cells outside the roots that share a face with a root cell.
pub fn cells_outlining_roots(model: &ContrastModel) -> usize {
    let g = model.grid();
    let vc = g.grid.voxel_volume_mm3();
    let d = g.grid.dims;
    let iodine = model.iodine_mm3();
    (0..g.len())
        .filter(|&i| {
            g.domain[i].is_some_and(|x| x != Domain::Intraneural)
                && iodine[i] / vc >= VISIBLE_DENSITY
        })
        .filter(|&i| {
            let ijk = g.grid.ijk(i);
            (0..6).any(|f| {
                let a = f / 2;
                let mut q = ijk;
                if f % 2 == 0 {
                    q[a] += 1;
                    if q[a] >= d[a] {
                        return false;
                    }
                } else {
                    if q[a] == 0 {
                        return false;
                    }
                    q[a] -= 1;
                }
                g.domain[g.grid.index(q[0], q[1], q[2])] == Some(Domain::Intraneural)
            })
        })
        .count()
}

/// Adds the contrast measurements of `model` (see the module docs).
pub fn measure(model: &ContrastModel, levels: &[LevelSpan], out: &mut Measurements) {
    let r = classify::classify(model, levels);
    for d in Domain::ALL {
        let i = d.index();
        out.insert(
            format!("iodine_{}_fraction", d.name()),
            r.retained_fraction[i],
        );
        out.insert(
            format!("iodine_entered_{}_fraction", d.name()),
            r.entered_fraction[i],
        );
    }
    out.insert(
        "epidural_levels_count".into(),
        r.epidural_levels.len() as f64,
    );
    out.insert("intrathecal_contrast_bool".into(), flag(r.intrathecal));
    out.insert("intravascular_uptake_bool".into(), flag(r.vascular));
    out.insert("intraneural_contrast_bool".into(), flag(r.intraneural));
    out.insert("subdural_contrast_bool".into(), flag(r.subdural));
    let epidural_entered = r.entered_fraction[Domain::Epidural.index()] >= classify::FLAG_FRACTION;
    out.insert(
        "epidural_spread_bool".into(),
        flag(epidural_entered && !r.epidural_levels.is_empty()),
    );
    out.insert(
        "perineural_spread_bool".into(),
        flag(
            epidural_entered
                && !r.intraneural
                && cells_outlining_roots(model) >= PERINEURAL_MIN_CELLS,
        ),
    );
    out.insert("contrast_pattern_count".into(), pattern_number(r.dominant));
}

/// Tip movement between injections that counts as a repositioning, mm. Our choice: a millimetre
/// takes the opening out of a 0.9 mm radicular vessel.
pub const REPOSITION_MIN_MM: f64 = 1.0;

/// Iodine of one injection (between two ledgers) that entered the vessels, as a fraction of the
/// iodine it injected (net inflow from other domains counted when positive).
fn vascular_fraction(from: &Ledger, to: &Ledger) -> f64 {
    let v = Domain::Vascular.index();
    let injected = to.injected - from.injected;
    if injected <= 0.0 {
        return 0.0;
    }
    let direct = to.injected_by_domain[v] - from.injected_by_domain[v];
    let inflow: f64 = (0..Domain::COUNT)
        .filter(|&e| e != v)
        .map(|e| (to.exchanged[e][v] - from.exchanged[e][v]).max(0.0))
        .sum();
    (direct + inflow) / injected
}

/// Adds the per-injection measurements (see the module docs): `starts[k]` is the ledger when
/// injection `k` began, `tips[k]` its outlet tip.
pub fn measure_injections(
    model: &ContrastModel,
    starts: &[Ledger],
    tips: &[[f64; 3]],
    out: &mut Measurements,
) {
    let now = *model.ledger();
    let vascular: Vec<bool> = (0..starts.len())
        .map(|k| {
            let to = starts.get(k + 1).unwrap_or(&now);
            vascular_fraction(&starts[k], to) >= classify::FLAG_FRACTION
        })
        .collect();
    let count = vascular.iter().filter(|&&v| v).count();
    out.insert("vascular_injections_count".into(), count as f64);
    let last = vascular.last().copied().unwrap_or(false);
    out.insert("last_injection_vascular_bool".into(), flag(last));
    let moved = |k: usize| {
        tips.get(k + 1).is_some_and(|b| {
            let a = tips[k];
            (0..3).map(|i| (b[i] - a[i]).powi(2)).sum::<f64>().sqrt() >= REPOSITION_MIN_MM
        })
    };
    let managed = !last && (0..vascular.len()).all(|k| !vascular[k] || moved(k));
    out.insert("vascular_uptake_managed_bool".into(), flag(managed));
}
