//! Transducers, their pose in the region frame, and the scan geometry of one frame.
//!
//! Probe frame: `beam` points from the probe face into the body; `lateral` runs along the array
//! AWAY from the orientation marker, so scan line 0 and image column 0 are on the marker side
//! (the screen convention: the marker dot sits at the top left of the image); `elevation` is
//! `lateral x beam`, across the slice. Depth `z` is measured along each scan line from the face.
//! Image coordinates `(x, y)` in mm: `x` along `lateral` from the centre of the face, `y` along
//! `beam` from the centre of the face.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::error::{UltrasoundError, check_finite3, check_range};

/// Which transducer is in use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProbeKind {
    /// Linear array: 38 mm footprint, 5-12 MHz, parallel scan lines.
    Linear,
    /// Curvilinear (convex) array: 60 mm radius, 2-5 MHz, 60 degree sector of diverging lines.
    Curvilinear,
}

/// Fixed properties of a transducer. Simulator choice for all of them: footprint and band are
/// those of common point-of-care probes (a 38 mm linear array of about 6-13 MHz and a 60 mm
/// radius convex array of 2-5 MHz, such as FUJIFILM SonoSite's HFL38x and C60x), the 60 degree
/// sector a round figure; apertures and elevation lens are typical of musculoskeletal and
/// abdominal probes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeSpec {
    /// The transducer.
    pub kind: ProbeKind,
    /// Linear: array length (footprint) in mm. Curvilinear: arc length of the sector face.
    pub footprint_mm: f64,
    /// Curvilinear radius of the face in mm (infinite for a linear array).
    pub radius_mm: f64,
    /// Full sector angle in degrees (0 for a linear array).
    pub sector_deg: f64,
    /// Lowest and highest centre frequency in MHz.
    pub band_mhz: (f64, f64),
    /// Largest active (sub-)aperture in mm, transmit and receive (our choice).
    pub aperture_mm: f64,
    /// Height of the elements across the slice (elevation aperture) in mm (our choice).
    pub elevation_aperture_mm: f64,
    /// Fixed focal depth of the elevation lens in mm (our choice).
    pub elevation_focus_mm: f64,
    /// Allowed display depth in mm.
    pub depth_range_mm: (f64, f64),
    /// Largest side of a scatterer lattice cell in mm (see [`super::scatter`] and
    /// [`super::Sampling::for_settings`]; our choice, tested by the speckle statistics).
    pub scatter_cell_mm: f64,
}

impl ProbeKind {
    /// The transducer's fixed properties.
    pub fn spec(self) -> ProbeSpec {
        match self {
            ProbeKind::Linear => ProbeSpec {
                kind: self,
                footprint_mm: 38.0,
                radius_mm: f64::INFINITY,
                sector_deg: 0.0,
                band_mhz: (5.0, 12.0),
                // 64 elements at 0.2 mm pitch.
                aperture_mm: 12.8,
                elevation_aperture_mm: 4.0,
                elevation_focus_mm: 20.0,
                depth_range_mm: (10.0, 90.0),
                scatter_cell_mm: 0.2,
            },
            ProbeKind::Curvilinear => ProbeSpec {
                kind: self,
                footprint_mm: 60.0 * 60f64.to_radians(),
                radius_mm: 60.0,
                sector_deg: 60.0,
                band_mhz: (2.0, 5.0),
                aperture_mm: 20.0,
                elevation_aperture_mm: 12.0,
                elevation_focus_mm: 60.0,
                depth_range_mm: (30.0, 240.0),
                scatter_cell_mm: 0.35,
            },
        }
    }
}

/// Where the probe is: the centre of its face, the beam direction, and the orientation-marker
/// direction (both unit vectors after validation). The marker side is the side of line 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ProbePose {
    /// Centre of the probe face in the region frame, mm.
    pub position_mm: DVec3,
    /// Direction of the central scan line into the body.
    pub beam_dir: DVec3,
    /// Direction from the face centre towards the orientation marker (perpendicular to the beam;
    /// its component along the beam is removed).
    pub marker_dir: DVec3,
}

impl ProbePose {
    /// A pose from the beam direction and a rotation about it: at 0 degrees the marker points along
    /// the component of region +x perpendicular to the beam (of +y when the beam is along x);
    /// positive angles turn it right-handed about `beam_dir`.
    pub fn from_rotation(position_mm: DVec3, beam_dir: DVec3, rotation_deg: f64) -> ProbePose {
        let b = beam_dir.normalize_or_zero();
        let reference = if b.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
        let m0 = (reference - b * reference.dot(b)).normalize_or_zero();
        let (s, c) = rotation_deg.to_radians().sin_cos();
        let m = m0 * c + b.cross(m0) * s;
        ProbePose {
            position_mm,
            beam_dir: b,
            marker_dir: m,
        }
    }

    /// Checks finiteness and orthogonality and returns the orthonormal probe frame.
    pub fn frame(&self) -> Result<ProbeFrame, UltrasoundError> {
        let origin = check_finite3("pose.position_mm", self.position_mm)?;
        let b = check_finite3("pose.beam_dir", self.beam_dir)?;
        let m = check_finite3("pose.marker_dir", self.marker_dir)?;
        let beam = b.try_normalize().ok_or(UltrasoundError::Degenerate {
            field: "pose.beam_dir",
        })?;
        let marker = (m - beam * m.dot(beam))
            .try_normalize()
            .filter(|_| m.length() > 0.0 && (m - beam * m.dot(beam)).length() > 1e-6 * m.length())
            .ok_or(UltrasoundError::Degenerate {
                field: "pose.marker_dir",
            })?;
        let lateral = -marker;
        let elevation = lateral.cross(beam);
        Ok(ProbeFrame {
            origin,
            beam,
            lateral,
            elevation,
        })
    }
}

/// The validated orthonormal probe frame (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeFrame {
    /// Centre of the face, mm.
    pub origin: DVec3,
    /// Into the body.
    pub beam: DVec3,
    /// Along the array, away from the marker.
    pub lateral: DVec3,
    /// Across the slice.
    pub elevation: DVec3,
}

impl ProbeFrame {
    /// Probe-frame coordinates `(lateral, axial, elevation)` of a region point.
    pub fn to_probe(&self, p: DVec3) -> DVec3 {
        let r = p - self.origin;
        DVec3::new(r.dot(self.lateral), r.dot(self.beam), r.dot(self.elevation))
    }

    /// The region point of probe-frame coordinates `(lateral, axial, elevation)`.
    pub fn to_region(&self, q: DVec3) -> DVec3 {
        self.origin + self.lateral * q.x + self.beam * q.y + self.elevation * q.z
    }
}

/// Where the scan lines of one frame are: `lines` lines, line `u` (fractional allowed) starts on
/// the face and runs `depth_mm` into the body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanGeometry {
    /// The probe's fixed properties.
    pub spec: ProbeSpec,
    /// The probe frame.
    pub frame: ProbeFrame,
    /// Number of scan lines.
    pub lines: usize,
    /// Display depth along each line, mm.
    pub depth_mm: f64,
}

impl ScanGeometry {
    /// Half the sector angle in radians (0 for a linear array).
    pub fn half_sector_rad(&self) -> f64 {
        0.5 * self.spec.sector_deg.to_radians()
    }

    /// Lateral position (linear, mm) or angle (curvilinear, rad) of fractional line `u`.
    pub fn line_coordinate(&self, u: f64) -> f64 {
        let t = if self.lines > 1 {
            u / (self.lines - 1) as f64
        } else {
            0.5
        };
        match self.spec.kind {
            ProbeKind::Linear => (t - 0.5) * self.spec.footprint_mm,
            ProbeKind::Curvilinear => (2.0 * t - 1.0) * self.half_sector_rad(),
        }
    }

    /// Start point and unit direction, in probe-plane coordinates `(x, y)`, of fractional line `u`.
    pub fn line_in_plane(&self, u: f64) -> ([f64; 2], [f64; 2]) {
        let c = self.line_coordinate(u);
        match self.spec.kind {
            ProbeKind::Linear => ([c, 0.0], [0.0, 1.0]),
            ProbeKind::Curvilinear => {
                let r = self.spec.radius_mm;
                let (s, co) = c.sin_cos();
                ([r * s, r * co - r], [s, co])
            }
        }
    }

    /// Start point and unit direction of fractional line `u` in the region frame.
    pub fn line_ray(&self, u: f64) -> (DVec3, DVec3) {
        let ([x, y], [dx, dy]) = self.line_in_plane(u);
        let f = &self.frame;
        (
            f.origin + f.lateral * x + f.beam * y,
            f.lateral * dx + f.beam * dy,
        )
    }

    /// Distance in mm between neighbouring lines at depth `z` (arc length for the sector).
    pub fn line_spacing_mm(&self, z: f64) -> f64 {
        let n = (self.lines.max(2) - 1) as f64;
        match self.spec.kind {
            ProbeKind::Linear => self.spec.footprint_mm / n,
            ProbeKind::Curvilinear => (self.spec.radius_mm + z) * 2.0 * self.half_sector_rad() / n,
        }
    }

    /// Fractional line index and depth of an in-plane point `(x, y)` (image coordinates).
    pub fn plane_to_line(&self, x: f64, y: f64) -> (f64, f64) {
        let n = (self.lines.max(2) - 1) as f64;
        match self.spec.kind {
            ProbeKind::Linear => ((x / self.spec.footprint_mm + 0.5) * n, y),
            ProbeKind::Curvilinear => {
                let r0 = self.spec.radius_mm;
                let yc = y + r0;
                let theta = super::angle::atan2(x, yc);
                let r = (x * x + yc * yc).sqrt();
                ((theta / self.half_sector_rad() + 1.0) * 0.5 * n, r - r0)
            }
        }
    }

    /// Image extent `(x_min, x_max, y_min, y_max)` in mm covering every line to full depth.
    pub fn image_extent_mm(&self) -> (f64, f64, f64, f64) {
        match self.spec.kind {
            ProbeKind::Linear => {
                let h = 0.5 * self.spec.footprint_mm;
                (-h, h, 0.0, self.depth_mm)
            }
            ProbeKind::Curvilinear => {
                let r0 = self.spec.radius_mm;
                let (s, c) = self.half_sector_rad().sin_cos();
                let w = (r0 + self.depth_mm) * s;
                (-w, w, r0 * c - r0, self.depth_mm)
            }
        }
    }
}

pub(crate) fn check_depth(spec: &ProbeSpec, depth_mm: f64) -> Result<f64, UltrasoundError> {
    check_range(
        "settings.depth_mm",
        depth_mm,
        spec.depth_range_mm.0,
        spec.depth_range_mm.1,
    )
}
