//! What a session refuses, and how it says so: invalid and out-of-state commands, modalities
//! the station lacks, malformed client messages, values the log cannot store and unknown fields.
//! Every refusal names the field at fault, and nothing refused is logged.

use render_worker::session::protocol::parse_client_message;
use render_worker::session::*;

use super::support::{Driver, config, env, env_with, place, pose};

#[test]
fn invalid_commands_are_rejected_naming_the_field_and_nothing_is_logged() {
    let mut d = Driver::new();
    let cases: Vec<(Command, &str, ErrorCode)> = vec![
        (
            pose(f64::NAN, 0.0),
            "command.orbital_deg",
            ErrorCode::NotFinite,
        ),
        (
            pose(0.0, 90.0),
            "command.angular_deg",
            ErrorCode::OutOfRange,
        ),
        (
            Command::CarmPose {
                orbital_deg: 0.0,
                angular_deg: 0.0,
                table_mm: [0.0, f64::INFINITY, 0.0],
            },
            "command.table_mm[1]",
            ErrorCode::NotFinite,
        ),
        (
            Command::Technique { kvp: 81, ma: 2.0 },
            "command.kvp",
            ErrorCode::OutOfRange,
        ),
        (
            Command::Technique { kvp: 80, ma: -1.0 },
            "command.ma",
            ErrorCode::OutOfRange,
        ),
        (
            Command::NeedleFeed { mm: -3.0 },
            "command.mm",
            ErrorCode::OutOfRange,
        ),
        (
            Command::NeedleRoll { deg: f64::NAN },
            "command.deg",
            ErrorCode::NotFinite,
        ),
        (
            Command::Inject {
                agent: Agent::Contrast,
                volume_ml: 250.0,
                rate_ml_per_s: 0.2,
            },
            "command.volume_ml",
            ErrorCode::OutOfRange,
        ),
        (
            Command::Inject {
                agent: Agent::Saline,
                volume_ml: 2.0,
                rate_ml_per_s: 0.0,
            },
            "command.rate_ml_per_s",
            ErrorCode::OutOfRange,
        ),
        (
            place([0.0; 3], [0.0, 0.0, 0.0]),
            "command.direction",
            ErrorCode::Invalid,
        ),
        // Station-dependent rejections.
        (
            Command::NeedleFeed { mm: 5.0 },
            "command.type",
            ErrorCode::State,
        ),
        (
            Command::Annotate {
                pixel: [10.0, 10.0],
                label: "behind_l4".into(),
            },
            "command.type",
            ErrorCode::State,
        ),
        (
            Command::NeedlePlace {
                instrument: "tuohy".into(),
                entry_mm: [0.0; 3],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
            "command.instrument",
            ErrorCode::InstrumentUnavailable,
        ),
        (
            Command::NeedlePlace {
                instrument: "contrast-syringe".into(),
                entry_mm: [0.0; 3],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
            "command.instrument",
            ErrorCode::InstrumentUnavailable,
        ),
        (
            place([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            "command.entry_mm",
            ErrorCode::Invalid,
        ),
    ];
    for (c, field, code) in cases {
        let e = d.err(c.clone());
        assert_eq!((e.field.as_str(), e.code), (field, code), "{c:?}: {e}");
    }
    assert!(d.s.log().is_empty(), "rejected commands must not be logged");
    // Sequence numbers: 0 is refused, a repeat with another command is refused, an identical
    // re-send is acknowledged as a duplicate and not applied twice.
    let e =
        d.s.apply(
            Envelope {
                seq: 0,
                command: Command::Shot,
            },
            0,
        )
        .unwrap_err();
    assert_eq!((e.field.as_str(), e.code), ("seq", ErrorCode::Sequence));
    d.ok(10, Command::Shot);
    let dup =
        d.s.apply(
            Envelope {
                seq: 1,
                command: Command::Shot,
            },
            20,
        )
        .unwrap();
    assert!(dup.duplicate);
    let e =
        d.s.apply(
            Envelope {
                seq: 1,
                command: pose(5.0, 0.0),
            },
            20,
        )
        .unwrap_err();
    assert_eq!(e.code, ErrorCode::Sequence);
    assert_eq!(d.s.log().len(), 1);
    assert_eq!(d.s.measurements()["fluoro_acquisitions_count"], 1.0);
}

#[test]
fn modalities_the_station_lacks_are_refused_with_a_clear_message() {
    let mut d = Driver::new();
    for c in [
        Command::ProbePose {
            position_mm: [0.0, -120.0, 0.0],
            beam_dir: [0.0, 1.0, 0.0],
            marker_dir: [1.0, 0.0, 0.0],
        },
        Command::ProbeSettings {
            depth_mm: Some(60.0),
            gain_db: Some(10.0),
            tgc_db: None,
            focus_mm: None,
            frequency_mhz: Some(5.0),
            dynamic_range_db: None,
        },
        Command::Inject {
            agent: Agent::Contrast,
            volume_ml: 1.0,
            rate_ml_per_s: 0.2,
        },
    ] {
        let e = d.err(c);
        assert_eq!(
            (e.field.as_str(), e.code),
            ("command.type", ErrorCode::ModalityUnavailable)
        );
        assert!(
            e.message.contains("modality not available at this station"),
            "{}",
            e.message
        );
    }
    // A station that lists ultrasound builds it (its views beside fluoroscopy's), and the
    // fluoroscopy-only session never built anything for ultrasound. A worker without an
    // implementation reports it unavailable (modality_seam).
    let s = Session::new(env_with(&["ultrasound"]), config());
    assert!(s.unavailable_modalities().is_empty());
    assert_eq!(s.modality_names(), ["fluoroscopy", "ultrasound"]);
    assert_eq!(
        s.views(),
        [ViewId::FLUOROSCOPY, ViewId::ULTRASOUND, ViewId::PLACEMENT]
    );
    let fluoro_only = Session::new(env(), config());
    assert!(fluoro_only.unavailable_modalities().is_empty());
    assert_eq!(fluoro_only.views(), [ViewId::FLUOROSCOPY]);
}

#[test]
fn client_messages_name_the_field_of_a_parse_error() {
    let e = parse_client_message(
        r#"{"type":"command","seq":3,"command":{"type":"carm_pose","angular_deg":0}}"#,
    )
    .unwrap_err();
    assert_eq!(e.0, Some(3));
    assert_eq!(e.1.field, "command.orbital_deg", "{:?}", e.1);
    let e = parse_client_message(
        r#"{"type":"command","seq":3,"command":{"type":"technique","kvp":80,"ma":"high"}}"#,
    )
    .unwrap_err();
    assert_eq!(e.1.field, "command.ma", "{:?}", e.1);
    // A kind that cannot name any command is refused at parse time; a well-formed kind that no
    // built-in command has is a modality's command, refused by a session none of whose
    // modalities declares it (`modality_seam`).
    let e = parse_client_message(r#"{"type":"command","seq":3,"command":{"type":"Warp Drive"}}"#)
        .unwrap_err();
    assert_eq!(e.1.field, "command.type", "{:?}", e.1);
    let m = parse_client_message(r#"{"type":"command","seq":3,"command":{"type":"warp_drive"}}"#)
        .unwrap();
    assert!(
        matches!(&m, protocol::ClientMessage::Command { command: Command::Modality(c), .. } if c.kind() == "warp_drive"),
        "{m:?}"
    );
    let e = parse_client_message(r#"{"type":"command","seq":-1,"command":{"type":"shot"}}"#)
        .unwrap_err();
    assert_eq!(e.1.field, "seq");
    let e = parse_client_message("not json").unwrap_err();
    assert_eq!(e.1.code, ErrorCode::Malformed);
    let ok = parse_client_message(
        r#"{"type":"command","seq":4,"command":{"type":"needle_feed","mm":2.5}}"#,
    )
    .unwrap();
    assert_eq!(
        ok,
        protocol::ClientMessage::Command {
            seq: 4,
            command: Command::NeedleFeed { mm: 2.5 }
        }
    );
}

/// What the server's log cannot store is refused before it is acknowledged: NUL in text fields
/// (PostgreSQL `text` cannot hold it), and sequence numbers above a PostgreSQL `bigint`.
#[test]
fn commands_the_log_cannot_store_are_refused_naming_the_field() {
    let mut s = Session::new(env(), config());
    let cases = [
        (u64::MAX, Command::Shot, "seq", ErrorCode::Sequence),
        (
            (i64::MAX as u64) + 1,
            Command::Shot,
            "seq",
            ErrorCode::Sequence,
        ),
        (
            1,
            Command::Annotate {
                pixel: [1.0, 1.0],
                label: "tar\0get".into(),
            },
            "command.label",
            ErrorCode::Invalid,
        ),
        (
            1,
            Command::NeedlePlace {
                instrument: "spinal\0".into(),
                entry_mm: [12.0, -100.0, 0.0],
                direction: [0.0, 1.0, 0.0],
                bevel_reference: [1.0, 0.0, 0.0],
            },
            "command.instrument",
            ErrorCode::Invalid,
        ),
    ];
    for (seq, command, field, code) in cases {
        let e = s.apply(Envelope { seq, command }, 0).unwrap_err();
        assert_eq!((e.field.as_str(), e.code), (field, code), "{e}");
    }
    assert!(s.log().is_empty());
    // The largest storable sequence number is accepted.
    s.apply(
        Envelope {
            seq: i64::MAX as u64,
            command: Command::Shot,
        },
        0,
    )
    .unwrap();
}

/// Unknown fields are refused, naming them, in the envelope and in every
/// command, unit commands included (serde alone ignores those).
#[test]
fn unknown_fields_in_messages_and_commands_are_refused() {
    for (text, field) in [
        (
            r#"{"type":"command","seq":1,"command":{"type":"shot"},"extra":1}"#,
            "extra",
        ),
        (
            r#"{"type":"command","seq":1,"command":{"type":"shot","x":1}}"#,
            "command.x",
        ),
        (
            r#"{"type":"command","seq":1,"command":{"type":"submit","score":1}}"#,
            "command.score",
        ),
        (
            r#"{"type":"command","seq":1,"command":{"type":"carm_pose","orbital_deg":0,"angular_deg":0,"zoom":2}}"#,
            "command.zoom",
        ),
        (
            r#"{"type":"views","visible":["fluoroscopy"],"all":true}"#,
            "all",
        ),
    ] {
        let (_, e) = parse_client_message(text).unwrap_err();
        assert_eq!(e.field, field, "{text}: {e}");
        assert_eq!(e.code, ErrorCode::Malformed);
    }
    // The same messages without the extra field parse.
    for text in [
        r#"{"type":"command","seq":1,"command":{"type":"shot"}}"#,
        r#"{"type":"command","seq":1,"command":{"type":"carm_pose","orbital_deg":0,"angular_deg":0}}"#,
        r#"{"type":"views","visible":["fluoroscopy"]}"#,
    ] {
        assert!(parse_client_message(text).is_ok(), "{text}");
    }
}
