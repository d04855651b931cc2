//! Scanner controls (what a learner turns) and frame sampling (what trades accuracy for time).

use serde::{Deserialize, Serialize};

use super::beam::Beam;
use super::error::{UltrasoundError, check_range};
use super::probe::{ProbeKind, ProbeSpec, check_depth};

/// Number of time-gain-compensation bands, equally spaced over the display depth.
pub const TGC_BANDS: usize = 6;

/// The scanner's controls.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Settings {
    /// Display depth in mm (within the probe's range).
    pub depth_mm: f64,
    /// Overall receive gain in dB (-30 ..= 60).
    pub gain_db: f64,
    /// Time-gain compensation in dB (-30 ..= 30 each) at the centres of [`TGC_BANDS`] equal depth
    /// bands, interpolated linearly between centres and held beyond the outer ones. All zero is
    /// "TGC off".
    pub tgc_db: [f64; TGC_BANDS],
    /// Transmit focal depth in mm (5 mm ..= display depth).
    pub focus_mm: f64,
    /// Centre frequency in MHz (within the probe's band).
    pub frequency_mhz: f64,
    /// Displayed dynamic range in dB (20 ..= 100): echoes from `-dynamic_range_db` to 0 dB after
    /// gain map to black .. white.
    pub dynamic_range_db: f64,
    /// Freeze: a [`super::Scanner`] keeps returning the last frame.
    pub frozen: bool,
}

impl Settings {
    /// Defaults for a probe: mid-band frequency, 40 mm (linear) or 100 mm (curvilinear) depth,
    /// focus at half depth, 20 dB gain, TGC off, 60 dB dynamic range.
    pub fn default_for(spec: &ProbeSpec) -> Settings {
        let depth_mm = match spec.kind {
            ProbeKind::Linear => 40.0,
            ProbeKind::Curvilinear => 100.0,
        };
        Settings {
            depth_mm,
            gain_db: 20.0,
            tgc_db: [0.0; TGC_BANDS],
            focus_mm: 0.5 * depth_mm,
            frequency_mhz: 0.5 * (spec.band_mhz.0 + spec.band_mhz.1),
            dynamic_range_db: 60.0,
            frozen: false,
        }
    }

    /// Refuses any control outside its range, naming it.
    pub fn validate(&self, spec: &ProbeSpec) -> Result<(), UltrasoundError> {
        check_depth(spec, self.depth_mm)?;
        check_range("settings.gain_db", self.gain_db, -30.0, 60.0)?;
        for &t in &self.tgc_db {
            check_range("settings.tgc_db", t, -30.0, 30.0)?;
        }
        check_range("settings.focus_mm", self.focus_mm, 5.0, self.depth_mm)?;
        check_range(
            "settings.frequency_mhz",
            self.frequency_mhz,
            spec.band_mhz.0,
            spec.band_mhz.1,
        )?;
        check_range(
            "settings.dynamic_range_db",
            self.dynamic_range_db,
            20.0,
            100.0,
        )?;
        Ok(())
    }

    /// The beam these settings give on a probe (no validation).
    pub fn beam(&self, spec: &ProbeSpec) -> Beam {
        Beam {
            frequency_mhz: self.frequency_mhz,
            focus_mm: self.focus_mm,
            aperture_mm: spec.aperture_mm,
            elevation_aperture_mm: spec.elevation_aperture_mm,
            elevation_focus_mm: spec.elevation_focus_mm,
        }
    }

    /// Time-gain compensation in dB at depth `z_mm`.
    pub fn tgc_at_db(&self, z_mm: f64) -> f64 {
        let band = self.depth_mm / TGC_BANDS as f64;
        let t = (z_mm / band - 0.5).clamp(0.0, (TGC_BANDS - 1) as f64);
        // `t >= 0` (or NaN, which both give 0): truncation is the floor, without a libm call
        // per pixel (the baseline x86-64 target has no rounding instruction).
        let i = (t as usize).min(TGC_BANDS - 2);
        let f = t - i as f64;
        self.tgc_db[i] * (1.0 - f) + self.tgc_db[i + 1] * f
    }
}

/// How finely one frame is computed. [`Sampling::for_settings`] gives the defaults; the bench
/// reports time against error for coarser and finer choices.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sampling {
    /// Scan lines per frame.
    pub lines: usize,
    /// Samples per line over the display depth.
    pub samples_per_line: usize,
    /// Step of the attenuation and interface march along each line, mm.
    pub march_step_mm: f64,
    /// Side of a square image pixel, mm.
    pub pixel_mm: f64,
    /// Side of a scatterer lattice cell, mm (the probe's default; smaller is slower and closer to
    /// fully developed speckle).
    pub scatter_cell_mm: f64,
}

impl Sampling {
    /// Defaults: at least 256 lines and at least two lines per lateral FWHM at every depth (so
    /// scan conversion between lines does not alias the speckle), axial samples every third of
    /// the axial FWHM, a 0.1 mm march, 512 image rows, and a scatterer cell no larger than 1.25
    /// axial sigmas (coarser lattices give pre-Rayleigh speckle: at 12 MHz a 0.2 mm cell gave
    /// mean/SD 1.67, a 0.1 mm cell 1.90; the probe's cell is the upper bound).
    pub fn for_settings(spec: &ProbeSpec, settings: &Settings) -> Sampling {
        let axial_fwhm = super::beam::axial_fwhm_mm(settings.frequency_mhz);
        let beam = settings.beam(spec);
        let spans = (0..=100)
            .map(|i| {
                let z = settings.depth_mm * f64::from(i) / 100.0;
                let width = match spec.kind {
                    ProbeKind::Linear => spec.footprint_mm,
                    ProbeKind::Curvilinear => (spec.radius_mm + z) * spec.sector_deg.to_radians(),
                };
                2.0 * width / beam.lateral_fwhm_mm(z)
            })
            .fold(0.0f64, f64::max);
        Sampling {
            lines: (spans.ceil() as usize + 1).max(256),
            samples_per_line: (3.0 * settings.depth_mm / axial_fwhm).ceil() as usize,
            march_step_mm: 0.1,
            pixel_mm: settings.depth_mm / 512.0,
            scatter_cell_mm: spec
                .scatter_cell_mm
                .min(1.25 * axial_fwhm / super::beam::FWHM_PER_SIGMA),
        }
    }

    /// A draft of the same frame: the preview a session shows while the probe is still moving,
    /// before the full frame. Same image pixels (so the same image size), half the lines, the
    /// samples per line and the march steps, and a scatterer lattice twice as coarse (an
    /// eighth of the scatterers, the cost that dominates an oblique pose). Its speckle is fixed
    /// to the tissue like the full frame's, on its own lattice, and less developed (fewer
    /// scatterers per resolution cell); the `ultrasound` bench reports its time and its
    /// difference from the full frame.
    pub fn draft(self) -> Sampling {
        Sampling {
            lines: (self.lines / 2).max(2),
            samples_per_line: (self.samples_per_line / 2).max(16),
            march_step_mm: (2.0 * self.march_step_mm).min(2.0),
            pixel_mm: self.pixel_mm,
            scatter_cell_mm: (2.0 * self.scatter_cell_mm).min(2.0),
        }
    }

    /// Refuses sampling that cannot make a frame, naming the field.
    pub fn validate(&self) -> Result<(), UltrasoundError> {
        check_range("sampling.lines", self.lines as f64, 2.0, 4096.0)?;
        check_range(
            "sampling.samples_per_line",
            self.samples_per_line as f64,
            16.0,
            65536.0,
        )?;
        check_range("sampling.march_step_mm", self.march_step_mm, 0.01, 2.0)?;
        check_range("sampling.pixel_mm", self.pixel_mm, 0.02, 2.0)?;
        check_range("sampling.scatter_cell_mm", self.scatter_cell_mm, 0.05, 2.0)?;
        Ok(())
    }
}
