//! Per-sample beam tables of one frame: the elevation and lateral widths and the energy factors
//! that keep uniform tissue's mean speckle the same at every depth.

use super::super::beam::{Beam, FWHM_PER_SIGMA};
use super::lookup::exp_neg;

/// Per-sample beam tables of one frame.
#[derive(Debug, Clone)]
pub(crate) struct BeamTables {
    /// Sample spacing along each line, mm.
    pub dz: f64,
    /// `1 / (2 sigma_e^2)` of the elevation profile at each sample.
    pub elev_inv2s2: Vec<f64>,
    /// `sqrt(sigma_e(focus) / sigma_e(z))` at each sample.
    pub elev_energy: Vec<f64>,
    /// Lateral sigma at each sample, mm.
    pub lat_sigma_mm: Vec<f64>,
    /// `sqrt(sigma_l(focus) / sigma_l(z))` at each sample.
    pub lat_energy: Vec<f64>,
    /// Axial sigma, mm.
    pub axial_sigma_mm: f64,
    /// Largest elevation FWHM over the depth, mm.
    pub max_elev_fwhm_mm: f64,
    /// Largest lateral FWHM over the depth, mm.
    pub max_lat_fwhm_mm: f64,
}

impl BeamTables {
    pub fn new(beam: &Beam, depth_mm: f64, samples: usize) -> BeamTables {
        let dz = depth_mm / (samples - 1) as f64;
        let sl_ref = beam.lateral_fwhm_mm(beam.focus_mm);
        let se_ref = beam.elevation_fwhm_mm(beam.elevation_focus_mm);
        let mut t = BeamTables {
            dz,
            elev_inv2s2: Vec::with_capacity(samples),
            elev_energy: Vec::with_capacity(samples),
            lat_sigma_mm: Vec::with_capacity(samples),
            lat_energy: Vec::with_capacity(samples),
            axial_sigma_mm: beam.axial_fwhm_mm() / FWHM_PER_SIGMA,
            max_elev_fwhm_mm: 0.0,
            max_lat_fwhm_mm: 0.0,
        };
        for s in 0..samples {
            let z = s as f64 * dz;
            let we = beam.elevation_fwhm_mm(z);
            let wl = beam.lateral_fwhm_mm(z);
            let se = we / FWHM_PER_SIGMA;
            t.elev_inv2s2.push(1.0 / (2.0 * se * se));
            t.elev_energy.push((se_ref / we).sqrt());
            t.lat_sigma_mm.push(wl / FWHM_PER_SIGMA);
            t.lat_energy.push((sl_ref / wl).sqrt());
            t.max_elev_fwhm_mm = t.max_elev_fwhm_mm.max(we);
            t.max_lat_fwhm_mm = t.max_lat_fwhm_mm.max(wl);
        }
        t
    }

    /// Nearest sample index of depth `z` (clamped).
    #[inline]
    pub fn sample_of(&self, z: f64) -> usize {
        self.sample_at(z / self.dz)
    }

    /// Nearest sample index of fractional sample `s = z / dz` (clamped).
    #[inline]
    pub fn sample_at(&self, s: f64) -> usize {
        // Round half up by truncation of a non-negative value (no libm call).
        ((s + 0.5).max(0.0) as usize).min(self.elev_inv2s2.len() - 1)
    }

    /// Peak-normalised elevation weight of offset `e` at depth `z`, times the energy factor.
    #[inline]
    pub fn elevation_weight(&self, e: f64, z: f64) -> f64 {
        let s = self.sample_of(z);
        exp_neg(e * e * self.elev_inv2s2[s]) * self.elev_energy[s]
    }
}
