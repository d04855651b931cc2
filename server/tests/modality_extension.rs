//! An open modality seam, end to end: a modality that no crate of the workspace ships, with
//! its own name (`thermal`), its own command kind (`thermal_gain`) and its own view (`thermal`,
//! wire code 77), is registered with the in-process host's modality factory and nothing else;
//! a station lists it; its frames stream through the real server's relay to a websocket client,
//! which learns the view's code and the command kind from the hello alone, and its command
//! counts as the engagement event the modality declares.

use std::time::Duration;

use futures::StreamExt;
use render_worker::session::frame::EncodedFrame;
use render_worker::session::{
    Command, CommandError, CommandSpec, Engagement, ErrorCode, Modality, ModalityError,
    ModalityFactory, ModalitySpec, ViewId, ViewImage, World, WorldChange,
};
use serde_json::{Value, json};
use sim_core::rubric::Measurements;
use tokio_tungstenite::tungstenite::Message;

use crate::dispatch::{Client, demo_server_with};

/// The thermal view: a code no built-in view has.
const THERMAL_VIEW: ViewId = ViewId::new("thermal", 77);

/// What the thermal modality declares.
static THERMAL: ModalitySpec = ModalitySpec {
    name: "thermal",
    label: "thermal imaging",
    views: &[THERMAL_VIEW],
    commands: &[CommandSpec::new(
        "thermal_gain",
        Some(Engagement::ViewChanged),
    )],
    constants: &[("max_gain", 8.0)],
};

/// The fields of `thermal_gain`.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Gain {
    gain: f64,
}

/// A thermal camera over the skin: its image brightens with the gain and with each needle
/// move (the needle warms the skin).
struct Thermal {
    gain: f64,
    needle_moves: u32,
    version: u64,
    rendered: u64,
}

impl Modality for Thermal {
    fn spec(&self) -> &'static ModalitySpec {
        &THERMAL
    }

    fn apply(&mut self, command: &Command, _: &World) -> Result<Value, CommandError> {
        let Command::Modality(c) = command else {
            return Err(CommandError::field(
                "command.type",
                ErrorCode::ModalityUnavailable,
                "thermal handles thermal_gain only",
            ));
        };
        let Gain { gain } = c.parse()?;
        if !(gain.is_finite() && (0.0..=8.0).contains(&gain)) {
            return Err(CommandError::field(
                "command.gain",
                ErrorCode::OutOfRange,
                "gain is 0 to 8",
            ));
        }
        self.gain = gain;
        self.version += 1;
        Ok(json!({ "gain": gain }))
    }

    fn world_changed(&mut self, change: &WorldChange, _: &World) {
        if *change == WorldChange::Needle {
            self.needle_moves += 1;
            self.version += 1;
        }
    }

    fn dirty_views(&self) -> Vec<ViewId> {
        if self.version != self.rendered {
            vec![THERMAL_VIEW]
        } else {
            Vec::new()
        }
    }

    fn render(&mut self, _: ViewId, _: &World) -> Result<Option<ViewImage>, ModalityError> {
        self.rendered = self.version;
        let level = (20.0 * self.gain + 10.0 * f64::from(self.needle_moves)).min(255.0) as u8;
        Ok(Some(ViewImage {
            width: 48,
            height: 32,
            pixels: vec![level; 48 * 32],
        }))
    }

    fn measure(&self, _: &World, out: &mut Measurements) {
        out.insert("thermal_gain_ratio".into(), self.gain / 8.0);
    }

    fn record(&self) -> Value {
        json!({ "gain": self.gain })
    }

    fn state(&self) -> Value {
        json!({ "gain": self.gain, "needle_moves": self.needle_moves })
    }

    fn restore(&mut self, state: Value) -> Result<(), ModalityError> {
        let bad = || ModalityError::State {
            modality: "thermal",
            message: format!("not a thermal state: {state}"),
        };
        self.gain = state["gain"].as_f64().ok_or_else(bad)?;
        self.needle_moves = state["needle_moves"]
            .as_u64()
            .and_then(|n| u32::try_from(n).ok())
            .ok_or_else(bad)?;
        self.version = 1;
        self.rendered = 0;
        Ok(())
    }
}

/// The next message of the socket (at most 60 s: a hang fails the test).
async fn next(ws: &mut crate::dispatch::Ws) -> Message {
    tokio::time::timeout(Duration::from_secs(60), ws.ws.next())
        .await
        .expect("a message within 60 s")
        .expect("open")
        .expect("ok")
}

#[tokio::test]
async fn a_new_modality_streams_its_own_view_through_the_server() {
    let srv = demo_server_with(true, None, &["thermal"]).await;
    let factory = ModalityFactory::standard()
        .with(&THERMAL, |_| {
            Box::new(Thermal {
                gain: 1.0,
                needle_moves: 0,
                version: 1,
                rendered: 0,
            })
        })
        .expect("thermal registers");
    srv.dispatcher
        .local_host()
        .expect("in-process host")
        .set_modalities(factory);

    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    // The hello lists the thermal view with its code and the thermal command kind.
    let hello: Value = loop {
        if let Message::Text(t) = next(&mut ws).await {
            break serde_json::from_str(&t).unwrap();
        }
    };
    assert_eq!(hello["type"], "hello");
    let info = &hello["session"];
    assert!(
        info["modalities"]
            .as_array()
            .unwrap()
            .contains(&json!("thermal")),
        "{info}"
    );
    let views = info["protocol"]["views"].as_array().unwrap();
    let thermal = views
        .iter()
        .find(|v| v["name"] == "thermal")
        .expect("thermal view");
    assert_eq!(thermal["code"], 77);
    assert_eq!(thermal["modality"], "thermal");
    let kinds = info["protocol"]["commands"].as_array().unwrap();
    assert!(kinds.iter().any(|k| k["type"] == "thermal_gain"
        && k["modality"] == "thermal"
        && k["engagement"] == "view_changed"));
    assert_eq!(info["protocol"]["constants"]["thermal"]["max_gain"], 8.0);

    // Its command, and a bad one named by its field.
    ws.send(1, json!({ "type": "thermal_gain", "gain": 4.0 }))
        .await;
    ws.send(2, json!({ "type": "thermal_gain", "gain": 40.0 }))
        .await;
    let (mut ack, mut error, mut thermal_frames) = (None, None, Vec::new());
    while ack.is_none() || error.is_none() || thermal_frames.is_empty() {
        match next(&mut ws).await {
            Message::Text(t) => {
                let m: Value = serde_json::from_str(&t).unwrap();
                match m["type"].as_str() {
                    Some("ack") => ack = Some(m),
                    Some("error") => error = Some(m),
                    _ => {}
                }
            }
            Message::Binary(b) => {
                assert_eq!(&b[..4], b"SIMF");
                if b[5] == 77 {
                    let f = EncodedFrame::parse(&b).expect("a thermal frame");
                    thermal_frames.push(f);
                }
            }
            _ => {}
        }
    }
    let ack = ack.unwrap();
    assert_eq!(
        (ack["seq"].as_u64(), &ack["outcome"]["gain"]),
        (Some(1), &json!(4.0))
    );
    assert_eq!(ack["engagement"], "view_changed");
    let error = error.unwrap();
    assert_eq!(error["error"]["field"], "command.gain", "{error}");
    let f = thermal_frames.last().unwrap();
    assert_eq!(f.view, THERMAL_VIEW);
    assert_eq!((f.width, f.height), (48, 32));

    // The accepted command is in the session's durable log and counts as the engagement its
    // modality declared.
    for _ in 0..100 {
        let (_, events) = learner
            .call("GET", &format!("/api/attempts/{attempt}/activity"), None)
            .await;
        if events
            .as_array()
            .unwrap()
            .iter()
            .any(|e| e["kind"] == "view_changed" && e["detail"]["command"] == "thermal_gain")
        {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("no view_changed event for thermal_gain");
}
