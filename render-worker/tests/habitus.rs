//! Body habitus: the slim and obese variants of the lumbar phantom beside the average one, with
//! the needle's depth to target, the brightness control's technique and the detector's signal
//! following, and the epidural station's habitus variants passing its scripted run.

use std::sync::{Arc, OnceLock};

use glam::DVec3;
use render_worker::session::modalities::fluoro::dose::source_to_skin_mm;
use render_worker::session::modalities::fluoro::scatter::{ScatterState, metering_factor};
use render_worker::session::region::Region;
use render_worker::session::*;
use sim_core::anatomy::phantom::habitus::Habitus;
use sim_core::anatomy::phantom::{self, PhantomParams};
use sim_core::fluoro::Projection;
use sim_core::fluoro::brightness::{
    BrightnessCurve, FrameExposure, METERING_RAYS_ACROSS, Technique, TubeLimits, meter,
    next_technique,
};
use sim_core::fluoro::detector::open_field_kerma_ngy;
use sim_core::needle::Tissue;

use crate::contrast::station_on;
use crate::needle_handling::{region, scripted_epidural_at};

/// The phantom of habitus `h` meshed at 2 mm (the average one is the needle tests' build),
/// built once per test binary and cached in the shared test scratch folder.
fn habitus_region(h: Habitus) -> Arc<Region> {
    static SLIM: OnceLock<Arc<Region>> = OnceLock::new();
    static OBESE: OnceLock<Arc<Region>> = OnceLock::new();
    let cell = match h {
        Habitus::Average => return region(),
        Habitus::Slim => &SLIM,
        Habitus::Obese => &OBESE,
    };
    Arc::clone(cell.get_or_init(|| {
        let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("phantom-lumbar-2mm-{}", h.name()));
        let params = h.apply(&PhantomParams::with_voxel_mm(2.0));
        let asset = phantom::ensure_built_with(&dir, &params, &mut |_| {}).unwrap();
        Arc::new(Region::from_asset(&asset))
    }))
}

#[test]
fn habitus_deepens_the_target_and_raises_the_technique() {
    let limits = TubeLimits::default();
    let mut rows = Vec::new();
    for h in Habitus::ALL {
        let reg = habitus_region(h);
        // Skin to the L4-L5 posterior epidural space along the AP beam (posterior to anterior).
        let target = DVec3::from_array(reg.landmarks["L4_L5_posterior_epidural_space"]);
        let skin = reg
            .skin_entry(target - DVec3::Y * 300.0, DVec3::Y, 400.0)
            .expect("the beam meets the skin");
        let depth_mm = target.y - skin.y;
        // The AP view at L4 on a 512^2 detector, metered as sessions meter it (grid in).
        let p = Projection {
            isocentre_mm: reg.landmarks["L4_body_centre"],
            detector_pixels: [512, 512],
            pixel_pitch_mm: [300.0 / 512.0; 2],
            ..Projection::default()
        };
        let m = meter(&reg.scene, &p, METERING_RAYS_ACROSS);
        let e = FrameExposure {
            frame_s: 1.0 / 30.0,
            duty: 0.25,
            source_to_detector_mm: p.source_to_detector_mm(),
            source_to_skin_mm: source_to_skin_mm(&reg, &p),
        };
        let scatter = Some(ScatterState { grid: true });
        let fixed = Technique { kvp: 80, ma: 2.0 };
        let kerma_fixed = m.detector_kerma_ngy(fixed, &e) * metering_factor(scatter, &m, 80, &p);
        let mut t = fixed;
        for _ in 0..12 {
            let k = m.detector_kerma_ngy(t, &e) * metering_factor(scatter, &m, t.kvp, &p);
            t = next_technique(BrightnessCurve::Standard, &limits, &e, t, k).technique;
        }
        let output = open_field_kerma_ngy(f64::from(t.kvp), t.ma / 30.0, p.source_to_detector_mm());
        eprintln!(
            "{}: skin to L4-L5 epidural {depth_mm:.1} mm, detector {kerma_fixed:.2} nGy at 80 kVp \
             2 mA, settles on {} kVp {:.2} mA (tube output {output:.1} nGy per pulse at the \
             detector, open field)",
            h.name(),
            t.kvp,
            t.ma
        );
        rows.push((depth_mm, kerma_fixed, output));
    }
    // The posterior skin moves with the subcutaneous fat: -7 mm (slim) and +25 mm (obese)
    // against the average; 3 mm for the 2 mm grid's surfaces.
    let (slim, avg, obese) = (rows[0], rows[1], rows[2]);
    assert!((avg.0 - slim.0 - 7.0).abs() < 3.0, "{rows:?}");
    assert!((obese.0 - avg.0 - 25.0).abs() < 3.0, "{rows:?}");
    // A thicker body lets less reach the detector at a fixed technique, and the control drives
    // the tube harder to make up for it (so the noise of a fixed technique rises with the
    // habitus, and the control holds it).
    assert!(slim.1 > avg.1 && avg.1 > obese.1, "{rows:?}");
    assert!(slim.2 < avg.2 && avg.2 < obese.2, "{rows:?}");
}

#[test]
fn habitus_variants_pass_the_scripted_epidural() {
    let mut loss = Vec::new();
    for h in [Habitus::Slim, Habitus::Obese] {
        // The committed station of this habitus, on the region its habitus names.
        let id = format!("l4-l5-interlaminar-epidural-{}", h.name());
        let reg = habitus_region(h);
        let station = station_on(&id, &reg);
        assert_eq!(station.station.region_asset(), h.region_name());
        let mut e = scripted_epidural_at(&id, &reg);
        assert_eq!(e.outlet_at_loss, Tissue::EpiduralFat, "{}", h.name());
        let t = e.run.s.snapshot().clock_ms + 500;
        let res = e.run.ok(t, Command::Submit).result.expect("a result");
        let m = &res.measurements;
        assert_eq!(m["lor_confirmed_bool"], 1.0, "{}: {m:?}", h.name());
        assert_eq!(m["dural_puncture_bool"], 0.0, "{}", h.name());
        assert_eq!(m["bone_contacts_count"], 0.0, "{}", h.name());
        eprintln!(
            "{}: loss of resistance at {:.1} mm",
            h.name(),
            e.loss_depth_mm
        );
        loss.push(e.loss_depth_mm);
    }
    assert!(
        loss[1] > loss[0] + 20.0,
        "slim {} mm, obese {} mm",
        loss[0],
        loss[1]
    );
}
