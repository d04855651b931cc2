//! Host-side tables of the GPU B-mode path: the constants shared with the shaders (and those
//! that mirror sim-core's private ones), the per-sample beam tables, the PSF taps and the tissue
//! property table built from sim-core's own functions.

use glam::DVec3;
use sim_core::material::MaterialClass;
use sim_core::ultrasound::beam::FWHM_PER_SIGMA;
use sim_core::ultrasound::tissue::{AIR, class_props, hu_props};
use sim_core::ultrasound::{AcousticProps, Beam, Texture};

/// Elevation reach of the scatter sum in FWHM (mirrors sim-core `scatter::ELEV_REACH_FWHM`).
pub(super) const ELEV_REACH_FWHM: f64 = 1.0;
/// Interfaces weaker than this are not drawn (mirrors sim-core `echo::MIN_INTERFACE_R`).
pub(super) const MIN_INTERFACE_R: f64 = 0.01;
/// Specular interface lobe, degrees (mirrors sim-core `echo::INTERFACE_LOBE_DEG`).
pub(super) const INTERFACE_LOBE_DEG: f64 = 15.0;
/// Finite-difference radius of the interface normal, mm (mirrors sim-core `echo::NORMAL_STEP_MM`).
pub(super) const NORMAL_STEP_MM: f64 = 1.0;
/// Nepers per decibel (amplitude): ln 10 / 20.
pub(super) const NP_PER_DB: f64 = std::f64::consts::LN_10 / 20.0;
/// Voxel code of a labelled voxel: `LABEL_BASE + label` (must match `medium.wgsl`).
pub(super) const LABEL_BASE: f32 = 1_000_000.0;
/// HU range of the table (must match `medium.wgsl`).
pub(super) const HU_MIN: i32 = -400;
pub(super) const HU_MAX: i32 = 1000;
/// Table row of the coupling gel (must match `medium.wgsl`; above every class label).
pub(super) const GEL_ROW: usize = 15;
/// First table row of the HU part (must match `medium.wgsl`).
pub(super) const HU_ROW: usize = 16;

pub(super) fn v4(v: DVec3, w: f64) -> [f32; 4] {
    [v.x as f32, v.y as f32, v.z as f32, w as f32]
}

/// Per-sample beam tables (sim-core `scatter::BeamTables`, rebuilt from the public [`Beam`]).
pub(super) struct Tables {
    pub(super) dz: f64,
    /// `(1 / 2 sigma_e^2, elevation energy, lateral sigma mm, lateral energy)` per sample.
    pub(super) rows: Vec<[f64; 4]>,
    pub(super) axial_sigma_mm: f64,
    pub(super) max_elev_fwhm_mm: f64,
    pub(super) max_lat_fwhm_mm: f64,
}

impl Tables {
    pub(super) fn new(beam: &Beam, depth_mm: f64, samples: usize) -> Tables {
        let dz = depth_mm / (samples - 1) as f64;
        let sl_ref = beam.lateral_fwhm_mm(beam.focus_mm);
        let se_ref = beam.elevation_fwhm_mm(beam.elevation_focus_mm);
        let (mut max_e, mut max_l) = (0.0f64, 0.0f64);
        let rows = (0..samples)
            .map(|s| {
                let z = s as f64 * dz;
                let we = beam.elevation_fwhm_mm(z);
                let wl = beam.lateral_fwhm_mm(z);
                let se = we / FWHM_PER_SIGMA;
                max_e = max_e.max(we);
                max_l = max_l.max(wl);
                [
                    1.0 / (2.0 * se * se),
                    (se_ref / we).sqrt(),
                    wl / FWHM_PER_SIGMA,
                    (sl_ref / wl).sqrt(),
                ]
            })
            .collect();
        Tables {
            dz,
            rows,
            axial_sigma_mm: beam.axial_fwhm_mm() / FWHM_PER_SIGMA,
            max_elev_fwhm_mm: max_e,
            max_lat_fwhm_mm: max_l,
        }
    }

    pub(super) fn sample_of(&self, z: f64) -> usize {
        ((z / self.dz + 0.5).max(0.0) as usize).min(self.rows.len() - 1)
    }

    /// Elevation weight of offset `e` at depth `z` (sim-core's, with `exp` for its table).
    pub(super) fn elevation_weight(&self, e: f64, z: f64) -> f64 {
        let r = self.rows[self.sample_of(z)];
        let x = e * e * r[0];
        if x >= 16.0 { 0.0 } else { (-x).exp() * r[1] }
    }
}

/// sim-core `scatter::conv_sigma`: the deposit's own spread is subtracted.
pub(super) fn conv_sigma(sigma_steps: f64) -> f64 {
    (sigma_steps * sigma_steps - 1.0 / 6.0).max(0.01).sqrt()
}

/// sim-core `scatter::gaussian_taps`.
pub(super) fn gaussian_taps(sigma: f64, k: usize) -> Vec<f32> {
    (0..=2 * k)
        .map(|i| {
            let t = i as f64 - k as f64;
            (-(t * t) / (2.0 * sigma * sigma)).exp() as f32
        })
        .collect()
}

/// sim-core `scatter::amplitude_norm`.
pub(super) fn amplitude_norm(beam: &Beam, tables: &Tables, h: f64) -> f64 {
    let sl = beam.lateral_fwhm_mm(beam.focus_mm) / FWHM_PER_SIGMA;
    let se = beam.elevation_fwhm_mm(beam.elevation_focus_mm) / FWHM_PER_SIGMA;
    let integral = std::f64::consts::PI.powf(1.5) * tables.axial_sigma_mm * sl * se;
    (3.0 * h * h * h / integral).sqrt()
}

/// A table row: `[impedance, attenuation, echogenicity dB, density], [roughness, fascicular]`.
pub(super) fn lut_row(p: &AcousticProps) -> [[f32; 4]; 2] {
    let fasc = if p.texture == Texture::Fascicular {
        1.0
    } else {
        0.0
    };
    [
        [
            p.impedance_mrayl as f32,
            p.attenuation_db_cm_mhz as f32,
            p.echogenicity_db as f32,
            p.scatter_density as f32,
        ],
        [p.roughness as f32, fasc, 0.0, 0.0],
    ]
}

/// The property table (layout in `medium.wgsl`).
pub(super) fn property_table() -> Vec<[[f32; 4]; 2]> {
    let mut rows = vec![lut_row(&AIR); HU_ROW];
    for (l, row) in rows.iter_mut().enumerate().skip(1) {
        if let Some(c) = MaterialClass::from_label(l as u8) {
            *row = lut_row(&class_props(c));
        }
    }
    rows[GEL_ROW] = lut_row(&sim_core::ultrasound::GEL);
    // At -400 HU itself `hu_props` is air, but just above it fat: the row at -400 is the limit
    // from above, which the interpolation in (-400, -399) needs (-400 and below is air, row 0).
    rows.extend((HU_MIN..=HU_MAX).map(|h| lut_row(&hu_props(f64::from(h).max(-399.5)))));
    rows
}

/// sim-core's interface-normal directions (`sphere_directions`) as shader vectors.
pub(super) fn sphere_directions() -> Vec<[f32; 4]> {
    sim_core::ultrasound::sphere_directions()
        .iter()
        .map(|d| v4(*d, 0.0))
        .collect()
}

/// Where one frame's time went, milliseconds (wall clock on the calling thread).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UltrasoundTimings {
    /// Uploading the medium (only on a new `medium_key`).
    pub medium_upload_ms: f64,
    /// CPU set-up: tables, weights, uniforms and their upload.
    pub setup_ms: f64,
    /// Scatter deposit (only with [`GpuUltrasound::profile`]; otherwise in `gpu_ms`).
    pub deposit_ms: f64,
    /// Lateral and axial convolution (profile only).
    pub convolve_ms: f64,
    /// Line march and envelope (profile only).
    pub march_ms: f64,
    /// Log compression and scan conversion (profile only).
    pub display_ms: f64,
    /// From submission to completion of the whole frame (or the sum of the stages).
    pub gpu_ms: f64,
    /// Mapping the read-back buffer and copying out.
    pub readback_ms: f64,
    /// Assembling the frame on the CPU (pixels, inside mask, needle view).
    pub finish_ms: f64,
}

/// Milliseconds since `t` (for [`UltrasoundTimings`]).
pub(super) fn ms(t: std::time::Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The layered test scene of the GPU tests and bench on `grid`: fat (-100 HU) down to 8 mm over
/// muscle (50 HU), and a 3 mm cortical plate at 45 mm under `x < 0` given by the label volume
/// (its HU say muscle: the label wins). Only with the `test-support` feature.
#[cfg(feature = "test-support")]
pub fn layered_test_volume(
    grid: sim_core::volume::VolumeGrid,
) -> (sim_core::volume::Volume<f32>, sim_core::volume::Volume<u8>) {
    use sim_core::volume::Volume;
    let mut hu = Volume::filled(grid, 50.0f32);
    let mut labels = Volume::filled(grid, 0u8);
    for k in 0..grid.dims[2] {
        for j in 0..grid.dims[1] {
            for i in 0..grid.dims[0] {
                let [x, _, z] = grid.voxel_center_mm(i, j, k);
                if z < 8.0 {
                    hu.set(i, j, k, -100.0);
                }
                if x < 0.0 && (45.0..48.0).contains(&z) {
                    labels.set(
                        i,
                        j,
                        k,
                        sim_core::material::MaterialClass::CorticalBone.label(),
                    );
                }
            }
        }
    }
    (hu, labels)
}
