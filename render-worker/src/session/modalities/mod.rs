//! The modality seam: how an imaging modality plugs into a session, and the factory that builds
//! the ones a station lists.
//!
//! A modality owns its state, the commands it declares, its views and renderer, and its
//! scorers. What it offers is data, its [`ModalitySpec`]: the session routes each command to the
//! one modality whose spec lists the command's kind, the hello of the session protocol tells
//! the client (and the server's relay) the views with their wire codes and the command kinds
//! with their engagement events, all read from the specs. The session tells every modality
//! about changes of the shared `World` (the needle moved, fluid was injected) and about
//! simulated time passing, and asks only dirty, visible views to render. A station without a
//! modality never constructs it, so it costs nothing there.
//!
//! Adding a modality is a folder here (its spec, state, commands, renderer, scorers) and one
//! line in [`ModalityFactory::standard`]. Embedders (and `render-worker/tests/modality_seam.rs`)
//! register their own, with its own name, command kinds and views, with
//! [`ModalityFactory::with`]; its commands travel as
//! [`Command::Modality`](crate::session::command::Command::Modality).

pub mod contrast;
pub mod fluoro;
mod modality;
mod renderers;
pub mod ultrasound;

use std::collections::BTreeMap;
use std::sync::Arc;

pub use crate::session::world::ImageRayError;
pub use modality::{FluidDelivery, Modality, ModalityContext, ModalityError, ModalitySpec};
pub use renderers::Renderers;

use crate::session::command::CORE_COMMANDS;
use crate::session::image::{ViewConflict, ViewId};

/// Builds one modality for a session.
pub type ModalityBuilder = dyn Fn(&ModalityContext<'_>) -> Box<dyn Modality> + Send + Sync;

/// Why a modality cannot be registered.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RegistrationError {
    /// One of its views clashes with a registered view.
    #[error("modality {modality:?}: {source}")]
    View {
        /// The modality.
        modality: &'static str,
        /// The clash.
        source: ViewConflict,
    },
    /// A command kind it declares is the session core's or another modality's.
    #[error("modality {modality:?} declares command kind {kind:?}, which {owner} handles")]
    CommandKind {
        /// The modality.
        modality: &'static str,
        /// The kind.
        kind: &'static str,
        /// Who handles it already.
        owner: String,
    },
    /// Not a snake-case name.
    #[error("modality name {0:?} is not lower-case snake case")]
    BadName(&'static str),
}

#[derive(Clone)]
struct Registration {
    spec: &'static ModalitySpec,
    build: Arc<ModalityBuilder>,
}

/// Builders by station modality name (`"fluoroscopy"`, `"ultrasound"`), each with the
/// [`ModalitySpec`] its modality declares.
#[derive(Clone)]
pub struct ModalityFactory {
    registered: BTreeMap<&'static str, Registration>,
}

impl std::fmt::Debug for ModalityFactory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.registered.keys()).finish()
    }
}

impl Default for ModalityFactory {
    fn default() -> Self {
        ModalityFactory::standard()
    }
}

impl ModalityFactory {
    /// Every modality this worker implements. One line per modality.
    pub fn standard() -> ModalityFactory {
        // The built-in specs are checked against each other by this crate's tests
        // (`standard_specs_register`), so registering them cannot fail.
        let mut f = ModalityFactory::empty();
        for (spec, build) in [
            (
                &fluoro::SPEC,
                Arc::new(fluoro::build) as Arc<ModalityBuilder>,
            ),
            (&contrast::SPEC, Arc::new(contrast::build)),
            (&ultrasound::SPEC, Arc::new(ultrasound::build)),
        ] {
            f.registered.insert(spec.name, Registration { spec, build });
        }
        f
    }

    /// No modality at all.
    pub fn empty() -> ModalityFactory {
        ModalityFactory {
            registered: BTreeMap::new(),
        }
    }

    /// Adds (or replaces) the modality `spec.name`, built by `builder`: its views join the
    /// process-wide view table, and its command kinds must be new (not the session core's, and
    /// not another registered modality's unless it replaces that modality).
    pub fn with(
        mut self,
        spec: &'static ModalitySpec,
        builder: impl Fn(&ModalityContext<'_>) -> Box<dyn Modality> + Send + Sync + 'static,
    ) -> Result<ModalityFactory, RegistrationError> {
        let snake = crate::session::command::is_snake_case;
        if !snake(spec.name) {
            return Err(RegistrationError::BadName(spec.name));
        }
        for c in spec.commands {
            let owner = if CORE_COMMANDS.iter().any(|k| k.kind == c.kind) {
                Some("the session core".to_string())
            } else {
                self.registered
                    .values()
                    .find(|r| r.spec.name != spec.name && r.spec.handles(c.kind))
                    .map(|r| format!("modality {:?}", r.spec.name))
            };
            if let Some(owner) = owner {
                return Err(RegistrationError::CommandKind {
                    modality: spec.name,
                    kind: c.kind,
                    owner,
                });
            }
            if !snake(c.kind) {
                return Err(RegistrationError::CommandKind {
                    modality: spec.name,
                    kind: c.kind,
                    owner: "nobody: a kind is lower-case snake case".into(),
                });
            }
        }
        for v in spec.views {
            ViewId::register(*v).map_err(|source| RegistrationError::View {
                modality: spec.name,
                source,
            })?;
        }
        self.registered.insert(
            spec.name,
            Registration {
                spec,
                build: Arc::new(builder),
            },
        );
        Ok(self)
    }

    /// Whether `name` can be built.
    pub fn provides(&self, name: &str) -> bool {
        self.registered.contains_key(name)
    }

    /// The spec of the registered modality `name`.
    pub fn spec(&self, name: &str) -> Option<&'static ModalitySpec> {
        self.registered.get(name).map(|r| r.spec)
    }

    /// Every registered spec, by name.
    pub fn specs(&self) -> impl Iterator<Item = &'static ModalitySpec> + '_ {
        self.registered.values().map(|r| r.spec)
    }

    /// The registered modality that handles command kind `kind`.
    pub fn handler_of(&self, kind: &str) -> Option<&'static ModalitySpec> {
        self.specs().find(|s| s.handles(kind))
    }

    /// Builds the modality `name`, or `None` when this worker does not implement it.
    pub fn build(&self, name: &str, ctx: &ModalityContext<'_>) -> Option<Box<dyn Modality>> {
        self.registered.get(name).map(|r| (r.build)(ctx))
    }
}
