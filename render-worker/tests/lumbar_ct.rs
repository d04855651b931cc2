//! The real-CT lumbar region (`assets/lumbar-ct`) in sessions: it loads through the
//! worker's loader, an AP shot shows the spine, and a scripted midline L4-L5 interlaminar
//! epidural on the `l4-l5-interlaminar-epidural-ct` station feels the loss of resistance at the
//! landmark computed from the masks and scores it.

use std::sync::{Arc, OnceLock};
use std::time::Instant;

use glam::DVec3;
use render_worker::session::loader::load_region;
use render_worker::session::*;
use sim_core::needle::{BoneSurface, Tissue};

use crate::contrast::{last_projection, mean_around, station_on};
use crate::driver::Run;
use crate::sessions::config;

const STATION: &str = "l4-l5-interlaminar-epidural-ct";
const TUOHY: &str = "tuohy-20g-89";
const TARGET: &str = "L4_L5_posterior_epidural_space";

/// The shipped region, loaded once per test binary through the worker's loader.
fn region() -> Arc<Region> {
    static REGION: OnceLock<Arc<Region>> = OnceLock::new();
    Arc::clone(REGION.get_or_init(|| {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let start = Instant::now();
        let r = load_region(&root, "lumbar-ct", &mut |_| {}).expect("lumbar-ct loads");
        eprintln!(
            "lumbar-ct loaded (hashes verified, BVHs built) in {:.2} s",
            start.elapsed().as_secs_f64()
        );
        Arc::new(r)
    }))
}

fn run() -> Run {
    let mut c = config();
    c.fluoro.noise = false;
    Run::new(
        SessionEnv::new(station_on(STATION, &region()), region(), Backends::cpu(1)),
        c,
    )
}

fn landmark(name: &str) -> DVec3 {
    DVec3::from_array(region().landmarks[name])
}

/// The station resolves its target to the region's landmark, and an AP shot shows the spine:
/// the L3 body images darker than the soft tissue 60 mm to either side of it.
#[test]
fn the_ct_region_loads_and_an_ap_shot_shows_the_spine() {
    let r0 = region();
    assert_eq!(r0.name, "lumbar-ct");
    assert!(r0.source.starts_with("ct:"), "{}", r0.source);
    let station = station_on(STATION, &r0);
    assert_eq!(
        station.targets["posterior_epidural_l4_l5"], r0.landmarks[TARGET],
        "the target is the landmark computed from the masks"
    );
    // The L4 inferior endplate, estimated on the CT's solid vertebra mesh, faces caudally
    // (within 30 degrees of -z, the bound the phantom's test uses: lordotic tilt).
    let n = render_worker::session::anatomy::endplate_normal(&r0, "L4", "L5").expect("endplate");
    let off_axis_deg = n.dot(DVec3::NEG_Z).acos().to_degrees();
    eprintln!("CT L4 inferior endplate normal {n:?}, {off_axis_deg:.1} degrees from -z");
    assert!(off_axis_deg < 30.0);
    let mut r = run();
    r.ok(500, Command::Shot);
    let img = r.render(ViewId::FLUOROSCOPY).unwrap();
    let p = last_projection(&r.s);
    let body = landmark("L3_body_centre");
    let bone = mean_around(&img, p.project_point(body.to_array()).unwrap(), 3);
    let soft: Vec<f64> = [-60.0, 60.0]
        .iter()
        .map(|dx| {
            let q = body + DVec3::X * *dx;
            mean_around(&img, p.project_point(q.to_array()).unwrap(), 3)
        })
        .collect();
    eprintln!(
        "AP {}x{}: L3 body {bone:.1}, soft tissue 60 mm left/right {:.1} / {:.1} grey levels",
        img.width, img.height, soft[0], soft[1]
    );
    // 10 grey levels of 255: a visible difference (simulator choice for this check; the body
    // is about 40 mm of bone along the beam).
    for s in soft {
        assert!(bone + 10.0 < s, "bone {bone} vs soft tissue {s}");
    }
}

/// A bone-free straight midline line from the skin to the target: the first of the tilts 0,
/// +5, -5, +10, .. +-40 degrees (positive: heading cranially) whose segment from 150 mm behind
/// the target to 3 mm before it meets no bone. (On this CT the window at the landmark opens
/// for a needle heading slightly caudally.)
fn approach(region: &Region, target: DVec3) -> DVec3 {
    for step in 0..=16u32 {
        let sign = if step % 2 == 1 { 1.0 } else { -1.0 };
        let a = (sign * 5.0 * f64::from(step.div_ceil(2))).to_radians();
        let dir = DVec3::new(0.0, a.cos(), a.sin());
        let far = target - dir * 150.0;
        if region.bones().first_hit(far, dir, 147.0).is_none() {
            return dir;
        }
    }
    panic!("no bone-free midline line to {target}");
}

/// The whole midline epidural by commands on the CT region: AP shot, skin marker over the line,
/// puncture, hub tilt onto it, advance to the interspinous tissue, LOR syringe with constant
/// pressure until the plunger gives way, then submit. The loss is felt in the epidural space and
/// the tip ends within the station's 3 mm of the landmark (its `tip_at_target` pass bound).
#[test]
fn a_scripted_midline_epidural_on_ct_feels_the_loss_and_scores() {
    let region = region();
    let target = landmark(TARGET);
    let dir = approach(&region, target);
    let entry = region
        .skin_entry(target - dir * 150.0, dir, 150.0)
        .expect("the line meets the skin");
    let mut r = run();
    let mut t = 0;
    let mut next = || {
        t += 500;
        t
    };
    r.ok(next(), Command::Shot);
    let m = DVec3::from_array(r.skin_marker(next(), (entry - DVec3::Y * 3.0).to_array()));
    r.ok(
        next(),
        Command::NeedlePuncture {
            instrument: TUOHY.into(),
            direction: None,
            bevel_reference: None,
        },
    );
    let d = target - m;
    r.ok(
        next(),
        Command::NeedleTilt {
            cc_deg: d.z.atan2(d.y).to_degrees(),
            ml_deg: -d.x.atan2(d.y).to_degrees(),
        },
    );
    let outlet = |r: &Run| {
        let n = r.s.world().needle.as_ref().unwrap();
        region.tissue_at(n.state.outlet().centre_mm.to_array())
    };
    let tip = |r: &Run| r.s.world().needle.as_ref().unwrap().state.tip_mm();
    // Advance in 2 mm steps to 15 mm short of the target, then 1 mm steps into the interspinous
    // tissue (ligament or, where the authored midline column is interrupted, deep soft tissue).
    let mut depth = 0.0;
    while depth < d.length() - 15.0 {
        let a = r.ok(next(), Command::NeedleFeed { mm: 2.0 });
        depth = a.outcome["depth_mm"].as_f64().unwrap();
        assert_eq!(a.outcome["bone_contact"], false, "bone at {depth} mm");
    }
    let hold = r.attach_lor_and_hold(next());
    next();
    assert_eq!(
        hold.outcome["lor"]["gave_way"],
        false,
        "{} (outlet in {:?})",
        hold.outcome,
        outlet(&r)
    );
    let mut loss = None;
    for _ in 0..60 {
        let a = r.ok(next(), Command::NeedleFeed { mm: 0.5 });
        depth = a.outcome["depth_mm"].as_f64().unwrap();
        if a.outcome["lor"]["gave_way"] == true {
            loss = Some(depth);
            break;
        }
    }
    let loss = loss.unwrap_or_else(|| panic!("no loss; outlet in {:?} at {depth} mm", outlet(&r)));
    let at_loss = outlet(&r);
    let tip_mm = tip(&r);
    eprintln!(
        "CT epidural: cranial tilt {:.0} deg, loss at {loss:.1} mm depth in {at_loss:?}, tip {:.2} mm from the landmark",
        dir.z.atan2(dir.y).to_degrees(),
        tip_mm.distance(target)
    );
    assert_eq!(at_loss, Tissue::EpiduralFat);
    r.ok(next(), Command::PlungerHold { on: false });
    r.ok(next(), Command::Aspirate);
    // Contrast through the needle: the transport grid is painted from the region's meshes
    // (`contrast::region_grid`); 1 mL at 0.5 mL/s, then 3 s to settle.
    r.ok(
        next(),
        Command::Syringe {
            action: SyringeAction::Detach,
            medium: None,
        },
    );
    let start = Instant::now();
    let t_inject = next();
    r.ok(
        t_inject,
        Command::Inject {
            agent: Agent::Contrast,
            volume_ml: 1.0,
            rate_ml_per_s: 0.5,
        },
    );
    r.ok(t_inject + 2500, Command::Tick);
    r.ok(t_inject + 5000, Command::Tick);
    eprintln!(
        "CT contrast: grid built and 5 s simulated in {:.2} s",
        start.elapsed().as_secs_f64()
    );
    let ack = r.ok(t_inject + 5500, Command::Submit);
    let res = ack.result.expect("a submit returns the result");
    let m = &res.measurements;
    eprintln!("CT epidural measurements: {m:?}");
    assert_eq!(m["lor_confirmed_bool"], 1.0, "{m:?}");
    assert_eq!(m["dural_puncture_bool"], 0.0, "{m:?}");
    assert_eq!(m["bone_contacts_count"], 0.0, "{m:?}");
    // The AP shot was taken at the default pose: the endplate tilt is measured on the CT's
    // vertebra mesh (`vertebrae_L4`), whatever its value.
    assert!(m["ap_endplate_tilt_deg"].is_finite(), "{m:?}");
    let credits: std::collections::BTreeMap<&str, Option<f64>> = res
        .rubric
        .criteria
        .iter()
        .map(|c| (c.id.as_str(), c.credit))
        .collect();
    assert!((m["injected_volume_ml"] - 1.0).abs() < 1e-6, "{m:?}");
    assert_eq!(m["intrathecal_contrast_bool"], 0.0, "{m:?}");
    assert_eq!(m["intravascular_uptake_bool"], 0.0, "{m:?}");
    assert_eq!(m["epidural_spread_bool"], 1.0, "{m:?}");
    for id in [
        "tip_at_target",
        "loss_of_resistance",
        "no_dural_puncture",
        "epidural_contrast_pattern",
        "no_intravascular_injection",
        "no_intrathecal_contrast",
    ] {
        assert_eq!(credits[id], Some(1.0), "{id}: {credits:?}");
    }
}
