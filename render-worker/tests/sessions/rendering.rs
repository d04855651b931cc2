//! When frames are rendered (only on exposure, only for visible views, on every change while
//! live) and how the GPU backend's session frames compare with the CPU reference's.

use std::collections::BTreeSet;

use render_worker::session::*;
use sim_core::compare::{Compare, Tolerance, block_mean_diffs};

use super::support::{
    Driver, config, drafting_backends, env, fluoro_only, place, pose, script,
    stoppable_drafting_env,
};

#[test]
fn frames_are_rendered_only_on_exposure_and_only_for_visible_views() {
    let mut d = Driver::new();
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "no image before any exposure"
    );
    d.ok(0, pose(20.0, 5.0));
    d.ok(0, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0]));
    d.ok(0, Command::NeedleFeed { mm: 20.0 });
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "moving without exposure keeps the last image"
    );
    d.ok(100, Command::Shot);
    assert!(
        d.s.render_dirty(&BTreeSet::new()).unwrap().is_empty(),
        "hidden views are not rendered"
    );
    let frames = d.s.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].input_seq, 4);
    assert_eq!((frames[0].image.width, frames[0].image.height), (128, 128));
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "nothing changed since"
    );
    // The image is not blank: bone and needle make a range of grey levels.
    let px = &frames[0].image.pixels;
    let (lo, hi) = (px.iter().min().unwrap(), px.iter().max().unwrap());
    assert!(hi - lo > 60, "grey range {lo}..{hi}");
}

#[test]
fn live_fluoroscopy_renders_on_every_change_and_books_its_time() {
    let mut d = Driver::new();
    // A technique set by hand: under the brightness control a step after a frame is itself a
    // change the next pulse images (`sessions::brightness`).
    d.ok(900, Command::Technique { kvp: 80, ma: 2.0 });
    d.ok(1000, Command::Live { on: true });
    assert_eq!(d.s.render_dirty(&fluoro_only()).unwrap().len(), 1);
    d.ok(1500, pose(-15.0, 0.0));
    let a = d.s.render_dirty(&fluoro_only()).unwrap();
    d.ok(1700, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0]));
    let b = d.s.render_dirty(&fluoro_only()).unwrap();
    assert_eq!(
        (a.len(), b.len()),
        (1, 1),
        "a pose change and a needle move each make a live frame"
    );
    assert_ne!(a[0].image, b[0].image, "the needle appears");
    d.ok(3000, Command::Live { on: false });
    assert!(
        d.s.render_dirty(&fluoro_only()).unwrap().is_empty(),
        "beam off: last image hold"
    );
    d.ok(4000, Command::Shot);
    let m = d.s.measurements();
    // Live from 1000 to 3000 ms (2 s) plus one shot (SHOT_EXPOSURE_MS = 100 ms).
    assert_eq!(m["fluoro_exposure_s"], 2.1);
    assert_eq!(m["fluoro_acquisitions_count"], 2.0);
    // Clock never runs backwards: an earlier time stamp is applied "now".
    let ack = d.ok(10, Command::Shot);
    assert_eq!(ack.t_ms, 4000);
}

/// Runs `steps` on a CPU-reference session and a GPU session; returns the fraction of pixels of
/// the final frame within one grey level, and the largest difference.
fn gpu_vs_cpu(steps: &[(u64, Command)]) -> Option<(f64, i32)> {
    let ctx = render_worker::gpu::context_for_tests()?;
    let mut gpu_env = env();
    gpu_env.backends = Backends::gpu(ctx);
    let mut cpu = Session::new(env(), config());
    let mut gpu = Session::new(gpu_env, config());
    // Render after every step, as a session thread does, so renderer state carries over.
    let (mut c, mut g) = (None, None);
    for (k, (t, command)) in steps.iter().enumerate() {
        for (s, last) in [(&mut cpu, &mut c), (&mut gpu, &mut g)] {
            let env = Envelope {
                seq: k as u64 + 1,
                command: command.clone(),
            };
            s.apply(env, *t).unwrap();
            if let Some(f) = s.render_dirty(&fluoro_only()).unwrap().pop() {
                *last = Some(f.image);
            }
        }
    }
    let (c, g) = (c.unwrap(), g.unwrap());
    // State and scores do not depend on the renderer.
    assert_eq!(cpu.snapshot().to_bytes(), gpu.snapshot().to_bytes());
    assert_eq!(cpu.measurements(), gpu.measurements());
    assert_eq!(gpu.score().record.renderer.kind, "gpu");
    let d = Compare::image(c.width as usize, c.height as usize)
        .tolerance(Tolerance::absolute(1.0))
        .all(&g.pixels, &c.pixels)
        .expect("frames of one size");
    let (within_one, max) = (d.fraction_within(), d.max_abs as i32);
    eprintln!(
        "GPU vs CPU session frame: {:.1} % of pixels within one grey level, max difference {max}",
        100.0 * within_one
    );
    Some((within_one, max))
}

#[test]
fn gpu_backend_session_matches_the_cpu_reference_session() {
    // AP views, needle in, live and single shots, technique change.
    let steps = vec![
        (100, Command::Technique { kvp: 75, ma: 2.5 }),
        (200, place([12.0, -100.0, 1.0], [0.0, 1.0, 0.05])),
        (300, Command::NeedleFeed { mm: 30.0 }),
        (400, Command::Live { on: true }),
        (500, Command::NeedleFeed { mm: 15.0 }),
        (600, Command::Live { on: false }),
        (700, Command::Shot),
    ];
    let Some((within_one, _)) = gpu_vs_cpu(&steps) else {
        return;
    };
    // render-worker/tests/fluoro.rs shows interior pixels within one grey level (2e-3 in ln T);
    // silhouette pixels of the demo's box edges, supersampled differently, are about 1.5 % of
    // this 128 x 128 view (measured 98.7 % within one level when written), so 97 %.
    assert!(within_one >= 0.97, "{within_one}");
}

/// Regression test: in the scripted attempt, the live frame made when the C-arm turns to orbital
/// -20 degrees with the needle 60 mm in differed from the CPU reference almost everywhere (0.3 %
/// of pixels within one grey level, up to 65 levels) although the two transmissions agreed (the
/// ROI median of `ln T` within 0.005). The cause was the automatic brightness, metered on the
/// noisy frame: with about 12 quanta per pixel behind the spine, the median was one of a few
/// integer counts 0.087 apart in `ln T`, and the small difference flipped it by one count (6
/// grey levels everywhere). sim-core now meters on the noise-free transmission
/// (`sim_core::fluoro::render::finish_frame`).
#[test]
fn gpu_session_oblique_view_with_needle_matches_the_cpu() {
    let steps = script()[..9].to_vec();
    let Some((within_one, _)) = gpu_vs_cpu(&steps) else {
        return;
    };
    assert!(within_one >= 0.97, "{within_one}");
}

/// What a session thread does before its first input (`Session::prefetch`) changes nothing a
/// client or a replay sees: on the GPU backend (which keeps the prefetched view), the first
/// shot's frame, the snapshot and the measurements equal those of a session that never
/// prefetched, and so does a second frame after a C-arm move (the prefetched view is not
/// shown again); a session with an image already prefetches nothing new.
#[test]
fn prefetch_before_the_first_shot_changes_no_frame_and_no_state() {
    let Some(ctx) = render_worker::gpu::context_for_tests() else {
        return;
    };
    let gpu = || {
        let mut e = env();
        e.backends = Backends::gpu(ctx.clone());
        Session::new(e, config())
    };
    let (mut plain, mut early) = (gpu(), gpu());
    early.prefetch();
    let steps = [
        (100, Command::Shot),
        (200, pose(20.0, 5.0)),
        (300, Command::Shot),
    ];
    for (k, (t, command)) in steps.into_iter().enumerate() {
        let mut frames = Vec::new();
        for s in [&mut plain, &mut early] {
            let env = Envelope {
                seq: k as u64 + 1,
                command: command.clone(),
            };
            s.apply(env, t).unwrap();
            frames.push(s.render_dirty(&fluoro_only()).unwrap());
            // After the first image a prefetch has nothing to prepare.
            s.prefetch();
        }
        let [a, b] = [&frames[0], &frames[1]];
        assert_eq!(a.len(), b.len(), "step {k}");
        for (x, y) in a.iter().zip(b) {
            assert!(x.image == y.image, "step {k}: the frames differ");
            assert_eq!(x.input_seq, y.input_seq);
        }
    }
    assert_eq!(plain.snapshot().to_bytes(), early.snapshot().to_bytes());
    assert_eq!(plain.measurements(), early.measurements());
    assert_eq!(plain.log(), early.log());
}

/// Progressive frames on the GPU backend (drafts forced on the small demo region): after a
/// C-arm move the session has a draft of the new image (half resolution, one sample per pixel,
/// doubled to the full size) before its full frame; the view stays dirty for the full frame,
/// and each image is drafted once. A needle-only change (the full frame reuses the kept
/// geometry) and the CPU reference get no draft. A replay of the log renders the draft and the
/// full frame of each step bit for bit, and the draft stays close to the full frame.
#[test]
fn drafts_come_before_full_frames_after_a_carm_move_and_replay_exactly() {
    let Some(ctx) = render_worker::gpu::context_for_tests() else {
        return;
    };
    let backends = drafting_backends(ctx);
    // Noiseless for the fidelity bound, with noise for exact replay of the noise too.
    for noise in [false, true] {
        let mut config = config();
        config.fluoro.noise = noise;
        let mut e = env();
        e.backends = backends.clone();
        let initial_env = e.clone();
        let mut s = Session::new(e, config);
        let initial = s.snapshot();
        let steps = [
            (100, Command::Shot, true),
            (200, pose(20.0, 5.0), false),
            (300, Command::Shot, true),
            (400, place([12.0, -100.0, 0.0], [0.0, 1.0, 0.0]), false),
            (500, Command::Shot, false),
        ];
        let mut shown = Vec::new();
        for (k, (t, command, drafted)) in steps.into_iter().enumerate() {
            s.apply(
                Envelope {
                    seq: k as u64 + 1,
                    command,
                },
                t,
            )
            .unwrap();
            let drafts = s.render_drafts(&fluoro_only()).unwrap();
            assert_eq!(drafts.len(), usize::from(drafted), "step {k}");
            assert!(
                s.render_drafts(&fluoro_only()).unwrap().is_empty(),
                "step {k}: an image is drafted once"
            );
            let full = s.render_dirty(&fluoro_only()).unwrap();
            if let Some(d) = drafts.first() {
                assert!(d.draft && !full[0].draft);
                assert_eq!((d.input_seq, d.t_ms), (full[0].input_seq, full[0].t_ms));
                assert_eq!(
                    (d.image.width, d.image.height),
                    (full[0].image.width, full[0].image.height)
                );
                assert!(
                    d.image != full[0].image,
                    "step {k}: the draft is the full frame"
                );
                // Close to the full frame: the same anatomy at half the resolution. Compared
                // without noise on 8 x 8 block means: bound 2 grey levels (0.55 and 0.22
                // measured here on lavapipe with scatter and the flat panel; 1.34 and 0.98 when
                // the draft took the full frame's pixel pitch for its scatter), with room for
                // other drivers.
                let diffs = block_mean_diffs(
                    &d.image.pixels,
                    &full[0].image.pixels,
                    d.image.width as usize,
                    8,
                );
                let mean_diff = diffs.iter().sum::<f64>() / diffs.len() as f64;
                println!(
                    "noise {noise}, step {k}: draft against full frame, 8 x 8 block means \
                     differ by {mean_diff:.2} grey levels"
                );
                assert!(noise || mean_diff < 2.0, "step {k}: {mean_diff}");
            }
            shown.push((k + 1, drafts.into_iter().next(), full.into_iter().next()));
        }
        // A replay of the log up to each step renders what was shown, draft and full, bit for bit.
        for (n, draft, full) in shown {
            let log = &s.log()[..n];
            let mut r = Session::restore(initial_env.clone(), &initial, log).unwrap();
            let replayed_draft = r.replay_draft(ViewId::FLUOROSCOPY).unwrap();
            if let Some(d) = draft {
                assert!(replayed_draft.unwrap().image == d.image, "step {n}: draft");
            }
            let replayed = r.render_dirty(&fluoro_only()).unwrap();
            if let Some(f) = full {
                assert!(replayed[0].image == f.image, "step {n}: full frame");
            }
        }
    }
    // The CPU reference has no drafts.
    let mut cpu = Session::new(env(), config());
    cpu.apply(
        Envelope {
            seq: 1,
            command: Command::Shot,
        },
        100,
    )
    .unwrap();
    assert!(cpu.render_drafts(&fluoro_only()).unwrap().is_empty());
    assert!(cpu.replay_draft(ViewId::FLUOROSCOPY).unwrap().is_none());
}

/// The prefetch of a C-arm come to rest gives up when a move supersedes it (the flag the
/// session thread watches raised, see `render_worker::interrupt`): nothing is prepared and the
/// view is still pending; unwatched, the same prefetch prepares it.
#[test]
fn a_superseded_prefetch_prepares_nothing() {
    use render_worker::interrupt::watching;
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;
    let Some(e) = stoppable_drafting_env() else {
        return;
    };
    let mut s = Session::new(e, config());
    s.prefetch();
    s.apply(
        Envelope {
            seq: 1,
            command: Command::Shot,
        },
        100,
    )
    .unwrap();
    s.render_dirty(&fluoro_only()).unwrap();
    s.apply(
        Envelope {
            seq: 2,
            command: pose(15.0, 0.0),
        },
        200,
    )
    .unwrap();
    assert!(s.prefetch_pending(&fluoro_only()));
    {
        let _w = watching(&Arc::new(AtomicBool::new(true)));
        s.prefetch();
    }
    assert!(
        s.prefetch_pending(&fluoro_only()),
        "a superseded prefetch prepared nothing"
    );
    s.prefetch();
    assert!(!s.prefetch_pending(&fluoro_only()), "prepared unwatched");
}
