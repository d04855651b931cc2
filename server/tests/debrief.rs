//! The debrief of a submitted attempt (`dispatch::debrief`): criteria with value, tolerance and
//! explanation, and the session's events from a step-by-step replay of its log.

use serde_json::{Value, json};

use crate::disclosure::{run_session, script, station_toml};
use crate::dispatch_support::{Client, Received, acked, demo_server_for};

fn kinds(d: &Value) -> Vec<&str> {
    d["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["kind"].as_str().unwrap())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_debrief_explains_each_criterion_and_ticks_every_event() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    let (attempt, _) = run_session(&learner).await;
    let path = format!("/api/attempts/{attempt}/debrief");
    let t0 = std::time::Instant::now();
    let (s, d) = learner.call("GET", &path, None).await;
    eprintln!("debrief of {} commands: {:?}", d["steps"], t0.elapsed());
    assert_eq!(s, 200, "{d}");
    assert_eq!(
        d["steps"],
        script().len() + 1,
        "every command and the submit"
    );
    let tip = d["criteria"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == "tip_at_target")
        .unwrap();
    assert!(
        tip["value"].is_number() && tip["tolerance"].is_object(),
        "{tip}"
    );
    let words = tip["explanation"].as_str().unwrap();
    assert!(
        words.starts_with("Measured ") && words.contains(" mm"),
        "{words}"
    );
    for c in d["criteria"].as_array().unwrap() {
        let e = c["explanation"].as_str().unwrap();
        let expected = if c["status"] == "missing" {
            "Not measured"
        } else {
            "Measured "
        };
        assert!(e.starts_with(expected), "{c}");
    }
    // The script's events: 4 shots and a live run, two punctures, an injection and a plunger
    // press, the bone stop at the facet, the submit last.
    let k = kinds(&d);
    assert_eq!(k.iter().filter(|k| **k == "image").count(), 4, "{k:?}");
    assert_eq!(k.iter().filter(|k| **k == "puncture").count(), 2, "{k:?}");
    assert_eq!(k.iter().filter(|k| **k == "injection").count(), 2, "{k:?}");
    assert!(k.contains(&"bone_contact"), "{k:?}");
    assert!(
        !k.contains(&"violation"),
        "the demo path stays outside the dural sac: {k:?}"
    );
    assert_eq!(k.last(), Some(&"submit"));
    let steps: Vec<u64> = d["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["step"].as_u64().unwrap())
        .collect();
    assert!(
        steps.windows(2).all(|w| w[0] <= w[1]),
        "in order: {steps:?}"
    );
    // The faculty review reads the same debrief.
    let (s, f) = faculty.call("GET", &path, None).await;
    assert_eq!(s, 200);
    assert_eq!(f["events"], d["events"]);
    // And the ultrasound images of the replay, not only the fluoroscopy ones (the station's
    // probe rests on the skin over its target from the start): the first and the last step's
    // B-mode images differ, as the probe was picked up, moved and set deeper in between.
    let frame = |q: String| {
        let url = format!(
            "http://{}/api/attempts/{attempt}/replay/frame?{q}",
            srv.addr
        );
        let cookie = faculty.cookie.clone();
        async move {
            reqwest::Client::new()
                .get(url)
                .header("Cookie", cookie)
                .send()
                .await
                .unwrap()
        }
    };
    let steps = d["steps"].as_u64().unwrap();
    let mut jpegs = Vec::new();
    for q in [
        "step=1&view=ultrasound".to_string(),
        format!("step={steps}&view=ultrasound"),
    ] {
        let r = frame(q).await;
        assert_eq!(r.status(), 200);
        assert_eq!(r.headers()["content-type"], "image/jpeg");
        let jpeg = r.bytes().await.unwrap();
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8], "a JPEG");
        jpegs.push(jpeg);
    }
    assert_ne!(jpegs[0], jpegs[1]);
    assert_eq!(frame("step=1&view=sideways".into()).await.status(), 400);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dural_puncture_is_a_violation_tick_and_open_attempts_have_no_debrief() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let path = format!("/api/attempts/{attempt}/debrief");
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    // Straight down the midline into the demo dural sac (y -35 to -20, |x| < 8).
    ws.send(1, json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [0, -120, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] })).await;
    ws.send(2, json!({ "type": "needle_feed", "mm": 40 })).await;
    ws.send(3, json!({ "type": "needle_feed", "mm": 50 })).await;
    ws.until(&mut got, |r| acked(r).len() == 3).await;
    let (s, body) = learner.call("GET", &path, None).await;
    assert_eq!(s, 409, "{body}");
    ws.send(4, json!({ "type": "submit" })).await;
    ws.until(&mut got, |r| {
        r.texts.iter().any(|t| t["type"] == "technical_result")
    })
    .await;
    let (s, d) = learner.call("GET", &path, None).await;
    assert_eq!(s, 200, "{d}");
    let violations: Vec<&Value> = d["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| e["kind"] == "violation")
        .collect();
    assert_eq!(violations.len(), 1, "{d:#}");
    assert_eq!(violations[0]["seq"], 3, "the feed that entered the sac");
    assert_eq!(
        violations[0]["label"],
        "The tip never entered the dural sac."
    );
    let dural = d["criteria"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == "no_dural_puncture")
        .unwrap();
    assert!(
        dural["explanation"]
            .as_str()
            .unwrap()
            .contains("safety criterion"),
        "{dural}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_reveal_outlines_the_structures_the_needle_passed_through() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let path = format!("/api/attempts/{attempt}/reveal");
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    // In AP, down the midline through the demo dural sac (y -35 to -20, |x| < 8, z -60 to 40).
    ws.send(1, json!({ "type": "needle_place", "instrument": "spinal-22g", "entry_mm": [0, -120, 0], "direction": [0, 1, 0], "bevel_reference": [1, 0, 0] })).await;
    ws.send(2, json!({ "type": "needle_feed", "mm": 45 })).await;
    ws.send(3, json!({ "type": "needle_feed", "mm": 45 })).await;
    ws.send(4, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r).len() == 4).await;
    let (s, body) = learner.call("GET", &path, None).await;
    assert_eq!(s, 409, "{body}");
    ws.send(5, json!({ "type": "submit" })).await;
    ws.until(&mut got, |r| {
        r.texts.iter().any(|t| t["type"] == "technical_result")
    })
    .await;
    let (s, r) = learner.call("GET", &path, None).await;
    assert_eq!(s, 200, "{r}");
    assert_eq!(r["step"], 5);
    let touched: Vec<&str> = r["touched"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t.as_str().unwrap())
        .collect();
    assert!(touched.contains(&"dural_sac"), "{touched:?}");
    let sac = r["outlines"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["structure"] == "dural_sac")
        .unwrap_or_else(|| panic!("{r}"));
    // The sac is 16 mm wide at the isocentre: about 16 x 2.03 / 0.586 = 55 pixels in AP, centred.
    let rows: Vec<u64> = sac["runs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|run| run[0].as_u64().unwrap())
        .collect();
    let cols: Vec<u64> = sac["runs"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|run| [run[1].as_u64().unwrap(), run[2].as_u64().unwrap()])
        .collect();
    let (x0, x1) = (*cols.iter().min().unwrap(), *cols.iter().max().unwrap());
    assert!((50..=62).contains(&(x1 - x0 + 1)), "{x0}..{x1}");
    assert!(x0 < 256 && x1 > 256, "{x0}..{x1}");
    assert!(rows.iter().min() < rows.iter().max());
    assert!(
        r["outlines"]
            .as_array()
            .unwrap()
            .iter()
            .all(|o| o["structure"] != "skin"),
        "envelopes are not outlined"
    );
}
