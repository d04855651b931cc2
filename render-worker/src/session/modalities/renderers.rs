//! The renderers a device offers to modalities, by modality name: the seam's view of a device.
//! The session's `devices` module (above the seam) opens a device and fills this map for the
//! built-in modalities; an embedder adds the renderer of its own modality with
//! [`Renderers::with`]. A modality takes its renderer with [`Renderers::get`] and knows its
//! concrete type; nothing here names one.

use std::any::Any;
use std::collections::BTreeMap;
use std::sync::Arc;

/// Renderers by modality name, shared by every session on one device.
#[derive(Clone, Default)]
pub struct Renderers {
    by_modality: BTreeMap<&'static str, Arc<dyn Any + Send + Sync>>,
}

impl std::fmt::Debug for Renderers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.by_modality.keys()).finish()
    }
}

impl Renderers {
    /// No renderer.
    pub fn new() -> Renderers {
        Renderers::default()
    }

    /// Adds (or replaces) the renderer of `modality`; `renderer` is what that modality's
    /// [`Renderers::get`] asks for (for example an `Arc<dyn FluoroBackend>`).
    pub fn with<T: Any + Send + Sync>(mut self, modality: &'static str, renderer: T) -> Renderers {
        self.by_modality.insert(modality, Arc::new(renderer));
        self
    }

    /// The renderer of `modality`, if it was added with type `T`.
    pub fn get<T: Any + Send + Sync>(&self, modality: &str) -> Option<&T> {
        self.by_modality.get(modality)?.downcast_ref::<T>()
    }

    /// Names of the modalities with a renderer.
    pub fn modalities(&self) -> impl Iterator<Item = &'static str> + '_ {
        self.by_modality.keys().copied()
    }
}
