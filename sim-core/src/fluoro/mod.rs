//! Fluoroscopy: the exact CPU reference (f64) of the C-arm image.
//!
//! Data flow, per detector pixel (and per sub-pixel sample):
//! 1. [`geometry::Projection`] gives the ray from the focal spot through the pixel.
//! 2. [`scene::Scene`] intersects it with every closed mesh (a [`crate::geom::Bvh`] each) and
//!    returns exact chord lengths per material, nested materials replacing each other by priority
//!    (soft tissue inside bone counts as bone only; a needle is subtracted from whatever holds it).
//! 3. [`contrast`] adds the stock-equivalent iodine column ray-marched through a concentration grid.
//! 4. [`attenuation`] turns chords into transmission: a polychromatic sum over a SpekPy tube spectrum
//!    with NIST-derived attenuation, or the single 60 keV reference energy.
//! 5. [`render`] normalises exposure, maps to 8-bit, adds seeded quantum noise and draws the
//!    collimator shutters.
//!
//! The GPU renderer in `render-worker` reproduces steps 1 to 4 and is tested against this module.
//! Units: millimetres for geometry, per-centimetre attenuation coefficients (as tabulated), and
//! every chord is converted to centimetres exactly once, in [`attenuation`].
//!
//! The model frame, the C-arm angles and the pixel convention are documented in [`geometry`].

pub mod analytic;
pub mod attenuation;
pub mod contrast;
pub mod geometry;
pub mod render;
pub mod scene;
pub mod spectrum;

pub use attenuation::{BasisDepths, EnergyModel, FluoroMaterial, MaterialChords, SpectralModel};
pub use contrast::IodineField;
pub use geometry::{Collimation, DetectorFrame, GpuRayFrame, Projection, Ray};
pub use render::{
    Exposure, Image, QuantumNoise, RenderSettings, TransmissionImage, render_chords, render_frame,
    render_transmission,
};
pub use scene::{ChordScratch, NOMINAL_CORTICAL_SHELL_MM, RayChords, Scene, SceneEntry};
pub use spectrum::{AttenuationTables, Basis, Spectrum};
