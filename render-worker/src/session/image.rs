//! What a modality hands to the session for display: a view name and an 8-bit grey image. The
//! session, the frame encoder and the protocol know only these types, never a modality's own.
//!
//! A view is data its modality declares ([`ViewId::new`] in the modality's
//! [`ModalitySpec`](crate::session::modalities::ModalitySpec)): a name (the JSON form, what a
//! client shows and asks for) and a one-byte wire code (the binary frame header, see
//! [`crate::session::frame`]). Registering a modality with the
//! [`ModalityFactory`](crate::session::modalities::ModalityFactory) registers its views in the
//! process-wide view table, which refuses a name or code already taken by another view; the
//! table is what frame parsing and the `views` message resolve names and codes with.

use std::collections::BTreeMap;
use std::sync::{OnceLock, RwLock};

use serde::{Deserialize, Serialize};

/// A rendered view of a session (one per modality display): a name and a wire code, both
/// unique among the views a process knows. Ordered by wire code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ViewId {
    code: u8,
    name: &'static str,
}

impl ViewId {
    /// The C-arm image.
    pub const FLUOROSCOPY: ViewId = ViewId::new("fluoroscopy", 0);
    /// The ultrasound B-mode image.
    pub const ULTRASOUND: ViewId = ViewId::new("ultrasound", 1);
    /// The external view of the body for placing the ultrasound probe (skin, probe, needle
    /// outside the skin, C-arm direction).
    pub const PLACEMENT: ViewId = ViewId::new("placement", 2);

    /// A view named `name` (lower-case snake case, as clients see it) with wire code `code`.
    pub const fn new(name: &'static str, code: u8) -> ViewId {
        ViewId { code, name }
    }

    /// Wire code in the binary frame header.
    pub fn code(self) -> u8 {
        self.code
    }

    /// Name (the JSON form).
    pub fn name(self) -> &'static str {
        self.name
    }

    /// The registered view with wire code `code`.
    pub fn from_code(code: u8) -> Option<ViewId> {
        table()
            .read()
            .ok()?
            .values()
            .copied()
            .find(|v| v.code == code)
    }

    /// The registered view named `name`.
    pub fn from_name(name: &str) -> Option<ViewId> {
        table().read().ok()?.get(name).copied()
    }

    /// Adds `view` to the process-wide view table (idempotent for the same view); refuses a
    /// view whose name or code another view already has.
    pub fn register(view: ViewId) -> Result<(), ViewConflict> {
        if !crate::session::command::is_snake_case(view.name) {
            return Err(ViewConflict::BadName(view.name));
        }
        let mut t = table().write().map_err(|_| ViewConflict::Poisoned)?;
        if let Some(existing) = t.values().find(|v| v.code == view.code && **v != view) {
            return Err(ViewConflict::Code {
                code: view.code,
                taken_by: existing.name,
                wanted_by: view.name,
            });
        }
        if let Some(existing) = t.get(view.name) {
            if *existing != view {
                return Err(ViewConflict::Name {
                    name: view.name,
                    code: existing.code,
                });
            }
        }
        t.insert(view.name, view);
        Ok(())
    }

    /// Every registered view, by wire code.
    pub fn registered() -> Vec<ViewId> {
        let mut v: Vec<ViewId> = table()
            .read()
            .map(|t| t.values().copied().collect())
            .unwrap_or_default();
        v.sort();
        v
    }
}

/// Why a view cannot be registered.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ViewConflict {
    /// Another view has this wire code.
    #[error("view code {code} is taken by {taken_by:?}; {wanted_by:?} needs another")]
    Code {
        /// The code.
        code: u8,
        /// The view that has it.
        taken_by: &'static str,
        /// The view that asked for it.
        wanted_by: &'static str,
    },
    /// Another view has this name with another code.
    #[error("view name {name:?} is registered with code {code}")]
    Name {
        /// The name.
        name: &'static str,
        /// Its registered code.
        code: u8,
    },
    /// Not lower-case snake case.
    #[error("view name {0:?} is not lower-case snake case")]
    BadName(&'static str),
    /// The table's lock was poisoned by a panic elsewhere.
    #[error("the view table is unavailable")]
    Poisoned,
}

fn table() -> &'static RwLock<BTreeMap<&'static str, ViewId>> {
    static TABLE: OnceLock<RwLock<BTreeMap<&'static str, ViewId>>> = OnceLock::new();
    TABLE.get_or_init(|| {
        RwLock::new(
            [ViewId::FLUOROSCOPY, ViewId::ULTRASOUND, ViewId::PLACEMENT]
                .into_iter()
                .map(|v| (v.name, v))
                .collect(),
        )
    })
}

impl Serialize for ViewId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name)
    }
}

impl<'de> Deserialize<'de> for ViewId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<ViewId, D::Error> {
        let name = std::borrow::Cow::<'de, str>::deserialize(d)?;
        ViewId::from_name(&name).ok_or_else(|| {
            let known: Vec<&str> = ViewId::registered().iter().map(|v| v.name).collect();
            serde::de::Error::custom(format!("unknown view {name:?} (known: {known:?})"))
        })
    }
}

impl std::fmt::Display for ViewId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name)
    }
}

/// An 8-bit grey image, row-major from the top-left pixel: what every view displays.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Grey levels, `width * height`, row-major from the top-left pixel.
    pub pixels: Vec<u8>,
}

impl From<sim_core::fluoro::Image> for ViewImage {
    fn from(i: sim_core::fluoro::Image) -> ViewImage {
        ViewImage {
            width: i.width,
            height: i.height,
            pixels: i.pixels,
        }
    }
}
