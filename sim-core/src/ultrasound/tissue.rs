//! Acoustic properties of tissue: from CT numbers (HU) with label overrides.
//!
//! Sources. "Mast" is T. D. Mast, "Empirical relationships between acoustic parameters in human
//! soft tissues", Acoust. Res. Lett. Online 1(2), 37-42 (2000), Table 1 (speed, density,
//! attenuation slope), rounded. "IT'IS" is the IT'IS Foundation tissue property database v4.1
//! (acoustic section), rounded, for tissues Mast does not list. Echogenicity, scatter density
//! and roughness are appearance parameters and always "our choice". Impedance is density x speed.
//!
//! Source check (2026-11): neither Mast's Table 1 nor the IT'IS acoustic tables could be read
//! from here, so no value below is confirmed against the table it cites; each says so and gives
//! the published range it does fall in, from sources that could be read:
//! - "MechMater": the compilation in Mech. Mater. 44, 174-188 (2012), Table 3 (density
//!   and speed ranges from Goss 1978/1980, Goldman & Hueter, Mast 2000 and others;
//!   <https://pmc.ncbi.nlm.nih.gov/articles/PMC3233242/table/T3>);
//! - "Fernandes": ex vivo measurements, Bioengineering 12(9), 946 (2025), Appendix A.1-A.2
//!   (mean +- SD; <https://www.mdpi.com/2306-5354/12/9/946>);
//! - "Sensors": Sensors 23(13), 5942 (2023), Table A2 (attenuation slopes;
//!   <https://pmc.ncbi.nlm.nih.gov/articles/PMC10346919/table/sensors-23-05942-t0A2>).
//!
//! Where no range was found the value says "unchecked" alone. No value was changed.
//!
//! HU do not determine acoustic properties uniquely; the HU table is a plausible mapping, not a
//! measurement of this patient.

use glam::DVec3;

use crate::material::MaterialClass;
use crate::volume::Volume;

/// Acoustic properties at one point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AcousticProps {
    /// Characteristic impedance, MRayl (10^6 kg m^-2 s^-1).
    pub impedance_mrayl: f64,
    /// Speed of sound, m/s (informational: the scanner images with 1540 m/s and the march does
    /// not refract).
    pub speed_m_s: f64,
    /// Attenuation slope, dB/cm/MHz (amplitude, one way; linear in frequency).
    pub attenuation_db_cm_mhz: f64,
    /// RMS speckle amplitude relative to a perfect plane reflector at the focus, dB.
    pub echogenicity_db: f64,
    /// Fraction (0 ..= 1) of scatterer lattice cells that hold a scatterer: 1 gives fully
    /// developed speckle, less gives sparser, spottier texture.
    pub scatter_density: f64,
    /// Diffuse fraction (0 ..= 1) of an interface echo that does not depend on beam alignment.
    pub roughness: f64,
    /// Internal structure of the scatter (see [`Texture`]).
    pub texture: Texture,
}

/// Internal structure of a tissue's scatter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Texture {
    /// Plain speckle.
    Speckle,
    /// Peripheral nerve: dark fascicles in bright perineurium (a tissue-fixed honeycomb of tubes
    /// along [`AcousticMedium::fibre_axis`], or of blobs where no axis is known), and anisotropy:
    /// brightest with the beam perpendicular to the fibres (see [`super::scatter`]).
    Fascicular,
}

/// Density (kg/m^3) x speed (m/s) in MRayl.
const fn mrayl(density: f64, speed: f64) -> f64 {
    density * speed * 1e-6
}

const fn props(
    density: f64,
    speed: f64,
    att: f64,
    echo: f64,
    scat: f64,
    rough: f64,
) -> AcousticProps {
    AcousticProps {
        impedance_mrayl: mrayl(density, speed),
        speed_m_s: speed,
        attenuation_db_cm_mhz: att,
        echogenicity_db: echo,
        scatter_density: scat,
        roughness: rough,
        texture: Texture::Speckle,
    }
}

/// Fat: Mast Table 1 (950 kg/m^3, 1478 m/s, 0.48 dB/cm/MHz), unchecked against the table; within
/// MechMater (fat 950 kg/m^3, 1468-1488 m/s) and near Fernandes (927 +- 15 kg/m^3, 1462 +- 26 m/s);
/// Sensors lists 0.8 dB/cm/MHz. Hypoechoic, sparse septa (our choice).
pub const FAT: AcousticProps = props(950.0, 1478.0, 0.48, -52.0, 0.35, 0.3);
/// Skeletal muscle: Mast Table 1 (1050 kg/m^3, 1547 m/s, 1.09 dB/cm/MHz), unchecked against the
/// table; within MechMater (1050 kg/m^3, 1517-1600 m/s), near Fernandes (1058 +- 16 kg/m^3,
/// 1562-1599 m/s across/along fibres); Sensors lists 1.2 dB/cm/MHz. Echogenicity ours.
pub const MUSCLE: AcousticProps = props(1050.0, 1547.0, 1.09, -46.0, 1.0, 0.3);
/// Generic soft tissue and skin: 1050 kg/m^3, 1540 m/s, 0.54 dB/cm/MHz (the soft-tissue average
/// used by Mast's regression; our choice of representative; unchecked).
pub const SOFT_TISSUE: AcousticProps = props(1050.0, 1540.0, 0.54, -44.0, 1.0, 0.3);
/// Blood in a vessel: Mast Table 1 (1060 kg/m^3, 1584 m/s, 0.2 dB/cm/MHz), unchecked (no range
/// found); anechoic (our choice).
pub const BLOOD: AcousticProps = props(1060.0, 1584.0, 0.2, -90.0, 1.0, 0.2);
/// Nerve: IT'IS (1075 kg/m^3, 1630 m/s), unchecked (no range found); attenuation 0.9 dB/cm/MHz
/// and echogenicity ours.
pub const NERVE: AcousticProps = AcousticProps {
    texture: Texture::Fascicular,
    ..props(1075.0, 1630.0, 0.9, -42.0, 1.0, 0.3)
};
/// Dura and CSF (CSF dominates): IT'IS (1007 kg/m^3, 1504 m/s, about 0.005 dB/cm/MHz), unchecked
/// (no range found); anechoic.
pub const DURA_CSF: AcousticProps = props(1007.0, 1504.0, 0.005, -90.0, 1.0, 0.2);
/// Epidural space: fat (Mast), slightly brighter than subcutaneous fat (our choice).
pub const EPIDURAL_FAT: AcousticProps = props(950.0, 1478.0, 0.48, -48.0, 0.5, 0.3);
/// Ligamentum flavum, as tendon: IT'IS (1142 kg/m^3, 1750 m/s), unchecked against IT'IS; within
/// MechMater (tendon 1130 kg/m^3, 1654-1852 m/s), Fernandes ligament 1101 +- 54 kg/m^3,
/// 1664 +- 42 m/s. Attenuation 1.1 and a bright, fibrillar echo are our choice.
pub const LIGAMENT: AcousticProps = props(1142.0, 1750.0, 1.1, -38.0, 1.0, 0.3);
/// Intervertebral disc, as cartilage: IT'IS (1100 kg/m^3, 1640 m/s), unchecked against IT'IS;
/// speed within MechMater (cartilage 1565-1770 m/s), density near Fernandes (1033 +- 43 kg/m^3).
/// Attenuation 1.0 ours.
pub const DISC: AcousticProps = props(1100.0, 1640.0, 1.0, -50.0, 1.0, 0.3);
/// Cortical bone: IT'IS (1908 kg/m^3, 3514 m/s), unchecked against IT'IS; within MechMater
/// (1800-2200 kg/m^3, 3200-4000 m/s), near Fernandes (1862 +- 101 kg/m^3, 3194 +- 113 m/s).
/// 20 dB/cm/MHz is our choice standing for absorption plus unresolved scattering (above the
/// 1-10 dB/cm/MHz Sensors lists), so bone shadows.
pub const CORTICAL_BONE: AcousticProps = props(1908.0, 3514.0, 20.0, -40.0, 1.0, 0.35);
/// Cancellous bone: IT'IS (1178 kg/m^3, 2117 m/s), unchecked against IT'IS; within MechMater
/// (trabecular 400-1600 kg/m^3, 1500-2400 m/s); Fernandes measured 572 +- 115 kg/m^3,
/// 2325 +- 173 m/s. 25 dB/cm/MHz our choice (as for cortex).
pub const CANCELLOUS_BONE: AcousticProps = props(1178.0, 2117.0, 25.0, -45.0, 1.0, 0.35);
/// Air or gas (HU below -400): 1.2 kg/m^3, 343 m/s; total reflection and no transmission.
pub const AIR: AcousticProps = props(1.2, 343.0, 1000.0, -120.0, 0.0, 0.5);

/// Properties of a labelled class (the label override of the HU mapping).
pub fn class_props(class: MaterialClass) -> AcousticProps {
    match class {
        MaterialClass::CorticalBone => CORTICAL_BONE,
        MaterialClass::Cancellous => CANCELLOUS_BONE,
        MaterialClass::Disc => DISC,
        MaterialClass::Muscle => MUSCLE,
        MaterialClass::Fat => FAT,
        MaterialClass::SoftTissue => SOFT_TISSUE,
        MaterialClass::Vessel => BLOOD,
        MaterialClass::Nerve => NERVE,
        MaterialClass::DuraCsf => DURA_CSF,
        MaterialClass::EpiduralSpace => EPIDURAL_FAT,
        MaterialClass::LigamentumFlavum => LIGAMENT,
    }
}

/// Properties from a CT number alone: air below -400 HU, fat up to -60 HU, soft tissue at 20 HU,
/// muscle at 50 HU, cancellous bone at 300 HU and cortex from 1000 HU, interpolated in between
/// (the knots are our choice, placed at the usual HU of each tissue).
pub fn hu_props(hu: f64) -> AcousticProps {
    const KNOTS: [(f64, AcousticProps); 6] = [
        (-400.0, AIR),
        (-60.0, FAT),
        (20.0, SOFT_TISSUE),
        (50.0, MUSCLE),
        (300.0, CANCELLOUS_BONE),
        (1000.0, CORTICAL_BONE),
    ];
    if hu <= KNOTS[0].0 {
        return AIR;
    }
    for w in KNOTS.windows(2) {
        let ((h0, a), (h1, b)) = (w[0], w[1]);
        if hu <= h1 {
            // The air knot is a step, not a ramp: anything above -400 HU is at least fat.
            if h0 == -400.0 {
                return FAT;
            }
            return lerp_props(&a, &b, (hu - h0) / (h1 - h0));
        }
    }
    CORTICAL_BONE
}

fn lerp_props(a: &AcousticProps, b: &AcousticProps, t: f64) -> AcousticProps {
    let l = |x: f64, y: f64| x + (y - x) * t;
    AcousticProps {
        impedance_mrayl: l(a.impedance_mrayl, b.impedance_mrayl),
        speed_m_s: l(a.speed_m_s, b.speed_m_s),
        attenuation_db_cm_mhz: l(a.attenuation_db_cm_mhz, b.attenuation_db_cm_mhz),
        echogenicity_db: l(a.echogenicity_db, b.echogenicity_db),
        scatter_density: l(a.scatter_density, b.scatter_density),
        roughness: l(a.roughness, b.roughness),
        texture: if t < 0.5 { a.texture } else { b.texture },
    }
}

/// What the scatter deposit reads of a tissue (see [`AcousticMedium::scatter_along`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScatterProps {
    /// [`AcousticProps::echogenicity_db`].
    pub echogenicity_db: f64,
    /// [`AcousticProps::scatter_density`].
    pub scatter_density: f64,
    /// [`AcousticProps::texture`].
    pub texture: Texture,
}

impl From<&AcousticProps> for ScatterProps {
    fn from(p: &AcousticProps) -> ScatterProps {
        ScatterProps {
            echogenicity_db: p.echogenicity_db,
            scatter_density: p.scatter_density,
            texture: p.texture,
        }
    }
}

/// Cells `ks` of a scatterer lattice column: the point `base_mm` with its coordinate `axis`
/// (0, 1 or 2) replaced by `k as f64 * h_mm`.
#[derive(Debug, Clone)]
pub struct LatticeColumn {
    /// A point of the column (its `axis` coordinate is not read), mm.
    pub base_mm: DVec3,
    /// The region axis the column runs along.
    pub axis: usize,
    /// Lattice cell, mm.
    pub h_mm: f64,
    /// The cells, in order.
    pub ks: std::ops::Range<i64>,
}

impl LatticeColumn {
    /// The point of cell `k`.
    #[inline]
    pub fn point(&self, k: i64) -> DVec3 {
        let mut p = self.base_mm;
        p[self.axis] = k as f64 * self.h_mm;
        p
    }
}

/// Where the acoustic properties come from. Implementations must be pure functions of the point
/// (the frame is deterministic and the scatterers are fixed to the tissue).
pub trait AcousticMedium: Sync {
    /// Properties at a region point (mm).
    fn props(&self, p_mm: DVec3) -> AcousticProps;

    /// Unit direction of the fibres (a nerve's course) at a point, where known. Only asked
    /// where the texture is [`Texture::Fascicular`].
    fn fibre_axis(&self, _p_mm: DVec3) -> Option<DVec3> {
        None
    }

    /// Whether the scatter deposit should ask [`scatter_along`](Self::scatter_along) once per
    /// lattice column rather than [`props`](Self::props) once per cell: `true` where the column
    /// lookup is the cheaper (a voxel grid that rounds the fixed coordinates once); the default
    /// `false` keeps a cheap `props` (an analytic medium) free of the column buffer.
    fn lookups_by_column(&self) -> bool {
        false
    }

    /// What the scatter deposit reads of the tissue at each cell of a lattice column, in
    /// order, into `out` (cleared first). Each must be [`props`](Self::props) at the cell's
    /// point, which the default asks; a medium on a voxel grid rounds the two fixed coordinates
    /// once.
    fn scatter_along(&self, column: &LatticeColumn, out: &mut Vec<ScatterProps>) {
        out.clear();
        out.extend(
            column
                .ks
                .clone()
                .map(|k| ScatterProps::from(&self.props(column.point(k)))),
        );
    }
}

/// One tissue everywhere (the statistics and calibration tests).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UniformMedium(pub AcousticProps);

impl AcousticMedium for UniformMedium {
    fn props(&self, _p_mm: DVec3) -> AcousticProps {
        self.0
    }
}

/// A region's CT (HU) with an optional label volume on the same grid: a labelled voxel takes its
/// class's properties (so soft tissue never counts inside bone), an unlabelled one the HU mapping.
/// Lookups are nearest-voxel, so tissue boundaries are sharp interfaces; outside the grid is air.
#[derive(Debug, Clone, Copy)]
pub struct CtMedium<'a> {
    /// CT numbers.
    pub hu: &'a Volume<f32>,
    /// [`MaterialClass::label`] per voxel (0 = no override), on the grid of `hu`.
    pub labels: Option<&'a Volume<u8>>,
}

impl CtMedium<'_> {
    /// The properties of voxel `idx` (linear index on the grid of `hu`): its label's class,
    /// else the HU mapping.
    pub fn voxel_props(&self, idx: usize) -> AcousticProps {
        if let Some(class) = self
            .labels
            .and_then(|l| MaterialClass::from_label(l.data[idx]))
        {
            return class_props(class);
        }
        hu_props(f64::from(self.hu.data[idx]))
    }
}

impl AcousticMedium for CtMedium<'_> {
    fn props(&self, p_mm: DVec3) -> AcousticProps {
        match self.hu.grid.nearest_voxel(p_mm.to_array()) {
            Some(idx) => self.voxel_props(idx),
            None => AIR,
        }
    }
}
