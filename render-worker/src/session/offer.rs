//! What a session offers a client, as data: the protocol constants and, from each modality's
//! [`ModalitySpec`](super::modalities::ModalitySpec), its views with their wire codes, the
//! command kinds it handles with their engagement events, and the numbers a client needs to
//! drive it. The hello of the session protocol carries it, so neither the server's relay nor
//! the web client keeps a copy of any of it.

use serde::{Deserialize, Serialize};

use super::command::{CORE_COMMANDS, Engagement, MAX_TILT_DEG};
use super::frame::{FLAG_DRAFT, HEADER_BYTES, HEADER_VERSION, MAGIC};
use super::machine::Session;

/// The constants and catalogue of one session's protocol.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProtocolInfo {
    /// The first four bytes of every binary frame (`SIMF`).
    pub frame_magic: String,
    /// Byte 4 of every binary frame.
    pub frame_header_version: u8,
    /// Header length, bytes; the JPEG follows.
    pub frame_header_bytes: usize,
    /// The bit of header byte 6 that marks a draft frame (a cheaper preview of the same input;
    /// the full frame follows).
    #[serde(default)]
    pub frame_draft_flag: u8,
    /// Views the session renders, with the wire code of frame header byte 5.
    pub views: Vec<ViewInfo>,
    /// Every command kind the session accepts.
    pub commands: Vec<CommandInfo>,
    /// Numbers a client needs, by modality name (the session core's under `"session"`): each a
    /// name with its unit suffix and a value.
    pub constants: std::collections::BTreeMap<String, std::collections::BTreeMap<String, f64>>,
}

/// One view of a session.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ViewInfo {
    /// Name (what the `views` message lists).
    pub name: String,
    /// Wire code (frame header byte 5).
    pub code: u8,
    /// The modality that renders it.
    pub modality: String,
}

/// One command kind a session accepts.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct CommandInfo {
    /// The JSON `type`.
    #[serde(rename = "type")]
    pub kind: String,
    /// The modality that handles it; absent for the session core's own.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub modality: Option<String>,
    /// Its engagement event by default (the acknowledgement carries the actual one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub engagement: Option<Engagement>,
}

/// Name under which the session core's own constants are listed.
pub const CORE: &str = "session";

impl ProtocolInfo {
    /// What `session` offers.
    pub fn of(session: &Session) -> ProtocolInfo {
        let specs = session.specs();
        let mut constants = std::collections::BTreeMap::new();
        constants.insert(
            CORE.to_string(),
            [("max_tilt_deg".to_string(), MAX_TILT_DEG)].into(),
        );
        for s in &specs {
            if !s.constants.is_empty() {
                constants.insert(
                    s.name.to_string(),
                    s.constants
                        .iter()
                        .map(|(k, v)| ((*k).to_string(), *v))
                        .collect(),
                );
            }
        }
        ProtocolInfo {
            frame_magic: String::from_utf8_lossy(MAGIC).into_owned(),
            frame_header_version: HEADER_VERSION,
            frame_header_bytes: HEADER_BYTES,
            frame_draft_flag: FLAG_DRAFT,
            views: specs
                .iter()
                .flat_map(|s| {
                    s.views.iter().map(|v| ViewInfo {
                        name: v.name().to_string(),
                        code: v.code(),
                        modality: s.name.to_string(),
                    })
                })
                .collect(),
            commands: CORE_COMMANDS
                .iter()
                .map(|c| CommandInfo {
                    kind: c.kind.to_string(),
                    modality: None,
                    engagement: c.engagement,
                })
                .chain(specs.iter().flat_map(|s| {
                    s.commands.iter().map(|c| CommandInfo {
                        kind: c.kind.to_string(),
                        modality: Some(s.name.to_string()),
                        engagement: c.engagement,
                    })
                }))
                .collect(),
            constants,
        }
    }
}
