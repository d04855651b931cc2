//! The detector's side of an exposure: air kerma at the detector, the quanta it carries, and how
//! many of them the detector turns into signal (its DQE), so that the quantum noise of a frame
//! follows the dose the learner (or the automatic brightness control) chose.
//!
//! # Quanta per unit air kerma
//! From the committed SpekPy spectrum `Phi(E)` (photons keV^-1 cm^-2 mAs^-1 at 100 cm, 1 keV
//! bins) and its air kerma per mAs ([`super::dose`]):
//!
//! ```text
//! q [photons mm^-2 nGy^-1] = (sum_E Phi(E) dE / 100 mm^2/cm^2) / (K [uGy/mAs] * 1000 nGy/uGy)
//! ```
//!
//! 80 kVp with 6.3 mm Al gives about 26 photons mm^-2 nGy^-1; for comparison IEC 62220-1's RQA5
//! beam (70 kVp behind 21 mm Al, harder) is tabulated at 30.2 photons mm^-2 nGy^-1
//! (30,174 per uGy), so the figures agree in size (the test below checks the order).
//!
//! # Behind the patient
//! The detector air kerma behind the patient is the unattenuated kerma times a kerma-weighted
//! transmission `T_K = sum_E w_K(E) exp(-sum_b A_b R_b(E))` with `w_K(E) ∝ Phi(E) E
//! (mu_en/rho)_air(E)` ([`kerma_model`]): the same basis depths as the image, weighted by what
//! each energy adds to air kerma instead of to the energy-integrating signal.
//!
//! The noise of a pixel is drawn as a Poisson count with mean `N T` (see
//! [`super::render::QuantumNoise`]), `T` the image's transmission and `N` the detected quanta of
//! an unattenuated pixel: `N = K_det q a DQE` for a pixel of area `a` (mm^2) at the detector.
//! Counting the detected quanta with the image's energy-weighted transmission instead of the
//! photon-weighted one is an approximation (beam hardening changes the mean energy behind the
//! patient); it keeps the variance of a pixel proportional to `1 / (K_det T)`, which is what a
//! quantum-limited detector shows.

use std::sync::OnceLock;

use super::attenuation::{BasisDepths, EnergyModel, SpectralModel};
use super::dose::{
    REFERENCE_DISTANCE_MM, air_kerma_ugy_per_mas_at_1m, air_kerma_ugy_per_mas_at_1m_interpolated,
    muen_air_table,
};
use super::spectrum::{AttenuationTables, Spectrum, UnknownKvp};

/// Zero-frequency detective quantum efficiency of the simulated flat panel (CsI:Tl on amorphous
/// silicon): about 0.65 at 70 kVp (RQA5), P. R. Granfors and R. Aufrichtig, "Performance of a
/// 41 x 41 cm^2 amorphous silicon flat panel x-ray detector for radiographic imaging
/// applications", Med. Phys. 27 (2000) 1324-1331. Taken as energy independent over 40-120 kVp
/// (simulator choice: the panel's CsI thickness absorbs most of a filtered fluoroscopy beam).
pub const FLAT_PANEL_DQE: f64 = 0.65;

/// Photons per mm^2 per nGy of unattenuated air kerma of the committed spectrum at `kvp`
/// (module docs).
pub fn quanta_per_mm2_per_ngy(kvp: u32) -> Result<f64, UnknownKvp> {
    let s = Spectrum::tungsten(kvp)?;
    let photons_per_cm2_per_mas: f64 = s.fluence.iter().sum::<f64>() * 1.0;
    let ugy_per_mas = air_kerma_ugy_per_mas_at_1m(kvp).ok_or(UnknownKvp { kvp })?;
    Ok(photons_per_cm2_per_mas / 100.0 / (ugy_per_mas * 1000.0))
}

/// Unattenuated air kerma at the detector plane, nGy, of `mas` at `kvp` with the focal spot
/// `source_to_detector_mm` away (inverse square from the spectra's 1 m). Zero for a
/// non-finite or non-positive charge or distance.
pub fn open_field_kerma_ngy(kvp: f64, mas: f64, source_to_detector_mm: f64) -> f64 {
    if !(mas.is_finite() && mas > 0.0 && source_to_detector_mm.is_finite())
        || source_to_detector_mm <= 0.0
    {
        return 0.0;
    }
    air_kerma_ugy_per_mas_at_1m_interpolated(kvp)
        * 1000.0
        * mas
        * (REFERENCE_DISTANCE_MM / source_to_detector_mm).powi(2)
}

/// Detected quanta of an unattenuated pixel of `pixel_area_mm2` (at the detector) for an
/// exposure of `mas` at `kvp`, `source_to_detector_mm` from the focal spot, by a detector of
/// quantum efficiency `dqe` (module docs). The mean count of a pixel is this times its
/// transmission.
pub fn detected_quanta_per_pixel(
    kvp: u32,
    mas: f64,
    source_to_detector_mm: f64,
    pixel_area_mm2: f64,
    dqe: f64,
) -> Result<f64, UnknownKvp> {
    let q = quanta_per_mm2_per_ngy(kvp)?;
    let k = open_field_kerma_ngy(f64::from(kvp), mas, source_to_detector_mm);
    Ok(k * q * pixel_area_mm2.max(0.0) * dqe.clamp(0.0, 1.0))
}

/// The air-kerma-weighted spectral model at `kvp`: its [`SpectralModel::transmission`] of a
/// ray's basis depths is the fraction of the open-field detector air kerma behind it.
pub fn kerma_model(kvp: u32) -> Result<&'static SpectralModel, UnknownKvp> {
    static MODELS: OnceLock<Vec<(u32, SpectralModel)>> = OnceLock::new();
    let models = MODELS.get_or_init(|| {
        let table = muen_air_table();
        let ratio = AttenuationTables::get().ratio_to_60kev();
        Spectrum::available_kvp()
            .into_iter()
            .map(|k| {
                let s = Spectrum::tungsten(k).expect("committed kVp");
                let raw: Vec<f64> = s
                    .energies_kev
                    .iter()
                    .zip(&s.fluence)
                    .zip(table)
                    .map(|((e, f), (_, muen))| f * e * muen)
                    .collect();
                let sum: f64 = raw.iter().sum();
                let keep: Vec<usize> = (0..raw.len()).filter(|&i| raw[i] > 0.0).collect();
                let model = SpectralModel {
                    model: EnergyModel::Spectral { kvp: k },
                    energies_kev: keep.iter().map(|&i| s.energies_kev[i]).collect(),
                    weights: keep.iter().map(|&i| raw[i] / sum).collect(),
                    ratio_to_60kev: keep.iter().map(|&i| ratio[i]).collect(),
                };
                (k, model)
            })
            .collect()
    });
    models
        .iter()
        .find(|(k, _)| *k == kvp)
        .map(|(_, m)| m)
        .ok_or(UnknownKvp { kvp })
}

/// Detector air kerma behind basis depths `a`, nGy, for `mas` at `kvp` and the focal spot
/// `source_to_detector_mm` away.
pub fn detector_kerma_ngy(
    kvp: u32,
    mas: f64,
    source_to_detector_mm: f64,
    a: &BasisDepths,
) -> Result<f64, UnknownKvp> {
    let t = kerma_model(kvp)?.transmission(a);
    Ok(open_field_kerma_ngy(f64::from(kvp), mas, source_to_detector_mm) * t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluoro::Basis;

    #[test]
    fn quanta_per_unit_kerma_are_those_of_a_diagnostic_beam() {
        // IEC 62220-1 RQA5 (70 kVp, 21 mm Al): 30.2 photons mm^-2 nGy^-1; RQA3 (50 kVp, 10 mm
        // Al) 21.8; softer, less filtered beams carry fewer photons per nGy. Ours (6.3 mm Al)
        // must lie in the same band and rise with the voltage.
        let q: Vec<f64> = [50, 70, 80, 100, 120]
            .iter()
            .map(|&k| quanta_per_mm2_per_ngy(k).unwrap())
            .collect();
        for w in q.windows(2) {
            assert!(w[1] > w[0], "{q:?}");
        }
        assert!(q[1] > 15.0 && q[1] < 35.0, "70 kVp: {}", q[1]);
        assert!(q[2] > 15.0 && q[2] < 35.0, "80 kVp: {}", q[2]);
        assert!(quanta_per_mm2_per_ngy(83).is_err());
    }

    #[test]
    fn detector_kerma_falls_with_the_inverse_square_and_the_kerma_transmission() {
        let open = open_field_kerma_ngy(80.0, 1.0, 1000.0);
        // 32.72 uGy/mAs at 1 m (SpekPy's get_kerma at 80 kVp, see `dose`).
        assert!((open - 32_720.0).abs() < 50.0, "{open}");
        let far = open_field_kerma_ngy(80.0, 1.0, 2000.0);
        assert!((far * 4.0 - open).abs() < 1e-9 * open);
        assert_eq!(open_field_kerma_ngy(80.0, -1.0, 1000.0), 0.0);
        assert_eq!(open_field_kerma_ngy(80.0, f64::NAN, 1000.0), 0.0);
        assert_eq!(open_field_kerma_ngy(80.0, 1.0, 0.0), 0.0);
        // 200 mm of soft tissue: the kerma-weighted transmission is a few percent and lies
        // below the energy-integrating one (kerma weights the soft photons more).
        let mut a = [0.0; Basis::COUNT];
        a[Basis::Water.index()] = 0.20 * 20.0;
        let tk = kerma_model(80).unwrap().transmission(&a);
        let te = SpectralModel::new(EnergyModel::Spectral { kvp: 80 })
            .unwrap()
            .transmission(&a);
        assert!(tk > 0.005 && tk < 0.08, "{tk}");
        assert!(tk < te, "{tk} {te}");
        // No attenuation: the open field exactly.
        let zero = detector_kerma_ngy(80, 1.0, 1000.0, &[0.0; Basis::COUNT]).unwrap();
        assert!((zero - open).abs() < 1e-9 * open);
    }

    #[test]
    fn detected_quanta_scale_with_charge_area_and_efficiency() {
        let n = detected_quanta_per_pixel(80, 0.1, 1480.0, 0.34, FLAT_PANEL_DQE).unwrap();
        let n2 = detected_quanta_per_pixel(80, 0.4, 1480.0, 0.34, FLAT_PANEL_DQE).unwrap();
        let n3 = detected_quanta_per_pixel(80, 0.1, 1480.0, 0.34 / 4.0, FLAT_PANEL_DQE).unwrap();
        assert!((n2 / n - 4.0).abs() < 1e-12);
        assert!((n / n3 - 4.0).abs() < 1e-12);
        let ideal = detected_quanta_per_pixel(80, 0.1, 1480.0, 0.34, 1.0).unwrap();
        assert!((n / ideal - FLAT_PANEL_DQE).abs() < 1e-12);
    }

    /// Relative variance of the noisy transmission over a uniform field of transmission `t`
    /// with `quanta` detected quanta per unattenuated pixel.
    fn relative_variance(quanta: f64, t: f64) -> f64 {
        use crate::fluoro::render::{QuantumNoise, TransmissionImage, apply_noise};
        let n = 256 * 256;
        let mut img = TransmissionImage {
            width: 256,
            height: 256,
            transmission: vec![t; n],
            exposed: vec![true; n],
            supersampled_pixels: 0,
        };
        apply_noise(
            &mut img,
            &QuantumNoise {
                photons_per_pixel: quanta,
                seed: 0x5eed,
            },
        );
        let mean = img.transmission.iter().sum::<f64>() / n as f64;
        let var = img
            .transmission
            .iter()
            .map(|v| (v - mean) * (v - mean))
            .sum::<f64>()
            / (n - 1) as f64;
        var / (mean * mean)
    }

    #[test]
    fn noise_variance_follows_the_detector_kerma() {
        // A 0.586 mm pixel behind 1 % kerma transmission, 80 kVp, charges over a 4x range: the
        // relative variance is 1 / (N T) (Poisson), so it falls as 1 / kerma. Tolerance 5 %:
        // eight times the estimator's own relative spread over 65,536 pixels,
        // sqrt(2 / 65,536) = 0.6 %, and well below the 25 % a dependence off by one power of
        // the charge over this 4x range would give.
        let area = (300.0_f64 / 512.0).powi(2);
        let t = 0.01;
        let base = detected_quanta_per_pixel(80, 0.1, 1480.0, area, FLAT_PANEL_DQE).unwrap();
        let v0 = relative_variance(base, t);
        for factor in [1.0, 2.0, 4.0] {
            let q =
                detected_quanta_per_pixel(80, 0.1 * factor, 1480.0, area, FLAT_PANEL_DQE).unwrap();
            let v = relative_variance(q, t);
            let expected = 1.0 / (q * t);
            assert!(
                (v / expected - 1.0).abs() < 0.05,
                "x{factor}: {v} vs {expected}"
            );
            assert!(
                (v0 / v / factor - 1.0).abs() < 0.05,
                "x{factor}: {v0} / {v}"
            );
        }
    }
}
