//! The point-spread function, in millimetres, at every depth.
//!
//! The PSF is separable in the frame of each scan line: axial (along the line) x lateral (in the
//! image plane, perpendicular to the line) x elevation (across the slice). Each factor is a
//! Gaussian envelope of the given FWHM; the axial one carries the carrier phase `exp(2 i k z)`.
//! Widths are physical lengths, so a sector's diverging lines get the same millimetre PSF as a
//! linear array's parallel ones (the reference system blurred by a fixed number of lines).

/// Speed of sound the scanner assumes for depth (m/s): the conventional 1540 m/s.
pub const ASSUMED_SPEED_M_S: f64 = 1540.0;

/// FWHM / sigma of a Gaussian: 2 sqrt(2 ln 2).
pub const FWHM_PER_SIGMA: f64 = 2.354_820_045_030_949;

/// Axial FWHM of the pulse-echo envelope, mm: 0.45 mm at 5 MHz, the reference atlas's nominal
/// axial width (methods page, "Coherent scatter and the point-spread function"), a pulse of
/// about two cycles. Simulator choice: it scales with 1/f, a constant fractional bandwidth.
pub fn axial_fwhm_mm(frequency_mhz: f64) -> f64 {
    0.45 * 5.0 / frequency_mhz
}

/// Wavelength at the assumed speed, mm.
pub fn wavelength_mm(frequency_mhz: f64) -> f64 {
    ASSUMED_SPEED_M_S * 1e-3 / frequency_mhz
}

/// The beam of one frame: frequency, transmit focus and apertures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    /// Centre frequency, MHz.
    pub frequency_mhz: f64,
    /// Transmit focal depth, mm.
    pub focus_mm: f64,
    /// Active lateral aperture, mm.
    pub aperture_mm: f64,
    /// Elevation aperture, mm.
    pub elevation_aperture_mm: f64,
    /// Elevation lens focus, mm.
    pub elevation_focus_mm: f64,
}

/// Smallest receive F-number of the dynamic receive focus (our choice: aperture growth stops at
/// F/1, typical of scanners).
const RECEIVE_F_NUMBER_MIN: f64 = 1.0;

impl Beam {
    /// Wavelength, mm.
    pub fn wavelength_mm(&self) -> f64 {
        wavelength_mm(self.frequency_mhz)
    }

    /// Axial FWHM, mm (depth independent).
    pub fn axial_fwhm_mm(&self) -> f64 {
        axial_fwhm_mm(self.frequency_mhz)
    }

    /// Lateral two-way FWHM at depth `z`, mm. Transmit: a fixed focus of F-number
    /// `F = focus / aperture` with FWHM `lambda F` at the focus, widening as a Gaussian beam
    /// away from it (Rayleigh length half the classic depth of field `7 lambda F^2`). Receive:
    /// dynamic focus with FWHM `lambda max(z / aperture, 1)`. The two-way amplitude PSF is their
    /// product, so `1 / w^2 = 1 / w_tx^2 + 1 / w_rx^2`.
    pub fn lateral_fwhm_mm(&self, z: f64) -> f64 {
        let lambda = self.wavelength_mm();
        let f_tx = self.focus_mm / self.aperture_mm;
        let rayleigh = 3.5 * lambda * f_tx * f_tx;
        let d = (z - self.focus_mm) / rayleigh;
        let w_tx = lambda * f_tx * (1.0 + d * d).sqrt();
        let w_rx = lambda * (z.max(0.0) / self.aperture_mm).max(RECEIVE_F_NUMBER_MIN);
        1.0 / (1.0 / (w_tx * w_tx) + 1.0 / (w_rx * w_rx)).sqrt()
    }

    /// Elevation two-way FWHM (slice thickness) at depth `z`, mm: the lens focus gives
    /// `lambda F_el`, the geometric cone `D_el |z - z_el| / z_el` away from it (quadrature sum;
    /// `D_el` at the face), and the same lens on receive narrows the two-way width by sqrt 2.
    pub fn elevation_fwhm_mm(&self, z: f64) -> f64 {
        let lambda = self.wavelength_mm();
        let ze = self.elevation_focus_mm;
        let de = self.elevation_aperture_mm;
        let focal = lambda * ze / de;
        let cone = de * (z - ze) / ze;
        (focal * focal + cone * cone).sqrt() / std::f64::consts::SQRT_2
    }
}
