//! Aiming at the hub while the needle is in tissue: how much of a hub tilt reaches the tip, and
//! which changes of path count as redirections.
//!
//! # Model (our choice, from beam theory)
//! Tilting the hub pivots the external shaft about the skin entry by the full hub angle. The
//! buried shaft is a slender tube embedded in tissue, which we treat as a beam on a Winkler
//! elastic foundation (Hetényi, *Beams on Elastic Foundation*, University of Michigan Press,
//! 1946): a rotation imposed at the skin decays along the buried shaft over the characteristic
//! length `lambda = (4 E I / k)^(1/4)`. We keep only the decay envelope, so the tip heading turns
//! by `hub angle * exp(-buried / lambda)` (the full solution's `cos(x / lambda)` factor, which
//! would let a deep tip turn against the hub, is dropped: a simplification, not a result). The
//! tip itself does not move; the next advance cuts along the new heading, branching from the
//! channel where the tip turned. A needle that is not buried re-aims fully.
//!
//! For a 22 G shaft (0.72 mm outer diameter) lambda is about 20 mm, for 18 G (1.27 mm) about
//! 36 mm: at 40 mm depth a 22 G tip turns by 14 % of the hub angle, an 18 G Tuohy by 33 %,
//! which is why a deep needle is withdrawn before it is redirected.

/// Young's modulus of stainless steel (AISI 304), N/mm^2 (193 GPa: ASM Handbook vol. 1, 1990).
pub const STEEL_YOUNG_MODULUS_N_PER_MM2: f64 = 193_000.0;

/// Inner to outer diameter ratio of the shaft tube. Our approximation of ISO 9626:2016 regular
/// wall tubing, whose nominal ratio runs from 0.57 (22 G: 0.72 / 0.41 mm) to 0.66 (18 G:
/// 1.27 / 0.84 mm).
pub const WALL_INNER_TO_OUTER: f64 = 0.6;

/// Winkler foundation modulus of the tissue around the shaft (force per unit length per unit
/// deflection), N/mm^2. Our choice: for a slender beam the modulus is of the order of the
/// tissue's Young's modulus, and passive skeletal muscle and subcutaneous tissue measure
/// about 10 to 100 kPa (0.01 to 0.1 N/mm^2); we take 50 kPa.
pub const TISSUE_FOUNDATION_N_PER_MM2: f64 = 0.05;

/// Largest angle between the hub's direction and the direction the needle punctured the skin
/// with, degrees. Our choice: beyond this the skin entry tears and the shaft bends visibly; a
/// physician withdraws and punctures again.
pub const MAX_HUB_DEVIATION_DEG: f64 = 45.0;

/// Channel a branch must discard for the next advance to count as a redirection, mm. Simulator
/// choice, the same as the ultrasound scorer's new-pass rule: smaller back-and-forth movements
/// (and steering at the channel's end) are adjustments of the same pass; a physician counts a
/// withdrawal and a re-advance in a new direction.
pub const REDIRECT_MIN_DISCARD_MM: f64 = 2.0;

/// Second moment of area of a tube of outer diameter `outer_mm` with [`WALL_INNER_TO_OUTER`],
/// mm^4.
pub fn tube_second_moment_mm4(outer_mm: f64) -> f64 {
    let inner = WALL_INNER_TO_OUTER * outer_mm;
    std::f64::consts::PI / 64.0 * (outer_mm.powi(4) - inner.powi(4))
}

/// Characteristic length over which a rotation imposed at the skin decays along the buried
/// shaft, mm (see the module docs).
pub fn deflection_length_mm(outer_mm: f64) -> f64 {
    let ei = STEEL_YOUNG_MODULUS_N_PER_MM2 * tube_second_moment_mm4(outer_mm);
    (4.0 * ei / TISSUE_FOUNDATION_N_PER_MM2).powf(0.25)
}

/// Fraction of a hub tilt that turns the tip heading with `buried_mm` of shaft in tissue.
pub fn tip_turn_fraction(outer_mm: f64, buried_mm: f64) -> f64 {
    (-buried_mm.max(0.0) / deflection_length_mm(outer_mm)).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deflection_lengths_match_the_hand_calculation() {
        // 22 G: I = pi/64 (0.72^4 - 0.432^4) = 0.01148 mm^4, EI = 2216 N mm^2,
        // (4 EI / 0.05)^(1/4) = 20.5 mm; 18 G: I = 0.1111 mm^4, lambda = 36.2 mm.
        assert!((deflection_length_mm(0.72) - 20.5).abs() < 0.1);
        assert!((deflection_length_mm(1.27) - 36.2).abs() < 0.1);
        assert_eq!(tip_turn_fraction(0.72, 0.0), 1.0);
        assert!(tip_turn_fraction(0.72, 40.0) < tip_turn_fraction(1.27, 40.0));
    }
}
