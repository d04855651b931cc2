//! Commands of modalities this crate does not define, and the JSON form of [`Command`] that
//! carries them beside the built-in kinds.
//!
//! The wire form of every command is one JSON object whose `type` names its kind. A kind that is
//! one of [`BUILTIN_KINDS`] is parsed into its typed variant, with the field-level errors of the
//! derived parser; any other kind becomes a [`Command::Modality`] holding the object's other
//! fields, which the modality that declares the kind parses and validates itself (the session
//! refuses a kind no modality of the station declares). Both serialise back to the same object,
//! so logs, snapshots and replays treat them alike.

use serde::de::{DeserializeOwned, Error as _};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{Command, CommandError, ErrorCode};

/// The kinds of the built-in [`Command`] variants (the `type` of their JSON form).
pub const BUILTIN_KINDS: &[&str] = &[
    "carm_pose",
    "technique",
    "shot",
    "live",
    "needle_place",
    "needle_feed",
    "needle_roll",
    "needle_withdraw",
    "skin_marker",
    "needle_puncture",
    "needle_tilt",
    "syringe",
    "plunger",
    "plunger_hold",
    "aspirate",
    "annotate",
    "probe_select",
    "probe_pose",
    "probe_move",
    "probe_drag",
    "probe_settings",
    "probe_freeze",
    "inject",
    "inject_stop",
    "tick",
    "submit",
];

/// Longest kind of a modality command, characters. Simulator choice: kinds are short snake-case
/// verbs (`probe_settings`); the bound keeps every logged kind small.
pub const MAX_KIND_CHARS: usize = 48;

/// Largest JSON size of a modality command's fields, bytes. Simulator choice: the largest
/// built-in command (a needle placement) is about 200 bytes of JSON; 4 KiB leaves room for a
/// modality's settings without letting one logged command cost much.
pub const MAX_FIELDS_BYTES: usize = 4096;

/// A command of a modality this crate does not define: its kind and its other JSON fields.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalityCommand {
    kind: String,
    fields: serde_json::Map<String, serde_json::Value>,
}

impl ModalityCommand {
    /// A command of kind `kind` with `fields` (every field of its JSON form but `type`).
    pub fn new(
        kind: impl Into<String>,
        fields: serde_json::Map<String, serde_json::Value>,
    ) -> ModalityCommand {
        ModalityCommand {
            kind: kind.into(),
            fields,
        }
    }

    /// The kind (the JSON `type`).
    pub fn kind(&self) -> &str {
        &self.kind
    }

    /// The fields other than `type`.
    pub fn fields(&self) -> &serde_json::Map<String, serde_json::Value> {
        &self.fields
    }

    /// The fields parsed as `T` (a modality's own command struct, typically with
    /// `deny_unknown_fields`); a field that does not parse is named in the error
    /// (`command.<path>`), as for the built-in commands.
    pub fn parse<T: DeserializeOwned>(&self) -> Result<T, CommandError> {
        let value = serde_json::Value::Object(self.fields.clone());
        serde_path_to_error::deserialize(value).map_err(|e| {
            let path = e.path().to_string();
            let field = if path.is_empty() || path == "." {
                "command".to_string()
            } else {
                format!("command.{path}")
            };
            CommandError::field(&field, ErrorCode::Malformed, e.inner().to_string())
        })
    }

    /// Checks what every modality command must satisfy whatever its modality: a snake-case kind
    /// that is not built in, and fields of bounded size without NUL characters (the server's
    /// copy of the log is PostgreSQL text).
    pub fn validate(&self) -> Result<(), CommandError> {
        if !is_kind(&self.kind) || BUILTIN_KINDS.contains(&self.kind.as_str()) {
            return Err(CommandError::field(
                "command.type",
                ErrorCode::Malformed,
                format!(
                    "{:?} is not a modality command kind (snake case, 1 to {MAX_KIND_CHARS} characters)",
                    self.kind
                ),
            ));
        }
        let text = serde_json::to_string(&self.fields).unwrap_or_default();
        if text.len() > MAX_FIELDS_BYTES {
            return Err(CommandError::field(
                "command",
                ErrorCode::Invalid,
                format!("{} bytes of fields; at most {MAX_FIELDS_BYTES}", text.len()),
            ));
        }
        if text.contains("\\u0000") {
            return Err(CommandError::field(
                "command",
                ErrorCode::Invalid,
                "must not contain NUL characters (U+0000)",
            ));
        }
        Ok(())
    }
}

/// Whether `kind` can name a modality command: lower-case snake case of 1 to
/// [`MAX_KIND_CHARS`] characters. Anything else is refused as an unknown variant.
fn is_kind(kind: &str) -> bool {
    kind.len() <= MAX_KIND_CHARS && super::spec::is_snake_case(kind)
}

impl Command {
    /// Parses the JSON form: a built-in kind into its variant, any other kind into
    /// [`Command::Modality`].
    pub fn from_json(value: serde_json::Value) -> Result<Command, serde_json::Error> {
        match value.get("type").and_then(serde_json::Value::as_str) {
            Some(kind) if !BUILTIN_KINDS.contains(&kind) && is_kind(kind) => {
                let kind = kind.to_string();
                let serde_json::Value::Object(mut fields) = value else {
                    return Err(serde_json::Error::custom("a command is a JSON object"));
                };
                fields.remove("type");
                Ok(Command::Modality(ModalityCommand { kind, fields }))
            }
            _ => Command::deserialize(value),
        }
    }

    /// The derived parser of the built-in kinds alone, for callers that track field paths
    /// (`serde_path_to_error`) through it.
    pub fn deserialize_builtin<'de, D: Deserializer<'de>>(d: D) -> Result<Command, D::Error> {
        Command::deserialize(d)
    }
}

impl Serialize for Command {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            Command::Modality(c) => {
                let mut map = s.serialize_map(Some(c.fields.len() + 1))?;
                map.serialize_entry("type", &c.kind)?;
                for (k, v) in &c.fields {
                    if k != "type" {
                        map.serialize_entry(k, v)?;
                    }
                }
                map.end()
            }
            builtin => Command::serialize(builtin, s),
        }
    }
}

impl<'de> Deserialize<'de> for Command {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Command, D::Error> {
        let value = serde_json::Value::deserialize(d)?;
        Command::from_json(value).map_err(D::Error::custom)
    }
}
