//! The needle as the scanner sees it: a steel shaft that reflects specularly.
//!
//! Per scan line, the closest approach between the line and the shaft gives the echo depth and
//! how much of the beam (lateral x elevation profile) the shaft fills. Brightness falls as the
//! shaft turns away from perpendicular to the beam (steep insertions fade); a reverberation tail
//! follows at multiples of the diameter; the beam behind it is shadowed through the same
//! two-way transmission `1 - R^2` as any interface. [`needle_view`] reports what a learner can
//! see: the part of the shaft inside the slice and whether that part contains the tip.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::beam::Beam;
use super::error::{UltrasoundError, check_finite3, check_range};
use super::probe::ScanGeometry;
use super::scatter::BeamTables;

/// Steel impedance (7850 kg/m^3 x 5800 m/s, handbook values) against soft tissue: amplitude
/// reflection (45.5 - 1.6) / (45.5 + 1.6).
pub const STEEL_REFLECTION: f64 = (45.5 - 1.62) / (45.5 + 1.62);
/// Angular half-width (1/e^(1/2)) of the specular lobe, degrees (our choice: at 20 degrees off
/// perpendicular the shaft is 13 dB dimmer).
pub const SPECULAR_LOBE_DEG: f64 = 10.0;
/// Diffuse fraction of a bare shaft's echo (our choice).
pub const NEEDLE_ROUGHNESS: f64 = 0.03;
/// Reverberation echoes drawn, and the amplitude ratio between successive ones (our choice).
pub const REVERB_COUNT: usize = 5;
/// Amplitude ratio of successive reverberations (our choice).
pub const REVERB_RATIO: f64 = 0.45;

/// A straight needle shaft from the hub to the tip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NeedleShaft {
    /// Hub end of the shaft, region frame, mm.
    pub hub_mm: DVec3,
    /// Tip, region frame, mm.
    pub tip_mm: DVec3,
    /// Outer diameter, mm (0.72 mm for 22 G).
    pub diameter_mm: f64,
}

impl NeedleShaft {
    pub(crate) fn validate(&self) -> Result<(), UltrasoundError> {
        check_finite3("needle.hub_mm", self.hub_mm)?;
        check_finite3("needle.tip_mm", self.tip_mm)?;
        check_range("needle.diameter_mm", self.diameter_mm, 0.1, 5.0)?;
        if self.hub_mm == self.tip_mm {
            return Err(UltrasoundError::Degenerate {
                field: "needle.tip_mm",
            });
        }
        Ok(())
    }
}

/// What the image shows of the needle, in image coordinates (mm, see [`super::probe`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NeedleView {
    /// First and last shaft points inside the slice (within half the slice thickness) and the
    /// field of view, hub side first; `None` when the needle does not cross the slice. An
    /// out-of-plane crossing is a short piece: a dot.
    pub in_slice: Option<([f64; 2], [f64; 2])>,
    /// Whether the tip itself is in the slice and the field of view. Only then is the distal end
    /// of `in_slice` the tip.
    pub tip_in_slice: bool,
}

impl NeedleView {
    /// The tip's image position when the tip is in the slice.
    pub fn tip_image_mm(&self) -> Option<[f64; 2]> {
        self.in_slice.filter(|_| self.tip_in_slice).map(|(_, b)| b)
    }
}

/// One line's encounter with the shaft.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LineHit {
    /// Depth along the line, mm.
    pub z: f64,
    /// Fraction of the beam the shaft fills (peak-normalised lateral x elevation profile).
    pub overlap: f64,
    /// Specular brightness factor of the shaft's angle to this line.
    pub specular: f64,
}

/// Closest approach of scan line `(o, d)` (depth `0 ..= depth`) and the shaft.
pub(crate) fn line_hit(
    n: &NeedleShaft,
    o: DVec3,
    d: DVec3,
    depth: f64,
    beam: &Beam,
    t: &BeamTables,
    elev: DVec3,
) -> Option<LineHit> {
    let a = n.hub_mm;
    let ab = n.tip_mm - a;
    let len2 = ab.length_squared();
    // Minimise |o + z d - a - s ab| over z in [0, depth], s in [0, 1].
    let w0 = o - a;
    let b = d.dot(ab);
    let (dd, e, f) = (d.dot(w0), ab.dot(w0), len2);
    let denom = f - b * b;
    let mut s = if denom > 1e-12 {
        ((e - b * dd) / denom).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let mut z = (s * b - dd).clamp(0.0, depth);
    s = ((z * b + e) / f).clamp(0.0, 1.0);
    z = (s * b - dd).clamp(0.0, depth);
    let v = a + ab * s - (o + d * z);
    let ev = v.dot(elev);
    let lv = (v - d * v.dot(d) - elev * ev).length();
    let r = 0.5 * n.diameter_mm;
    let se = beam.elevation_fwhm_mm(z) / super::beam::FWHM_PER_SIGMA;
    let sl = t.lat_sigma_mm[t.sample_of(z)];
    let ee = (ev.abs() - r).max(0.0);
    let ll = (lv - r).max(0.0);
    let overlap = (-(ee * ee) / (2.0 * se * se) - (ll * ll) / (2.0 * sl * sl)).exp();
    if overlap < 1e-3 {
        return None;
    }
    let u = ab / len2.sqrt();
    let psi = d.dot(u).abs().min(1.0).asin();
    let lobe = SPECULAR_LOBE_DEG.to_radians();
    let specular =
        NEEDLE_ROUGHNESS + (1.0 - NEEDLE_ROUGHNESS) * (-(psi * psi) / (2.0 * lobe * lobe)).exp();
    Some(LineHit {
        z,
        overlap,
        specular,
    })
}

/// The part of the shaft in the slice (|elevation| <= half the slice FWHM at its depth) and in
/// the field of view, sampled every 0.05 mm along the shaft.
pub fn needle_view(n: &NeedleShaft, geo: &ScanGeometry, beam: &Beam) -> NeedleView {
    let f = &geo.frame;
    let len = n.hub_mm.distance(n.tip_mm);
    let steps = (len / 0.05).ceil().max(1.0) as usize;
    let lines_max = (geo.lines - 1) as f64;
    let inside = |p: DVec3| -> Option<[f64; 2]> {
        let q = f.to_probe(p);
        let (u, z) = geo.plane_to_line(q.x, q.y);
        let ok = (0.0..=lines_max).contains(&u)
            && (0.0..=geo.depth_mm).contains(&z)
            && q.z.abs() <= 0.5 * beam.elevation_fwhm_mm(z);
        ok.then_some([q.x, q.y])
    };
    let mut first = None;
    let mut last = None;
    for i in 0..=steps {
        let p = n.hub_mm.lerp(n.tip_mm, i as f64 / steps as f64);
        if let Some(xy) = inside(p) {
            first.get_or_insert(xy);
            last = Some(xy);
        }
    }
    NeedleView {
        in_slice: first.zip(last),
        tip_in_slice: inside(n.tip_mm).is_some(),
    }
}
