//! The session host and the wire: the websocket protocol over channels, hand-over from snapshot
//! and log, shutdown, and one real socket (split from `sessions.rs`, which keeps the session
//! state machine's tests).

use std::sync::Arc;

use futures::{SinkExt, StreamExt};
use render_worker::session::demo::{demo_region, demo_station};
use render_worker::session::frame::EncodedFrame;
use render_worker::session::protocol::{ServerMessage, WsMessage, serve_connection};
use render_worker::session::*;

use crate::sessions::{config, pose, script};

fn host(capacity: usize) -> SessionHost {
    SessionHost::with_regions(
        vec![demo_station(&[])],
        vec![Arc::new(demo_region())],
        Backends::cpu(1),
        capacity,
        config(),
    )
}

fn cmd_text(seq: u64, command: &Command) -> WsMessage {
    WsMessage::Text(
        serde_json::to_string(
            &serde_json::json!({ "type": "command", "seq": seq, "command": command }),
        )
        .unwrap(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn protocol_over_channels_acknowledges_every_input_and_keeps_only_the_newest_frame() {
    let host = host(4);
    let h = host.create("demo-station").await.unwrap();
    assert!(matches!(
        host.create("no-such-station").await,
        Err(HostError::UnknownStation(_))
    ));
    // Client -> worker: unbounded. Worker -> client: room for one message, so a client that
    // does not read blocks the worker's sends (a slow client).
    let (mut to_worker, from_client) =
        futures::channel::mpsc::unbounded::<Result<WsMessage, String>>();
    let (to_client, mut from_worker) = futures::channel::mpsc::channel::<WsMessage>(1);
    let task = tokio::spawn(serve_connection(h.clone(), to_client, from_client));
    let text = |m: WsMessage| match m {
        WsMessage::Text(t) => serde_json::from_str::<ServerMessage>(&t).unwrap(),
        other => panic!("expected text, got {other:?}"),
    };
    assert!(matches!(
        text(from_worker.next().await.unwrap()),
        ServerMessage::Hello { last_seq: 0, .. }
    ));
    // 1..=12: shots, each a new image (live fluoroscopy would image them once per pulse); one
    // bad command after them.
    for k in 1..=12u64 {
        to_worker
            .send(Ok(cmd_text(k, &Command::Shot)))
            .await
            .unwrap();
    }
    to_worker
        .send(Ok(cmd_text(13, &pose(f64::from(500), 0.0))))
        .await
        .unwrap();
    // Read everything until the 12 acks and the error have arrived.
    let (mut acks, mut errors, mut frames) = (Vec::new(), Vec::new(), Vec::new());
    while acks.len() < 12 || errors.is_empty() {
        match tokio::time::timeout(std::time::Duration::from_secs(20), from_worker.next())
            .await
            .unwrap()
            .unwrap()
        {
            WsMessage::Binary(b) => frames.push(EncodedFrame::parse(&b).unwrap()),
            m => match text(m) {
                ServerMessage::Ack(a) => acks.push(a.seq),
                ServerMessage::Error { seq, error } => errors.push((seq, error)),
                ServerMessage::Hello { .. } => panic!("second hello"),
            },
        }
    }
    assert_eq!(
        acks,
        (1..=12).collect::<Vec<_>>(),
        "every input acknowledged, in order"
    );
    assert_eq!(errors[0].0, Some(13));
    assert_eq!(errors[0].1.field, "command.orbital_deg");
    // Wait for the frame that reflects input 12.
    while frames.last().is_none_or(|f| f.input_seq < 12) {
        match tokio::time::timeout(std::time::Duration::from_secs(20), from_worker.next())
            .await
            .unwrap()
            .unwrap()
        {
            WsMessage::Binary(b) => frames.push(EncodedFrame::parse(&b).unwrap()),
            other => panic!("unexpected {other:?}"),
        }
    }
    assert!(
        frames.windows(2).all(|w| w[0].frame_seq < w[1].frame_seq),
        "frames arrive newest-last"
    );
    // Inputs never dropped: the session's log has all twelve.
    let (snap, log) = h.snapshot().await.unwrap();
    assert_eq!((snap.last_seq, log.len()), (12, 12));

    // A client that stops reading: eleven more shots are imaged while it sleeps; when it reads
    // again it gets at most the frame the worker was blocked on and then the newest one.
    for k in 13..=23u64 {
        h.command(Envelope {
            seq: k,
            command: Command::Shot,
        })
        .await
        .unwrap();
    }
    // Let the session thread render the last one (it renders after acknowledging).
    let mut rx = h.frames();
    while rx
        .borrow_and_update()
        .get(&ViewId::FLUOROSCOPY)
        .is_none_or(|f| f.input_seq < 23)
    {
        rx.changed().await.unwrap();
    }
    let mut late = Vec::new();
    while late.last().is_none_or(|f: &EncodedFrame| f.input_seq < 23) {
        match tokio::time::timeout(std::time::Duration::from_secs(20), from_worker.next())
            .await
            .unwrap()
            .unwrap()
        {
            WsMessage::Binary(b) => late.push(EncodedFrame::parse(&b).unwrap()),
            other => panic!("unexpected {other:?}"),
        }
    }
    // At most: the two slots of the channel (buffer 1 + 1 per sender), the frame whose send was
    // blocked, and the newest one.
    assert!(
        late.len() <= 4,
        "stale frames were skipped: got {} for 11 renders",
        late.len()
    );
    to_worker.send(Ok(WsMessage::Close)).await.unwrap();
    task.await.unwrap().unwrap();
    host.close(&h.info.id).unwrap();
    assert_eq!(host.health().sessions, 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn host_hands_a_session_over_from_snapshot_and_log() {
    let a = host(2);
    let b = host(2);
    let h = a.create("demo-station").await.unwrap();
    for (k, (_, c)) in script().into_iter().enumerate() {
        h.command(Envelope {
            seq: k as u64 + 1,
            command: c,
        })
        .await
        .unwrap();
    }
    let (snap, log) = h.snapshot().await.unwrap();
    let moved = b.restore_blocking(&snap, &log).unwrap();
    let (snap2, log2) = moved.snapshot().await.unwrap();
    assert_eq!((snap2.to_bytes(), log2), (snap.to_bytes(), log));
    // The client re-sends its last input after reconnecting: acknowledged as a duplicate.
    let last = script().pop().unwrap().1;
    let ack = moved
        .command(Envelope {
            seq: snap.last_seq,
            command: last,
        })
        .await
        .unwrap();
    assert!(ack.duplicate);
    // Capacity is enforced.
    b.create("demo-station").await.unwrap();
    assert_eq!(
        b.create("demo-station").await.unwrap_err(),
        HostError::Full(2)
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_ends_every_session_thread_before_returning() {
    let shot = |seq| Envelope {
        seq,
        command: Command::Shot,
    };
    let h = host(3);
    let mut sessions = Vec::new();
    for _ in 0..2 {
        let s = h.create("demo-station").await.unwrap();
        s.command(shot(1)).await.unwrap();
        sessions.push(s);
    }
    let frames: Vec<_> = sessions.iter().map(|s| s.frames()).collect();
    let h2 = h.clone();
    tokio::task::spawn_blocking(move || h2.shutdown())
        .await
        .unwrap();
    assert_eq!(h.health().sessions, 0);
    for (s, f) in sessions.iter().zip(&frames) {
        // The actor thread has returned: it dropped its frame sender and its command queue.
        assert!(f.has_changed().is_err(), "session thread still running");
        assert!(s.command(shot(2)).await.is_err());
    }
    // The host goes on serving new sessions.
    let s = h.create("demo-station").await.unwrap();
    s.command(shot(1)).await.unwrap();
}

async fn http(addr: std::net::SocketAddr, request: &str) -> String {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut s = tokio::net::TcpStream::connect(addr).await.unwrap();
    s.write_all(request.as_bytes()).await.unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).await.unwrap();
    out
}

/// `POST /sessions` for the demo station: the 201's body.
async fn create_demo_session(addr: std::net::SocketAddr) -> serde_json::Value {
    let body = r#"{"station_id":"demo-station"}"#;
    let created = http(
        addr,
        &format!(
            "POST /sessions HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        ),
    )
    .await;
    assert!(created.starts_with("HTTP/1.1 201"), "{created}");
    serde_json::from_str(created.split("\r\n\r\n").nth(1).unwrap()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn real_websocket_creates_a_session_takes_a_shot_and_streams_a_jpeg() {
    use tokio_tungstenite::tungstenite::Message;
    let host = host(2);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, http::router(host)).await });
    let health = http(
        addr,
        "GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n",
    )
    .await;
    assert!(health.starts_with("HTTP/1.1 200"), "{health}");
    assert!(
        health.contains("\"capacity\":2") && health.contains("cpu-reference"),
        "{health}"
    );
    let json = create_demo_session(addr).await;
    let ws_path = json["ws"].as_str().unwrap();
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}{ws_path}"))
        .await
        .unwrap();
    let hello = ws.next().await.unwrap().unwrap();
    assert!(hello.to_text().unwrap().contains("\"hello\""));
    ws.send(Message::Text(
        r#"{"type":"command","seq":1,"command":{"type":"shot"}}"#.into(),
    ))
    .await
    .unwrap();
    let (mut acked, mut frame) = (false, None);
    while !acked || frame.is_none() {
        match tokio::time::timeout(std::time::Duration::from_secs(20), ws.next())
            .await
            .unwrap()
            .unwrap()
            .unwrap()
        {
            Message::Text(t) => {
                let m: ServerMessage = serde_json::from_str(&t).unwrap();
                assert!(matches!(m, ServerMessage::Ack(ref a) if a.seq == 1), "{t}");
                acked = true;
            }
            Message::Binary(b) => frame = Some(EncodedFrame::parse(&b).unwrap()),
            _ => {}
        }
    }
    let f = frame.unwrap();
    assert_eq!((f.input_seq, f.width, f.height), (1, 128, 128));
    assert_eq!(&f.jpeg[..2], &[0xFF, 0xD8]);
    ws.close(None).await.unwrap();
}

/// On the worker's own socket: a client that sends 10,000 commands without
/// reading, then reads, gets every answer in order, and the session takes another command.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_sent_without_reading_is_answered_in_order_on_the_worker_socket() {
    use tokio_tungstenite::tungstenite::Message;
    const N: u64 = 10_000;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, http::router(host(1))).await });
    let json = create_demo_session(addr).await;
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://{addr}{}", json["ws"].as_str().unwrap()))
            .await
            .unwrap();
    let started = std::time::Instant::now();
    let text = |seq: u64| {
        let c = if seq.is_multiple_of(2) {
            Command::Tick
        } else {
            pose((seq % 90) as f64 - 45.0, 0.0)
        };
        match cmd_text(seq, &c) {
            WsMessage::Text(t) => Message::Text(t.into()),
            _ => unreachable!(),
        }
    };
    let send = async {
        for seq in 1..=N {
            ws.feed(text(seq)).await.unwrap();
        }
        ws.flush().await.unwrap();
    };
    tokio::time::timeout(std::time::Duration::from_secs(120), send)
        .await
        .expect("the worker keeps reading a burst");
    let mut next = 1;
    while next <= N + 1 {
        if next == N + 1 {
            ws.send(text(N + 1)).await.unwrap();
        }
        let m = tokio::time::timeout(std::time::Duration::from_secs(60), ws.next())
            .await
            .expect("an answer within 60 s")
            .unwrap()
            .unwrap();
        if let Message::Text(t) = m {
            match serde_json::from_str::<ServerMessage>(&t).unwrap() {
                ServerMessage::Ack(a) => {
                    assert_eq!(a.seq, next, "in order");
                    next += 1;
                }
                ServerMessage::Hello { .. } => {}
                other => panic!("{other:?}"),
            }
        }
    }
    eprintln!(
        "worker socket burst: {N} commands, last answer after {:.2} s",
        started.elapsed().as_secs_f64()
    );
}

/// A CPU reference that says it prefetches, and counts the prefetches its renderers are asked
/// for.
/// A host of the demo station whose fluoroscopy renderers count their prefetches.
fn counting_host(prefetches: &Arc<std::sync::atomic::AtomicUsize>) -> SessionHost {
    let backends = Backends::new(
        Arc::new(CountingPrefetch {
            prefetches: Arc::clone(prefetches),
        }),
        Backends::cpu(1).ultrasound,
    );
    SessionHost::with_regions(
        vec![demo_station(&[])],
        vec![Arc::new(demo_region())],
        backends,
        2,
        config(),
    )
}

struct CountingPrefetch {
    prefetches: Arc<std::sync::atomic::AtomicUsize>,
}

struct CountingRenderer {
    inner: Box<dyn FluoroRenderer>,
    prefetches: Arc<std::sync::atomic::AtomicUsize>,
}

impl FluoroBackend for CountingPrefetch {
    fn profile(&self) -> BackendProfile {
        CpuFluoroBackend { threads: 1 }.profile()
    }

    fn renderer(
        &self,
        region: &Arc<render_worker::session::region::Region>,
    ) -> Result<
        Box<dyn FluoroRenderer>,
        render_worker::session::modalities::fluoro::FluoroRenderError,
    > {
        Ok(Box::new(CountingRenderer {
            inner: CpuFluoroBackend { threads: 1 }.renderer(region)?,
            prefetches: Arc::clone(&self.prefetches),
        }))
    }

    fn prefetches(&self) -> bool {
        true
    }
}

impl FluoroRenderer for CountingRenderer {
    fn render(
        &mut self,
        needle: Option<&render_worker::session::modalities::fluoro::NeedleShaft>,
        projection: &sim_core::fluoro::Projection,
        settings: &sim_core::fluoro::RenderSettings,
        iodine: Option<&sim_core::fluoro::IodineField>,
    ) -> Result<
        sim_core::fluoro::Image,
        render_worker::session::modalities::fluoro::FluoroRenderError,
    > {
        self.inner.render(needle, projection, settings, iodine)
    }

    fn prefetch(
        &mut self,
        _needle: Option<&render_worker::session::modalities::fluoro::NeedleShaft>,
        _projection: &sim_core::fluoro::Projection,
        _settings: &sim_core::fluoro::RenderSettings,
        _iodine: Option<&sim_core::fluoro::IodineField>,
    ) -> Result<(), render_worker::session::modalities::fluoro::FluoroRenderError> {
        self.prefetches
            .fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        Ok(())
    }
}

/// A new session's thread prefetches its first view before any input arrives, once; a
/// restored session (its images already taken) does not.
#[test]
fn a_new_session_prefetches_its_first_view_before_any_input() {
    let prefetches = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let h = counting_host(&prefetches);
    let count = || prefetches.load(std::sync::atomic::Ordering::SeqCst);
    let wait_for = |n: usize| {
        let t0 = std::time::Instant::now();
        while count() < n && t0.elapsed() < std::time::Duration::from_secs(30) {
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
    };
    let s = h.create_blocking("demo-station").expect("session");
    wait_for(1);
    assert_eq!(count(), 1, "the new session prefetched");
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(s.command(Envelope {
        seq: 1,
        command: Command::Shot,
    }))
    .expect("shot");
    let (snapshot, log) = rt.block_on(s.snapshot()).expect("snapshot");
    h.close(&s.info.id).unwrap();
    let restored = h.restore_blocking(&snapshot, &log).expect("restored");
    // Give the restored session's thread the time it would take to prefetch.
    std::thread::sleep(std::time::Duration::from_millis(300));
    assert_eq!(
        count(),
        1,
        "a restored session with an image prefetches nothing"
    );
    h.close(&restored.info.id).unwrap();
    h.shutdown();
}

/// A client's tick that comes a little before the pulse a waiting change is due at (its timer
/// runs on its own clock, out of phase with the session's pulse grid) is held until that pulse
/// and images the change then, instead of a whole pulse period later.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tick_just_before_a_pulse_images_the_waiting_change_at_that_pulse() {
    let host = host(2);
    let h = host.create("demo-station").await.unwrap();
    // Nothing rendered: the session's thread stays free, so only the hold can delay a tick.
    h.set_visible(std::collections::BTreeSet::new());
    let mut seq = 0;
    let mut command = |command: Command| {
        seq += 1;
        h.command(Envelope { seq, command })
    };
    let sent = std::time::Instant::now();
    let since = command(Command::Live { on: true }).await.unwrap().t_ms;
    // A C-arm move in the pulse that imaged the pedal press waits for the next pulse, due at
    // `since + 134` (7.5 pulses per second, the default).
    command(pose(4.0, 0.0)).await.unwrap();
    let due = since + 134;
    let images = |snap: &SessionSnapshot| -> Vec<u64> {
        snap.modalities["fluoroscopy"]["images"]
            .as_array()
            .unwrap()
            .iter()
            .map(|i| i["t_ms"].as_u64().unwrap())
            .collect()
    };
    // A tick 20 ms early by the session's clock (which started at `since` no earlier than
    // `sent`): held until the pulse (a quarter period, 33 ms, is the most a tick is held).
    tokio::time::sleep_until((sent + std::time::Duration::from_millis(due - 20 - since)).into())
        .await;
    let ack = command(Command::Tick).await.unwrap();
    let (snap, _) = h.snapshot().await.unwrap();
    assert!(
        (due..due + 15).contains(&ack.t_ms),
        "tick applied at {} for the pulse at {due}",
        ack.t_ms
    );
    assert_eq!(images(&snap).last(), Some(&ack.t_ms), "{:?}", images(&snap));
    assert_eq!(
        snap.modalities["fluoroscopy"]["images"]
            .as_array()
            .unwrap()
            .last()
            .unwrap()["projection"]["orbital_deg"],
        4.0
    );
}

/// The listener the server and the worker serve sessions on turns Nagle's algorithm off on
/// every connection it accepts (a plain listener's connections keep it on).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn session_servers_accept_connections_with_nagle_off() {
    use axum::serve::Listener;
    let plain = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let served = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let (a, b) = (plain.local_addr().unwrap(), served.local_addr().unwrap());
    let mut served = render_worker::cluster::accepting(served);
    let clients = tokio::spawn(async move {
        let x = tokio::net::TcpStream::connect(a).await.unwrap();
        let y = tokio::net::TcpStream::connect(b).await.unwrap();
        (x, y)
    });
    let (plain_io, _) = plain.accept().await.unwrap();
    let (served_io, _) = served.accept().await;
    assert!(!plain_io.nodelay().unwrap());
    assert!(served_io.nodelay().unwrap());
    drop(clients.await.unwrap());
}

/// Once a moved C-arm comes to rest (no input for `PREFETCH_AFTER_PAUSE`) the session prefetches
/// the view, once; not while a drag goes on, not the view on screen, not while live.
#[test]
fn a_c_arm_come_to_rest_is_prefetched_once_and_a_drag_is_not() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let prefetches = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let h = counting_host(&prefetches);
    let count = || prefetches.load(std::sync::atomic::Ordering::SeqCst);
    let pause = host::PREFETCH_AFTER_PAUSE;
    let s = h.create_blocking("demo-station").expect("session");
    let mut seq = 0;
    let mut command = |c: Command| {
        seq += 1;
        rt.block_on(s.command(Envelope { seq, command: c }))
            .expect("command");
    };
    command(Command::Shot);
    std::thread::sleep(3 * pause);
    assert_eq!(
        count(),
        1,
        "the first view, before any input; none for the view on screen"
    );
    // A drag: a pose every 20 ms. While it goes on nothing is prefetched (asserted when the
    // test's own thread kept the pace: a pause of the machine would be a pause of the drag).
    let mut longest = std::time::Duration::ZERO;
    let mut last = std::time::Instant::now();
    for k in 1..=15 {
        command(pose(f64::from(k), 0.0));
        longest = longest.max(last.elapsed());
        last = std::time::Instant::now();
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    if longest < pause / 2 {
        assert_eq!(count(), 1, "nothing prefetched during the drag");
    }
    // At rest: the view is prefetched once.
    std::thread::sleep(4 * pause);
    assert_eq!(count(), 2, "the view the C-arm came to rest at");
    std::thread::sleep(2 * pause);
    assert_eq!(count(), 2, "once");
    // Its shot, then live fluoroscopy with a move: nothing more to prefetch.
    command(Command::Shot);
    command(Command::Live { on: true });
    command(pose(-5.0, 0.0));
    std::thread::sleep(3 * pause);
    assert_eq!(count(), 2, "the view on screen, and a move while live");
    // Beam off, the fluoroscopy view hidden: a move comes to rest unprepared.
    command(Command::Live { on: false });
    s.set_visible(std::collections::BTreeSet::new());
    command(pose(9.0, 0.0));
    std::thread::sleep(3 * pause);
    assert_eq!(count(), 2, "nothing prepared for a hidden view");
    h.close(&s.info.id).unwrap();
    h.shutdown();
}

/// A C-arm dragged under live fluoroscopy on a region without drafts (the demo region, the CPU
/// renderer): every pulse that images a move is shown while the drag goes on, not only once it
/// ends. Poses every 40 ms at 30 pulses per second, each imaged at once or at the next pulse;
/// the frames published during the drag follow it, and the last pose is on screen after it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_live_drag_without_drafts_shows_its_pulses_while_it_goes_on() {
    let host = host(2);
    let h = host.create("demo-station").await.unwrap();
    let (tx, _replies) = tokio::sync::mpsc::unbounded_channel();
    let mut seq = 0;
    let mut send = |command: Command| {
        seq += 1;
        h.send(Envelope { seq, command }, tx.clone()).unwrap();
        seq
    };
    let rate: Command =
        serde_json::from_value(serde_json::json!({ "type": "pulse_rate", "pps": 30.0 })).unwrap();
    send(rate);
    let on = send(Command::Live { on: true });
    let mut frames = h.frames();
    let mut shown = std::collections::BTreeSet::new();
    let mut last = on;
    for k in 0..25 {
        tokio::time::sleep(std::time::Duration::from_millis(40)).await;
        last = send(pose(2.0 * k as f64, 0.0));
        let f = frames.borrow_and_update();
        shown.extend(f.values().map(|f| f.input_seq).filter(|s| *s > on));
    }
    assert!(
        shown.len() >= 5,
        "frames of the drag shown while it went on: inputs {shown:?}"
    );
    let settled = tokio::time::timeout(std::time::Duration::from_secs(10), async {
        loop {
            if frames
                .borrow_and_update()
                .values()
                .any(|f| f.input_seq == last)
            {
                return;
            }
            frames.changed().await.unwrap();
        }
    })
    .await;
    assert!(settled.is_ok(), "the last pose is shown once the drag ends");
}
