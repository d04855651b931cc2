//! Instrument profiles as data: geometry for drawing and for the contrast outlet, and the
//! kinematic family with its parameters.
//!
//! Every number below names where it comes from. Several are provisional by nature: a needle's
//! path radius depends on tissue, shaft stiffness and insertion conditions (Misra et al. 2010;
//! Majewicz et al. 2012), so a profile value is a teaching default, not a device prediction.

use serde::{Deserialize, Serialize};

/// How the needle's path responds to the bevel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum PathModel {
    /// The tip travels on a straight line whatever the bevel orientation (rigid family).
    Straight,
    /// Webster et al. (2006) bevel-tip steering: the path is locally a circular arc whose
    /// curvature vector is `response / nominal_radius_mm`, and the bending response relaxes toward
    /// the bevel direction exponentially with insertion distance over `response_length_mm`.
    Curved {
        /// Radius of the path when the response is fully settled toward the bevel, millimetres.
        nominal_radius_mm: f64,
        /// Insertion distance over which the response closes 1 - 1/e of its gap to the bevel.
        response_length_mm: f64,
    },
}

impl PathModel {
    /// Nominal curvature `1 / R` in 1/mm (zero for straight paths).
    pub fn nominal_curvature_per_mm(&self) -> f64 {
        match *self {
            PathModel::Straight => 0.0,
            PathModel::Curved {
                nominal_radius_mm, ..
            } => 1.0 / nominal_radius_mm,
        }
    }

    /// Response length in millimetres (`None` for straight paths, which have no response).
    pub fn response_length_mm(&self) -> Option<f64> {
        match *self {
            PathModel::Straight => None,
            PathModel::Curved {
                response_length_mm, ..
            } => Some(response_length_mm),
        }
    }
}

/// Shape of the distal tip, for drawing only (the path model is separate, because a tip's visible
/// shape does not determine its path radius: Okazawa et al. 2005; Adebar et al. 2016).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum TipGeometry {
    /// A straight shaft ending in a flat bevel (Quincke cutting tip). The bevel plane spans
    /// `bevel_length_mm` along the axis and faces the bevel direction.
    Bevel {
        /// Axial length of the bevel face, millimetres.
        bevel_length_mm: f64,
    },
    /// A rigid distal segment bent toward the bevel direction by `bend_deg` over `bent_length_mm`
    /// (Tuohy curve, or the pre-bent tip of a steerable needle).
    Bent {
        /// Length of the bent distal segment, millimetres.
        bent_length_mm: f64,
        /// Bend angle between the shaft axis and the distal segment, degrees.
        bend_deg: f64,
    },
}

/// The side or end opening through which contrast leaves the needle: the outlet footprint sampled
/// against tissue labels by the contrast model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Opening {
    /// Axial length of the opening, millimetres.
    pub length_mm: f64,
    /// Distance from the tip back to the distal edge of the opening, along the shaft, millimetres.
    pub distal_edge_from_tip_mm: f64,
}

/// One instrument: everything the simulator needs to move and draw it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InstrumentProfile {
    /// Short stable identifier (used in logs and station files).
    pub id: String,
    /// Human-readable name.
    pub name: String,
    /// Outer diameter of the shaft, millimetres.
    pub outer_diameter_mm: f64,
    /// Length of the shaft from hub to tip, millimetres; feeding stops when the hub reaches the
    /// skin.
    pub shaft_length_mm: f64,
    /// The contrast outlet.
    pub opening: Opening,
    /// Tip shape for drawing.
    pub tip: TipGeometry,
    /// Kinematic family and its parameters.
    pub path: PathModel,
    /// Total width of the hub-minus-tip twist window at 100 mm buried depth, degrees. Zero means
    /// one-to-one roll (rigid instruments). The window scales linearly with buried depth.
    pub torsional_play_deg_at_100mm: f64,
}

/// Outer diameter of a 22G needle. ISO 9626:2016 Table 1 gives 0.698-0.730 mm for 22G normal
/// wall; the reference simulator's methods page models 0.70 mm.
const OD_22G_MM: f64 = 0.70;
/// Outer diameter of an 18G needle. ISO 9626:2016 Table 1 gives 1.260-1.330 mm for 18G normal
/// wall; the reference simulator's methods page models 1.27 mm.
const OD_18G_MM: f64 = 1.27;
/// 3.5 inch, the usual adult spinal and epidural needle length (catalogue standard); our default.
const SHAFT_3_5_INCH_MM: f64 = 88.9;

impl InstrumentProfile {
    /// Rigid straight 22G Quincke spinal needle: straight path, one-to-one roll.
    pub fn spinal_22g_quincke() -> Self {
        Self {
            id: "spinal-22g-quincke".into(),
            name: "22G Quincke spinal needle (rigid, straight)".into(),
            outer_diameter_mm: OD_22G_MM,
            shaft_length_mm: SHAFT_3_5_INCH_MM,
            opening: Opening {
                // 1.5 mm is the authored opening length of the reference simulator's spinal
                // needle (methods page, "Outlet routing"); it is not a measured lumen.
                length_mm: 1.5,
                // A Quincke opening is the bevel face itself, which starts at the tip.
                distal_edge_from_tip_mm: 0.0,
            },
            // The bevel face is the opening, so its axial length equals the opening length.
            tip: TipGeometry::Bevel {
                bevel_length_mm: 1.5,
            },
            // Rigid family: the reference simulator models the rigid spinal needle as straight.
            path: PathModel::Straight,
            // Rigid instruments roll one-to-one (reference methods page, "Hub roll").
            torsional_play_deg_at_100mm: 0.0,
        }
    }

    /// The same 22G Quincke needle with bevel steering switched on, with the path radius of a
    /// published gel-phantom deflection: Rand et al. (Anesth Pain Med 2016;6(5):e36607) measured
    /// 8.89 mm of deflection after 80 mm of a 22G Quincke needle in ballistic gel, and a circular
    /// path tangent at entry with that deflection has a radius of L^2 / (2 d) = 360 mm. Roll
    /// stays one-to-one.
    pub fn spinal_22g_quincke_gel_fit() -> Self {
        Self {
            id: "spinal-22g-quincke-gel-fit".into(),
            name: "22G Quincke spinal needle (bevel deflection, gel fit)".into(),
            path: PathModel::Curved {
                nominal_radius_mm: 360.0,
                // Same provisional 25 mm response as the flexible profile (our assumption).
                response_length_mm: 25.0,
            },
            ..Self::spinal_22g_quincke()
        }
    }

    /// Rigid 18G Tuohy epidural needle with its curved tip: straight path, one-to-one roll; the
    /// curve matters for drawing and for where the side opening faces.
    pub fn tuohy_18g() -> Self {
        Self {
            id: "tuohy-18g".into(),
            name: "18G Tuohy epidural needle (rigid, bent tip)".into(),
            outer_diameter_mm: OD_18G_MM,
            shaft_length_mm: SHAFT_3_5_INCH_MM,
            opening: Opening {
                // 2 mm is the authored Tuohy opening length of the reference simulator (methods
                // page, "Outlet routing"); it is not a measured lumen.
                length_mm: 2.0,
                // The Tuohy opening sits on the outside of the curve just behind the blunt
                // tip; 0.3 mm is our assumption.
                distal_edge_from_tip_mm: 0.3,
            },
            // Our assumption for drawing: a 3 mm distal curve of 20 degrees.
            tip: TipGeometry::Bent {
                bent_length_mm: 3.0,
                bend_deg: 20.0,
            },
            path: PathModel::Straight,
            torsional_play_deg_at_100mm: 0.0,
        }
    }

    /// Flexible pre-bent steerable needle: Webster bevel-tip kinematics with the reference
    /// simulator's provisional values (methods page, "Kinematics and bending response").
    pub fn flexible_prebent() -> Self {
        Self {
            id: "flexible-prebent".into(),
            name: "Flexible pre-bent steerable needle".into(),
            // Our assumption: the same 22G shaft as the spinal needle.
            outer_diameter_mm: OD_22G_MM,
            // Our assumption: a 150 mm shaft, long enough for deep steered approaches.
            shaft_length_mm: 150.0,
            opening: Opening {
                // Our assumption: an end opening as long as the spinal needle's.
                length_mm: 1.5,
                distal_edge_from_tip_mm: 0.0,
            },
            // 4 mm / 15 degrees: the reference simulator's separately drawn pre-bent tip.
            tip: TipGeometry::Bent {
                bent_length_mm: 4.0,
                bend_deg: 15.0,
            },
            path: PathModel::Curved {
                // 120 mm nominal radius and 25 mm response: the reference simulator's
                // provisional profile values (not a measured trajectory).
                nominal_radius_mm: 120.0,
                response_length_mm: 25.0,
            },
            // 30 degrees at 100 mm: the reference simulator's nominal play window (its deadband
            // follows the precedent of Ertop et al. 2020; not fitted to a device).
            torsional_play_deg_at_100mm: 30.0,
        }
    }

    /// All built-in profiles.
    pub fn builtin() -> Vec<Self> {
        vec![
            Self::spinal_22g_quincke(),
            Self::spinal_22g_quincke_gel_fit(),
            Self::tuohy_18g(),
            Self::flexible_prebent(),
        ]
    }

    /// True when roll is transmitted one-to-one (no torsional play).
    pub fn is_torsionally_rigid(&self) -> bool {
        self.torsional_play_deg_at_100mm == 0.0
    }

    /// Check that every number is finite and in its physical range.
    pub fn validate(&self) -> Result<(), ProfileError> {
        let positive = |field: &'static str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(ProfileError::NotPositive { field, value })
            }
        };
        let non_negative = |field: &'static str, value: f64| {
            if value.is_finite() && value >= 0.0 {
                Ok(())
            } else {
                Err(ProfileError::Negative { field, value })
            }
        };
        positive("outer_diameter_mm", self.outer_diameter_mm)?;
        positive("shaft_length_mm", self.shaft_length_mm)?;
        positive("opening.length_mm", self.opening.length_mm)?;
        non_negative(
            "opening.distal_edge_from_tip_mm",
            self.opening.distal_edge_from_tip_mm,
        )?;
        if let PathModel::Curved {
            nominal_radius_mm,
            response_length_mm,
        } = self.path
        {
            positive("nominal_radius_mm", nominal_radius_mm)?;
            positive("response_length_mm", response_length_mm)?;
        }
        non_negative(
            "torsional_play_deg_at_100mm",
            self.torsional_play_deg_at_100mm,
        )?;
        Ok(())
    }
}

/// Why an instrument profile was refused: the field at fault and its value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProfileError {
    /// A length that must be finite and positive is not.
    #[error("{field} must be > 0, got {value}")]
    NotPositive {
        /// The offending field.
        field: &'static str,
        /// The value given.
        value: f64,
    },
    /// A length or angle that must be finite and not negative is not.
    #[error("{field} must be >= 0, got {value}")]
    Negative {
        /// The offending field.
        field: &'static str,
        /// The value given.
        value: f64,
    },
}
