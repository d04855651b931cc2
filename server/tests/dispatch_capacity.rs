//! A server whose in-process worker is full refuses a new session with a clear 503
//! (`at_capacity`, with `Retry-After`), and the sessions already running go on.

use serde_json::json;

use crate::dispatch::{Client, Received, acked};
use crate::dispatch_support::demo_server_sized;

#[tokio::test]
async fn a_session_beyond_capacity_gets_a_clear_503_and_running_ones_go_on() {
    let toml = render_worker::session::demo::demo_station_toml(&[]);
    let srv = demo_server_sized(true, None, &toml, 1).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_, first) = learner.start_demo_attempt().await;
    let (_, (status, refused)) = learner.try_demo_attempt().await;
    assert_eq!(status, 503, "{refused}");
    assert_eq!(refused["error"]["code"], "at_capacity", "{refused}");
    assert_eq!(refused["error"]["capacity"], 1);
    assert_eq!(refused["error"]["retry_after_s"], 30);
    let message = refused["error"]["message"].as_str().unwrap();
    assert!(message.contains("all 1 live-session slots"), "{message}");
    // The running session still answers and renders.
    let mut ws = learner.websocket(first["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == [1] && r.frames.last() == Some(&1))
        .await;
}
