//! Needle handling in sessions on the procedural phantom: a scripted paramedian
//! L4-L5 epidural (skin marker, AP and contralateral oblique shots, puncture, hub tilt, advance
//! with constant plunger pressure until the loss of resistance, aspiration, submit), bad commands
//! refused naming their field, bit-identical replay, a soak of random needle commands, and the
//! radiation estimate against an independent calculation.
//!
//! The region is the phantom meshed at 2 mm (built once per test binary): at the 4 mm of the
//! other session tests the 3.5 mm ligamentum flavum is not resolved.

use std::collections::BTreeSet;
use std::sync::{Arc, OnceLock};

use glam::DVec3;
use render_worker::session::*;
use sim_core::needle::Tissue;
use sim_core::rng::SplitMix64;

use crate::contrast::station_on;
use crate::driver::Run;
use crate::sessions::config;

const EPIDURAL: &str = "l4-l5-interlaminar-epidural";
const TUOHY: &str = "tuohy-20g-89";

/// The phantom meshed at 2 mm, built once per test binary.
pub(crate) fn region() -> Arc<Region> {
    static REGION: OnceLock<Arc<Region>> = OnceLock::new();
    Arc::clone(REGION.get_or_init(|| {
        use sim_core::anatomy::phantom::{self, PhantomParams};
        // Cached by parameter hash in the shared test scratch folder: the server's browser tests
        // load the same build instead of meshing it again.
        let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("phantom-lumbar-2mm");
        let asset =
            phantom::ensure_built_with(&dir, &PhantomParams::with_voxel_mm(2.0), &mut |_| {})
                .unwrap();
        Arc::new(Region::from_asset(&asset))
    }))
}

fn env(id: &str) -> SessionEnv {
    SessionEnv::new(station_on(id, &region()), region(), Backends::cpu(1))
}

pub(crate) fn quiet() -> SessionConfig {
    let mut c = config();
    c.fluoro.noise = false;
    c
}

/// The paramedian target: the lateral posterior epidural space at L4-L5, left of the midline,
/// where a straight line from the left paramedian skin crosses the erector spinae, the
/// interspinous soft tissue and the ligamentum flavum without touching bone (found by scanning
/// straight paths on this phantom).
pub(crate) fn epidural_target() -> DVec3 {
    DVec3::new(-10.0, -39.0, -54.0)
}

/// Where the planned line (30 mm lateral at 120 mm behind the target) meets the skin.
pub(crate) fn planned_entry() -> DVec3 {
    planned_entry_on(&region())
}

/// [`planned_entry`] on `reg` (a habitus variant: the target is the same, the skin is not; the
/// planned line starts 170 mm behind it, beyond the obese body's skin).
pub(crate) fn planned_entry_on(reg: &Region) -> DVec3 {
    let t = epidural_target();
    let far = t + DVec3::new(-30.0, -120.0, 0.0) * (170.0 / 120.0);
    reg.skin_entry(far, t - far, 300.0)
        .expect("the planned line meets the skin")
}

pub(crate) fn json_f64(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut x = v;
    for p in path {
        x = &x[*p];
    }
    x.as_f64()
        .unwrap_or_else(|| panic!("{path:?} missing in {v}"))
}

/// What the scripted epidural saw.
pub(crate) struct Epidural {
    pub(crate) run: Run,
    /// Depth at which the plunger gave way, mm.
    pub(crate) loss_depth_mm: f64,
    /// Whether a feed that took the tip into or through the ligamentum flavum reported a force
    /// drop (pop). The skin's pop, on the first feeds, does not count.
    pub(crate) flavum_pop: bool,
    /// Largest total force reported, N.
    pub(crate) peak_n: f64,
    /// Tissue at the outlet when the plunger gave way.
    pub(crate) outlet_at_loss: Tissue,
}

/// The whole epidural by commands: AP shot, marker, shot, puncture down the beam, hub tilt onto
/// the planned line, contralateral oblique, advance, loss of resistance, aspiration.
pub(crate) fn scripted_epidural() -> Epidural {
    scripted_epidural_on(&region())
}

/// [`scripted_epidural`] on region `reg` (the same station and script; the entry is where the
/// planned line meets this region's skin).
pub(crate) fn scripted_epidural_on(reg: &Arc<Region>) -> Epidural {
    scripted_epidural_at(EPIDURAL, reg)
}

/// [`scripted_epidural_on`] with station `station` (one of the epidural station's habitus
/// variants).
pub(crate) fn scripted_epidural_at(station: &str, reg: &Arc<Region>) -> Epidural {
    let env = SessionEnv::new(station_on(station, reg), Arc::clone(reg), Backends::cpu(1));
    let mut r = Run::new(env, quiet());
    let mut t = 0;
    let mut next = || {
        t += 500;
        t
    };
    r.ok(next(), Command::Shot);
    let entry = planned_entry_on(reg);
    // A point 3 mm off the skin along the beam: the marker snaps onto the skin.
    let m = DVec3::from_array(r.skin_marker(next(), (entry - DVec3::Y * 3.0).to_array()));
    assert!(m.distance(entry) < 1.0, "{m} vs {entry}");
    r.ok(next(), Command::Shot);
    let punct = r.ok(
        next(),
        Command::NeedlePuncture {
            instrument: TUOHY.into(),
            direction: None,
            bevel_reference: None,
        },
    );
    assert_eq!(
        punct.outcome["direction"],
        serde_json::json!([0.0, 1.0, 0.0])
    );
    // Aim from the marker at the target: medial (towards +x, the patient's right) and
    // cranio-caudal components of the turn from the beam (+y).
    let d = epidural_target() - m;
    let ml = -d.x.atan2(d.y).to_degrees();
    let cc = d.z.atan2(d.y).to_degrees();
    let tilt = r.ok(
        next(),
        Command::NeedleTilt {
            cc_deg: cc,
            ml_deg: ml,
        },
    );
    assert!(json_f64(&tilt.outcome, &["hub_deviation_deg"]) > 10.0);
    r.ok(
        next(),
        Command::CarmPose {
            orbital_deg: 50.0,
            angular_deg: 0.0,
            table_mm: [0.0; 3],
        },
    );
    r.ok(next(), Command::Shot);
    let mut flavum_pop = false;
    let mut peak_n: f64 = 0.0;
    let mut depth = 0.0;
    let approach = d.length() - 25.0;
    while depth < approach {
        let a = r.ok(next(), Command::NeedleFeed { mm: 2.0 });
        depth = json_f64(&a.outcome, &["depth_mm"]);
        peak_n = peak_n.max(json_f64(&a.outcome, &["force", "peak_n"]));
        assert_eq!(a.outcome["bone_contact"], false, "bone at {depth} mm");
    }
    // The syringe goes on once the needle sits in the interspinous ligament (the needle stands
    // by itself there): the plunger must not give way in the muscle on the way.
    let outlet_tissue = |r: &Run| {
        let n = r.s.world().needle.as_ref().unwrap();
        reg.tissue_at(n.state.outlet().centre_mm.to_array())
    };
    let tip_tissue = |r: &Run| {
        let n = r.s.world().needle.as_ref().unwrap();
        reg.tissue_at(n.state.tip_mm().to_array())
    };
    // A feed with a pop whose tip starts or ends in the flavum is the flavum's pop.
    let feed = |r: &mut Run, t: u64, mm: f64, flavum_pop: &mut bool| {
        let before = tip_tissue(r);
        let a = r.ok(t, Command::NeedleFeed { mm });
        let through_flavum = [before, tip_tissue(r)].contains(&Tissue::LigamentumFlavum);
        *flavum_pop |= through_flavum && a.outcome["force"]["pop"] == true;
        a
    };
    for _ in 0..40 {
        if outlet_tissue(&r) == Tissue::InterspinousLigament {
            break;
        }
        let a = feed(&mut r, next(), 1.0, &mut flavum_pop);
        depth = json_f64(&a.outcome, &["depth_mm"]);
    }
    assert_eq!(
        outlet_tissue(&r),
        Tissue::InterspinousLigament,
        "at {depth} mm"
    );
    let hold = r.attach_lor_and_hold(next());
    next();
    assert_eq!(hold.outcome["lor"]["gave_way"], false, "{}", hold.outcome);
    let mut loss = None;
    for _ in 0..80 {
        let a = feed(&mut r, next(), 0.5, &mut flavum_pop);
        depth = json_f64(&a.outcome, &["depth_mm"]);
        peak_n = peak_n.max(json_f64(&a.outcome, &["force", "peak_n"]));
        if a.outcome["lor"]["gave_way"] == true {
            loss = Some(depth);
            break;
        }
    }
    let loss_depth_mm = loss.expect("the plunger gave way");
    let snap = r.s.snapshot();
    let n = snap.needle.as_ref().unwrap();
    let outlet_at_loss = reg.tissue_at(n.state.outlet().centre_mm.to_array());
    r.ok(next(), Command::PlungerHold { on: false });
    let asp = r.ok(next(), Command::Aspirate);
    assert_eq!(asp.outcome["aspirate"], "nothing", "{}", asp.outcome);
    // Swap syringes and inject contrast; while it runs the LOR syringe cannot go back on.
    r.ok(
        next(),
        Command::Syringe {
            action: SyringeAction::Detach,
            medium: None,
        },
    );
    r.ok(
        next(),
        Command::Inject {
            agent: Agent::Contrast,
            volume_ml: 1.0,
            rate_ml_per_s: 0.2,
        },
    );
    let busy = r.err(Command::Syringe {
        action: SyringeAction::Attach,
        medium: None,
    });
    assert_eq!(busy.field, "command.type", "{busy}");
    r.ok(next(), Command::Shot);
    Epidural {
        run: r,
        loss_depth_mm,
        flavum_pop,
        peak_n,
        outlet_at_loss,
    }
}

#[test]
fn a_scripted_paramedian_epidural_feels_the_loss_and_scores() {
    let mut e = scripted_epidural();
    assert_eq!(e.outlet_at_loss, Tissue::EpiduralFat);
    assert!(e.flavum_pop, "the flavum pop shows as a force drop");
    assert!(e.peak_n > 1.0, "peak force {} N", e.peak_n);
    let t = e.run.s.snapshot().clock_ms + 500;
    let ack = e.run.ok(t, Command::Submit);
    let res = ack.result.expect("a submit returns the result");
    let m = &res.measurements;
    assert_eq!(m["lor_confirmed_bool"], 1.0, "{m:?}");
    assert_eq!(m["false_loss_count"], 0.0);
    assert_eq!(m["dural_puncture_bool"], 0.0);
    assert_eq!(m["skin_punctures_count"], 1.0);
    assert_eq!(m["redirections_count"], 0.0);
    assert_eq!(m["bone_contacts_count"], 0.0);
    assert_eq!(m["aspiration_done_bool"], 1.0);
    assert!(m["air_kerma_mgy"] > 0.0 && m["kerma_area_product_gycm2"] > 0.0);
    assert!(
        (m["fluoro_time_s"] - 0.4).abs() < 1e-9,
        "four shots of 0.1 s"
    );
    for id in [
        "loss_of_resistance",
        "false_loss",
        "aspiration",
        "skin_punctures",
        "redirections",
        "bone_contacts",
        "air_kerma",
        "fluoro_time",
    ] {
        let c = res
            .rubric
            .criteria
            .iter()
            .find(|c| c.id == id)
            .unwrap_or_else(|| panic!("criterion {id}"));
        assert_eq!(c.credit, Some(1.0), "{id}: {c:?}");
    }
    // The saline of the loss of resistance went to the injection ledger.
    let snap = e.run.s.snapshot();
    assert!(!snap.injections.is_empty());
    assert!(e.loss_depth_mm > 30.0);
}

#[test]
fn the_marker_shows_on_the_next_shot_and_the_pixel_form_lands_on_its_ray() {
    let mut r = Run::new(env(EPIDURAL), quiet());
    r.ok(500, Command::Shot);
    let before = r.render(ViewId::FLUOROSCOPY).unwrap();
    let entry = planned_entry();
    // The pixel where the entry point images on the shot just taken.
    let snap = r.s.snapshot();
    let proj: sim_core::fluoro::Projection =
        serde_json::from_value(snap.modalities["fluoroscopy"]["images"][0]["projection"].clone())
            .unwrap();
    let px = proj.project_point(entry.to_array()).unwrap();
    let ack = r.ok(
        1000,
        Command::SkinMarker {
            pixel: Some(px),
            position_mm: None,
        },
    );
    let m: [f64; 3] = serde_json::from_value(ack.outcome["marker_mm"].clone()).unwrap();
    assert!(DVec3::from_array(m).distance(entry) < 1.0);
    // Last-image hold: no new frame until the next shot, which shows the steel marker.
    assert!(r.render(ViewId::FLUOROSCOPY).is_none());
    r.ok(1500, Command::Shot);
    let after = r.render(ViewId::FLUOROSCOPY).unwrap();
    let (x, y) = (px[0] as usize, px[1] as usize);
    let w = before.width as usize;
    let at = |img: &ViewImage| {
        let mut s = 0.0;
        for dy in 0..3 {
            for dx in 0..3 {
                s += f64::from(img.pixels[(y + dy - 1) * w + x + dx - 1]);
            }
        }
        s / 9.0
    };
    assert!(
        (at(&after) - at(&before)).abs() > 5.0,
        "marker invisible: {} vs {}",
        at(&after),
        at(&before)
    );
}

#[test]
fn bad_needle_commands_are_refused_naming_the_field() {
    let mut r = Run::new(env(EPIDURAL), quiet());
    let field = |e: CommandError| e.field;
    assert_eq!(
        field(r.err(Command::NeedlePuncture {
            instrument: TUOHY.into(),
            direction: None,
            bevel_reference: None,
        })),
        "command.type",
        "no marker yet"
    );
    assert_eq!(field(r.err(Command::Aspirate)), "command.type");
    assert_eq!(
        field(r.err(Command::Syringe {
            action: SyringeAction::Attach,
            medium: None,
        })),
        "command.type",
        "syringe without needle"
    );
    assert_eq!(
        field(r.err(Command::SkinMarker {
            pixel: Some([10.0, 10.0]),
            position_mm: None,
        })),
        "command.pixel",
        "no image to mark yet"
    );
    assert_eq!(
        field(r.err(Command::SkinMarker {
            pixel: None,
            position_mm: Some([0.0, -500.0, 0.0]),
        })),
        "command.position_mm",
        "far from the skin"
    );
    assert_eq!(
        field(r.err(Command::SkinMarker {
            pixel: None,
            position_mm: None,
        })),
        "command.pixel"
    );
    r.ok(500, Command::Shot);
    assert_eq!(
        field(r.err(Command::SkinMarker {
            pixel: Some([1e6, 3.0]),
            position_mm: None,
        })),
        "command.pixel",
        "outside the image"
    );
    let entry = planned_entry();
    r.ok(
        1000,
        Command::SkinMarker {
            pixel: None,
            position_mm: Some(entry.to_array()),
        },
    );
    assert_eq!(
        field(r.err(Command::NeedlePuncture {
            instrument: TUOHY.into(),
            direction: Some([0.0, -1.0, 0.0]),
            bevel_reference: None,
        })),
        "command.direction",
        "puncture pointing out of the body"
    );
    assert_eq!(
        field(r.err(Command::NeedlePuncture {
            instrument: "lor-syringe".into(),
            direction: None,
            bevel_reference: None,
        })),
        "command.instrument"
    );
    r.ok(
        1500,
        Command::NeedlePuncture {
            instrument: TUOHY.into(),
            direction: None,
            bevel_reference: None,
        },
    );
    for (c, f) in [
        (
            Command::NeedleTilt {
                cc_deg: 21.0,
                ml_deg: 0.0,
            },
            "command.cc_deg",
        ),
        (
            Command::NeedleTilt {
                cc_deg: 0.0,
                ml_deg: f64::NAN,
            },
            "command.ml_deg",
        ),
        (Command::Plunger { ml: 0.5 }, "command.type"),
        (Command::Plunger { ml: 0.0 }, "command.ml"),
        (Command::Plunger { ml: -1.0 }, "command.ml"),
        (Command::PlungerHold { on: true }, "command.type"),
        (
            Command::Syringe {
                action: SyringeAction::Detach,
                medium: Some(sim_core::needle::LorMedium::Air),
            },
            "command.medium",
        ),
    ] {
        assert_eq!(field(r.err(c.clone())), f, "{c:?}");
    }
    // Tilting the hub step by step is refused at 45 degrees from the puncture direction.
    let mut last = None;
    for _ in 0..4 {
        last = Some(r.try_apply(
            r.s.snapshot().clock_ms + 10,
            Command::NeedleTilt {
                cc_deg: 15.0,
                ml_deg: 0.0,
            },
        ));
    }
    let e = last.unwrap().unwrap_err();
    assert_eq!(e.field, "command.cc_deg", "{e}");
    r.ok(
        r.s.snapshot().clock_ms + 10,
        Command::Syringe {
            action: SyringeAction::Attach,
            medium: Some(sim_core::needle::LorMedium::Air),
        },
    );
    // The contrast syringe goes on only after the loss-of-resistance syringe comes off.
    let e = r.err(Command::Inject {
        agent: Agent::Contrast,
        volume_ml: 1.0,
        rate_ml_per_s: 0.5,
    });
    assert_eq!(e.field, "command.type", "{e}");
    // A tilt of nothing, and aspiration with the opening still outside the skin, are refused.
    assert_eq!(
        field(r.err(Command::NeedleTilt {
            cc_deg: 0.0,
            ml_deg: 0.0,
        })),
        "command.cc_deg"
    );
    assert_eq!(field(r.err(Command::Aspirate)), "command.type");
    // Pressing with the opening outside the skin squirts fluid: no loss, no false loss.
    let a = r.ok(r.s.snapshot().clock_ms + 10, Command::Plunger { ml: 0.2 });
    assert!(a.outcome["lor"].is_object());
    assert_eq!(r.s.measurements()["false_loss_count"], 0.0);
    // Nothing refused reached the log.
    assert_eq!(
        r.s.log().len(),
        8,
        "shot, marker, puncture, three tilts, attach, plunger"
    );
}

#[test]
fn replay_of_needle_handling_is_bit_identical() {
    let e = scripted_epidural();
    let initial = Session::new(env(EPIDURAL), quiet()).snapshot();
    let live = &e.run.s;
    let replayed = Session::restore(env(EPIDURAL), &initial, live.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), live.snapshot().to_bytes());
    assert_eq!(replayed.measurements(), live.measurements());
}

/// 5 x 10^4 random hub, feed, withdraw, roll, marker, puncture and syringe commands on the 2 mm
/// phantom session: no NaN in any acknowledgement or measurement, the tip always on its recorded
/// channel, the syringe never below empty, and replay of the whole log bit-identical. (10^5 took
/// 188 s of CI's 2 cores with its replay; sim-core's own needle soak keeps 10^5 on the core.)
#[test]
fn soak_of_random_needle_commands() {
    let mut r = Run::new(env(EPIDURAL), quiet());
    let mut rng = SplitMix64::new(1919);
    let entry = planned_entry();
    r.ok(1, Command::Shot);
    let mut t = 1;
    let mut accepted = 0;
    for i in 0..50_000 {
        t += 10;
        let u = rng.next_f64();
        let c = if u < 0.3 {
            Command::NeedleFeed {
                mm: rng.next_f64() * 3.0,
            }
        } else if u < 0.45 {
            Command::NeedleWithdraw {
                mm: rng.next_f64() * 5.0,
            }
        } else if u < 0.55 {
            Command::NeedleRoll {
                deg: rng.next_f64() * 360.0 - 180.0,
            }
        } else if u < 0.7 {
            Command::NeedleTilt {
                cc_deg: rng.next_f64() * 10.0 - 5.0,
                ml_deg: rng.next_f64() * 10.0 - 5.0,
            }
        } else if u < 0.75 {
            Command::SkinMarker {
                pixel: None,
                position_mm: Some(
                    (entry
                        + DVec3::new(
                            rng.next_f64() * 20.0 - 10.0,
                            -2.0,
                            rng.next_f64() * 20.0 - 10.0,
                        ))
                    .to_array(),
                ),
            }
        } else if u < 0.8 {
            Command::NeedlePuncture {
                instrument: TUOHY.into(),
                direction: None,
                bevel_reference: None,
            }
        } else if u < 0.85 {
            Command::Syringe {
                action: if rng.next_f64() < 0.7 {
                    SyringeAction::Attach
                } else {
                    SyringeAction::Detach
                },
                medium: None,
            }
        } else if u < 0.92 {
            Command::Plunger {
                ml: 0.05 + rng.next_f64() * 0.5,
            }
        } else if u < 0.97 {
            Command::PlungerHold {
                on: rng.next_f64() < 0.5,
            }
        } else {
            Command::Aspirate
        };
        let name = c.name().to_string();
        if let Ok(a) = r.try_apply(t, c) {
            accepted += 1;
            let text = serde_json::to_string(&a.outcome).unwrap();
            assert!(
                !text.contains("null") || name != "needle_feed",
                "step {i}: {text}"
            );
        }
        if let Some(n) = &r.s.world().needle {
            let s = &n.state;
            assert!(s.tip_mm().is_finite(), "step {i}");
            if let Some(seg) = s.tract.segments.get(s.cursor.segment) {
                let on = seg.pose_at(s.cursor.offset_mm).position_mm;
                assert!(
                    on.distance(s.tip_mm()) < 1e-9,
                    "step {i}: tip off its channel"
                );
            }
        }
        if let Some(syr) = &r.s.world().hands.syringe {
            assert!(syr.contents_ml() >= 0.0, "step {i}");
        }
    }
    assert!(accepted > 25_000, "{accepted} accepted");
    let m = r.s.measurements();
    assert!(m.values().all(|v| v.is_finite()), "{m:?}");
    let initial = Session::new(env(EPIDURAL), quiet()).snapshot();
    let replayed = Session::restore(env(EPIDURAL), &initial, r.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), r.s.snapshot().to_bytes());
    let _ = BTreeSet::<u8>::new();
}

/// The source of an AP pose (orbital and angular 0: the beam runs along +y), from the pose alone:
/// the isocentre moved against the table's translation, then the source-to-isocentre distance
/// back along the beam. Written here from the C-arm's definition, not taken from
/// `Projection::frame`.
fn ap_source_mm(p: &sim_core::fluoro::Projection) -> DVec3 {
    assert_eq!((p.orbital_deg, p.angular_deg), (0.0, 0.0), "an AP pose");
    DVec3::from_array(p.isocentre_mm)
        - DVec3::from_array(p.table_translation_mm)
        - DVec3::Y * p.source_to_isocentre_mm
}

/// Distance from `origin` to the skin along `dir` by testing every skin triangle
/// (Moller-Trumbore, nearest positive hit): a separate intersection routine from the BVH walk
/// behind `Region::skin_entry`, so a wrong skin entry in production cannot cancel out.
fn skin_distance_by_every_triangle_mm(origin: DVec3, dir: DVec3) -> f64 {
    let region = region();
    let skin = region
        .scene
        .entries()
        .iter()
        .find(|e| e.name == "skin")
        .expect("the phantom has a skin");
    let dir = dir.normalize();
    let mut nearest = f64::INFINITY;
    for tri in skin.bvh.triangles_mm() {
        let [a, b, c] = tri.map(DVec3::from_array);
        let (e1, e2) = (b - a, c - a);
        let p = dir.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            continue;
        }
        let s = origin - a;
        let u = s.dot(p) / det;
        let q = s.cross(e1);
        let v = dir.dot(q) / det;
        let t = e2.dot(q) / det;
        if (0.0..=1.0).contains(&u) && v >= 0.0 && u + v <= 1.0 && t > 0.0 {
            nearest = nearest.min(t);
        }
    }
    assert!(nearest.is_finite(), "the beam meets the skin");
    nearest
}

#[test]
fn the_dose_estimate_follows_the_inverse_square_and_the_live_time() {
    let mut r = Run::new(env(EPIDURAL), quiet());
    // A technique set by hand (the brightness control would step it after each frame).
    r.ok(400, Command::Technique { kvp: 80, ma: 2.0 });
    r.ok(500, Command::Shot);
    let m1 = r.s.measurements();
    // Independent: the source from the pose, the skin by testing every triangle of its mesh.
    let snap = r.s.snapshot();
    let proj: sim_core::fluoro::Projection =
        serde_json::from_value(snap.modalities["fluoroscopy"]["images"][0]["projection"].clone())
            .unwrap();
    let source = ap_source_mm(&proj);
    let ssd_m = skin_distance_by_every_triangle_mm(source, DVec3::Y) / 1000.0;
    // The phantom's posterior skin lies 0.5 to 0.8 m from the source of a 1 m C-arm (a sanity
    // range around the default source-to-isocentre distance less the body's half depth).
    assert!((0.5..0.8).contains(&ssd_m), "source-to-skin {ssd_m} m");
    // 80 kVp, 2 mA, 0.1 s: 0.2 mAs.
    let k1m = sim_core::fluoro::dose::air_kerma_ugy_per_mas_at_1m(80).unwrap();
    let expected_mgy = k1m * 0.2 / 1000.0 / (ssd_m * ssd_m);
    // The production skin entry walks a BVH in f64 over the same triangles: agreement to 1e-9
    // relative is round-off.
    assert!(
        (m1["air_kerma_mgy"] / expected_mgy - 1.0).abs() < 1e-9,
        "{} vs {expected_mgy}",
        m1["air_kerma_mgy"]
    );
    // KAP: kerma times the field at the skin (300 mm detector square scaled to the skin plane).
    let sid = proj.source_to_isocentre_mm + proj.isocentre_to_detector_mm;
    let area_cm2 = (30.0 * 30.0) * (ssd_m * 1000.0 / sid).powi(2);
    let kap = m1["air_kerma_mgy"] / 1000.0 * area_cm2;
    assert!((m1["kerma_area_product_gycm2"] / kap - 1.0).abs() < 1e-9);
    // Ten seconds of live fluoroscopy at the same pose at the default 7.5 pulses per second,
    // each pulse one video frame's charge (2 mA / 30 s): a quarter of the continuous 20 mAs, so
    // 25 times one shot's 0.2 mAs.
    r.ok(1000, Command::Live { on: true });
    r.ok(11_000, Command::Live { on: false });
    let m2 = r.s.measurements();
    assert!((m2["air_kerma_mgy"] / m1["air_kerma_mgy"] - 26.0).abs() < 1e-6);
    assert!((m2["fluoro_time_s"] - 10.1).abs() < 1e-9);
    // The table moved 100 mm along the beam: the skin's distance from the source changes and
    // the kerma per mAs follows the inverse square of it.
    r.ok(
        11_500,
        Command::CarmPose {
            orbital_deg: 0.0,
            angular_deg: 0.0,
            table_mm: [0.0, -100.0, 0.0],
        },
    );
    r.ok(12_000, Command::Shot);
    let m3 = r.s.measurements();
    let snap = r.s.snapshot();
    let proj3: sim_core::fluoro::Projection = serde_json::from_value(
        snap.modalities["fluoroscopy"]["images"]
            .as_array()
            .and_then(|v| v.last())
            .unwrap()["projection"]
            .clone(),
    )
    .unwrap();
    let ssd3_m = skin_distance_by_every_triangle_mm(ap_source_mm(&proj3), DVec3::Y) / 1000.0;
    // Moving the table 100 mm along the beam moves the skin 100 mm against the source.
    assert!(
        ((ssd3_m - ssd_m).abs() - 0.1).abs() < 1e-6,
        "{ssd_m} -> {ssd3_m}"
    );
    let ratio = (m3["air_kerma_mgy"] - m2["air_kerma_mgy"]) / m1["air_kerma_mgy"];
    assert!(
        (ratio - (ssd_m / ssd3_m).powi(2)).abs() < 1e-9,
        "inverse square: {ratio} vs {}",
        (ssd_m / ssd3_m).powi(2)
    );
}

/// Twenty straight paramedian trajectories to the posterior epidural space (scanned on this
/// phantom: bone-free lines that cross the ligamentum flavum into the epidural fat), each
/// advanced in 0.5 mm feeds with constant pressure on a saline syringe from the moment the
/// outlet sits in the interspinous ligament: the plunger gives way on the first feed whose end
/// puts the outlet in the epidural fat (within one feed step of the boundary, found by a
/// 0.05 mm march along the same line), and never while the outlet is in ligament or flavum;
/// every path shows the pop (a force drop) through the ligamentum flavum.
#[test]
fn loss_of_resistance_is_felt_at_the_epidural_boundary_on_twenty_trajectories() {
    let reg = region();
    let setback = {
        let p = sim_core::needle::InstrumentProfile::tuohy_18g().opening;
        p.distal_edge_from_tip_mm + 0.5 * p.length_mm
    };
    let mut paths = Vec::new();
    'scan: for tz in [-56.0, -54.0] {
        for tx in [-10.0, -7.0] {
            for dx in [-40.0, -35.0, -30.0, -25.0, -20.0] {
                for dz in [0.0, 10.0, 20.0, 35.0] {
                    let t = DVec3::new(tx, -39.0, tz);
                    let far = t + DVec3::new(dx, -120.0, dz);
                    let dir = (t - far).normalize();
                    let Some(skin) = reg.skin_entry(far, dir, 200.0) else {
                        continue;
                    };
                    // March the outlet along the line: tissues in order, no bone.
                    let mut seq = Vec::new();
                    let mut s = 0.0;
                    while s < (t - skin).length() + 2.0 {
                        let tissue = reg.tissue_at((skin + dir * s).to_array());
                        if seq.last().map(|x: &(Tissue, f64)| x.0) != Some(tissue) {
                            seq.push((tissue, s));
                        }
                        s += 0.05;
                    }
                    let bone = seq.iter().any(|x| x.0 == Tissue::Bone);
                    let flavum = seq.iter().position(|x| x.0 == Tissue::LigamentumFlavum);
                    let epi = seq.iter().position(|x| x.0 == Tissue::EpiduralFat);
                    if let (false, Some(f), Some(e)) = (bone, flavum, epi) {
                        // The syringe goes on in the interspinous ligament, so the line must go
                        // from the ligament straight into the flavum: through muscle between
                        // them the plunger rightly gives way early (a false loss). The syringe
                        // goes on in that last ligament run.
                        let from_ligament = f > 0 && seq[f - 1].0 == Tissue::InterspinousLigament;
                        if e == f + 1 && from_ligament {
                            paths.push((skin, dir, seq[e].1, seq[f - 1].1));
                            if paths.len() == 20 {
                                break 'scan;
                            }
                        }
                    }
                }
            }
        }
    }
    assert_eq!(paths.len(), 20, "trajectories found");
    for (k, (skin, dir, boundary_tip_mm, ligament_mm)) in paths.into_iter().enumerate() {
        // The boundary for the outlet is `setback` deeper for the tip; the 0.05 mm tolerance is the
        // march's resolution.
        let boundary = boundary_tip_mm + setback;
        let mut r = Run::new(env(EPIDURAL), quiet());
        r.ok(
            1,
            Command::NeedlePlace {
                instrument: TUOHY.into(),
                entry_mm: skin.to_array(),
                direction: dir.to_array(),
                bevel_reference: [0.0, 0.0, 1.0],
            },
        );
        let mut t = 1;
        let outlet = |r: &Run| {
            let n = r.s.world().needle.as_ref().unwrap();
            (
                reg.tissue_at(n.state.outlet().centre_mm.to_array()),
                n.state.buried_mm(),
            )
        };
        // Into the ligament that leads to the flavum (a line may graze another ligament
        // sliver first, with muscle after it).
        while outlet(&r).0 != Tissue::InterspinousLigament || outlet(&r).1 < ligament_mm + setback {
            t += 10;
            r.ok(t, Command::NeedleFeed { mm: 0.5 });
            assert!(
                outlet(&r).1 < boundary,
                "path {k}: no ligament before the space"
            );
        }
        t += 10;
        r.ok(
            t,
            Command::Syringe {
                action: SyringeAction::Attach,
                medium: None,
            },
        );
        t += 10;
        let a = r.ok(t, Command::PlungerHold { on: true });
        assert_eq!(a.outcome["lor"]["gave_way"], false, "path {k}");
        let mut pop = false;
        let loss = loop {
            t += 10;
            let a = r.ok(t, Command::NeedleFeed { mm: 0.5 });
            pop |= a.outcome["force"]["pop"] == true;
            let (tissue, depth) = outlet(&r);
            if a.outcome["lor"]["gave_way"] == true {
                break (tissue, depth);
            }
            assert!(depth < boundary + 1.0, "path {k}: no loss by {depth} mm");
        };
        assert_eq!(loss.0, Tissue::EpiduralFat, "path {k}");
        assert!(pop, "path {k}: no force drop through the ligamentum flavum");
        assert!(
            loss.1 >= boundary - 0.05 && loss.1 < boundary + 0.5 + 0.05,
            "path {k}: loss at {} mm, boundary {boundary} mm",
            loss.1
        );
        assert_eq!(r.s.measurements()["lor_confirmed_bool"], 1.0);
        assert_eq!(r.s.measurements()["false_loss_count"], 0.0);
    }
}

/// Targets that name a landmark are the region's landmark, and on the phantom they lie in the
/// tissue the station means: the epidural targets in the epidural fat, the subpedicular target
/// in neither the nerve root nor a vessel (the typed coordinates of the first revisions fell in
/// the dural sac and the L4 nerve root).
#[test]
fn landmark_targets_lie_where_their_names_say() {
    let reg = region();
    for (id, target, landmark, tissue) in [
        (
            EPIDURAL,
            "posterior_epidural_l4_l5",
            "L4_L5_posterior_epidural_space",
            Some(Tissue::EpiduralFat),
        ),
        (
            EPIDURAL,
            "ventral_interlaminar_line_l4_l5",
            "L4_L5_posterior_epidural_space",
            Some(Tissue::EpiduralFat),
        ),
        (
            "l4-left-transforaminal",
            "left_l4_subpedicular",
            "L4_transforaminal_target_left",
            None,
        ),
        (
            "l4-left-transforaminal-vascular-uptake",
            "left_l4_subpedicular",
            "L4_transforaminal_target_left",
            None,
        ),
    ] {
        let e = env(id);
        let p = e.station.targets[target];
        assert_eq!(p, reg.landmarks[landmark], "{id} {target}");
        let at = reg.tissue_at(p);
        match tissue {
            Some(t) => assert_eq!(at, t, "{id} {target}"),
            None => assert!(
                ![
                    Tissue::NerveRoot,
                    Tissue::Vessel,
                    Tissue::Bone,
                    Tissue::Intrathecal
                ]
                .contains(&at),
                "{id} {target} in {at:?}"
            ),
        }
    }
}
