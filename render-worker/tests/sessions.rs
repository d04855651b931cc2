//! Sessions: command validation, on-demand rendering, needle and scoring, snapshot and exact
//! replay, and the pinned frames of a scripted session.
//!
//! Scenes are the analytic demo region (boxes with known geometry) at 128 x 128 pixels, so each
//! frame renders in milliseconds. The fixtures live in `sessions/support.rs` (other test modules
//! use them through this module); the tests are grouped by concern in `sessions/`.

mod brightness;
mod collimation;
mod dose;
mod magnification;
mod pulsed;
mod receptor;
mod rendering;
mod replay;
mod scatter;
mod scoring;
mod support;
mod temporal;
mod validation;

use render_worker::session::*;

pub(crate) use support::{config, pose, script};
use support::{env, fluoro_only, place};

/// The scripted session of `frames_of_a_scripted_session_are_pinned`: shots, C-arm moves, a
/// live run with needle motion, an annotation and a submit, rendering after every step.
fn scripted_frames_sha256(env: SessionEnv, removed: &[&str]) -> (String, usize) {
    use sha2::{Digest, Sha256};
    let steps: Vec<(u64, Command)> = vec![
        (0, Command::Shot),
        (100, pose(-30.0, 5.0)),
        (200, Command::Shot),
        (300, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0])),
        (400, Command::Live { on: true }),
        (500, Command::NeedleFeed { mm: 20.0 }),
        (600, Command::NeedleRoll { deg: 90.0 }),
        (700, pose(15.0, -10.0)),
        (800, Command::Technique { kvp: 95, ma: 3.5 }),
        (900, Command::NeedleWithdraw { mm: 5.0 }),
        (1000, Command::Live { on: false }),
        (
            1100,
            Command::Annotate {
                pixel: [64.0, 64.0],
                label: "target".into(),
            },
        ),
        (1200, Command::Submit),
    ];
    // The script predates pulsed fluoroscopy, the brightness control, the detector's noise
    // model, the temporal chain and scatter: removing their fields from a new session's state
    // gives a session recorded before them (`RECORDED_BEFORE`: the continuous beam, the manual
    // technique and the noise the first hashes were recorded with); removing none, a session
    // of today.
    let mut initial = Session::new(env.clone(), config()).snapshot();
    if let Some(f) = initial.modalities.get_mut("fluoroscopy") {
        let f = f.as_object_mut().unwrap();
        for field in removed {
            assert!(f.remove(*field).is_some(), "a new session has {field}");
        }
    }
    let mut s = Session::restore(env, &initial, &[]).unwrap();
    let mut h = Sha256::new();
    let mut frames = 0;
    for (k, (t, command)) in steps.into_iter().enumerate() {
        let env = Envelope {
            seq: k as u64 + 1,
            command,
        };
        s.apply(env, t).unwrap();
        for f in s.render_dirty(&fluoro_only()).unwrap() {
            h.update(f.input_seq.to_le_bytes());
            h.update(f.t_ms.to_le_bytes());
            h.update(&f.image.pixels);
            frames += 1;
        }
    }
    (hex::encode(h.finalize()), frames)
}

/// The fields of a session recorded before pulsing, the brightness control, the detector
/// model, the temporal chain, scatter and receptor profiles.
const RECORDED_BEFORE: [&str; 6] = [
    "pulse_rate_pps",
    "brightness",
    "detector_noise",
    "temporal",
    "scatter",
    "receptor",
];

/// Pins the frames of a scripted session: a restructuring of the session code must leave every
/// pixel as it was. Hashes recorded before the modality seam moved the fluoroscopy modality into
/// its own folder (commit 3baf252). The GPU hash is pinned only on the software adapter it was
/// recorded on (another driver or vector width rounds differently).
#[test]
fn frames_of_a_scripted_session_are_pinned() {
    let (cpu, n) = scripted_frames_sha256(env(), &RECORDED_BEFORE);
    eprintln!("scripted session, CPU reference: {n} frames, sha256 {cpu}");
    assert_eq!(n, 8);
    assert_eq!(
        cpu,
        "46845c29b961755f6987ea9a78e173e848112eabb0386a518704740a34839355"
    );
    // A session recorded before scatter: pulsed, under the brightness control, detector noise,
    // the temporal chain (pinned when the chain came).
    let (chain, n) = scripted_frames_sha256(env(), &["scatter", "receptor"]);
    eprintln!("scripted session before scatter, CPU reference: {n} frames, sha256 {chain}");
    assert_eq!(n, 7, "a change waits for its pulse");
    assert_eq!(
        chain,
        "5835be215c10d5793f196785c8639137960ca958efd0c826a8d5f3ea808a2565"
    );
    // A session recorded before receptor profiles: the same with scatter and the grid in
    // (pinned when scatter came).
    let (scatter, n) = scripted_frames_sha256(env(), &["receptor"]);
    eprintln!("scripted session before receptors, CPU reference: {n} frames, sha256 {scatter}");
    assert_eq!(n, 7, "a change waits for its pulse");
    assert_eq!(
        scatter,
        "6b12b71be7117ef5ac03b25e5d67b52dc19b8f699811b706a5eabe80dc654674"
    );
    // Today's session: the same on the demo station's flat panel (pinned when receptor
    // profiles came).
    let (today, n) = scripted_frames_sha256(env(), &[]);
    eprintln!("scripted session of today, CPU reference: {n} frames, sha256 {today}");
    assert_eq!(n, 7, "a change waits for its pulse");
    assert_eq!(
        today,
        "597c9e82fb247f598be2426d845640eb92a754103c7e5e35c0edcd03ccaa02fd"
    );
    if let Some(ctx) = render_worker::gpu::context_for_tests() {
        let adapter = ctx.summary.name.clone();
        // Every pass drawn by the adapter (how the hash was recorded), then, on a software
        // adapter, the geometric pass on the CPU (pinned when it came; its other passes are
        // still the adapter's, so it too is pinned on that adapter only).
        let mut gpu_env = env();
        let adapter_drawn =
            std::sync::Arc::new(GpuFluoroBackend::new(ctx.clone()).with_adapter_geometry());
        gpu_env.backends = Backends::new(adapter_drawn, Backends::gpu(ctx.clone()).ultrasound);
        let (gpu, n) = scripted_frames_sha256(gpu_env, &RECORDED_BEFORE);
        eprintln!("scripted session, GPU ({adapter}): {n} frames, sha256 {gpu}");
        assert_eq!(n, 8);
        let mut gpu_env = env();
        gpu_env.backends = Backends::gpu(ctx.clone());
        let (cpu_pass, n) = scripted_frames_sha256(gpu_env, &RECORDED_BEFORE);
        eprintln!(
            "scripted session, GPU ({adapter}) with the CPU geometric pass ({}): {n} frames, sha256 {cpu_pass}",
            ctx.summary.is_software
        );
        assert_eq!(n, 8);
        if adapter == "llvmpipe (LLVM 15.0.6, 256 bits)" {
            assert_eq!(
                gpu,
                "ecbc106b6ca2d30445360918924e8276b2ac7a9a2a269fffd05e0bd633e13df1"
            );
            assert_eq!(
                cpu_pass,
                "48a1df52557b1c387a4d68df92fe983bbdbe999ce2ba4a664f8963e042065d64"
            );
        }
    }
}
