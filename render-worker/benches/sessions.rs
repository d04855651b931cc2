//! Session costs: idle CPU, session overhead over a bare render, and N concurrent streamed
//! sessions over loopback websockets (input-to-frame latency p50/p99, frames per second).
//!
//! Scene: the analytic demo region (`render_worker::session::demo`), CPU reference renderer,
//! 512 x 512 detector, 2 x 2 adaptive supersampling, quantum noise on. `BENCH_QUICK=1` shortens
//! every phase (CI, under a minute on 2 cores in the dev profile).
//!
//! Last, resident memory with 0, 1, 8 and 16 live sessions on the default lumbar phantom station
//! (the phantom is built once into the target folder, about 70 s on 2 cores, and read back from
//! there in about 5 s afterwards), against the baseline of one anatomy upload per session; then
//! one of those sessions goes on for 60 more frames (120 in full mode), and what stays resident
//! per frame is reported (a leak shows there).
//! `cargo bench -p render-worker --bench sessions -- memory` runs that section alone.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures::{SinkExt, StreamExt};
use render_worker::session::demo::{demo_region, demo_station};
use render_worker::session::frame::EncodedFrame;
use render_worker::session::*;
use tokio_tungstenite::tungstenite::Message;

fn rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<f64>().ok())
        .map_or(0.0, |kb| kb / 1024.0)
}

fn config(px: u32) -> SessionConfig {
    SessionConfig {
        fluoro: FluoroConfig {
            detector_pixels: px,
            detector_mm: 300.0,
            supersample: 2,
            noise: true,
        },
        seed: 1,
    }
}

fn host(capacity: usize, extra: &[&str]) -> SessionHost {
    host_with(capacity, extra, Backends::cpu(0))
}

fn host_with(capacity: usize, extra: &[&str], backends: Backends) -> SessionHost {
    SessionHost::with_regions(
        vec![demo_station(extra)],
        vec![Arc::new(demo_region())],
        backends,
        capacity,
        config(512),
    )
}

/// [`sim_core::stats::percentile`] of `v` with `p` as a fraction (0.5 for the median).
fn percentile(v: &mut [f64], p: f64) -> f64 {
    sim_core::stats::percentile(v, 100.0 * p)
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    if std::env::args().skip(1).any(|a| a == "memory") {
        memory(&rt, quick);
        return;
    }

    // 1. Idle sessions.
    println!("## Idle sessions (process CPU while no input arrives)\n");
    println!("| sessions | idle period (s) | CPU time (ms) | CPU per session-second (ms) |");
    println!("|---:|---:|---:|---:|");
    let idle_s = if quick { 2.0 } else { 5.0 };
    for n in [1usize, 8] {
        let h = host(n, &[]);
        let handles: Vec<_> = (0..n)
            .map(|_| h.create_blocking("demo-station").expect("session"))
            .collect();
        rt.block_on(async {
            for s in &handles {
                s.command(Envelope {
                    seq: 1,
                    command: Command::Shot,
                })
                .await
                .expect("shot");
            }
            // Idle starts once every session has rendered and published its frame.
            for s in &handles {
                let mut rx = s.frames();
                while rx.borrow_and_update().get(&ViewId::FLUOROSCOPY).is_none() {
                    rx.changed().await.expect("session alive");
                }
            }
        });
        std::thread::sleep(Duration::from_millis(200));
        let c0 = render_worker::session::calibration::process_cpu_s();
        std::thread::sleep(Duration::from_secs_f64(idle_s));
        let used_ms = (render_worker::session::calibration::process_cpu_s() - c0) * 1000.0;
        println!(
            "| {n} | {idle_s} | {used_ms:.0} | {:.2} |",
            used_ms / (n as f64 * idle_s)
        );
        h.shutdown();
    }

    // 2. A session's cost over the bare renderer, and with another modality listed.
    println!("\n## Shot to encoded frame: session vs. bare `render_frame` (512 x 512)\n");
    println!("| path | station modalities | median time (ms) | state bytes | RSS after (MiB) |");
    println!("|---|---|---:|---:|---:|");
    let reps = if quick { 3 } else { 20 };
    let region = Arc::new(demo_region());
    let projection = sim_core::fluoro::Projection::default();
    let settings = sim_core::fluoro::RenderSettings {
        supersample: 2,
        noise: Some(sim_core::fluoro::QuantumNoise {
            photons_per_pixel: 3000.0,
            seed: 1,
        }),
        ..Default::default()
    };
    let mut bare = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        let img: ViewImage =
            sim_core::fluoro::render_frame(&region.scene, None, &projection, &settings)
                .expect("render")
                .into();
        let _ = render_worker::session::frame::encode_jpeg(&img).expect("jpeg");
        bare.push(t.elapsed().as_secs_f64() * 1000.0);
    }
    println!(
        "| bare render_frame + JPEG | - | {:.1} | - | {:.0} |",
        percentile(&mut bare, 0.5),
        rss_mb()
    );
    for extra in [&[][..], &["ultrasound"][..]] {
        let (station, sha) = demo_station(extra);
        let mut s = Session::new(
            SessionEnv::new(
                Arc::new(StationContext::new(station, sha, &region)),
                Arc::clone(&region),
                Backends::cpu(0),
            ),
            config(512),
        );
        let visible: BTreeSet<ViewId> = [ViewId::FLUOROSCOPY].into();
        let mut times = Vec::new();
        for k in 0..reps {
            let t = Instant::now();
            s.apply(
                Envelope {
                    seq: k as u64 + 1,
                    command: Command::Shot,
                },
                k as u64,
            )
            .expect("shot");
            let f = s
                .render_dirty(&visible)
                .expect("render")
                .pop()
                .expect("frame");
            let _ = EncodedFrame::new(f.view, 1, f.input_seq, f.t_ms, &f.image).expect("jpeg");
            times.push(t.elapsed().as_secs_f64() * 1000.0);
        }
        let mods = std::iter::once("fluoroscopy")
            .chain(extra.iter().copied())
            .collect::<Vec<_>>()
            .join(" + ");
        println!(
            "| session (modalities built: {}) | {mods} | {:.1} | {} | {:.0} |",
            s.modality_names().join(", "),
            percentile(&mut times, 0.5),
            s.snapshot().to_bytes().len(),
            rss_mb()
        );
    }

    let img: ViewImage =
        sim_core::fluoro::render_frame(&region.scene, None, &projection, &settings)
            .expect("render")
            .into();
    let mut jpeg = Vec::new();
    for _ in 0..reps {
        let t = Instant::now();
        let _ = render_worker::session::frame::encode_jpeg(&img).expect("jpeg");
        jpeg.push(t.elapsed().as_secs_f64() * 1000.0);
    }
    println!(
        "| JPEG encoding alone | - | {:.1} | - | {:.0} |",
        percentile(&mut jpeg, 0.5),
        rss_mb()
    );

    // 3. Concurrent streamed sessions over loopback websockets.
    let mut backends: Vec<Backends> = vec![Backends::cpu(0)];
    match render_worker::gpu::GpuContext::new_headless() {
        Ok(ctx) => backends.push(Backends::gpu(ctx)),
        Err(e) => println!("\n(no GPU adapter, GPU rows skipped: {e})"),
    }
    // The phantom region: 4 mm grid in quick mode, 2 mm otherwise (the default asset is 1.5 mm;
    // its frame cost on the CPU is in sim-core's fluoro bench).
    let voxel_mm = if quick { 4.0 } else { 2.0 };
    let t = Instant::now();
    // Cached by parameter hash where the tests cache this grid (`phantom-lumbar-<voxel>mm` in
    // the workspace's test scratch folder): the bench times sessions, not meshing.
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("phantom-lumbar-{voxel_mm}mm"));
    let asset = sim_core::anatomy::phantom::ensure_built_with(
        &dir,
        &sim_core::anatomy::phantom::PhantomParams::with_voxel_mm(voxel_mm),
        &mut |_| {},
    )
    .expect("phantom");
    let phantom = Arc::new(Region::from_asset(&asset));
    let stations_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let facet = sim_core::rubric::load_station_dir(&stations_dir)
        .expect("stations")
        .into_iter()
        .find(|f| f.station.id == "l4-l5-left-facet")
        .expect("facet station");
    let facet = (facet.station, sha256_hex(facet.text.as_bytes()));
    println!(
        "\n(phantom at {voxel_mm} mm: {} triangles, ready in {:.1} s)",
        phantom.scene.triangle_count(),
        t.elapsed().as_secs_f64()
    );
    println!("\n## One phantom frame per renderer (512 x 512, 2 x 2 supersampling, noise)\n");
    println!("| renderer | per-session renderer set-up (ms) | frame median (ms) |");
    println!("|---|---:|---:|");
    for b in &backends {
        if quick && b.fluoro.profile().kind == "cpu-reference" {
            // About 6 s per frame on 2 loaded cores: full mode only.
            println!("| cpu-reference cpu | (full mode only) | |");
            continue;
        }
        let t = Instant::now();
        let mut r = b.fluoro.renderer(&phantom).expect("renderer");
        let setup_ms = t.elapsed().as_secs_f64() * 1000.0;
        let p = sim_core::fluoro::Projection {
            isocentre_mm: phantom.landmarks["L4_body_centre"],
            ..Default::default()
        };
        let mut times = Vec::new();
        for _ in 0..reps.min(3) {
            let t = Instant::now();
            let _ = r.render(None, &p, &settings, None).expect("frame");
            times.push(t.elapsed().as_secs_f64() * 1000.0);
        }
        let profile = b.fluoro.profile();
        println!(
            "| {} {} | {setup_ms:.0} | {:.1} |",
            profile.kind,
            profile.device,
            percentile(&mut times, 0.5)
        );
    }
    println!("\n## Concurrent live sessions over loopback websockets (512 x 512)\n");
    println!(
        "| scene | renderer | sessions | inputs per session | latency p50 (ms) | latency p99 (ms) | frames/s per session |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|");
    let counts: &[usize] = if quick { &[1, 4] } else { &[1, 2, 4, 8] };
    let inputs = if quick { 5 } else { 30 };
    let gpu = backends.get(1).cloned();
    let mut runs: Vec<(&str, Backends, &[usize])> = backends
        .iter()
        .map(|b| ("demo boxes", b.clone(), counts))
        .collect();
    // The CPU reference on the phantom takes seconds per frame here: one session, full mode only.
    match gpu {
        Some(g) => runs.push(("phantom", g, counts)),
        None if !quick => runs.push(("phantom", backends[0].clone(), &[1])),
        None => println!("(no GPU: phantom sessions on the CPU run in full mode only)"),
    }
    for (scene, backend, counts) in runs {
        let profile = backend.fluoro.profile();
        for &n in counts {
            let (h, station_id) = if scene == "phantom" {
                let h = SessionHost::with_regions(
                    vec![facet.clone()],
                    vec![Arc::clone(&phantom)],
                    backend.clone(),
                    n,
                    config(512),
                );
                (h, "l4-l5-left-facet")
            } else {
                (host_with(n, &[], backend.clone()), "demo-station")
            };
            let host = h.clone();
            let (lat, fps) = rt.block_on(async move {
                let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                    .await
                    .expect("bind");
                let addr = listener.local_addr().expect("addr");
                let server = tokio::spawn(async move {
                    axum::serve(listener, http::router(h.clone()))
                        .await
                        .map(|_| h)
                });
                let mut clients = Vec::new();
                for _ in 0..n {
                    clients.push(tokio::spawn(async move {
                        client(addr, inputs, station_id).await
                    }));
                }
                let mut lat = Vec::new();
                let mut fps = Vec::new();
                for c in clients {
                    let (l, f) = c.await.expect("client");
                    lat.extend(l);
                    fps.push(f);
                }
                server.abort();
                (lat, fps.iter().sum::<f64>() / fps.len() as f64)
            });
            // Session threads release their GPU resources before the next run (and before the
            // process exits, see `SessionHost::shutdown`).
            host.shutdown();
            let mut lat = lat;
            println!(
                "| {scene} | {} {} | {n} | {inputs} | {:.1} | {:.1} | {fps:.1} |",
                profile.kind,
                profile.device,
                percentile(&mut lat, 0.5),
                percentile(&mut lat, 0.99)
            );
        }
    }
    memory(&rt, quick);
}

/// Resident memory of an in-process host on the default lumbar phantom station (the default
/// session configuration, as the server runs it) with 0, 1, 8 and 16 live sessions, on this
/// machine's device (the GPU renderer when one opens, as the server chooses). Each session takes
/// a shot (its renderer is made on its first exposure), then its needle goes in through the skin
/// towards the station's facet target and a second shot shows it.
fn memory(rt: &tokio::runtime::Runtime, quick: bool) {
    use sim_core::anatomy::phantom;
    let root = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("regions");
    let t = Instant::now();
    let region = Arc::new(
        render_worker::session::loader::load_region(&root, phantom::REGION_NAME, &mut |_| {})
            .expect("default lumbar phantom"),
    );
    let stations_dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let station = sim_core::rubric::load_station_dir(&stations_dir)
        .expect("stations")
        .into_iter()
        .find(|f| f.station.id == "l4-l5-left-facet")
        .expect("facet station");
    let station = (station.station, sha256_hex(station.text.as_bytes()));
    // From behind (-y) towards the target, entering where that line meets the skin.
    let target = glam::DVec3::from(station.0.targets[0].position_mm);
    let dir = glam::DVec3::new(0.1, 1.0, 0.0).normalize();
    let far = target - 150.0 * dir;
    let skin = region.skin_entry(far, dir, 200.0).expect("skin entry");
    let needle = Command::NeedlePlace {
        instrument: station.0.instruments[0].id.clone(),
        entry_mm: skin.to_array(),
        direction: dir.to_array(),
        bevel_reference: [1.0, 0.0, 0.0],
    };
    println!(
        "\n## Resident memory per live session (default lumbar phantom, {} triangles, loaded in {:.1} s)\n",
        region.scene.triangle_count(),
        t.elapsed().as_secs_f64()
    );
    println!(
        "Each session: a shot, its needle placed and fed 20 mm, a second shot; memory is read \
         1.6 s after the last frame. The first session's increment includes a shared upload.\n"
    );
    // As `Backends::open` chooses (the GPU when it opens and passes its self-test), plus, on a
    // GPU, the baseline of one anatomy upload per session (what every session cost before the
    // uploads were shared); in quick mode the baseline stops at one session.
    let mut variants: Vec<(&str, Backends, &[usize])> = Vec::new();
    match render_worker::session::devices::open_gpu() {
        Ok(ctx) => {
            // Its draft scene is built before the rows (sessions otherwise start building it at
            // their first C-arm move, in the middle of a measurement).
            let shared = GpuFluoroBackend::new(ctx.clone());
            shared.wait_for_draft_scene(&region);
            let shared = Backends::new(Arc::new(shared), Backends::gpu(ctx.clone()).ultrasound);
            variants.push(("one per region", shared, &[0, 1, 8, 16]));
            let private = Backends::new(
                Arc::new(GpuFluoroBackend::with_private_uploads(ctx.clone())),
                Backends::gpu(ctx).ultrasound,
            );
            let counts: &[usize] = if quick { &[0, 1] } else { &[0, 1, 8, 16] };
            variants.push(("one per session (baseline)", private, counts));
        }
        Err(e) => {
            println!("(no usable GPU: {e}; CPU reference renderer)");
            // A CPU shot of the default phantom takes seconds: one session in quick mode.
            let counts: &[usize] = if quick { &[0, 1] } else { &[0, 1, 8, 16] };
            variants.push(("the region's scene", Backends::cpu(0), counts));
        }
    }
    println!(
        "| renderer | anatomy upload | live sessions | RSS (MiB) | added per session since the row above (MiB) | session set-up and both shots, mean (ms) |"
    );
    println!("|---|---|---:|---:|---:|---:|");
    let mut soaks = Vec::new();
    for (label, backends, counts) in variants {
        let profile = backends.fluoro.profile();
        let top = counts.iter().copied().max().unwrap_or(0);
        let h = SessionHost::with_regions(
            vec![station.clone()],
            vec![Arc::clone(&region)],
            backends,
            top.max(1),
            SessionConfig::default(),
        );
        let mut handles = Vec::new();
        let mut last_mb = None;
        for &n in counts {
            let t = Instant::now();
            let added = n - handles.len();
            while handles.len() < n {
                let s = h.create_blocking(&station.0.id).expect("session");
                rt.block_on(async {
                    for (seq, command) in [
                        (1, Command::Shot),
                        (2, needle.clone()),
                        (3, Command::NeedleFeed { mm: 20.0 }),
                        (4, Command::Shot),
                    ] {
                        s.command(Envelope { seq, command }).await.expect("command");
                    }
                    frame_of(&s, 4).await;
                });
                handles.push(s);
            }
            let per_ms = t.elapsed().as_secs_f64() * 1000.0 / added.max(1) as f64;
            // Measured at rest: a process that has rendered nothing for a second hands the
            // allocator's free memory back (`render_worker::alloc::busy`).
            std::thread::sleep(Duration::from_millis(1_600));
            let rss = rss_mb();
            let per = match last_mb {
                Some((m, k)) if n > k => format!("{:.1}", (rss - m) / (n - k) as f64),
                _ => "-".to_string(),
            };
            last_mb = Some((rss, n));
            let per_ms = if added == 0 {
                "-".to_string()
            } else {
                format!("{per_ms:.0}")
            };
            println!(
                "| {} {} | {label} | {n} | {rss:.0} | {per} | {per_ms} |",
                profile.kind, profile.device
            );
        }
        // The soak on the renderer sessions get (the baseline has no draft scene built).
        if let Some(first) = handles.first().filter(|_| soaks.is_empty()) {
            soaks.push((label, soak(rt, first, if quick { 60 } else { 120 })));
        }
        // Session threads release their GPU resources before the next variant.
        h.shutdown();
        drop(handles);
    }
    println!(
        "\nOne live session goes on (C-arm moves of 0.5 degrees and 0.5 mm needle feeds in turn, \
         a shot after each, after as many frames to warm up; memory read 1.6 s after the last \
         frame): what stays resident per frame \
         (a leak shows here).\n"
    );
    println!("| anatomy upload | frames | RSS before (MiB) | RSS after (MiB) | per frame (MiB) |");
    println!("|---|---:|---:|---:|---:|");
    for (label, (frames, before, after)) in soaks {
        println!(
            "| {label} | {frames} | {before:.0} | {after:.0} | {:.3} |",
            (after - before) / frames as f64
        );
    }
}

/// `frames` more frames of session `s` (alternately a C-arm move and a needle feed, each with a
/// shot) after as many to warm up: (frames, RSS before, RSS after), MiB, each read at rest.
fn soak(rt: &tokio::runtime::Runtime, s: &SessionHandle, frames: u64) -> (u64, f64, f64) {
    run_soak_frames(rt, s, 0..frames);
    std::thread::sleep(Duration::from_millis(1_600));
    let before = rss_mb();
    run_soak_frames(rt, s, frames..2 * frames);
    std::thread::sleep(Duration::from_millis(1_600));
    (frames, before, rss_mb())
}

fn run_soak_frames(rt: &tokio::runtime::Runtime, s: &SessionHandle, frames: std::ops::Range<u64>) {
    rt.block_on(async {
        for k in frames {
            let seq = 1_000 + 2 * k;
            let command = if k % 2 == 0 {
                Command::CarmPose {
                    orbital_deg: 0.5 * (k % 40) as f64,
                    angular_deg: 0.0,
                    table_mm: [0.0; 3],
                }
            } else {
                Command::NeedleFeed { mm: 0.5 }
            };
            s.command(Envelope { seq, command }).await.expect("command");
            let shot = Envelope {
                seq: seq + 1,
                command: Command::Shot,
            };
            s.command(shot).await.expect("command");
            frame_of(s, seq + 1).await;
        }
    });
}

/// Waits until the session has published a fluoroscopy frame showing input `seq`.
async fn frame_of(s: &SessionHandle, seq: u64) {
    let mut rx = s.frames();
    while rx
        .borrow_and_update()
        .get(&ViewId::FLUOROSCOPY)
        .is_none_or(|f| f.input_seq < seq)
    {
        rx.changed().await.expect("session alive");
    }
}

/// One scripted client: create a session, live fluoroscopy on, then C-arm moves, each sent when
/// the frame of the previous one arrived. Returns input-to-frame latencies (ms) and frames/s.
async fn client(addr: std::net::SocketAddr, inputs: u64, station_id: &str) -> (Vec<f64>, f64) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let body = format!(r#"{{"station_id":"{station_id}"}}"#);
    let mut s = tokio::net::TcpStream::connect(addr).await.expect("connect");
    let req = format!(
        "POST /sessions HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    s.write_all(req.as_bytes()).await.expect("write");
    let mut resp = String::new();
    s.read_to_string(&mut resp).await.expect("read");
    let json: serde_json::Value =
        serde_json::from_str(resp.split("\r\n\r\n").nth(1).unwrap_or("{}")).expect("json");
    let path = json["ws"].as_str().expect("ws path").to_string();
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}{path}"))
        .await
        .expect("ws");
    let mut latencies = Vec::new();
    let started = Instant::now();
    let mut frames = 0u64;
    // Live fluoroscopy at 30 pulses per second (the most demanding rate): a pose that lands in
    // a pulse that already made an image is imaged by the next pulse, at the client's tick, as
    // the web client does; the latency counts that wait.
    let pulse = Duration::from_millis(34);
    let mut seq = 0u64;
    for k in 0..=inputs + 1 {
        let command = match k {
            0 => serde_json::json!({ "type": "pulse_rate", "pps": 30.0 }),
            1 => serde_json::json!({ "type": "live", "on": true }),
            _ => serde_json::json!({ "type": "carm_pose", "orbital_deg": k as f64,
                "angular_deg": 0.0, "table_mm": [0.0, 0.0, 0.0] }),
        };
        seq += 1;
        let want = seq;
        let msg =
            serde_json::json!({ "type": "command", "seq": seq, "command": command }).to_string();
        let t = Instant::now();
        ws.send(Message::Text(msg.into())).await.expect("send");
        if k == 0 {
            continue;
        }
        loop {
            match tokio::time::timeout(pulse, ws.next()).await {
                Err(_) => {
                    // No pulse has imaged it yet: tick the clock into the next pulse.
                    seq += 1;
                    let tick = serde_json::json!({ "type": "command", "seq": seq,
                        "command": { "type": "tick" } })
                    .to_string();
                    ws.send(Message::Text(tick.into())).await.expect("send");
                }
                Ok(Some(Ok(Message::Binary(b)))) => {
                    let f = EncodedFrame::parse(&b).expect("frame");
                    frames += 1;
                    if f.input_seq >= want {
                        break;
                    }
                }
                Ok(Some(Ok(_))) => {}
                Ok(_) => return (latencies, 0.0),
            }
        }
        if k > 1 {
            latencies.push(t.elapsed().as_secs_f64() * 1000.0);
        }
    }
    let fps = frames as f64 / started.elapsed().as_secs_f64();
    let _ = ws.close(None).await;
    (latencies, fps)
}
