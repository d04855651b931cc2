//! What a command kind stands for beyond the session: the engagement event a learning record
//! counts it as, declared per kind by the session core ([`CORE_COMMANDS`]) and by each modality
//! (its [`ModalitySpec`](crate::session::modalities::ModalitySpec)).

use serde::{Deserialize, Serialize};

/// The engagement event an accepted command stands for in the learning records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Engagement {
    /// The learner changed what an image shows (C-arm, technique, probe).
    ViewChanged,
    /// An image was acquired (a shot, live fluoroscopy started).
    ImageAcquired,
    /// The needle moved in tissue.
    NeedleAdjusted,
    /// Something was injected through the needle.
    Injection,
}

/// One command kind and the engagement it stands for by default (a modality may refine it per
/// command, see [`Modality::engagement`](crate::session::modalities::Modality::engagement)).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CommandSpec {
    /// The JSON `type`.
    #[serde(rename = "type")]
    pub kind: &'static str,
    /// Its engagement event, if it counts as one.
    pub engagement: Option<Engagement>,
    /// Whether the command moves what a view shows, so that a refinement of that view still
    /// being rendered is obsolete once it comes (see `crate::interrupt`): the session stops it
    /// and drafts the new view instead. Not part of the protocol.
    #[serde(skip)]
    pub supersedes: bool,
}

impl CommandSpec {
    /// A kind and its engagement.
    pub const fn new(kind: &'static str, engagement: Option<Engagement>) -> CommandSpec {
        CommandSpec {
            kind,
            engagement,
            supersedes: false,
        }
    }

    /// The same kind, marked as moving what a view shows ([`CommandSpec::supersedes`]).
    pub const fn superseding(self) -> CommandSpec {
        CommandSpec {
            supersedes: true,
            ..self
        }
    }
}

/// The engagement `specs` declare for commands of kind `kind` (none for a kind they do not list).
pub fn engagement_of(specs: &[CommandSpec], kind: &str) -> Option<Engagement> {
    specs
        .iter()
        .find(|c| c.kind == kind)
        .and_then(|c| c.engagement)
}

/// Whether `name` is lower-case snake case (`a`-`z`, `0`-`9`, `_`), the form of every name on
/// the session protocol: modality names, command kinds, view names.
pub fn is_snake_case(name: &str) -> bool {
    !name.is_empty()
        && name
            .bytes()
            .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_')
}

/// The kinds the session core handles itself: the needle and the learner's hands, tick and
/// submit.
pub const CORE_COMMANDS: &[CommandSpec] = &[
    CommandSpec::new("needle_place", Some(Engagement::NeedleAdjusted)),
    CommandSpec::new("needle_puncture", Some(Engagement::NeedleAdjusted)),
    CommandSpec::new("needle_feed", Some(Engagement::NeedleAdjusted)),
    CommandSpec::new("needle_roll", Some(Engagement::NeedleAdjusted)),
    CommandSpec::new("needle_tilt", Some(Engagement::NeedleAdjusted)),
    CommandSpec::new("needle_withdraw", Some(Engagement::NeedleAdjusted)),
    CommandSpec::new("skin_marker", None),
    CommandSpec::new("syringe", None),
    CommandSpec::new("plunger", Some(Engagement::Injection)),
    CommandSpec::new("plunger_hold", None),
    CommandSpec::new("aspirate", None),
    CommandSpec::new("tick", None),
    CommandSpec::new("submit", None),
];
