//! Websocket fuzzing of the session relay (the websocket half of the fuzzing): malformed
//! JSON, oversized messages, out-of-range and wrong-typed values, unknown fields, seeded random
//! mutations of valid commands, and bursts of bad input with and without reading. Every bad
//! input gets an error naming the field (or, for an oversized message, close code 1009), nothing
//! panics, and the server stays healthy: the session and a new one still take commands.

use std::time::Duration;

use futures::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::frame::Frame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::{Data, OpCode};

use super::dispatch::{Client, Received, Ws, acked, demo_server};
use super::dispatch_hardening::close_frame;

/// Hand-written bad inputs: the text sent and the field its error must name.
fn bad_inputs() -> Vec<(String, &'static str)> {
    let cmd = |c: Value| json!({ "type": "command", "seq": 1, "command": c }).to_string();
    let nested = format!("{}{}", "[".repeat(10_000), "]".repeat(10_000));
    vec![
        // Malformed JSON and messages.
        ("".into(), "message"),
        ("{".into(), "message"),
        ("not json".into(), "message"),
        (nested, "message"),
        ("[]".into(), "type"),
        ("null".into(), "type"),
        (r#"{"type":"commandx"}"#.into(), "type"),
        (r#"{"type":"command"}"#.into(), "seq"),
        (r#"{"type":"command","seq":1}"#.into(), "command"),
        (r#"{"type":"command","seq":1,"command":null}"#.into(), "command.type"),
        (r#"{"type":"command","seq":1,"command":[]}"#.into(), "command.type"),
        // Sequence numbers: wrong type, negative, fractional, zero, beyond u64, beyond 2^63-1.
        (r#"{"type":"command","seq":"1","command":{"type":"shot"}}"#.into(), "seq"),
        (r#"{"type":"command","seq":-1,"command":{"type":"shot"}}"#.into(), "seq"),
        (r#"{"type":"command","seq":1.5,"command":{"type":"shot"}}"#.into(), "seq"),
        (r#"{"type":"command","seq":0,"command":{"type":"shot"}}"#.into(), "seq"),
        (
            r#"{"type":"command","seq":18446744073709551616,"command":{"type":"shot"}}"#.into(),
            "seq",
        ),
        (
            r#"{"type":"command","seq":9223372036854775808,"command":{"type":"shot"}}"#.into(),
            "seq",
        ),
        // Unknown fields and commands.
        (
            r#"{"type":"command","seq":1,"command":{"type":"shot"},"extra":1}"#.into(),
            "extra",
        ),
        (cmd(json!({ "type": "shot", "power": 9 })), "command.power"),
        (cmd(json!({ "type": "teleport" })), "command.type"),
        // Wrong types and NaN-like strings.
        (
            cmd(json!({ "type": "carm_pose", "orbital_deg": "20", "angular_deg": 0 })),
            "command.orbital_deg",
        ),
        (
            cmd(json!({ "type": "carm_pose", "orbital_deg": "NaN", "angular_deg": 0 })),
            "command.orbital_deg",
        ),
        (
            cmd(json!({ "type": "carm_pose", "orbital_deg": 0, "angular_deg": "-Infinity" })),
            "command.angular_deg",
        ),
        (cmd(json!({ "type": "live", "on": "yes" })), "command.on"),
        (
            cmd(json!({ "type": "technique", "kvp": -80, "ma": 2 })),
            "command.kvp",
        ),
        (
            cmd(json!({ "type": "technique", "kvp": 4_294_967_296u64, "ma": 2 })),
            "command.kvp",
        ),
        // Out of range: huge, negative, beyond f64.
        (
            cmd(json!({ "type": "carm_pose", "orbital_deg": 1e308, "angular_deg": 0 })),
            "command.orbital_deg",
        ),
        (
            r#"{"type":"command","seq":1,"command":{"type":"carm_pose","orbital_deg":1e400,"angular_deg":0}}"#.into(),
            "message",
        ),
        (cmd(json!({ "type": "needle_feed", "mm": -5 })), "command.mm"),
        (
            cmd(json!({ "type": "inject", "agent": "contrast", "volume_ml": 0, "rate_ml_per_s": 1 })),
            "command.volume_ml",
        ),
        (
            cmd(json!({ "type": "carm_pose", "orbital_deg": 0, "angular_deg": 0, "table_mm": [0, 0, -1e9] })),
            "command.table_mm[2]",
        ),
        // Text the log could not store, and too long.
        (
            cmd(json!({ "type": "annotate", "pixel": [1, 1], "label": "L4\u{0}" })),
            "command.label",
        ),
        (
            cmd(json!({ "type": "needle_place", "instrument": "x".repeat(10_000), "entry_mm": [0, 0, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] })),
            "command.instrument",
        ),
        (
            cmd(json!({ "type": "annotate", "pixel": [1, 1], "label": "x".repeat(60_000) })),
            "command.label",
        ),
        // Views.
        (r#"{"type":"views","visible":["xray"]}"#.into(), "visible"),
        (r#"{"type":"views","visible":"fluoroscopy"}"#.into(), "visible"),
    ]
}

/// Reads `n` answers (acknowledgements and errors), at most 60 s apart; panics on a close.
async fn answers(ws: &mut Ws, n: usize) -> Vec<Value> {
    let mut out = Vec::new();
    while out.len() < n {
        let m = tokio::time::timeout(Duration::from_secs(60), ws.ws.next())
            .await
            .expect("an answer within 60 s")
            .expect("the socket stays open")
            .expect("no socket error");
        match m {
            Message::Text(t) => {
                let v: Value = serde_json::from_str(&t).expect("answers are JSON");
                if v["type"] == "ack" || v["type"] == "error" {
                    out.push(v);
                }
            }
            Message::Close(f) => panic!("the socket closed: {f:?}"),
            _ => {}
        }
    }
    out
}

/// The small seedable generator of the fuzz (SplitMix64, as `sim_core::rng`).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// A valid command, then one random mutation of it: a field's value replaced by a hostile one,
/// a field removed or added, or the whole text cut short.
fn mutated(rng: &mut Rng, seq: u64) -> String {
    let valid = [
        json!({ "type": "carm_pose", "orbital_deg": 20, "angular_deg": -5, "table_mm": [0, 0, 0] }),
        json!({ "type": "technique", "kvp": 80, "ma": 2.0 }),
        json!({ "type": "needle_feed", "mm": 2 }),
        json!({ "type": "needle_roll", "deg": 30 }),
        json!({ "type": "annotate", "pixel": [10, 10], "label": "L4" }),
        json!({ "type": "inject", "agent": "contrast", "volume_ml": 1, "rate_ml_per_s": 0.5 }),
        json!({ "type": "probe_settings", "depth_mm": 50, "gain_db": 10, "frequency_mhz": 5 }),
    ];
    let hostile = [
        json!("NaN"),
        json!(null),
        json!(true),
        json!(-1),
        json!(1e308),
        json!(-1e308),
        json!(u64::MAX),
        json!([]),
        json!({}),
        json!("x".repeat(300)),
        json!("\u{0}"),
        json!([1e308, "a", null]),
    ];
    let mut c = valid[rng.below(valid.len())].clone();
    let keys: Vec<String> = c.as_object().unwrap().keys().cloned().collect();
    let key = keys[rng.below(keys.len())].clone();
    let text = match rng.below(4) {
        0 => {
            c[&key] = hostile[rng.below(hostile.len())].clone();
            None
        }
        1 => {
            c.as_object_mut().unwrap().remove(&key);
            None
        }
        2 => {
            c["unexpected"] = hostile[rng.below(hostile.len())].clone();
            None
        }
        _ => {
            let full = json!({ "type": "command", "seq": seq, "command": c }).to_string();
            let cut = rng.below(full.len());
            Some(full[..cut].to_string())
        }
    };
    text.unwrap_or_else(|| json!({ "type": "command", "seq": seq, "command": c }).to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_websocket_input_gets_clear_errors_and_the_server_stays_healthy() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_attempt, session) = learner.start_demo_attempt().await;
    let ws_path = session["ws"].as_str().unwrap().to_string();
    let mut ws = learner.websocket(&ws_path).await;
    let mut got = Received::default();
    ws.until(&mut got, |r| !r.texts.is_empty()).await;

    // Each hand-written bad input, one at a time: an error naming its field.
    let cases = bad_inputs();
    for (text, field) in &cases {
        ws.ws
            .send(Message::Text(text.clone().into()))
            .await
            .expect("send");
        let a = answers(&mut ws, 1).await;
        assert_eq!(a[0]["type"], "error", "{text:.200}: {}", a[0]);
        assert_eq!(a[0]["error"]["field"], *field, "{text:.200}: {}", a[0]);
        assert!(
            !a[0]["error"]["message"].as_str().unwrap_or("").is_empty(),
            "{}",
            a[0]
        );
    }
    // A binary message is not understood either.
    ws.ws
        .send(Message::Binary(vec![0u8; 100].into()))
        .await
        .expect("send");
    let a = answers(&mut ws, 1).await;
    assert_eq!(a[0]["error"]["field"], "message", "{}", a[0]);
    // None of it was applied.
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == [1]).await;

    // Seeded random mutations of valid commands, sent without reading, then read: one answer
    // each, in order; refusals name a field.
    let mut rng = Rng(20);
    let n = 2_000u64;
    for i in 0..n {
        let text = mutated(&mut rng, 2 + i);
        ws.ws.feed(Message::Text(text.into())).await.expect("send");
    }
    ws.ws.flush().await.expect("flush");
    let a = answers(&mut ws, n as usize).await;
    let (mut accepted, mut refused) = (0, 0);
    let mut last_seq = 1;
    for v in &a {
        if v["type"] == "ack" {
            accepted += 1;
            let seq = v["seq"].as_u64().unwrap();
            assert!(seq > last_seq, "acknowledged in order: {v}");
            last_seq = seq;
        } else {
            refused += 1;
            let field = v["error"]["field"].as_str().unwrap_or("");
            assert!(!field.is_empty(), "{v}");
        }
    }
    eprintln!("websocket fuzz: {n} mutated commands, {accepted} accepted, {refused} refused");
    assert!(refused > n as usize / 2, "most mutations are refused");

    // The session still works, and so does a new one of another learner.
    ws.send(10_000, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r).contains(&10_000)).await;
    let other = Client::login(srv.addr, "learner2@demo.invalid").await;
    let (_, s2) = other.start_demo_attempt().await;
    let mut ws2 = other.websocket(s2["ws"].as_str().unwrap()).await;
    let mut got2 = Received::default();
    ws2.send(1, json!({ "type": "shot" })).await;
    ws2.until(&mut got2, |r| acked(r) == [1]).await;

    // Oversized: just under the limit is an ordinary error, over it closes with 1009.
    let label = "x".repeat(server::dispatch::MAX_CLIENT_MESSAGE_BYTES - 200);
    let under = json!({ "type": "command", "seq": 10_001, "command": { "type": "annotate", "pixel": [1, 1], "label": label } });
    ws.ws
        .send(Message::Text(under.to_string().into()))
        .await
        .expect("send");
    let a = answers(&mut ws, 1).await;
    assert_eq!(a[0]["error"]["field"], "command.label", "{}", a[0]);
    let over = "x".repeat(server::dispatch::MAX_CLIENT_MESSAGE_BYTES + 1);
    ws.ws.send(Message::Text(over.into())).await.expect("send");
    let (code, reason) = close_frame(&mut ws, Duration::from_secs(30)).await;
    assert_eq!(code, 1009, "{reason}");
    // A message in fragments, each frame under the limit and the whole over it: 1009 too.
    let mut ws = learner.websocket(&ws_path).await;
    let part = || vec![b'x'; server::dispatch::MAX_CLIENT_MESSAGE_BYTES / 2];
    let frames = [
        Frame::message(part(), OpCode::Data(Data::Text), false),
        Frame::message(part(), OpCode::Data(Data::Continue), false),
        Frame::message(part(), OpCode::Data(Data::Continue), true),
    ];
    for f in frames {
        if ws.ws.send(Message::Frame(f)).await.is_err() {
            break; // The server may close before the last fragment.
        }
    }
    let (code, reason) = close_frame(&mut ws, Duration::from_secs(30)).await;
    assert_eq!(code, 1009, "{reason}");
    // And the session goes on after the oversized messages.
    let mut ws = learner.websocket(&ws_path).await;
    ws.send(10_002, json!({ "type": "shot" })).await;
    let mut got = Received::default();
    ws.until(&mut got, |r| acked(r).contains(&10_002)).await;
    // The server answers its health check with both sessions live.
    let (_, health) = learner.call("GET", "/healthz", None).await;
    assert_eq!(health["sessions"]["live"], 2, "{health}");
}

/// A burst of bad input with the answers read while sending (the without-reading variant is in
/// the test above): every message is answered.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_bad_input_read_while_sending_is_answered() {
    let srv = demo_server(true, None).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_attempt, session) = learner.start_demo_attempt().await;
    let ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let (mut tx, mut rx) = ws.ws.split();
    let cases = bad_inputs();
    let n = 3_000usize;
    let reader = tokio::spawn(async move {
        let mut got = 0usize;
        while got < n {
            let m = tokio::time::timeout(Duration::from_secs(60), rx.next())
                .await
                .expect("an answer within 60 s")
                .expect("open")
                .expect("ok");
            if let Message::Text(t) = m {
                let v: Value = serde_json::from_str(&t).unwrap();
                if v["type"] == "error" {
                    assert!(v["error"]["field"].as_str().is_some_and(|f| !f.is_empty()));
                    got += 1;
                }
            }
        }
        got
    });
    for i in 0..n {
        let (text, _) = &cases[i % cases.len()];
        tx.send(Message::Text(text.clone().into()))
            .await
            .expect("send");
    }
    let got = tokio::time::timeout(Duration::from_secs(300), reader)
        .await
        .expect("answered within 300 s")
        .expect("reader");
    assert_eq!(got, n);
}
