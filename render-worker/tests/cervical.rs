//! The cervical stations in sessions on the cervical phantom: a scripted paramedian
//! C7-T1 interlaminar epidural (AP shot, marker, puncture, contralateral oblique, advance with
//! constant plunger pressure to the loss of resistance, aspiration, submit) and a scripted left
//! C5 medial branch block in the lateral view (needle onto the articular pillar's centroid), each
//! scoring full credit on its key criteria, and each replayed bit-identically from its log.
//!
//! The region is the cervical phantom meshed at 1.5 mm (built once per test binary, about 6 s):
//! at 2 mm its 2.5 mm flavum and posterior epidural space are about a voxel thick.

use std::sync::{Arc, OnceLock};

use glam::DVec3;
use render_worker::session::*;
use sim_core::needle::Tissue;

use crate::contrast::station_on;
use crate::driver::Run;
use crate::needle_handling::{json_f64, quiet};

const EPIDURAL: &str = "c7-t1-interlaminar-epidural";
const MBB: &str = "c5-left-medial-branch-block";

/// The cervical phantom meshed at 1.5 mm, built once per test binary.
pub(crate) fn region() -> Arc<Region> {
    static REGION: OnceLock<Arc<Region>> = OnceLock::new();
    Arc::clone(REGION.get_or_init(|| {
        use sim_core::anatomy::phantom::cervical;
        // Cached by parameter hash in the shared test scratch folder (the server's browser
        // tests load the same build).
        let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("phantom-cervical-1.5mm");
        let asset =
            cervical::ensure_built_with(&dir, &cervical::params_with_voxel_mm(1.5), &mut |_| {})
                .unwrap();
        Arc::new(Region::from_asset(&asset))
    }))
}

fn env(id: &str) -> SessionEnv {
    SessionEnv::new(station_on(id, &region()), region(), Backends::cpu(1))
}

fn landmark(name: &str) -> DVec3 {
    DVec3::from_array(region().landmarks[name])
}

/// A clock that advances half a second per command.
fn clock() -> impl FnMut() -> u64 {
    let mut t = 0;
    move || {
        t += 500;
        t
    }
}

/// Marks the skin where the line from `far` to `target` enters it and punctures there, aimed at
/// the target; returns the marker.
/// The marker is placed 3 mm off the skin towards the X-ray source, `beam` being the central
/// ray's direction (the marker snaps onto the skin along the beam).
fn puncture_towards(
    r: &mut Run,
    t_ms: u64,
    (far, target): (DVec3, DVec3),
    beam: DVec3,
    instrument: &str,
) -> DVec3 {
    let entry = region()
        .skin_entry(far, target - far, 300.0)
        .expect("the planned line meets the skin");
    let marker = r.ok(
        t_ms,
        Command::SkinMarker {
            pixel: None,
            position_mm: Some((entry - beam * 3.0).to_array()),
        },
    );
    let m = DVec3::from_array(
        serde_json::from_value::<[f64; 3]>(marker.outcome["marker_mm"].clone()).unwrap(),
    );
    assert!(m.distance(entry) < 1.0, "{m} vs {entry}");
    r.ok(
        t_ms + 1,
        Command::NeedlePuncture {
            instrument: instrument.into(),
            direction: Some((target - m).normalize().to_array()),
            bevel_reference: None,
        },
    );
    m
}

/// The scripted C7-T1 epidural: AP shot squared to the C7 inferior endplate (about 9 degrees
/// caudal: C7's tilt in the phantom's lordosis), marker and puncture on a left paramedian line 25 mm
/// lateral at 100 mm behind the target (bone-free on this phantom: found by scanning straight
/// lines), contralateral oblique shot, advance, plunger held until the loss of resistance,
/// aspiration. Returns the run and the tissue at the outlet when the plunger gave way.
fn scripted_epidural() -> (Run, Tissue) {
    let mut r = Run::new(env(EPIDURAL), quiet());
    let mut next = clock();
    let pose = |orbital_deg: f64, angular_deg: f64| Command::CarmPose {
        orbital_deg,
        angular_deg,
        table_mm: [0.0; 3],
    };
    // Square the C7 inferior endplate: tilt the beam in the sagittal plane until it lies in the
    // endplate (what the operator does by eye), from the endplate normal the scorer uses.
    let n = render_worker::session::anatomy::endplate_normal(&region(), "C7", "T1").unwrap();
    let n = n * n.z.signum();
    let square_deg = (-n.y).atan2(n.z).to_degrees();
    r.ok(next(), pose(0.0, square_deg));
    r.ok(next(), Command::Shot);
    let target = landmark("C7_T1_posterior_epidural_space");
    let far = target + DVec3::new(-25.0, -100.0, 0.0);
    let m = puncture_towards(&mut r, next(), (far, target), DVec3::Y, "tuohy-20g-89");
    next();
    // Contralateral oblique: the station's target is midline (side +1), so orbital -50.
    r.ok(next(), pose(-50.0, 0.0));
    r.ok(next(), Command::Shot);
    let approach = m.distance(target) - 12.0;
    let mut depth = 0.0;
    while depth < approach {
        let a = r.ok(next(), Command::NeedleFeed { mm: 2.0 });
        depth = json_f64(&a.outcome, &["depth_mm"]);
        assert_eq!(a.outcome["bone_contact"], false, "bone at {depth} mm");
    }
    r.ok(
        next(),
        Command::Syringe {
            action: SyringeAction::Attach,
            medium: None,
        },
    );
    let hold = r.ok(next(), Command::PlungerHold { on: true });
    assert_eq!(hold.outcome["lor"]["gave_way"], false, "{}", hold.outcome);
    let mut gave_way = false;
    for _ in 0..60 {
        let a = r.ok(next(), Command::NeedleFeed { mm: 0.5 });
        assert_eq!(a.outcome["bone_contact"], false, "{}", a.outcome);
        if a.outcome["lor"]["gave_way"] == true {
            gave_way = true;
            break;
        }
    }
    assert!(gave_way, "the plunger gave way");
    let n = r.s.world().needle.as_ref().unwrap();
    let outlet = region().tissue_at(n.state.outlet().centre_mm.to_array());
    r.ok(next(), Command::PlungerHold { on: false });
    let asp = r.ok(next(), Command::Aspirate);
    assert_eq!(asp.outcome["aspirate"], "nothing", "{}", asp.outcome);
    (r, outlet)
}

/// The scripted left C5 medial branch block: a true lateral view, a marker on a posterolateral
/// line at 45 degrees (bone-free to the target on this phantom), puncture aimed at the pillar's
/// centroid, advance until the tip meets the pillar, a confirming lateral shot.
fn scripted_mbb() -> Run {
    let mut r = Run::new(env(MBB), quiet());
    let mut next = clock();
    r.ok(
        next(),
        Command::CarmPose {
            // The tube on the patient's left, the beam towards +x.
            orbital_deg: -90.0,
            angular_deg: 0.0,
            table_mm: [0.0; 3],
        },
    );
    r.ok(next(), Command::Shot);
    let target = landmark("C5_medial_branch_target_left");
    let far = target + DVec3::new(-60.0, -60.0, 0.0);
    let m = puncture_towards(&mut r, next(), (far, target), DVec3::X, "spinal-22g-89");
    next();
    let d = m.distance(target);
    let mut depth = 0.0;
    let mut bone = false;
    while depth < d + 3.0 && !bone {
        let step = (d - depth - 2.0).clamp(0.5, 5.0);
        let a = r.ok(next(), Command::NeedleFeed { mm: step });
        depth = json_f64(&a.outcome, &["depth_mm"]);
        bone = a.outcome["bone_contact"] == true;
    }
    assert!(bone, "the needle met the pillar (depth {depth} mm of {d})");
    r.ok(next(), Command::Shot);
    r
}

/// Submits the run: every criterion of the station's rubric gets full credit and the outcome is
/// met.
fn assert_full_marks(run: &mut Run) {
    let t = run.s.snapshot().clock_ms + 500;
    let res = run
        .ok(t, Command::Submit)
        .result
        .expect("a submit returns the result");
    for c in &res.rubric.criteria {
        assert_eq!(
            c.credit,
            Some(1.0),
            "{}: {c:?} {:?}",
            c.id,
            res.measurements
        );
    }
    assert_eq!(res.rubric.outcome, sim_core::rubric::Outcome::Met);
}

#[test]
fn a_scripted_c7_t1_epidural_feels_the_loss_and_scores() {
    let (mut r, outlet) = scripted_epidural();
    assert_eq!(outlet, Tissue::EpiduralFat);
    assert_full_marks(&mut r);
}

#[test]
fn a_scripted_c5_medial_branch_block_reaches_the_pillar_and_scores() {
    let mut r = scripted_mbb();
    assert_full_marks(&mut r);
}

#[test]
fn replay_of_the_cervical_stations_is_bit_identical() {
    for (id, live) in [(EPIDURAL, scripted_epidural().0), (MBB, scripted_mbb())] {
        let initial = Session::new(env(id), quiet()).snapshot();
        let replayed = Session::restore(env(id), &initial, live.s.log()).unwrap();
        assert_eq!(
            replayed.snapshot().to_bytes(),
            live.s.snapshot().to_bytes(),
            "{id}"
        );
        assert_eq!(replayed.measurements(), live.s.measurements(), "{id}");
    }
}

/// The stations' landmark targets resolve to the cervical phantom's landmarks, in the tissue
/// their names say (the epidural target in the epidural fat; the pillar target off the bone,
/// with bone within 2 mm medially).
#[test]
fn cervical_station_targets_are_the_phantom_landmarks() {
    let reg = region();
    let epi = station_on(EPIDURAL, &reg);
    let p = epi.targets["posterior_epidural_c7_t1"];
    assert_eq!(p, reg.landmarks["C7_T1_posterior_epidural_space"]);
    assert_eq!(reg.tissue_at(p), Tissue::EpiduralFat);
    let mbb = station_on(MBB, &reg);
    let p = mbb.targets["left_c5_pillar_centroid"];
    assert_eq!(p, reg.landmarks["C5_medial_branch_target_left"]);
    assert_ne!(reg.tissue_at(p), Tissue::Bone);
    let medial = DVec3::from_array(p) + DVec3::X * 2.0;
    assert_eq!(reg.tissue_at(medial.to_array()), Tissue::Bone);
}

/// A needle driven from the side into the left vertebral artery between the C5 and C6
/// transverse processes (a horizontal lateral line, bone-free: checked below) is recorded as a
/// vertebral artery puncture, a critical failure of the medial branch block.
#[test]
fn a_needle_in_the_vertebral_artery_fails_the_block() {
    let reg = region();
    let artery = 0.5
        * (landmark("C5_foramen_transversarium_left") + landmark("C6_foramen_transversarium_left"));
    let far = artery - DVec3::X * 60.0;
    let entry = reg
        .skin_entry(far, DVec3::X, 60.0)
        .expect("the line meets the skin");
    let depth = entry.distance(artery);
    for k in 0..=(depth * 4.0) as usize {
        let p = entry + DVec3::X * (k as f64 * 0.25);
        assert_ne!(reg.tissue_at(p.to_array()), Tissue::Bone, "bone at {p}");
    }
    assert_eq!(reg.tissue_at(artery.to_array()), Tissue::Vessel);
    let mut r = Run::new(env(MBB), quiet());
    r.ok(
        500,
        Command::NeedlePlace {
            instrument: "spinal-22g-89".into(),
            entry_mm: entry.to_array(),
            direction: [1.0, 0.0, 0.0],
            bevel_reference: [0.0, 0.0, 1.0],
        },
    );
    r.ok(1000, Command::NeedleFeed { mm: depth });
    let res = r
        .ok(1500, Command::Submit)
        .result
        .expect("a submit returns the result");
    assert_eq!(res.measurements["vertebral_artery_puncture_bool"], 1.0);
    assert_eq!(res.rubric.outcome, sim_core::rubric::Outcome::NotMet);
}
