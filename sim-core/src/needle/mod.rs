//! Needle mechanics: bevel-tip kinematics, torsional play, the recorded tract, bone contact,
//! automatic placement, hub tilt, and what the hands feel (insertion force, loss of resistance,
//! aspiration).
//!
//! The path is a low-order interaction model in the nonholonomic framework of Webster et al.
//! (2006), not a device predictor: the insertion force ([`force`]) is computed along the path
//! but does not act back on it (no tissue displacement, rate dependence or elastic shaft
//! equilibrium), and the tract is retraced exactly.
//!
//! - [`profile`]: instruments as data (rigid 22G Quincke spinal, rigid 18G Tuohy, flexible
//!   pre-bent steerable needle), each number with its source.
//! - [`kinematics`]: one substep is the exact chord of a circular arc whose curvature comes from
//!   the exact mean of the exponentially relaxing bending response (second order in the substep);
//!   the frame is parallel-transported.
//! - [`play`]: hub roll reaches the bevel through a depth-dependent deadband.
//! - [`hub`]: hub tilt while in tissue (the shaft as a beam on an elastic foundation) and the
//!   redirection rule.
//! - [`tract`]: the cut channel and the tip's place on it.
//! - [`contact`]: centre-line ray casts against bone; steep contacts arrest, shallow ones slide.
//! - [`state`]: the serializable [`NeedleState`], the commands and the replayable [`Needle`] log.
//! - [`placement`]: automatic placement toward a target by duty-cycled 180 degree flips.
//!
//! Handling, pure models the session drives once per 0.5 mm substep:
//! - [`tissue`]: the mechanical [`Tissue`] class of a structure name.
//! - [`force`]: the insertion force along the path after Okamura, Simone & O'Leary (2004):
//!   capsule stiffness up to a puncture ("pop"), cutting at the tip, friction along the shaft.
//! - [`syringe`]: the loss-of-resistance syringe (saline or air) against tissue opening
//!   pressures, false loss of resistance, and aspiration with published false-negative rates.
//!
//! ```
//! use glam::DVec3;
//! use sim_core::needle::{InitialResponse, InstrumentProfile, Needle, NeedleCommand, NeedleState};
//!
//! let state = NeedleState::new(
//!     InstrumentProfile::flexible_prebent(),
//!     DVec3::ZERO,
//!     DVec3::Z,
//!     DVec3::X,
//!     1.0,
//!     InitialResponse::Settled,
//! )
//! .unwrap();
//! let mut needle = Needle::new(state);
//! needle.apply_free(NeedleCommand::Feed { mm: 50.0 }).unwrap();
//! // A settled 120 mm-radius needle bends toward its bevel (+x): 120 (1 - cos(50/120)) mm.
//! let expected_x = 120.0 * (1.0 - (50.0f64 / 120.0).cos());
//! assert!((needle.state.tip_mm().x - expected_x).abs() < 1e-9);
//! ```

pub mod contact;
pub mod force;
pub mod hub;
pub mod kinematics;
pub mod placement;
pub mod play;
pub mod profile;
pub mod state;
pub mod syringe;
pub mod tissue;
pub mod tract;

pub use contact::{BoneSurface, HalfSpaceBone, NoBone, RayHit, SphereBone};
pub use force::{ForceModel, ForceParams, ForcePhase, ForceSample, ForceState};
pub use kinematics::Pose;
pub use placement::{PlacementConfig, PlacementFailure, PlacementReport, place_toward};
pub use play::TorsionalPlay;
pub use profile::{InstrumentProfile, Opening, PathModel, ProfileError, TipGeometry};
pub use state::{
    ArrestReason, CommandOutcome, ContactArrest, FeedOutcome, FeedStop, InitialResponse, Needle,
    NeedleCommand, NeedleError, NeedleState, OutletFootprint, RollOutcome, TiltOutcome,
    WithdrawOutcome,
};
pub use syringe::{Aspirate, LorFeel, LorMedium, LorSyringe, aspirate, is_false_loss};
pub use tissue::{LayerStack, Tissue};
pub use tract::{SegmentKind, Tract, TractCursor, TractSegment};
