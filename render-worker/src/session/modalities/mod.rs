//! The modality seam: how an imaging modality plugs into a session, and the factory that builds
//! the ones a station lists.
//!
//! A modality owns its state, the commands of the classes it accepts, its views and renderer,
//! and its scorers. The session routes each command by
//! [`CommandClass`](crate::session::command::CommandClass) to the one modality that accepts it,
//! tells every modality about changes of the shared `World` (the needle moved, fluid was
//! injected) and about simulated time passing, and asks only dirty, visible views to render. A station without a modality never constructs it, so it costs nothing there.
//!
//! Adding a modality is a folder here (its state, commands, renderer, scorers) and one line in
//! [`ModalityFactory::standard`]. Tests and embedders can register their own with
//! [`ModalityFactory::with`].

pub mod contrast;
pub mod fluoro;
mod modality;
pub mod ultrasound;

use std::collections::BTreeMap;
use std::sync::Arc;

pub use modality::{Modality, ModalityContext, ModalityError};

/// Builds one modality for a session.
pub type ModalityBuilder = dyn Fn(&ModalityContext<'_>) -> Box<dyn Modality> + Send + Sync;

/// Builders by station modality name (`"fluoroscopy"`, `"ultrasound"`).
#[derive(Clone)]
pub struct ModalityFactory {
    builders: BTreeMap<&'static str, Arc<ModalityBuilder>>,
}

impl std::fmt::Debug for ModalityFactory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.builders.keys()).finish()
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
        ModalityFactory::empty()
            .with("fluoroscopy", fluoro::build)
            .with("contrast", contrast::build)
            .with("ultrasound", ultrasound::build)
    }

    /// No modality at all.
    pub fn empty() -> ModalityFactory {
        ModalityFactory {
            builders: BTreeMap::new(),
        }
    }

    /// Adds (or replaces) the builder of the station modality `name`.
    pub fn with(
        mut self,
        name: &'static str,
        builder: impl Fn(&ModalityContext<'_>) -> Box<dyn Modality> + Send + Sync + 'static,
    ) -> ModalityFactory {
        self.builders.insert(name, Arc::new(builder));
        self
    }

    /// Whether `name` can be built.
    pub fn provides(&self, name: &str) -> bool {
        self.builders.contains_key(name)
    }

    /// Builds the modality `name`, or `None` when this worker does not implement it.
    pub fn build(&self, name: &str, ctx: &ModalityContext<'_>) -> Option<Box<dyn Modality>> {
        self.builders.get(name).map(|b| b(ctx))
    }
}
