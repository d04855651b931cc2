//! Needle handling: time per 100 mm layered insertion (force + held LOR plunger per substep)
//! against the substep size, the error of the flavum pop and of the loss of resistance against
//! the exact layer boundary, and the time of the dose sum.
//!
//! Path (the interlaminar test path): skin 2, fat 15, interspinous ligament 30, flavum 3.3,
//! epidural fat 4.2 mm, then the dural sac to 100 mm. The flavum's far side (50.3 mm) is off
//! every substep grid below, so the errors show the discretisation. The pop error is the first
//! pop after the flavum's far side minus 50.3 mm; the loss error is the first give-way of a
//! saline syringe held from the ligament on, minus 50.3 mm.
//!
//! `BENCH_QUICK=1` runs fewer repetitions (CI).

use std::hint::black_box;

use sim_core::fluoro::dose::{DoseExposure, air_kerma_ugy_per_mas_at_1m, incident_dose};
use sim_core::needle::{ForceModel, ForceState, LayerStack, LorMedium, LorSyringe, Tissue};
use sim_core::stats::Timing;

fn path() -> LayerStack {
    LayerStack::new(vec![
        (Tissue::Skin, 2.0),
        (Tissue::SubcutaneousFat, 15.0),
        (Tissue::InterspinousLigament, 30.0),
        (Tissue::LigamentumFlavum, 3.3),
        (Tissue::EpiduralFat, 4.2),
        (Tissue::Intrathecal, 100.0),
    ])
}

/// One 100 mm insertion; returns (first pop at or after the flavum exit, first give-way), mm.
fn insert_100mm(stack: &LayerStack, model: &ForceModel, h: f64) -> (f64, f64) {
    let mut force = ForceState::new();
    let mut syringe = LorSyringe::new(LorMedium::Saline);
    let lig = stack.start_of(Tissue::InterspinousLigament).unwrap_or(0.0);
    let exit = stack.end_of(Tissue::LigamentumFlavum).unwrap_or(0.0);
    let (mut pop_at, mut loss_at) = (f64::NAN, f64::NAN);
    let mut shaft = Vec::with_capacity(8);
    let n = (100.0 / h).round() as usize;
    for k in 1..=n {
        let d = k as f64 * h;
        let t = stack.tissue_at(d);
        stack.shaft_into(d, &mut shaft);
        let s = force.cut(model, t, h, &shaft);
        if s.pop && d >= exit && pop_at.is_nan() {
            pop_at = d;
        }
        if d >= lig {
            let feel = syringe.hold(t);
            if feel.gave_way && loss_at.is_nan() {
                loss_at = d;
            }
        }
    }
    (pop_at, loss_at)
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let reps = if quick { 5 } else { 51 };
    let stack = path();
    let model = ForceModel::literature();
    let exit = stack.end_of(Tissue::LigamentumFlavum).unwrap_or(0.0);
    println!(
        "Needle handling: 100 mm layered insertion, force + held LOR syringe per substep \
         ({reps} repetitions, median)"
    );
    println!();
    println!("| substep (mm) | substeps | pop error (mm) | loss error (mm) | time (us) |");
    println!("|---:|---:|---:|---:|---:|");
    for h in [2.0, 1.0, 0.5, 0.25, 0.1] {
        let (pop_at, loss_at) = insert_100mm(&stack, &model, h);
        let t = Timing::run(reps, || {
            black_box(insert_100mm(&stack, &model, black_box(h)));
        })
        .median_s();
        println!(
            "| {h} | {} | {:.2} | {:.2} | {:.1} |",
            (100.0 / h).round(),
            pop_at - exit,
            loss_at - exit,
            t * 1e6
        );
    }
    println!();
    // The kerma sum: 119 bins, tables parsed once before timing.
    let k80 = air_kerma_ugy_per_mas_at_1m(80).unwrap_or(f64::NAN);
    let t_sum = Timing::run(reps, || {
        black_box(air_kerma_ugy_per_mas_at_1m(black_box(80)));
    })
    .median_s();
    let e = DoseExposure {
        kvp: 82.5,
        ma: 2.0,
        seconds: 0.1,
        source_to_skin_mm: 600.0,
        field_area_at_detector_mm2: 40_000.0,
        source_to_detector_mm: 1000.0,
    };
    let t_dose = Timing::run(reps, || {
        black_box(incident_dose(black_box(&e)));
    })
    .median_s();
    println!("| dose | result | time (us) |");
    println!("|---|---:|---:|");
    println!(
        "| air kerma sum, 80 kVp (uGy/mAs at 1 m) | {k80:.3} | {:.2} |",
        t_sum * 1e6
    );
    println!(
        "| incident_dose, 82.5 kVp interpolated (mGy) | {:.5} | {:.3} |",
        incident_dose(&e).air_kerma_mgy,
        t_dose * 1e6
    );
}
