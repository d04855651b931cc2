//! Tube spectra and mass-attenuation tables, generated offline (SpekPy 2.5.4, xraydb 4.5.8) by
//! `sim-core/data/fluoro/generate_spectra.py` and compiled in with `include_str!`.
//!
//! Bin convention: 1 keV bins `[n, n+1)` keV labelled by their centre `n + 0.5` keV, from 1.5 to
//! 119.5 keV; the attenuation tables are evaluated at the same centres. See
//! `sim-core/data/fluoro/README.md` for the exact command and versions.

use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

const SPECTRA_CSV: &str = include_str!("../../data/fluoro/spectra_w10_al6p3.csv");
const MU_CSV: &str = include_str!("../../data/fluoro/mass_attenuation_cm2_per_g.csv");
const MU60_CSV: &str = include_str!("../../data/fluoro/mass_attenuation_60kev.csv");

/// The reference energy of the single-energy mode and of the per-material coefficients, keV.
pub const REFERENCE_ENERGY_KEV: f64 = 60.0;

/// A basis material with a tabulated mass attenuation coefficient. Every scene material
/// attenuates with the energy dependence of one basis (see [`super::attenuation`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Basis {
    /// Water (soft tissues).
    Water,
    /// NIST "Bone, Compact (ICRU)" (cortical and cancellous bone).
    Bone,
    /// Iodine (contrast).
    Iodine,
    /// Aluminium (filters, step wedges).
    Aluminium,
    /// Iron (steel instruments).
    Iron,
}

impl Basis {
    /// Number of bases.
    pub const COUNT: usize = 5;
    /// Every basis, in table-column (and channel) order.
    pub const ALL: [Basis; 5] = [
        Basis::Water,
        Basis::Bone,
        Basis::Iodine,
        Basis::Aluminium,
        Basis::Iron,
    ];

    /// Column index in the tables.
    pub fn index(self) -> usize {
        self as usize
    }

    /// Column name in the CSV files.
    pub fn column(self) -> &'static str {
        match self {
            Basis::Water => "water",
            Basis::Bone => "bone_compact_icru",
            Basis::Iodine => "iodine",
            Basis::Aluminium => "aluminium",
            Basis::Iron => "iron",
        }
    }
}

/// Mass attenuation coefficients of the bases on the bin-centre grid.
#[derive(Debug, Clone, PartialEq)]
pub struct AttenuationTables {
    /// Bin centres, keV.
    pub energies_kev: Vec<f64>,
    /// `mu_over_rho_cm2_per_g[bin][basis]`.
    pub mu_over_rho_cm2_per_g: Vec<[f64; Basis::COUNT]>,
    /// Each basis at exactly [`REFERENCE_ENERGY_KEV`], cm^2/g.
    pub mu_over_rho_60kev_cm2_per_g: [f64; Basis::COUNT],
}

impl AttenuationTables {
    /// The committed tables (parsed once).
    pub fn get() -> &'static AttenuationTables {
        static TABLES: OnceLock<AttenuationTables> = OnceLock::new();
        TABLES.get_or_init(|| {
            let (header, rows) = parse_csv(MU_CSV);
            let cols: Vec<usize> = Basis::ALL
                .iter()
                .map(|b| {
                    header
                        .iter()
                        .position(|h| h == b.column())
                        .expect("basis column in attenuation table")
                })
                .collect();
            let energies_kev = rows.iter().map(|r| r[0]).collect();
            let mu = rows
                .iter()
                .map(|r| std::array::from_fn(|b| r[cols[b]]))
                .collect();
            let mut at60 = [f64::NAN; Basis::COUNT];
            for line in MU60_CSV.lines().skip(1).filter(|l| !l.trim().is_empty()) {
                let (name, value) = line.split_once(',').expect("name,value");
                let b = Basis::ALL
                    .iter()
                    .position(|b| b.column() == name.trim())
                    .expect("known basis");
                at60[b] = value.trim().parse().expect("number");
            }
            assert!(
                at60.iter().all(|x| x.is_finite()),
                "every basis has a 60 keV value"
            );
            AttenuationTables {
                energies_kev,
                mu_over_rho_cm2_per_g: mu,
                mu_over_rho_60kev_cm2_per_g: at60,
            }
        })
    }

    /// `mu/rho(E) / mu/rho(60 keV)` of every basis per bin: the factor that carries a 60 keV
    /// linear attenuation coefficient to energy `E`.
    pub fn ratio_to_60kev(&self) -> Vec<[f64; Basis::COUNT]> {
        self.mu_over_rho_cm2_per_g
            .iter()
            .map(|row| std::array::from_fn(|b| row[b] / self.mu_over_rho_60kev_cm2_per_g[b]))
            .collect()
    }
}

/// A tube spectrum: photon fluence per 1 keV bin (relative units).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Spectrum {
    /// Tube voltage, kVp.
    pub kvp: u32,
    /// Bin centres, keV (the same grid as [`AttenuationTables`]).
    pub energies_kev: Vec<f64>,
    /// Photon fluence per bin (SpekPy units; only ratios matter).
    pub fluence: Vec<f64>,
}

/// Error for a tube voltage without a committed spectrum.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("no committed spectrum for {kvp} kVp (available: 40 to 120 kVp in steps of 5)")]
pub struct UnknownKvp {
    /// The voltage asked for.
    pub kvp: u32,
}

impl Spectrum {
    /// Tube voltages with a committed spectrum, kVp.
    pub fn available_kvp() -> Vec<u32> {
        let (header, _) = spectra();
        header
            .iter()
            .skip(1)
            .map(|h| h.trim_start_matches("kvp").parse().expect("kvpNN"))
            .collect()
    }

    /// The committed tungsten spectrum (10 degree anode, 6.3 mm Al) at `kvp`.
    pub fn tungsten(kvp: u32) -> Result<Spectrum, UnknownKvp> {
        let (header, rows) = spectra();
        let col = header
            .iter()
            .position(|h| *h == format!("kvp{kvp}"))
            .ok_or(UnknownKvp { kvp })?;
        Ok(Spectrum {
            kvp,
            energies_kev: rows.iter().map(|r| r[0]).collect(),
            fluence: rows.iter().map(|r| r[col]).collect(),
        })
    }

    /// Fluence-weighted mean photon energy, keV (at 80 kVp: 48.23 keV with the bin-centre
    /// convention; SpekPy's `get_emean()` gives the same).
    pub fn mean_energy_kev(&self) -> f64 {
        let n: f64 = self.fluence.iter().sum();
        self.energies_kev
            .iter()
            .zip(&self.fluence)
            .map(|(e, f)| e * f)
            .sum::<f64>()
            / n
    }

    /// Energy-integrating detector weights `w_E = E Phi(E) / sum E Phi(E)` (an ideal detector
    /// with unit absorption efficiency, as on the methods page). They sum to 1.
    pub fn detector_weights(&self) -> Vec<f64> {
        let ef: Vec<f64> = self
            .energies_kev
            .iter()
            .zip(&self.fluence)
            .map(|(e, f)| e * f)
            .collect();
        let s: f64 = ef.iter().sum();
        ef.into_iter().map(|x| x / s).collect()
    }
}

fn spectra() -> &'static (Vec<String>, Vec<Vec<f64>>) {
    static SPECTRA: OnceLock<(Vec<String>, Vec<Vec<f64>>)> = OnceLock::new();
    SPECTRA.get_or_init(|| parse_csv(SPECTRA_CSV))
}

pub(crate) fn parse_csv(text: &str) -> (Vec<String>, Vec<Vec<f64>>) {
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header = lines
        .next()
        .expect("header")
        .split(',')
        .map(|s| s.trim().to_string())
        .collect::<Vec<_>>();
    let rows = lines
        .map(|l| {
            let r: Vec<f64> = l
                .split(',')
                .map(|s| s.trim().parse().expect("numeric CSV cell"))
                .collect();
            assert_eq!(r.len(), header.len(), "row width");
            r
        })
        .collect();
    (header, rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_are_centred_and_shared_by_spectra_and_tables() {
        let t = AttenuationTables::get();
        let s = Spectrum::tungsten(80).unwrap();
        assert_eq!(t.energies_kev, s.energies_kev);
        for (i, e) in s.energies_kev.iter().enumerate() {
            assert_eq!(*e, i as f64 + 1.5);
        }
        // Nothing above the tube voltage: the 79.5 keV bin is the last non-empty one at 80 kVp.
        let last = s.fluence.iter().rposition(|&f| f > 0.0).unwrap();
        assert_eq!(s.energies_kev[last], 79.5);
        assert_eq!(
            Spectrum::available_kvp(),
            (40..=120).step_by(5).collect::<Vec<_>>()
        );
        assert!(Spectrum::tungsten(82).is_err());
    }

    #[test]
    fn mean_energy_at_80_kvp_matches_spekpy() {
        // The methods page quotes about 48.34 keV for its 80 kVp beam; SpekPy 2.5.4 with 1 keV
        // bins gives 48.23 keV (`get_emean()`). The band 48.2-48.4 keV holds both: 0.1 keV
        // either side of 48.3 keV, the 0.11 keV between the two figures rounded up.
        let e = Spectrum::tungsten(80).unwrap().mean_energy_kev();
        assert!((48.2..48.4).contains(&e), "{e}");
        // Harder beam at higher voltage.
        assert!(Spectrum::tungsten(120).unwrap().mean_energy_kev() > e + 5.0);
    }

    #[test]
    fn iodine_k_edge_is_between_the_32_5_and_33_5_kev_bins() {
        let t = AttenuationTables::get();
        let i = Basis::Iodine.index();
        let below = t.mu_over_rho_cm2_per_g[31][i];
        let above = t.mu_over_rho_cm2_per_g[32][i];
        assert_eq!((t.energies_kev[31], t.energies_kev[32]), (32.5, 33.5));
        // The K-shell jump ratio of iodine is about 5 to 6 (Elam et al. 2002); 5x is a floor.
        assert!(above > 5.0 * below, "{below} -> {above}");
        // Everywhere else mu/rho falls with energy between neighbouring bins above 2 keV, apart from
        // the L edges (< 6 keV) of iodine and the K edge of iron (7.1 keV).
        for k in 8..t.energies_kev.len() - 1 {
            if k != 31 {
                assert!(t.mu_over_rho_cm2_per_g[k + 1][i] < t.mu_over_rho_cm2_per_g[k][i]);
            }
        }
    }

    #[test]
    fn sixty_kev_reference_values() {
        let t = AttenuationTables::get();
        // NIST XCOM iodine at 60 keV is 7.579 cm^2/g (methods page); xraydb's Elam tables give
        // 7.577, 0.03 % lower.
        let iodine = t.mu_over_rho_60kev_cm2_per_g[Basis::Iodine.index()];
        assert!((iodine - 7.579).abs() < 0.005, "{iodine}");
        // Water at 60 keV: NIST XCOM 0.2059 cm^2/g.
        let water = t.mu_over_rho_60kev_cm2_per_g[Basis::Water.index()];
        assert!((water - 0.2059).abs() < 0.001, "{water}");
    }
}
