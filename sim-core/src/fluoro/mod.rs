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
//! [`dose`] estimates the incident air kerma and kerma-area product of an exposure from the same
//! spectra (an estimate, not a dose record); [`detector`] turns an exposure into the detector's
//! air kerma and detected quanta (the noise of a frame), and [`brightness`] is the automatic
//! brightness control that steps the technique to hold the detector kerma at a target;
//! [`temporal`] is live fluoroscopy's detector lag and recursive filter; [`scatter`] adds the
//! scattered radiation (kernel superposition on a coarse grid, an anti-scatter grid, the air
//! gap) and holds the photon Monte Carlo it is checked against; [`receptor`] is the detector's
//! profile (flat panel or image intensifier: glare, blur, distortion, vignetting).
//!
//! The GPU renderer in `render-worker` reproduces steps 1 to 4 and is tested against this module.
//! Units: millimetres for geometry, per-centimetre attenuation coefficients (as tabulated), and
//! every chord is converted to centimetres exactly once, in [`attenuation`].
//!
//! The model frame, the C-arm angles and the pixel convention are documented in [`geometry`].
//!
//! # Contract for the GPU renderer
//! Everything a GPU implementation needs is public and stable (names are kept once committed):
//! - Rays: [`Projection::gpu_ray_frame`] (`f32`, relative to the source) gives the exact ray of
//!   any continuous pixel coordinate; pixel `(i, j)`'s centre is `[i + 0.5, j + 0.5]`.
//!   [`Projection::projection_matrix`] maps model points to pixels (for rasterising meshes).
//! - Channels: one path length per [`FluoroMaterial`], in [`FluoroMaterial::index`] order
//!   (11 tissue classes in `MaterialClass::ALL` order, then steel). Nesting is by
//!   [`SceneEntry::priority`]: each point of a ray belongs to the highest-priority mesh containing
//!   it. For strictly nested meshes this equals "own chord minus the chords of the meshes directly
//!   inside"; [`Scene::ray_entry_chords`] gives the raw per-mesh chords an L-buffer accumulates,
//!   so both stages can be validated separately. Cancellous runs are clamped (see [`scene`]).
//! - Attenuation: per material [`FluoroMaterial::mu_60kev_per_cm`] and [`FluoroMaterial::basis`];
//!   [`attenuation::basis_depths`] sums `mu_60 * L` per basis (plus the iodine column times
//!   [`attenuation::iodine_stock_mu_60kev_per_cm`]); [`SpectralModel`] holds the weights `w_E`
//!   and the factors `R_b(E)`, and `T = sum_E w_E exp(-sum_b A_b R_b(E))`.
//! - Reference outputs: [`render_chords`] (per-pixel chords, no supersampling),
//!   [`render_transmission`] and [`render_frame`]; [`analytic`] has the sphere phantom and exact
//!   reference chords.
//! - Nesting for an L-buffer: [`nesting::nesting_plan`] gives each mesh's direct container and
//!   the effective materials its chord adds to and removes from.

pub mod analytic;
pub mod attenuation;
pub mod brightness;
pub mod contrast;
pub mod detector;
pub mod dose;
pub mod draft;
pub mod footprint;
pub mod geometry;
pub mod nesting;
pub mod receptor;
pub mod render;
mod rows;
pub mod scatter;
pub mod scene;
pub mod scene_store;
pub mod spectrum;
pub mod temporal;

pub use attenuation::{BasisDepths, EnergyModel, FluoroMaterial, MaterialChords, SpectralModel};
pub use contrast::IodineField;
pub use dose::{DoseExposure, DoseIncrement, air_kerma_ugy_per_mas_at_1m, incident_dose};
pub use geometry::{Collimation, DetectorFrame, GpuRayFrame, Projection, Ray};
pub use render::{
    Exposure, Image, QuantumNoise, RenderSettings, TransmissionImage, render_chords, render_frame,
    render_transmission,
};
pub use scene::{ChordScratch, NOMINAL_CORTICAL_SHELL_MM, RayChords, Scene, SceneEntry, SceneRef};
pub use spectrum::{AttenuationTables, Basis, Spectrum};
