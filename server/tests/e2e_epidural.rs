//! Interlaminar epidurals by hand in headless Chromium (`web-client/tests/e2e_epidural.mjs`):
//! the lumbar and cervical phantom stations, a trajectory planned with the session's needle
//! model, performed on the page (AP view, skin marker, puncture, hub tilt, oblique, loss of
//! resistance, aspiration, submit) and checked against the stored result.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use render_worker::session::region::Region;
use render_worker::session::world;
use render_worker::session::{Backends, SessionConfig, SessionHost, sha256_hex};
use serde_json::Value;
use server::dispatch::Dispatcher;
use server::test_support::{TestDb, test_db};
use server::{AppState, app};
use sim_core::anatomy::phantom::{self, PhantomParams};
use sim_core::fluoro::Projection;
use sim_core::needle::Tissue;
use sim_core::needle::force::POP_DROP_N;

use crate::dispatch::base_workers;
use crate::e2e_browser::{BROWSER_TURN, can_run, run_script, strings};
use crate::records_support::test_config;

/// The phantom meshed at 2 mm, as the render-worker needle-handling tests (at 4 mm the 3.5 mm
/// ligamentum flavum is not resolved).
fn phantom_region() -> Arc<Region> {
    static REGION: std::sync::OnceLock<Arc<Region>> = std::sync::OnceLock::new();
    Arc::clone(REGION.get_or_init(|| {
        // The build the render-worker tests cache by parameter hash in the shared test scratch
        // folder (made here when this binary runs first).
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("phantom-lumbar-2mm");
        let asset =
            phantom::ensure_built_with(&dir, &PhantomParams::with_voxel_mm(2.0), &mut |_| {})
                .expect("phantom");
        Arc::new(Region::from_asset(&asset))
    }))
}

/// A server whose only station is `station_id` from `assets/stations`, on `region`, sessions
/// in-process on the CPU renderer with quantum noise off (as the render-worker test: images of
/// one view differ only where something changed). Returns the address, the database and the
/// stations folder (keep it while the server runs).
async fn phantom_server(
    station_id: &str,
    region: Arc<Region>,
) -> (SocketAddr, TestDb, tempfile::TempDir) {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let file = sim_core::rubric::load_station_dir(&assets)
        .expect("the repository's stations")
        .into_iter()
        .find(|f| f.station.id == station_id)
        .unwrap_or_else(|| panic!("station {station_id}"));
    let stations = tempfile::tempdir().expect("temporary stations folder");
    std::fs::write(
        stations.path().join(format!("{station_id}.toml")),
        &file.text,
    )
    .expect("write the station");
    let mut session = SessionConfig::default();
    session.fluoro.noise = false;
    let host = SessionHost::with_regions(
        vec![(file.station, sha256_hex(file.text.as_bytes()))],
        vec![region],
        Backends::cpu(0),
        4,
        session,
    );
    let dir = stations.path().display().to_string();
    let config = test_config(&[("PAINSIM_STATIONS_DIR", &dir)]);
    let db = test_db().await;
    server::records::prepare(&db.pool, &config.records, true)
        .await
        .expect("stations and demo accounts");
    let state = AppState {
        pool: db.pool.clone(),
        embedded_db: true,
        workers: base_workers(),
        dispatcher: Some(Dispatcher::new(Some(host.clone()), host, None)),
        config,
    };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app(state)).await });
    (addr, db, stations)
}

/// A planned paramedian epidural line: the station, the target, a far point on the line behind
/// the skin, the C-arm's isocentre, the AP view's cranio-caudal angle (whole degrees) and the
/// contralateral oblique's orbital angle.
struct EpiduralPlan {
    station: &'static str,
    target: [f64; 3],
    far: [f64; 3],
    isocentre: [f64; 3],
    ap_angular_deg: f64,
    oblique_orbital_deg: f64,
    /// How far short of the target the 2 mm feeds stop (the session test's approach).
    approach_short_mm: f64,
}

impl EpiduralPlan {
    /// The lumbar plan of render-worker/tests/needle_handling.rs (`scripted_epidural`): the
    /// target in the lateral posterior epidural space left of the midline at L4-L5, the line 30 mm
    /// lateral at 120 mm behind it, the C-arm centred on the L4 body centre.
    fn lumbar(region: &Region) -> EpiduralPlan {
        let target = [-10.0, -39.0, -54.0];
        EpiduralPlan {
            station: "l4-l5-interlaminar-epidural",
            target,
            far: [target[0] - 30.0, target[1] - 120.0, target[2]],
            isocentre: region.landmarks["L4_body_centre"],
            ap_angular_deg: 0.0,
            oblique_orbital_deg: 50.0,
            approach_short_mm: 25.0,
        }
    }

    /// The cervical plan of render-worker/tests/cervical.rs (`scripted_epidural`): the C7-T1
    /// posterior epidural landmark, the line 25 mm left at 100 mm behind it, the C-arm centred on
    /// the target (the station's primary target: the region has no L4), the AP view tilted to
    /// square the C7 inferior endplate to the nearest degree, the oblique at -50 degrees (the
    /// contralateral side of a midline target, see the fluoroscopy scorer).
    fn cervical(region: &Region) -> EpiduralPlan {
        let target = region.landmarks["C7_T1_posterior_epidural_space"];
        let n = render_worker::session::anatomy::endplate_normal(region, "C7", "T1")
            .expect("the C7 inferior endplate");
        let n = n * n.z.signum();
        EpiduralPlan {
            station: "c7-t1-interlaminar-epidural",
            target,
            far: [target[0] - 25.0, target[1] - 100.0, target[2]],
            isocentre: target,
            ap_angular_deg: (-n.y).atan2(n.z).to_degrees().round(),
            oblique_orbital_deg: -50.0,
            // The neck's deep soft tissue lies under the fat as well as between the muscles:
            // the syringe goes on between the muscles, 12 mm short of the target.
            approach_short_mm: 12.0,
        }
    }
}

/// The trajectory of a scripted paramedian epidural (`plan`) in the browser's terms: the
/// skin entry of the planned line as a pixel of the AP image (512 pixels over 300 mm:
/// `Projection::default` at the plan's isocentre and AP angle); the hub tilts that aim from
/// there at the target; the oblique's angle; and the depth at which the syringe goes on: 2 mm
/// feeds up to the plan's approach margin short of the target, then 1 mm feeds until the
/// outlet is in the interspinous ligament, found here with the session's needle model (puncture down the AP
/// beam, the tilt as the browser sends it, in 0.5 degree steps). One more millimetre than the
/// session test asks for the outlet's last millimetre to be in the ligament too: the browser's
/// marker comes from a pixel, a few hundredths of a millimetre from the entry, and the plunger
/// must not give way in the muscle before it. Last, the depth at which the outlet reaches the
/// epidural fat in 0.5 mm feeds (the loss).
fn epidural_trajectory(region: &Region, plan: &EpiduralPlan) -> Value {
    let (target, far) = (plan.target, plan.far);
    let toward: Vec<f64> = (0..3).map(|i| target[i] - far[i]).collect();
    let entry = region
        .skin_entry(far.into(), [toward[0], toward[1], toward[2]].into(), 200.0)
        .expect("the planned line meets the skin")
        .to_array();
    let projection = Projection {
        isocentre_mm: plan.isocentre,
        angular_deg: plan.ap_angular_deg,
        ..Projection::default()
    };
    let pixel = projection
        .project_point(entry)
        .expect("the entry is in the AP image");
    let d: Vec<f64> = (0..3).map(|i| target[i] - entry[i]).collect();
    let half = |deg: f64| (2.0 * deg).round() / 2.0;
    let (cc, ml) = (
        half(d[2].atan2(d[1]).to_degrees() - plan.ap_angular_deg),
        half(-d[0].atan2(d[1]).to_degrees()),
    );
    let (sb, cb) = plan.ap_angular_deg.to_radians().sin_cos();
    // The needle as the session moves it: punctured down the AP beam (+y tilted by the AP
    // angle) with the default bevel (cranial).
    let profile = world::profile_for_kind("tuohy-needle").expect("a Tuohy profile");
    let mut needle = world::new_needle(profile, entry, [0.0, cb, sb], [0.0, 0.0, 1.0])
        .expect("a needle at the entry");
    for (deg, axis) in [(cc, [0.0, 0.0, 1.0]), (ml, [-1.0, 0.0, 0.0])] {
        if deg != 0.0 {
            let toward = axis.map(|v: f64| v * deg.signum());
            needle.tilt(toward.into(), deg.abs()).expect("tilt");
        }
    }
    let bones = region.bones();
    let approach = d.iter().map(|v| v * v).sum::<f64>().sqrt() - plan.approach_short_mm;
    while needle.buried_mm() < approach {
        needle.feed(2.0, &bones);
    }
    let in_ligament = |n: &sim_core::needle::NeedleState, back_mm: f64| {
        let o = n.outlet();
        let p = o.centre_mm - o.axis * back_mm;
        region.tissue_at(p.to_array()) == Tissue::InterspinousLigament
    };
    for _ in 0..40 {
        if in_ligament(&needle, 0.0) && in_ligament(&needle, 1.0) {
            break;
        }
        needle.feed(1.0, &bones);
    }
    assert!(in_ligament(&needle, 1.0), "{}", needle.buried_mm());
    let advance_mm = needle.buried_mm();
    // Where the plunger held under pressure gives way: the outlet in the epidural fat, sampled
    // after each 0.5 mm feed as the session does.
    for _ in 0..80 {
        needle.feed(0.5, &bones);
        if region.tissue_at(needle.outlet().centre_mm.to_array()) == Tissue::EpiduralFat {
            break;
        }
    }
    serde_json::json!({
        "station": plan.station,
        "apAngularDeg": plan.ap_angular_deg,
        "lorDepthMm": needle.buried_mm(),
        "markerPixel": pixel,
        "tiltCcDeg": cc,
        "tiltMlDeg": ml,
        "tiltMlExactDeg": -d[0].atan2(d[1]).to_degrees(),
        "advanceMm": advance_mm.round(),
        "obliqueOrbitalDeg": plan.oblique_orbital_deg,
        "entryMm": entry,
    })
}

/// A whole L4-L5 interlaminar epidural through the UI only (`web-client/tests/
/// e2e_epidural.mjs`) on the phantom: AP shots, the skin marker dragged on the image and seen
/// on the next shot, the puncture, hub tilts by touch and keys, the advance, the contralateral
/// oblique, loss of resistance with the syringe held under pressure while advancing,
/// aspiration and the submit; the scores come from the session's measurements.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn interlaminar_epidural_by_hand_in_headless_chromium() {
    if !can_run("interlaminar_epidural_by_hand_in_headless_chromium") {
        return;
    }
    let _turn = BROWSER_TURN.lock().await;
    let region = phantom_region();
    let trajectory = epidural_trajectory(&region, &EpiduralPlan::lumbar(&region));
    eprintln!("epidural trajectory: {trajectory}");
    let (addr, db, _stations) = phantom_server("l4-l5-interlaminar-epidural", region).await;
    let report = run_script(
        "e2e_epidural.mjs",
        addr,
        "epidural",
        &[("E2E_EPIDURAL", &trajectory.to_string())],
    )
    .await;
    eprintln!("epidural in the browser: {report}");
    assert_epidural_by_hand(&report, &trajectory);
    // With the keys the hub stands at the planned tilt (the planned line keeps its height, so
    // the tilt is across only and the hub's deviation is its size).
    assert_eq!(trajectory["tiltCcDeg"], 0.0, "{trajectory}");
    let ml = trajectory["tiltMlDeg"].as_f64().unwrap();
    assert_eq!(
        report["hub_text"],
        format!("{:.1}°", ml.abs()),
        "{report:#}"
    );
    let stored: Value = sqlx::query_scalar("SELECT measurements FROM technical_results")
        .fetch_one(&db.pool)
        .await
        .unwrap();
    assert_eq!(stored["lor_confirmed_bool"], 1.0, "{stored:#}");
}

/// What both epidurals by hand must show (`report` from `e2e_epidural.mjs`, `trajectory` from
/// [`epidural_trajectory`]).
fn assert_epidural_by_hand(report: &Value, trajectory: &Value) {
    let steps = strings(&report["steps"]);
    assert_eq!(
        steps,
        [
            "session open",
            "ap",
            "marker",
            "punctured",
            "tilted",
            "oblique",
            "advanced",
            "loss of resistance",
            "aspirated",
            "submitted"
        ]
    );
    // The marker: acknowledged, and seen on the next shot of the same view near its pixel (a
    // 4 x 4 block within 4 blocks changed by more than 5 grey levels, the render-worker test's
    // threshold for a 3 x 3 pixel mean) while no block farther than 12 blocks did (quantum noise
    // is off; the image's windowing follows its content, so far blocks move by a few levels:
    // 2.3 measured).
    let m = &report["marker"];
    assert!(m["text"].as_str().unwrap().contains("on the skin"), "{m:#}");
    assert!(
        m["change_near"].as_f64().unwrap() > 5.0,
        "the marker did not show near its pixel: {m:#}"
    );
    assert!(m["change_far"].as_f64().unwrap() < 5.0, "{m:#}");
    assert_eq!(m["cursor_hidden_after_shot"], true, "{m:#}");
    // The two-finger drag tilted the hub by 3 degrees (24 px at 8 px a degree), the button by 2
    // more, the Shift + drag of 8 px by 1 more.
    assert_eq!(report["touch_hub"], "3.0°", "{report:#}");
    assert_eq!(report["button_hub"], "5.0°", "{report:#}");
    assert_eq!(report["drag_hub"], "6.0°", "{report:#}");
    // The plunger gave way under held pressure where the model puts the outlet into the
    // epidural fat (within one 0.5 mm feed: the browser's entry is a few hundredths of a
    // millimetre off the planned one), and the panels never told where the tip was.
    let lor = &report["lor"];
    assert!(
        lor["text"].as_str().unwrap().contains("gives way"),
        "{lor:#}"
    );
    let depth: f64 = lor["depth"]
        .as_str()
        .unwrap()
        .trim_end_matches(" mm")
        .parse()
        .unwrap();
    let planned = trajectory["lorDepthMm"].as_f64().unwrap();
    assert!((depth - planned).abs() <= 0.5, "{depth} vs {planned}");
    // The force trace shows the pop: a drop between consecutive samples larger than the force
    // model's pop threshold.
    let trace: Vec<f64> = lor["trace"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let drop = trace.windows(2).map(|w| w[0] - w[1]).fold(0.0, f64::max);
    assert!(drop > POP_DROP_N, "largest drop {drop} N: {lor:#}");
    assert!(
        report["telltales"].as_array().unwrap().is_empty(),
        "{report:#}"
    );
    assert!(
        !report["aspirate_text"].as_str().unwrap().is_empty(),
        "{report:#}"
    );
    // The session's measurements, as the session test's: one skin puncture, loss of resistance
    // confirmed and no false loss, no dural puncture, no redirection or bone contact,
    // aspiration done, a dose from the shots.
    let ms = &report["measurements"];
    let v = |k: &str| {
        ms[k]
            .as_f64()
            .unwrap_or_else(|| panic!("measurement {k}: {ms:#}"))
    };
    assert_eq!(v("skin_punctures_count"), 1.0, "{ms:#}");
    assert_eq!(v("lor_confirmed_bool"), 1.0, "{ms:#}");
    assert_eq!(v("dural_puncture_bool"), 0.0, "{ms:#}");
    assert_eq!(v("aspiration_done_bool"), 1.0, "{ms:#}");
    assert_eq!(v("false_loss_count"), 0.0, "{ms:#}");
    assert_eq!(v("redirections_count"), 0.0, "{ms:#}");
    assert_eq!(v("bone_contacts_count"), 0.0, "{ms:#}");
    // Five shots of 0.1 s each (the session test's four, and a first AP shot on which the
    // brightness control settles).
    assert!((v("fluoro_time_s") - 0.5).abs() < 1e-9, "{ms:#}");
    for k in ["air_kerma_mgy", "kerma_area_product_gycm2"] {
        assert!(v(k) > 0.0, "{k}: {ms:#}");
    }
    assert!(
        !report["dose_text"].as_str().unwrap().starts_with('–'),
        "{report:#}"
    );
    assert_eq!(report["command_errors"], 0, "{report:#}");
    assert_eq!(report["accessible"]["unlabeled_buttons"], 0, "{report:#}");
    assert_eq!(report["accessible"]["unlabeled_inputs"], 0, "{report:#}");
    assert!(
        report["console_errors"].as_array().unwrap().is_empty(),
        "{report:#}"
    );
}

/// The cervical phantom meshed at 1.5 mm, as the render-worker cervical tests (at 2 mm its
/// 2.5 mm flavum and posterior epidural space are about a voxel thick).
fn cervical_region() -> Arc<Region> {
    use sim_core::anatomy::phantom::cervical;
    // Cached as the lumbar one above (one browser test uses it, so no lock is needed).
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("phantom-cervical-1.5mm");
    let asset =
        cervical::ensure_built_with(&dir, &cervical::params_with_voxel_mm(1.5), &mut |_| {})
            .expect("cervical phantom");
    Arc::new(Region::from_asset(&asset))
}

/// A whole C7-T1 interlaminar epidural through the UI only, on the cervical phantom: the same
/// script and checks as the L4-L5 one, with the AP view tilted to square the C7 inferior
/// endplate; then the cervical station's alignment and target criteria from the session's
/// measurements.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cervical_interlaminar_epidural_by_hand_in_headless_chromium() {
    if !can_run("cervical_interlaminar_epidural_by_hand_in_headless_chromium") {
        return;
    }
    let _turn = BROWSER_TURN.lock().await;
    let region = cervical_region();
    let trajectory = epidural_trajectory(&region, &EpiduralPlan::cervical(&region));
    eprintln!("cervical epidural trajectory: {trajectory}");
    let (addr, db, _stations) = phantom_server("c7-t1-interlaminar-epidural", region).await;
    let report = run_script(
        "e2e_epidural.mjs",
        addr,
        "cervical-epidural",
        &[("E2E_EPIDURAL", &trajectory.to_string())],
    )
    .await;
    eprintln!("cervical epidural in the browser: {report}");
    assert_epidural_by_hand(&report, &trajectory);
    let ms = &report["measurements"];
    let v = |k: &str| {
        ms[k]
            .as_f64()
            .unwrap_or_else(|| panic!("measurement {k}: {ms:#}"))
    };
    // The station's pass bounds: AP within 2 degrees of the endplate (the whole-degree AP angle
    // is within half a degree of square), the oblique at 50, the tip within 3 mm of the target.
    assert!(v("ap_endplate_tilt_deg") <= 2.0, "{ms:#}");
    assert_eq!(v("clo_angle_deg"), 50.0, "{ms:#}");
    assert!(v("tip_to_target_mm") <= 3.0, "{ms:#}");
    let stored: Value = sqlx::query_scalar("SELECT measurements FROM technical_results")
        .fetch_one(&db.pool)
        .await
        .unwrap();
    assert_eq!(stored["lor_confirmed_bool"], 1.0, "{stored:#}");
}
