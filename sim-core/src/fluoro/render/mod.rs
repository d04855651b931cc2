//! The CPU reference frame: transmission per pixel (with supersampling), quantum noise,
//! automatic brightness, log mapping to 8 bit and collimator shutters.
//!
//! Everything is deterministic: the same inputs (and noise seed) give bit-identical images, for
//! any thread count, because each pixel's noise comes from its own seeded generator.
//!
//! The steps, in order, each in a module of its own: `transmission` (chords, spectral model,
//! supersampling), `noise` (seeded Poisson counts), `display` (automatic brightness, log tone
//! curve, shutters) and `frame`, which chains them and holds the finish the GPU renderer shares.

mod display;
mod frame;
mod noise;
mod settings;
mod transmission;

#[cfg(test)]
mod tests;

pub use display::{exposure_centre, to_display, to_display_centred};
pub use frame::{DetectorSignal, finish_frame, finish_frame_f32, render_frame};
pub use noise::apply_noise;
pub use settings::{
    Exposure, Image, QuantumNoise, RenderSettings, SHUTTER_GREY, TransmissionImage,
};
pub use transmission::{mark_projected_edges, pixel_chords, render_chords, render_transmission};
