//! The contrast modality in sessions on the procedural phantom: each compartment's
//! pattern from a tip placed in it, bad input refused, bit-identical replay with injections and
//! ticks, frames that darken where the contrast is (CPU reference and GPU), and stations without
//! contrast that never build a model.
//!
//! The region is the phantom meshed at 4 mm (built in memory once per test binary); the
//! transport grid is the 1 mm crop the modality uses. Volumes and times are small so each test
//! stays within seconds in the dev profile.

use std::collections::BTreeSet;
use std::sync::{Arc, OnceLock};

use render_worker::session::modalities::contrast::{self, QUANTUM_MS};
use render_worker::session::*;
use sim_core::compare::{Compare, Tolerance};
use sim_core::contrast::{ContrastGrid, Domain};
use sim_core::fluoro::Projection;

use crate::driver::Run;
use crate::sessions::config;

/// The phantom meshed at 4 mm, loaded once per test binary (shared with the ultrasound tests).
pub(crate) fn region() -> Arc<Region> {
    static REGION: OnceLock<Arc<Region>> = OnceLock::new();
    Arc::clone(REGION.get_or_init(|| {
        use sim_core::anatomy::phantom::{self, PhantomParams};
        // Cached by parameter hash in the shared test scratch folder.
        let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("phantom-lumbar-4mm");
        let asset =
            phantom::ensure_built_with(&dir, &PhantomParams::with_voxel_mm(4.0), &mut |_| {})
                .unwrap();
        Arc::new(Region::from_asset(&asset))
    }))
}

/// A station from `assets/stations` with its targets resolved on [`region`].
pub(crate) fn station(id: &str) -> Arc<StationContext> {
    station_on(id, &region())
}

/// A station from `assets/stations` with its targets resolved on `region`.
pub(crate) fn station_on(id: &str, region: &Region) -> Arc<StationContext> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let file = sim_core::rubric::load_station_dir(&dir)
        .unwrap()
        .into_iter()
        .find(|f| f.station.id == id)
        .unwrap_or_else(|| panic!("station {id}"));
    Arc::new(StationContext::new(
        file.station,
        sha256_hex(file.text.as_bytes()),
        region,
    ))
}

const EPIDURAL: &str = "l4-l5-interlaminar-epidural";
const TRANSFORAMINAL: &str = "l4-left-transforaminal";

fn env_of(id: &str, backends: Backends) -> SessionEnv {
    SessionEnv::new(station(id), region(), backends)
}

fn quiet_config() -> SessionConfig {
    let mut c = config();
    c.fluoro.noise = false;
    c
}

fn axis_dir(axis: usize) -> [f64; 3] {
    let mut d = [0.0; 3];
    d[axis] = 1.0;
    d
}

/// Cells of `domain` whose neighbours within `pure` cells along `axis` and `across` cells across
/// it are of the same domain, nearest `near` first.
fn sites(
    g: &ContrastGrid,
    domain: Domain,
    near: [f64; 3],
    axis: usize,
    pure: i64,
    across: i64,
) -> Vec<[f64; 3]> {
    let d = g.grid.dims;
    let same = |q: [i64; 3]| {
        (0..3).all(|b| q[b] >= 0 && q[b] < d[b] as i64)
            && g.domain[g.grid.index(q[0] as usize, q[1] as usize, q[2] as usize)] == Some(domain)
    };
    let mut out: Vec<(f64, [f64; 3])> = (0..g.len())
        .filter(|&i| g.domain[i] == Some(domain))
        .filter(|&i| {
            let ijk = g.grid.ijk(i).map(|v| v as i64);
            (-pure..=pure).all(|s| {
                (-across..=across).all(|t| {
                    (0..3).filter(|&a| a != axis).all(|a| {
                        let mut q = ijk;
                        q[axis] += s;
                        q[a] += t;
                        same(q)
                    })
                })
            })
        })
        .map(|i| {
            let [x, y, z] = g.grid.ijk(i);
            let p = g.grid.voxel_center_mm(x, y, z);
            ((0..3).map(|a| (p[a] - near[a]).powi(2)).sum::<f64>(), p)
        })
        .collect();
    out.sort_by(|a, b| a.0.total_cmp(&b.0));
    out.into_iter().map(|(_, p)| p).collect()
}

/// Places the spinal needle 3 mm behind `tip` along `axis` and feeds it there; true when the tip
/// arrived within 0.5 mm.
fn place_tip(r: &mut Run, t_ms: u64, tip: [f64; 3], axis: usize, instrument: &str) -> bool {
    let dir = axis_dir(axis);
    let entry: [f64; 3] = std::array::from_fn(|a| tip[a] - 3.0 * dir[a]);
    let bevel = axis_dir((axis + 1) % 3);
    let placed = r.try_apply(
        t_ms,
        Command::NeedlePlace {
            instrument: instrument.into(),
            entry_mm: entry,
            direction: dir,
            bevel_reference: bevel,
        },
    );
    if let Err(e) = placed {
        eprintln!("placing at {entry:?}: {e}");
        return false;
    }
    r.ok(t_ms, Command::NeedleFeed { mm: 3.0 });
    let at = needle_tip(&r.s);
    let miss = (0..3).map(|a| (at[a] - tip[a]).powi(2)).sum::<f64>().sqrt();
    if miss >= 0.5 {
        eprintln!("tip {at:?} missed {tip:?} by {miss:.2} mm");
    }
    miss < 0.5
}

fn needle_tip(s: &Session) -> [f64; 3] {
    s.world().needle.as_ref().unwrap().state.tip_mm().to_array()
}

fn inject(agent: Agent, volume_ml: f64, rate_ml_per_s: f64) -> Command {
    Command::Inject {
        agent,
        volume_ml,
        rate_ml_per_s,
    }
}

/// A session of `id` with the tip in the first usable site of `domain` near `near`, an injection
/// of `volume_ml` at 0.5 mL/s, and a tick just after it ends.
fn pattern_session(
    id: &str,
    domain: Domain,
    near: [f64; 3],
    axis: usize,
    pure: i64,
    across: i64,
    volume_ml: f64,
) -> Run {
    let st = station(id);
    let g = contrast::transport_grid(&region(), &st).expect("phantom grid");
    for tip in sites(&g, domain, near, axis, pure, across)
        .into_iter()
        .take(12)
    {
        let mut r = Run::new(env_of(id, Backends::cpu(1)), quiet_config());
        let needle = if id == EPIDURAL {
            "tuohy-20g-89"
        } else {
            "spinal-22g-89"
        };
        if !place_tip(&mut r, 0, tip, axis, needle) {
            continue;
        }
        if let Err(e) = r.try_apply(100, inject(Agent::Contrast, volume_ml, 0.5)) {
            eprintln!("{domain:?} at {tip:?}: {e}");
            continue;
        }
        let end = 100 + (volume_ml / 0.5 * 1000.0) as u64 + 2 * QUANTUM_MS;
        r.ok(end, Command::Tick);
        return r;
    }
    panic!("no usable {domain:?} site near {near:?}");
}

fn epidural_target() -> [f64; 3] {
    station(EPIDURAL).targets["posterior_epidural_l4_l5"]
}

#[test]
fn each_compartment_gives_its_pattern_and_the_scorers_name_it() {
    let c = epidural_target();
    // (station, domain, needle axis, purity along and across it, volume mL, the flag that must
    // be set, near). The thin compartments (a one-cell subdural layer, 0.9 mm vessels) take the
    // transforaminal station's 22 G spinal needle, whose opening fits inside them; the Tuohy's
    // 18 G opening straddles them (a mixed outlet).
    let cases = [
        (EPIDURAL, Domain::Epidural, 1, 2, 1, 0.2, None, c),
        (
            EPIDURAL,
            Domain::Intrathecal,
            1,
            2,
            1,
            0.1,
            Some("intrathecal_contrast_bool"),
            [c[0], c[1] + 10.0, c[2]],
        ),
        (
            TRANSFORAMINAL,
            Domain::Subdural,
            2,
            1,
            0,
            0.05,
            Some("subdural_contrast_bool"),
            c,
        ),
        (
            TRANSFORAMINAL,
            Domain::Vascular,
            2,
            1,
            0,
            0.05,
            Some("intravascular_uptake_bool"),
            c,
        ),
        (
            EPIDURAL,
            Domain::Pooling,
            1,
            3,
            1,
            0.1,
            None,
            [c[0] + 15.0, c[1] - 18.0, c[2]],
        ),
    ];
    // Every compartment flag: each case sets its own and must leave the others at 0.
    let flags = [
        "intrathecal_contrast_bool",
        "subdural_contrast_bool",
        "intravascular_uptake_bool",
        "intraneural_contrast_bool",
    ];
    for (id, domain, axis, pure, across, vol, flag, near) in cases {
        let started = std::time::Instant::now();
        let r = pattern_session(id, domain, near, axis, pure, across, vol);
        let m = r.s.measurements();
        eprintln!(
            "{domain:?}: {:.1} s; pattern {} levels {} entered epidural {:.3} intrathecal {:.3} subdural {:.3} vascular {:.3} pooling {:.3}; volume {} mL",
            started.elapsed().as_secs_f64(),
            m["contrast_pattern_count"],
            m["epidural_levels_count"],
            m["iodine_entered_epidural_fraction"],
            m["iodine_entered_intrathecal_fraction"],
            m["iodine_entered_subdural_fraction"],
            m["iodine_entered_vascular_fraction"],
            m["iodine_entered_pooling_fraction"],
            m["injected_volume_ml"],
        );
        // The delivered volume to the model's stopping tolerance (1e-9 of the rate times a
        // substep).
        assert!((m["injected_volume_ml"] - vol).abs() < 1e-6, "{domain:?}");
        let name = format!("iodine_entered_{}_fraction", domain.name());
        assert!(m[&name] > 0.5, "{domain:?}: {name} = {}", m[&name]);
        for f in flags {
            if Some(f) != flag {
                assert_eq!(m[f], 0.0, "{domain:?}: {f}");
            }
        }
        if let Some(f) = flag {
            assert_eq!(m[f], 1.0, "{domain:?}: {f}");
        }
        match domain {
            Domain::Epidural => {
                assert_eq!(m["contrast_pattern_count"], 1.0);
                assert_eq!(m["epidural_spread_bool"], 1.0);
                assert!(m["epidural_levels_count"] >= 1.0);
            }
            Domain::Pooling => {
                assert_eq!(m["contrast_pattern_count"], 6.0);
                assert_eq!(m["epidural_spread_bool"], 0.0);
            }
            _ => {}
        }
    }
}

#[test]
fn bad_injections_are_refused_naming_the_field() {
    let mut r = Run::new(env_of(EPIDURAL, Backends::cpu(1)), quiet_config());
    let cases = [
        (inject(Agent::Contrast, -1.0, 0.5), "command.volume_ml"),
        (inject(Agent::Contrast, f64::NAN, 0.5), "command.volume_ml"),
        (inject(Agent::Contrast, 500.0, 0.5), "command.volume_ml"),
        (inject(Agent::Saline, 1.0, 0.0), "command.rate_ml_per_s"),
        (
            inject(Agent::Saline, 1.0, f64::INFINITY),
            "command.rate_ml_per_s",
        ),
        (
            inject(Agent::LocalAnaesthetic, 1.0, 50.0),
            "command.rate_ml_per_s",
        ),
        (
            inject(Agent::DilutedContrast { stock_percent: 0 }, 1.0, 0.5),
            "command.agent.stock_percent",
        ),
        // No needle at all, then a needle placed on the skin but not in the body.
        (inject(Agent::Contrast, 1.0, 0.5), "command.type"),
    ];
    for (c, field) in cases {
        let e = r.try_apply(0, c.clone()).unwrap_err();
        assert_eq!(e.field, field, "{c:?}: {e}");
    }
    let c = epidural_target();
    r.ok(
        0,
        Command::NeedlePlace {
            instrument: "tuohy-20g-89".into(),
            entry_mm: [c[0], c[1] - 40.0, c[2]],
            direction: [0.0, 1.0, 0.0],
            bevel_reference: [1.0, 0.0, 0.0],
        },
    );
    let e = r
        .try_apply(0, inject(Agent::Contrast, 1.0, 0.5))
        .unwrap_err();
    assert_eq!(
        (e.field.as_str(), e.code),
        ("command.type", ErrorCode::State)
    );
    assert!(e.message.contains("no needle in the body"), "{e}");
    // A needle in the body outside the transport crop: the needle is named, its tip's
    // position is not (the message reaches the learner's browser).
    r.ok(0, Command::NeedleFeed { mm: 2.0 });
    let e = r
        .try_apply(0, inject(Agent::Contrast, 1.0, 0.5))
        .unwrap_err();
    assert_eq!(e.field, "needle", "{e}");
    assert!(!e.message.contains('['), "no coordinates: {e}");
    assert!(r.s.world().injections.is_empty());
    assert_eq!(r.s.log().len(), 2, "only the needle commands are logged");
}

/// The script of the replay and imaging tests: live fluoroscopy over an epidural injection in
/// ticks, a stop, a saline flush, a needle move and a shot.
fn script(tip: [f64; 3]) -> Vec<(u64, Command)> {
    let entry = [tip[0], tip[1] - 3.0, tip[2]];
    let mut s = vec![
        (
            0,
            Command::NeedlePlace {
                instrument: "tuohy-20g-89".into(),
                entry_mm: entry,
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
        ),
        (0, Command::NeedleFeed { mm: 3.0 }),
        (50, Command::Live { on: true }),
        (100, inject(Agent::Contrast, 0.3, 0.5)),
    ];
    for k in 1..=6 {
        s.push((100 + 130 * k, Command::Tick));
    }
    s.extend([
        (950, Command::InjectStop),
        (1000, inject(Agent::Saline, 0.05, 0.5)),
        (1250, Command::Tick),
        (1300, Command::NeedleWithdraw { mm: 1.0 }),
        (1400, Command::Live { on: false }),
        (1500, Command::Shot),
    ]);
    s
}

fn epidural_tip() -> [f64; 3] {
    let st = station(EPIDURAL);
    let g = contrast::transport_grid(&region(), &st).expect("grid");
    sites(&g, Domain::Epidural, epidural_target(), 1, 3, 1)[0]
}

fn run_script(env: SessionEnv, steps: &[(u64, Command)]) -> (Run, Vec<RenderedView>) {
    let mut r = Run::new(env, quiet_config());
    let views: BTreeSet<ViewId> = [ViewId::FLUOROSCOPY].into();
    let mut frames = Vec::new();
    for (t, c) in steps {
        r.ok(*t, c.clone());
        frames.extend(r.s.render_dirty(&views).unwrap());
    }
    (r, frames)
}

#[test]
fn replay_with_injections_and_ticks_is_bit_identical() {
    let steps = script(epidural_tip());
    let env = || env_of(EPIDURAL, Backends::cpu(1));
    let initial = Session::new(env(), quiet_config()).snapshot();
    let (live, frames) = run_script(env(), &steps);
    let m = live.s.measurements();
    assert!(m["injected_volume_ml"] > 0.2, "{m:?}");
    // A command rejected by the session state (after the clock moved for it) changes nothing:
    // its time is not logged, and stepping on the fixed time grid makes the model independent
    // of how commands chunk the clock.
    let mut probe = run_script(env(), &steps[..5]).0;
    let e = probe
        .try_apply(
            300,
            Command::NeedlePlace {
                instrument: "tuohy-20g-89".into(),
                entry_mm: [0.0; 3],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
        )
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::State);
    for (t, c) in &steps[5..] {
        probe.ok(*t, c.clone());
    }
    assert_eq!(probe.s.snapshot().to_bytes(), live.s.snapshot().to_bytes());
    // Replay from the initial snapshot and from one in the middle.
    let replayed = Session::restore(env(), &initial, live.s.log()).unwrap();
    assert_eq!(replayed.snapshot().to_bytes(), live.s.snapshot().to_bytes());
    assert_eq!(replayed.measurements(), m);
    let (half, _) = run_script(env(), &steps[..8]);
    let mut restored = Session::restore(env(), &half.s.snapshot(), live.s.log()).unwrap();
    assert_eq!(restored.snapshot().to_bytes(), live.s.snapshot().to_bytes());
    assert_eq!(restored.measurements(), m);
    let views: BTreeSet<ViewId> = [ViewId::FLUOROSCOPY].into();
    let last = restored.render_dirty(&views).unwrap().pop().unwrap();
    assert_eq!(last.image, frames.last().unwrap().image);
    // Live frames came while the contrast moved, one per new field, not on idle ticks.
    assert!(frames.len() >= 6, "{} frames", frames.len());
}

/// Mean grey level in a square of `half` pixels around `px`.
pub(crate) fn mean_around(image: &ViewImage, px: [f64; 2], half: i64) -> f64 {
    let (w, h) = (i64::from(image.width), i64::from(image.height));
    let (cx, cy) = (px[0] as i64, px[1] as i64);
    let mut sum = 0.0;
    let mut n = 0.0;
    for y in (cy - half).max(0)..=(cy + half).min(h - 1) {
        for x in (cx - half).max(0)..=(cx + half).min(w - 1) {
            sum += f64::from(image.pixels[(y * w + x) as usize]);
            n += 1.0;
        }
    }
    sum / n
}

pub(crate) fn last_projection(s: &Session) -> Projection {
    let snap = s.snapshot();
    let img = snap.modalities["fluoroscopy"]["images"]
        .as_array()
        .and_then(|a| a.last())
        .cloned()
        .unwrap();
    serde_json::from_value(img["projection"].clone()).unwrap()
}

/// Frames of the script's live run: the first (before any contrast) and the one when the
/// injection stopped, with the darkening measured where the tip projects.
fn darkening(env: SessionEnv, tip: [f64; 3]) -> (ViewImage, ViewImage, f64) {
    let steps = script(tip);
    let (r, frames) = run_script(env, &steps[..10]);
    let p = last_projection(&r.s);
    let px = p.project_point(tip).unwrap();
    let before = frames.first().unwrap().image.clone();
    let after = frames.last().unwrap().image.clone();
    let d = mean_around(&before, px, 2) - mean_around(&after, px, 2);
    (before, after, d)
}

#[test]
fn fluoroscopy_darkens_where_the_contrast_is_on_cpu_and_gpu() {
    let tip = epidural_tip();
    let (before, after, d) = darkening(env_of(EPIDURAL, Backends::cpu(0)), tip);
    let far = mean_around(&before, [8.0, 8.0], 4) - mean_around(&after, [8.0, 8.0], 4);
    eprintln!("CPU: darkening at the tip {d:.1} grey levels, in a far corner {far:.2}");
    assert!(d > 3.0, "contrast must darken the image at the tip: {d}");
    // Elsewhere only the automatic brightness moves (it meters the whole frame).
    assert!(d > 5.0 * far.abs(), "and darken only there: {d} vs {far}");
    let Some(ctx) = render_worker::gpu::context_for_tests() else {
        return;
    };
    let (gpu_before, gpu_after, gd) = darkening(env_of(EPIDURAL, Backends::gpu(ctx)), tip);
    let within_one = |cpu: &ViewImage, gpu: &ViewImage| {
        Compare::image(cpu.width as usize, cpu.height as usize)
            .tolerance(Tolerance::absolute(1.0))
            .all(&gpu.pixels, &cpu.pixels)
            .expect("frames of one size")
            .fraction_within()
    };
    let (w0, w1) = (
        within_one(&before, &gpu_before),
        within_one(&after, &gpu_after),
    );
    eprintln!(
        "GPU: darkening {gd:.1}; pixels within one grey level of the CPU: {:.1} % before, {:.1} % with contrast",
        100.0 * w0,
        100.0 * w1
    );
    // The phantom's 4 mm meshes have many thin silhouettes, supersampled differently by the two
    // renderers (measured 91 % of pixels within one grey level without contrast when written;
    // the demo region's boxes reach 98.7 %, render-worker/tests/sessions.rs). The iodine march
    // (midpoint rule, about 1e-3 in ln T) must add no disagreement of its own: the frame with
    // contrast agrees as well as the one without (to 1 %), and the darkening at the tip agrees
    // within one grey level.
    assert!(w1 >= w0 - 0.01, "{w1} vs {w0}");
    // And the renderers agree at all: at least 90 % of pixels within one grey level without
    // contrast (measured 91 % when written and 92.2 % on lavapipe now; a half-pixel shift of the
    // detector grid or a lost supersample drops it far below).
    assert!(
        w0 >= 0.90,
        "GPU and CPU agree on only {:.1} % of pixels",
        100.0 * w0
    );
    assert!((gd - d).abs() <= 1.0, "GPU {gd} vs CPU {d}");
}

#[test]
fn a_station_without_contrast_builds_no_contrast_model() {
    let mut r = Run::new(env_of("l4-l5-left-facet", Backends::cpu(1)), quiet_config());
    assert_eq!(r.s.modality_names(), ["fluoroscopy"]);
    let e = r
        .try_apply(0, inject(Agent::Contrast, 0.5, 0.5))
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::ModalityUnavailable);
    assert!(r.s.world().iodine.is_none());
    assert!(!r.s.snapshot().modalities.contains_key("contrast"));
    // A contrast station builds its model only when fluid first moves (or the dura is
    // punctured): an idle contrast session has an empty state and no field.
    let mut c = Run::new(env_of(EPIDURAL, Backends::cpu(1)), quiet_config());
    assert_eq!(c.s.modality_names(), ["fluoroscopy", "contrast"]);
    c.ok(5000, Command::Tick);
    assert!(c.s.world().iodine.is_none());
    assert_eq!(
        c.s.snapshot().modalities["contrast"],
        serde_json::json!({ "events": [] })
    );
    assert!(!c.s.measurements().contains_key("intrathecal_contrast_bool"));
}

/// The analytic demo region (boxes, no phantom) with a station that lists contrast: one uniform
/// epidural box along the demo's posterior approach, so whole-process tests (the server's
/// browser test) inject in milliseconds and see the contrast live.
#[test]
fn the_demo_station_with_contrast_injects_and_shows_it_live() {
    use render_worker::session::demo::{demo_region, demo_station};
    let region = Arc::new(demo_region());
    let (st, sha) = demo_station(&["contrast"]);
    let env = SessionEnv::new(
        Arc::new(StationContext::new(st, sha, &region)),
        region,
        Backends::cpu(1),
    );
    let steps = [
        (0, Command::Technique { kvp: 80, ma: 20.0 }),
        (
            0,
            Command::NeedlePlace {
                instrument: "spinal-22g".into(),
                entry_mm: [12.0, -78.0, 0.0],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
        ),
        (0, Command::NeedleFeed { mm: 15.0 }),
        (100, Command::Live { on: true }),
        (200, inject(Agent::Contrast, 0.5, 0.5)),
        (700, Command::Tick),
        (1300, Command::InjectStop),
        (3500, Command::Tick),
    ];
    let (r, frames) = run_script(env, &steps);
    let m = r.s.measurements();
    assert!((m["injected_volume_ml"] - 0.5).abs() < 1e-6, "{m:?}");
    assert_eq!(m["contrast_pattern_count"], 1.0);
    let tip = needle_tip(&r.s);
    let px = last_projection(&r.s).project_point(tip).unwrap();
    let (first, last) = (
        &frames.first().unwrap().image,
        &frames.last().unwrap().image,
    );
    let d = mean_around(first, px, 3) - mean_around(last, px, 3);
    eprintln!(
        "demo contrast: {} frames, darkening at the tip {d:.1}",
        frames.len()
    );
    assert!(d > 10.0, "{d}");
    // Live on (pulses at 7.5 per second from 100 ms), then one frame per pulse with a newer
    // field: the injection's start at 200 ms falls in the pulse live-on imaged, so the tick at
    // 700 ms images it; then the stop and the settling tick.
    assert_eq!(frames.len(), 4);
}

/// The vascular-uptake station: a test dose into a radicular vessel, then the needle
/// repositioned into the epidural space and a second dose. The per-injection scorers see one
/// vascular injection that was managed and a clean last one; injecting again from the same spot
/// is not managed.
#[test]
fn the_vascular_uptake_station_scores_recognition_and_repositioning() {
    const ID: &str = "l4-left-transforaminal-vascular-uptake";
    let st = station(ID);
    let target = st.targets["left_l4_subpedicular"];
    let g = contrast::transport_grid(&region(), &st).expect("grid");
    let vessels = sites(&g, Domain::Vascular, target, 2, 1, 0);
    let epidural = sites(&g, Domain::Epidural, target, 1, 2, 1);
    let dose = |r: &mut Run, t: u64, ml: f64| {
        r.try_apply(t, inject(Agent::Contrast, ml, 0.5))
            .map(|_| {
                r.ok(
                    t + (ml / 0.5 * 1000.0) as u64 + 2 * QUANTUM_MS,
                    Command::Tick,
                )
            })
            .is_ok()
    };
    let mut tried = 0;
    for v in vessels.iter().take(8) {
        let mut r = Run::new(env_of(ID, Backends::cpu(1)), quiet_config());
        if !place_tip(&mut r, 0, *v, 2, "spinal-22g-89") || !dose(&mut r, 100, 0.05) {
            continue;
        }
        let m = r.s.measurements();
        if m["last_injection_vascular_bool"] != 1.0 {
            continue;
        }
        assert_eq!(
            m["vascular_uptake_managed_bool"], 0.0,
            "not yet repositioned"
        );
        // Injecting again from the same spot: two vascular doses, not managed.
        let mut same = Run::new(env_of(ID, Backends::cpu(1)), quiet_config());
        assert!(place_tip(&mut same, 0, *v, 2, "spinal-22g-89"));
        assert!(dose(&mut same, 100, 0.05) && dose(&mut same, 1000, 0.05));
        let m = same.s.measurements();
        assert_eq!(m["vascular_injections_count"], 2.0);
        assert_eq!(m["vascular_uptake_managed_bool"], 0.0);
        // Repositioned: withdraw, place in the epidural space near the target, inject again.
        r.ok(1000, Command::NeedleWithdraw { mm: 3.0 });
        for e in epidural.iter().take(8) {
            tried += 1;
            let mut moved = Run::new(env_of(ID, Backends::cpu(1)), quiet_config());
            for entry in r.s.log() {
                moved.ok(entry.t_ms, entry.command.clone());
            }
            if !place_tip(&mut moved, 1100, *e, 1, "spinal-22g-89") || !dose(&mut moved, 1200, 0.1)
            {
                continue;
            }
            let m = moved.s.measurements();
            eprintln!(
                "vascular dose at {v:?}, then epidural at {e:?}: {:?}",
                [
                    "vascular_injections_count",
                    "last_injection_vascular_bool",
                    "vascular_uptake_managed_bool",
                    "perineural_spread_bool",
                    "epidural_spread_bool",
                ]
                .map(|k| m[k])
            );
            assert_eq!(m["vascular_injections_count"], 1.0);
            assert_eq!(m["last_injection_vascular_bool"], 0.0);
            assert_eq!(m["vascular_uptake_managed_bool"], 1.0);
            // The cumulative flag still reports that a vessel took contrast.
            assert_eq!(m["intravascular_uptake_bool"], 1.0);
            let result = moved.s.score();
            for id in ["final_injection_not_vascular", "vascular_uptake_managed"] {
                let c = result
                    .rubric
                    .criteria
                    .iter()
                    .find(|c| c.id == id)
                    .unwrap_or_else(|| panic!("{id}"));
                assert_eq!(c.credit, Some(1.0), "{id}: {c:?}");
            }
            return;
        }
        panic!("no epidural site accepted a second dose ({tried} tried)");
    }
    panic!("no vessel site near {target:?} gave vascular uptake");
}
