//! What a learner's browser is told (`server::dispatch::disclosure`, `records::modes`): every
//! message of a scripted session with every command kind, recorded and checked key by key; the
//! station's mode set by the course's faculty only; the station definition learners get.

use std::collections::BTreeSet;

use serde_json::{Value, json};

use crate::dispatch_support::{Client, Received, acked, demo_server_for};
use crate::e2e_browser::ultrasound_demo_station_toml;

/// The demo station with fluoroscopy, ultrasound and contrast and a loss-of-resistance syringe.
pub(crate) fn station_toml() -> String {
    ultrasound_demo_station_toml()
        .replace(
            "modalities = [\"fluoroscopy\", \"ultrasound\"]",
            "modalities = [\"fluoroscopy\", \"ultrasound\", \"contrast\"]",
        )
        .replace(
            "[[instruments]]\nid = \"contrast-syringe\"",
            "[[instruments]]\nid = \"lor-syringe\"\nkind = \"loss-of-resistance-syringe\"\n\n\
             [[instruments]]\nid = \"contrast-syringe\"",
        )
}

/// Every command kind a learner's hands and eyes use (session core, fluoroscopy, ultrasound,
/// contrast), including a loss of resistance and a bone contact.
pub(crate) fn script() -> Vec<Value> {
    vec![
        json!({ "type": "technique", "kvp": 85, "ma": 2.5 }),
        json!({ "type": "brightness", "curve": "standard" }),
        json!({ "type": "pulse_rate", "pps": 15 }),
        json!({ "type": "collimation", "width_mm": 250.0, "height_mm": 200.0 }),
        json!({ "type": "magnification", "field_mm": 225.0 }),
        json!({ "type": "recursive_filter", "level": "low" }),
        json!({ "type": "grid", "grid": "in" }),
        json!({ "type": "carm_pose", "orbital_deg": 20, "angular_deg": -5 }),
        json!({ "type": "shot" }),
        json!({ "type": "live", "on": true }),
        json!({ "type": "live", "on": false }),
        json!({ "type": "carm_pose", "orbital_deg": 0, "angular_deg": 0 }),
        json!({ "type": "shot" }),
        json!({ "type": "skin_marker", "pixel": [214.0, 256.0] }),
        json!({ "type": "needle_puncture", "instrument": "spinal-22g" }),
        json!({ "type": "needle_tilt", "cc_deg": 1, "ml_deg": -1 }),
        json!({ "type": "needle_feed", "mm": 30 }),
        json!({ "type": "needle_roll", "deg": 90 }),
        json!({ "type": "syringe", "action": "attach", "medium": "saline" }),
        json!({ "type": "plunger_hold", "on": true }),
        json!({ "type": "needle_feed", "mm": 40 }),
        json!({ "type": "needle_feed", "mm": 40 }),
        json!({ "type": "plunger_hold", "on": false }),
        json!({ "type": "plunger", "ml": 0.2 }),
        json!({ "type": "aspirate" }),
        json!({ "type": "needle_feed", "mm": 40 }),
        json!({ "type": "syringe", "action": "detach" }),
        json!({ "type": "probe_select", "instrument": "linear-probe" }),
        json!({ "type": "probe_pose", "position_mm": [10.0, -120.0, 0.0], "beam_dir": [0.0, 1.0, 0.0], "marker_dir": [0.0, 0.0, 1.0] }),
        json!({ "type": "probe_move", "slide_mm": [2.0, 0.0] }),
        json!({ "type": "probe_drag", "pixel": [190.0, 140.0] }),
        json!({ "type": "probe_settings", "depth_mm": 60 }),
        json!({ "type": "probe_freeze", "on": true }),
        json!({ "type": "probe_freeze", "on": false }),
        json!({ "type": "needle_withdraw", "mm": 5 }),
        json!({ "type": "inject", "agent": "contrast", "volume_ml": 1, "rate_ml_per_s": 0.5 }),
        json!({ "type": "tick" }),
        json!({ "type": "inject_stop" }),
        // Out, and in again onto the demo facet's bone (x 22, z -10 under the flat skin).
        json!({ "type": "needle_withdraw", "mm": 50 }),
        json!({ "type": "needle_withdraw", "mm": 50 }),
        json!({ "type": "skin_marker", "pixel": [179.8, 290.6] }),
        json!({ "type": "needle_puncture", "instrument": "spinal-22g" }),
        json!({ "type": "needle_feed", "mm": 45 }),
        json!({ "type": "needle_feed", "mm": 40 }),
        json!({ "type": "annotate", "pixel": [256.0, 256.0], "label": "behind_l4" }),
        json!({ "type": "shot" }),
    ]
}

/// Every key of the messages a browser may receive, at any depth. A new key fails the test
/// until someone decides whether a physician would know it (then it goes here) or not (then
/// `disclosure::NEVER` or `disclosure::HINTS` takes it).
const ALLOWED_KEYS: &[&str] = &[
    // Message envelopes and the hello.
    "type",
    "seq",
    "t_ms",
    "duplicate",
    "engagement",
    "outcome",
    "error",
    "field",
    "code",
    "message",
    "last_seq",
    "session",
    "id",
    "station_id",
    "modalities",
    "views",
    "mode",
    "unavailable_modalities",
    "protocol",
    "commands",
    "modality",
    "constants",
    "contrast",
    "settle_ms",
    "tick_ms",
    "fluoroscopy",
    "default_pulse_rate_pps",
    "max_tilt_deg",
    "frame_draft_flag",
    "frame_header_bytes",
    "frame_header_version",
    "frame_magic",
    "name",
    // The C-arm's console: technique, dose, detector, collimation.
    "acquisitions",
    "air_gap_mm",
    "collimation",
    "detector",
    "detector_mm",
    "dose",
    "air_kerma_mgy",
    "fluoro_time_s",
    "kerma_area_product_gycm2",
    "exposure_s",
    "field_mm",
    "grid",
    "image",
    "pulse_rate_pps",
    "recursive_filter",
    "technique",
    "brightness",
    "detector_kerma_ngy",
    "kvp",
    "limited_by",
    "ma",
    "next_kvp",
    "next_ma",
    "live",
    "width_mm",
    "height_mm",
    "iris_diameter_mm",
    "carm_deg",
    "image_carm_deg",
    "left_mm",
    "right_mm",
    "top_mm",
    "bottom_mm",
    "iris_radius_mm",
    "pps",
    "on",
    "level",
    "curve",
    // The hands: depth marks on the shaft, hub tilt, force, syringe, aspirate.
    "depth_mm",
    "hub_deviation_deg",
    "punctured",
    "bone_contact",
    "force",
    "friction_n",
    "peak_n",
    "pop",
    "samples",
    "tip_n",
    "total_n",
    "advanced_mm",
    "retraced_mm",
    "slides",
    "stop",
    "withdrawn_mm",
    "attached",
    "hold",
    "text",
    "lor",
    "resistance",
    "gave_way",
    "injected_ml",
    "remaining_ml",
    "medium",
    "pressed_ml",
    // The injection.
    "injecting",
    "iodine_injected_ml",
    // The scanner's console and the probe in the learner's hand.
    "ultrasound",
    "frozen",
    "band_mhz",
    "beam_dir",
    "depth_range_mm",
    "focus_mm",
    "height",
    "marker_side",
    "origin_mm",
    "pixel_mm",
    "width",
    "instrument",
    "marker_dir",
    "position_mm",
    "probe",
    "settings",
    "dynamic_range_db",
    "frequency_mhz",
    "gain_db",
    "tgc_db",
    // The assessment-mode result message.
    "result",
    "source",
    "withheld",
    "attempt_id",
    "notice",
];

/// Tissue words (the mechanical classes of `sim_core::needle::Tissue` and the structures behind
/// them) that no string a browser receives may contain.
const TISSUE_WORDS: &[&str] = &[
    "subcutaneous",
    "muscle",
    "interspinous",
    "flavum",
    "epidural",
    "intrathecal",
    "dura",
    "csf",
    "nerve",
    "root",
    "vessel",
    "disc",
    "bone",
    "soft_tissue",
    "ligament",
    "fat",
];

fn walk<'a>(v: &'a Value, keys: &mut BTreeSet<&'a str>, strings: &mut Vec<&'a str>) {
    match v {
        Value::Object(o) => {
            for (k, x) in o {
                keys.insert(k);
                walk(x, keys, strings);
            }
        }
        Value::Array(a) => a.iter().for_each(|x| walk(x, keys, strings)),
        Value::String(s) => strings.push(s),
        _ => {}
    }
}

/// Runs [`script`] and a submit as `learner` in a new demo attempt; every text message.
pub(crate) async fn run_session(learner: &Client) -> (String, Vec<Value>) {
    let (attempt, session) = learner.start_demo_attempt().await;
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    let commands = script();
    for (i, c) in commands.iter().enumerate() {
        ws.send(i as u64 + 1, c.clone()).await;
    }
    let n = commands.len();
    let answered =
        |r: &Received| acked(r).len() + r.texts.iter().filter(|t| t["type"] == "error").count();
    ws.until(&mut got, |r| answered(r) >= n).await;
    let errors: Vec<&Value> = got.texts.iter().filter(|t| t["type"] == "error").collect();
    assert!(
        errors.is_empty(),
        "every scripted command is accepted: {errors:#?}"
    );
    ws.send(n as u64 + 1, json!({ "type": "submit" })).await;
    ws.until(&mut got, |r| {
        r.texts.iter().any(|t| t["type"] == "technical_result")
    })
    .await;
    (attempt, got.texts)
}

fn ack_of(texts: &[Value], seq: usize) -> &Value {
    texts
        .iter()
        .find(|t| t["type"] == "ack" && t["seq"] == seq as u64)
        .unwrap_or_else(|| panic!("no ack of {seq}"))
}

async fn set_mode(client: &Client, course: &str, station: &str, mode: Value) -> (u16, Value) {
    client
        .call(
            "PUT",
            &format!("/api/courses/{course}/station-modes/{station}"),
            Some(json!({ "mode": mode })),
        )
        .await
}

async fn demo_course(client: &Client) -> String {
    client.demo_course().await.as_str().unwrap().to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_assessment_session_tells_the_browser_nothing_it_could_not_see() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    let course = demo_course(&faculty).await;
    let (s, set) = set_mode(&faculty, &course, "demo-station", json!("assessment")).await;
    assert_eq!(s, 200, "{set}");
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (attempt, texts) = run_session(&learner).await;

    let mut keys = BTreeSet::new();
    let mut strings = Vec::new();
    for t in &texts {
        walk(t, &mut keys, &mut strings);
    }
    let unexpected: Vec<&&str> = keys.iter().filter(|k| !ALLOWED_KEYS.contains(k)).collect();
    assert!(
        unexpected.is_empty(),
        "keys the browser got that nobody decided on: {unexpected:?}"
    );
    for k in keys.iter() {
        assert!(
            !k.contains("tip_mm") && !k.contains("target") && !k.ends_with("_in_slice"),
            "{k}"
        );
    }
    for s in &strings {
        let lower = s.to_lowercase();
        for w in TISSUE_WORDS {
            assert!(!lower.contains(w), "a string names a tissue ({w}): {s:?}");
        }
        assert!(
            !lower.contains("target"),
            "a string names the target: {s:?}"
        );
    }
    // Each message kind of the script reached the browser, as intended.
    assert_eq!(texts[0]["type"], "hello");
    assert_eq!(texts[0]["session"]["mode"], "assessment");
    let feed = ack_of(&texts, 17);
    assert!(feed["outcome"]["force"]["samples"].is_array(), "{feed}");
    assert_eq!(feed["outcome"]["ultrasound"], json!({ "frozen": false }));
    let stops: Vec<&Value> = texts
        .iter()
        .filter_map(|t| t["outcome"]["outcome"].get("stop"))
        .collect();
    assert!(
        stops.contains(&&json!("hard_stop")),
        "a bone contact in the script: {stops:?}"
    );
    // What aspiration drew back, in the words of what the eye sees, without its category.
    let aspirated = texts
        .iter()
        .find(|t| t["seq"] == 25)
        .expect("the aspiration's acknowledgement");
    assert_eq!(
        aspirated["outcome"]["text"], "nothing comes back",
        "{aspirated}"
    );
    assert!(
        aspirated["outcome"].get("aspirate").is_none(),
        "{aspirated}"
    );
    let lor: Vec<&Value> = texts
        .iter()
        .filter_map(|t| t["outcome"].get("lor"))
        .collect();
    assert!(!lor.is_empty(), "the syringe's feel reaches the browser");
    let result = texts
        .iter()
        .find(|t| t["type"] == "technical_result")
        .unwrap();
    assert_eq!(result["result"]["withheld"], true, "{result}");

    // The debrief is the attempt's, read once the session is over.
    let (s, detail) = learner
        .call("GET", &format!("/api/attempts/{attempt}"), None)
        .await;
    assert_eq!(s, 200);
    assert_eq!(detail["attempt"]["mode"], "assessment");
    assert_eq!(detail["attempt"]["state"], "submitted");
    assert_eq!(detail["results"][0]["id"], result["result"]["id"]);
    assert!(detail["results"][0]["measurements"]["tip_to_target_mm"].is_number());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_practice_session_keeps_its_hints_and_result_but_not_positions() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let (_, texts) = run_session(&learner).await;
    assert_eq!(
        texts[0]["session"]["mode"], "practice",
        "no setting: practice"
    );
    let feed = ack_of(&texts, 17);
    assert!(
        feed["outcome"]["ultrasound"].get("tip_in_slice").is_some(),
        "practice keeps the in-slice hint: {feed}"
    );
    // Everything but the result (the debrief after the attempt, which measures all of it).
    let during: Vec<&Value> = texts
        .iter()
        .filter(|t| t["type"] != "technical_result")
        .collect();
    let all = serde_json::to_string(&during).unwrap();
    for never in [
        "tip_mm",
        "entry_mm",
        "marker_mm",
        "surface_point_mm",
        "annotation_error_mm",
    ] {
        assert!(!all.contains(never), "{never} reached the browser");
    }
    let result = texts
        .iter()
        .find(|t| t["type"] == "technical_result")
        .unwrap();
    assert!(
        result["result"]["measurements"]["tip_to_target_mm"].is_number(),
        "practice: the debrief comes at submit"
    );
    let submit_ack = texts
        .iter()
        .find(|t| t["type"] == "ack" && t["seq"] == script().len() as u64 + 1)
        .unwrap();
    assert!(
        submit_ack.get("result").is_none(),
        "the result comes once, in its own message"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_course_faculty_set_a_station_mode_and_attempts_keep_theirs() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let admin = Client::login(srv.addr, "admin@demo.invalid").await;
    let course = demo_course(&faculty).await;
    let table = || async {
        let rows: Vec<(String, String)> =
            sqlx::query_as("SELECT station_id, mode FROM course_station_modes ORDER BY station_id")
                .fetch_all(&srv.db.pool)
                .await
                .unwrap();
        rows
    };

    // An attempt opened in practice keeps practice after the course changes.
    let (_, courses) = learner.call("GET", "/api/courses", None).await;
    let course_v = courses
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == course.as_str())
        .unwrap()
        .clone();
    let before = learner.new_attempt_in(&course_v["id"]).await;

    let (s, list) = learner
        .call("GET", &format!("/api/courses/{course}/station-modes"), None)
        .await;
    assert_eq!(s, 200);
    assert_eq!(
        list,
        json!([{ "station_id": "demo-station", "mode": "practice", "set_by": null, "set_at": null }])
    );

    for (who, client, mode, status) in [
        ("learner", &learner, json!("assessment"), 403),
        ("faculty, unknown mode", &faculty, json!("exam"), 400),
        ("faculty, not a string", &faculty, json!(1), 400),
        ("faculty, null", &faculty, Value::Null, 400),
    ] {
        let (s, body) = set_mode(client, &course, "demo-station", mode).await;
        assert_eq!(s, status, "{who}: {body}");
        assert!(table().await.is_empty(), "{who}: nothing stored");
    }
    let (s, _) = set_mode(&faculty, &course, "no-such-station", json!("assessment")).await;
    assert_eq!(s, 404);
    let (s, _) = set_mode(
        &faculty,
        "00000000-0000-0000-0000-000000000000",
        "demo-station",
        json!("assessment"),
    )
    .await;
    assert_eq!(s, 404);
    let (s, body) = faculty
        .call(
            "PUT",
            &format!("/api/courses/{course}/station-modes/demo-station"),
            Some(json!({ "mode": "assessment", "extra": 1 })),
        )
        .await;
    assert_eq!(s, 400, "{body}");
    assert!(table().await.is_empty());

    let (s, body) = set_mode(&faculty, &course, "demo-station", json!("assessment")).await;
    assert_eq!(s, 200, "{body}");
    assert_eq!(body["mode"], "assessment");
    assert_eq!(
        table().await,
        vec![("demo-station".to_string(), "assessment".to_string())]
    );
    let after = learner.new_attempt_in(&course_v["id"]).await;
    for (id, mode) in [(&before, "practice"), (&after, "assessment")] {
        let (_, d) = learner
            .call("GET", &format!("/api/attempts/{id}"), None)
            .await;
        assert_eq!(d["attempt"]["mode"], mode, "{id}");
    }
    // An admin may set it back; the audit trail has both changes.
    let (s, _) = set_mode(&admin, &course, "demo-station", json!("practice")).await;
    assert_eq!(s, 200);
    let audits: i64 =
        sqlx::query_scalar("SELECT COUNT(*) FROM audit_events WHERE action = 'station_mode_set'")
            .fetch_one(&srv.db.pool)
            .await
            .unwrap();
    assert_eq!(audits, 2);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn learners_get_station_targets_without_their_positions() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    let (s, as_learner) = learner
        .call("GET", "/api/stations/demo-station", None)
        .await;
    assert_eq!(s, 200);
    let (_, as_faculty) = faculty
        .call("GET", "/api/stations/demo-station", None)
        .await;
    assert_eq!(as_learner["targets"][0]["name"], "behind_l4");
    assert!(
        as_learner["targets"][0].get("position_mm").is_none(),
        "{as_learner}"
    );
    assert!(
        as_faculty["targets"][0]["position_mm"].is_array(),
        "{as_faculty}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_learner_cannot_score_an_open_attempt_through_its_replay() {
    let srv = demo_server_for(true, None, &station_toml()).await;
    let learner = Client::login(srv.addr, "learner@demo.invalid").await;
    let faculty = Client::login(srv.addr, "faculty@demo.invalid").await;
    let (attempt, session) = learner.start_demo_attempt().await;
    let mut ws = learner.websocket(session["ws"].as_str().unwrap()).await;
    let mut got = Received::default();
    ws.send(1, json!({ "type": "shot" })).await;
    ws.until(&mut got, |r| acked(r) == vec![1]).await;
    let replay = format!("/api/attempts/{attempt}/replay");
    let frame = format!("/api/attempts/{attempt}/replay/frame?step=1");
    let (s, body) = learner.call("GET", &replay, None).await;
    assert_eq!(s, 409, "{body}");
    assert!(!body.to_string().contains("tip_to_target"), "{body}");
    assert_eq!(learner.call("GET", &frame, None).await.0, 409);
    let (s, body) = faculty.call("GET", &replay, None).await;
    assert_eq!(s, 200, "reviewers may look at any time: {body}");
    ws.send(2, json!({ "type": "submit" })).await;
    ws.until(&mut got, |r| {
        r.texts.iter().any(|t| t["type"] == "technical_result")
    })
    .await;
    let (s, body) = learner.call("GET", &replay, None).await;
    assert_eq!(s, 200, "the learner's own replay once submitted: {body}");
    // No needle in this session: its reveal touches nothing (not a 404).
    let (s, r) = learner
        .call("GET", &format!("/api/attempts/{attempt}/reveal"), None)
        .await;
    assert_eq!(s, 200, "{r}");
    assert_eq!(r["touched"], json!([]));
    assert_eq!(r["width"], 512);
}
