//! The needle outlet, the injected agent, input validation and routing: which cells an outlet
//! opens into and with what conductance, and which faces a dural puncture opens.

use super::ContrastError;
use super::grid::{ContrastGrid, Domain};
use super::pressure::OutletNode;

/// What the syringe holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Agent {
    /// Iodinated contrast at the given fraction of stock (1.0 = undiluted Omnipaque 300).
    Contrast {
        /// Stock fraction, 0..=1.
        stock_fraction: f64,
    },
    /// Preservative-free normal saline: no iodine, same hydraulics.
    Saline,
    /// Local anaesthetic: no iodine, same hydraulics.
    LocalAnaesthetic,
}

impl Agent {
    /// Undiluted contrast.
    pub const CONTRAST: Agent = Agent::Contrast {
        stock_fraction: 1.0,
    };

    /// Iodine per unit fluid volume, as a stock fraction.
    pub fn stock_fraction(self) -> f64 {
        match self {
            Agent::Contrast { stock_fraction } => stock_fraction,
            Agent::Saline | Agent::LocalAnaesthetic => 0.0,
        }
    }
}

/// The opening of a needle: the bevel lies along the last `opening_mm` of the shaft before the
/// tip.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeedleOutlet {
    /// Tip position, model frame, mm.
    pub tip_mm: [f64; 3],
    /// Shaft direction towards the tip (need not be normalised).
    pub direction: [f64; 3],
    /// Length of the opening along the shaft, mm.
    pub opening_mm: f64,
    /// Outer diameter of the needle, mm.
    pub outer_diameter_mm: f64,
}

impl NeedleOutlet {
    /// A Tuohy needle: 1.27 mm outer diameter (18 G) with a 2 mm opening (the reference model's
    /// authored values, atlas methods "Contrast transport").
    pub fn tuohy(tip_mm: [f64; 3], direction: [f64; 3]) -> NeedleOutlet {
        NeedleOutlet {
            tip_mm,
            direction,
            opening_mm: 2.0,
            outer_diameter_mm: 1.27,
        }
    }

    /// A spinal (Quincke) needle: 0.70 mm outer diameter (22 G) with a 1.5 mm opening (same
    /// source).
    pub fn spinal(tip_mm: [f64; 3], direction: [f64; 3]) -> NeedleOutlet {
        NeedleOutlet {
            tip_mm,
            direction,
            opening_mm: 1.5,
            outer_diameter_mm: 0.70,
        }
    }

    /// Checks every field; the error names the first bad one.
    pub fn validate(&self) -> Result<(), ContrastError> {
        for (a, v) in self.tip_mm.iter().enumerate() {
            finite("outlet.tip_mm", *v, a)?;
        }
        for (a, v) in self.direction.iter().enumerate() {
            finite("outlet.direction", *v, a)?;
        }
        if self.direction.iter().map(|v| v * v).sum::<f64>() == 0.0 {
            return Err(ContrastError::ZeroDirection);
        }
        check_range("outlet.opening_mm", self.opening_mm, 0.0, 20.0, "mm")?;
        check_range(
            "outlet.outer_diameter_mm",
            self.outer_diameter_mm,
            0.0,
            5.0,
            "mm",
        )?;
        Ok(())
    }

    fn unit_direction(&self) -> [f64; 3] {
        let d = self.direction;
        let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        d.map(|v| v / n)
    }

    /// Distance from `p` to the opening's axis segment, mm.
    pub fn distance_to_opening(&self, p: [f64; 3]) -> f64 {
        let d = self.unit_direction();
        let back: [f64; 3] = std::array::from_fn(|a| self.tip_mm[a] - d[a] * self.opening_mm);
        let t = (0..3)
            .map(|a| (p[a] - back[a]) * d[a])
            .sum::<f64>()
            .clamp(0.0, self.opening_mm);
        (0..3)
            .map(|a| {
                let q = back[a] + t * d[a];
                (p[a] - q) * (p[a] - q)
            })
            .sum::<f64>()
            .sqrt()
    }

    /// Points of the bevel footprint: along the opening at quarter steps, on the axis and on a
    /// ring of the outer radius.
    pub fn footprint(&self) -> Vec<[f64; 3]> {
        let d = self.unit_direction();
        // Two unit vectors perpendicular to d.
        let helper = if d[0].abs() < 0.9 {
            [1.0, 0.0, 0.0]
        } else {
            [0.0, 1.0, 0.0]
        };
        let cross = |a: [f64; 3], b: [f64; 3]| {
            [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ]
        };
        let u0 = cross(d, helper);
        let nu = (u0[0] * u0[0] + u0[1] * u0[1] + u0[2] * u0[2]).sqrt();
        let u = u0.map(|v| v / nu);
        let w = cross(d, u);
        let r = 0.5 * self.outer_diameter_mm;
        let mut pts = Vec::new();
        for s in 0..=4 {
            let t = self.opening_mm * f64::from(s) / 4.0;
            let c: [f64; 3] = std::array::from_fn(|a| self.tip_mm[a] - d[a] * t);
            pts.push(c);
            for q in 0..8 {
                let ang = std::f64::consts::TAU * f64::from(q) / 8.0;
                let (sn, cs) = ang.sin_cos();
                pts.push(std::array::from_fn(|a| c[a] + r * (cs * u[a] + sn * w[a])));
            }
        }
        pts
    }
}

fn finite(field: &'static str, v: f64, axis: usize) -> Result<(), ContrastError> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(ContrastError::NotFinite {
            field,
            axis,
            value: v,
        })
    }
}

/// `Ok` when `min < v <= max` and finite, else an error naming `field`.
pub(crate) fn check_range(
    field: &'static str,
    v: f64,
    min: f64,
    max: f64,
    unit: &'static str,
) -> Result<(), ContrastError> {
    if v.is_finite() && v > min && v <= max {
        Ok(())
    } else {
        Err(ContrastError::OutOfRange {
            field,
            value: v,
            min,
            max,
            unit,
        })
    }
}

/// Largest accepted injection volume, mL: above any single spinal injection (caudal epidurals
/// use up to about 20 mL; our choice of a refusal limit, not a safety limit).
pub const MAX_VOLUME_ML: f64 = 50.0;
/// Largest accepted rate, mL/s (hand injection through a spinal needle stays below about 1 mL/s;
/// our choice of a refusal limit).
pub const MAX_RATE_ML_S: f64 = 5.0;

/// A request to inject.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Injection {
    /// What is injected.
    pub agent: Agent,
    /// Volume, mL (1 mL = 1000 mm^3).
    pub volume_ml: f64,
    /// Rate, mL/s.
    pub rate_ml_s: f64,
}

impl Injection {
    /// Checks the numbers; the error names the first bad field.
    pub fn validate(&self) -> Result<(), ContrastError> {
        check_range(
            "injection.volume_ml",
            self.volume_ml,
            0.0,
            MAX_VOLUME_ML,
            "mL",
        )?;
        check_range(
            "injection.rate_ml_s",
            self.rate_ml_s,
            0.0,
            MAX_RATE_ML_S,
            "mL/s",
        )?;
        if let Agent::Contrast { stock_fraction } = self.agent {
            if !(stock_fraction.is_finite() && (0.0..=1.0).contains(&stock_fraction)) {
                return Err(ContrastError::OutOfRange {
                    field: "injection.agent.stock_fraction",
                    value: stock_fraction,
                    min: 0.0,
                    max: 1.0,
                    unit: "of stock",
                });
            }
        }
        Ok(())
    }
}

/// Standard deviation of the source neighbourhood, mm, and its cutoff radius: the reference's
/// numerical source neighbourhood (sigma 1.1 mm, cutoff 2.2 mm), not a physical aperture.
pub const SOURCE_SIGMA_MM: f64 = 1.1;
/// Cutoff of the source neighbourhood, mm.
pub const SOURCE_CUTOFF_MM: f64 = 2.2;

/// Routes an outlet: the domains its bevel footprint touches, then every cell of those domains
/// within the source cutoff of the opening, each joined to the lumen with a conductance of
/// `w * mobility * h` (Gaussian weight `w` of the distance). The split between domains is left to
/// the pressure solve: a vessel (high mobility, venous drain) takes most of the flow.
pub fn route(g: &ContrastGrid, outlet: &NeedleOutlet) -> Result<OutletNode, ContrastError> {
    outlet.validate()?;
    if g.cell_at(outlet.tip_mm).is_none() {
        return Err(ContrastError::OutletOutsideGrid {
            tip_mm: outlet.tip_mm,
        });
    }
    let mut touched = [false; Domain::COUNT];
    for p in outlet.footprint() {
        if let Some(d) = g.cell_at(p).and_then(|c| g.domain[c]) {
            touched[d.index()] = true;
        }
    }
    if !touched.iter().any(|&t| t) {
        return Err(ContrastError::OutletNotInDomain {
            tip_mm: outlet.tip_mm,
        });
    }
    let h = g.grid.spacing_mm;
    let hmin = h[0].min(h[1]).min(h[2]);
    let cutoff = SOURCE_CUTOFF_MM.max(0.5 * outlet.outer_diameter_mm + 0.75 * hmin);
    let sigma = SOURCE_SIGMA_MM.max(0.5 * hmin);
    let v = g.grid.world_to_voxel(outlet.tip_mm);
    let reach: [usize; 3] =
        std::array::from_fn(|a| ((cutoff + outlet.opening_mm) / h[a]).ceil() as usize + 1);
    let mut contacts = Vec::new();
    let dims = g.grid.dims;
    let lo: [usize; 3] =
        std::array::from_fn(|a| (v[a].round() as i64 - reach[a] as i64).max(0) as usize);
    let hi: [usize; 3] = std::array::from_fn(|a| {
        ((v[a].round() as i64 + reach[a] as i64).max(0) as usize).min(dims[a] - 1)
    });
    for k in lo[2]..=hi[2] {
        for j in lo[1]..=hi[1] {
            for i in lo[0]..=hi[0] {
                let c = g.grid.index(i, j, k);
                let Some(d) = g.domain[c] else { continue };
                if !touched[d.index()] {
                    continue;
                }
                let dist = outlet.distance_to_opening(g.grid.voxel_center_mm(i, j, k));
                if dist > cutoff {
                    continue;
                }
                let w = (-0.5 * (dist / sigma).powi(2)).exp();
                let m = g.props[c].mobility.iter().sum::<f64>() / 3.0;
                contacts.push((c, w * m * hmin));
            }
        }
    }
    if contacts.is_empty() {
        return Err(ContrastError::OutletNotInDomain {
            tip_mm: outlet.tip_mm,
        });
    }
    Ok(OutletNode { contacts })
}

/// The faces a dural puncture opens: faces between epidural, subdural and intrathecal cells whose
/// two centres lie within `radius` (outer radius plus half a cell) of the needle's path from the
/// tip back `depth_mm` along the shaft.
pub fn puncture_faces(
    g: &ContrastGrid,
    outlet: &NeedleOutlet,
    depth_mm: f64,
) -> Vec<(usize, usize)> {
    let path = NeedleOutlet {
        opening_mm: depth_mm.max(outlet.opening_mm),
        ..*outlet
    };
    let h = g.grid.spacing_mm;
    let radius = 0.5 * outlet.outer_diameter_mm + 0.5 * h[0].max(h[1]).max(h[2]);
    let canal = |d: Option<Domain>| {
        matches!(
            d,
            Some(Domain::Epidural | Domain::Subdural | Domain::Intrathecal)
        )
    };
    let [nx, ny, nz] = g.grid.dims;
    let strides = [1, nx, nx * ny];
    let mut out = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let c = g.grid.index(i, j, k);
                if !canal(g.domain[c]) {
                    continue;
                }
                let pc = g.grid.voxel_center_mm(i, j, k);
                if path.distance_to_opening(pc) > radius {
                    continue;
                }
                let ijk = [i, j, k];
                for a in 0..3 {
                    if ijk[a] + 1 >= g.grid.dims[a] {
                        continue;
                    }
                    let nb = c + strides[a];
                    if !canal(g.domain[nb]) || g.domain[nb] == g.domain[c] {
                        continue;
                    }
                    let mut q = ijk;
                    q[a] += 1;
                    if path.distance_to_opening(g.grid.voxel_center_mm(q[0], q[1], q[2])) <= radius
                    {
                        out.push((c, a));
                    }
                }
            }
        }
    }
    out
}
