//! Anatomy questions every modality and scorer may ask of a station in its region: the primary
//! target, the side of the body it lies on, and structure geometry (endplate and facet joint
//! planes) estimated from the region's meshes. None of it depends on an imaging modality.

use glam::DVec3;

use super::region::Region;
use super::world::StationContext;

/// The target that the station's `tip_to_target_mm` criterion names, else its first target.
pub fn primary_target(station: &StationContext) -> Option<[f64; 3]> {
    let named = station
        .station
        .rubric
        .criteria
        .iter()
        .find(|c| c.measurement == "tip_to_target_mm")
        .and_then(|c| c.target.as_ref())
        .and_then(|t| station.targets.get(t));
    named
        .or_else(|| {
            station
                .station
                .targets
                .first()
                .and_then(|t| station.targets.get(&t.name))
        })
        .copied()
}

/// -1 for a target left of the midline (x below the L4 body centre's), +1 for right.
pub fn target_side(region: &Region, target: [f64; 3]) -> f64 {
    let mid = region.landmarks.get("L4_body_centre").map_or(0.0, |c| c[0]);
    if target[0] < mid { -1.0 } else { 1.0 }
}

/// Angle between a line and a plane (given by its normal), degrees in 0..=90.
pub fn angle_to_plane_deg(line: DVec3, plane_normal: DVec3) -> f64 {
    line.normalize()
        .dot(plane_normal.normalize())
        .abs()
        .min(1.0)
        .asin()
        .to_degrees()
}

/// Outward normal of the inferior endplate of vertebra `upper`, estimated from its cortical mesh:
/// a 5 x 5 bundle of rays (12 mm wide, well inside a 35 mm endplate) leaves the body centre
/// towards the next body centre; the mean of the surface normals where they first meet the
/// cortex (turned to point caudally, along the rays) is the endplate normal. `None` when the region lacks the structures or landmarks.
pub fn endplate_normal(region: &Region, upper: &str, lower: &str) -> Option<DVec3> {
    let c = DVec3::from_array(*region.landmarks.get(&format!("{upper}_body_centre"))?);
    let l = DVec3::from_array(*region.landmarks.get(&format!("{lower}_body_centre"))?);
    // The phantom's cortex is `L4_cortical`; an imported CT's whole vertebra is `vertebrae_L4`.
    let bone = region
        .entry(&format!("{upper}_cortical"))
        .or_else(|| region.entry(&format!("vertebrae_{upper}")))?;
    let axis = (l - c).normalize();
    let e1 = axis.any_orthonormal_vector();
    let e2 = axis.cross(e1);
    let mut sum = DVec3::ZERO;
    for i in -2..=2 {
        for j in -2..=2 {
            let o = c + e1 * (3.0 * f64::from(i)) + e2 * (3.0 * f64::from(j));
            if let Some(h) = region.first_hit(bone, o.to_array(), axis.to_array(), 60.0) {
                // A solid bone mesh is left here (outward normal along the ray); a cortical
                // shell (the phantom's cortex is a mask of its own around the marrow) is entered
                // through its inner surface, parallel to the endplate, normal against the ray.
                sum += h.normal * h.normal.dot(axis).signum();
            }
        }
    }
    (sum.length() > 0.0).then(|| sum.normalize())
}

/// Normal of the facet joint plane nearest to `target`, estimated from the bone meshes around
/// the joint landmark (`*_facet_joint_left/right`): of 2000 directions (a Fibonacci sphere),
/// the one along which bone lies closest on both sides (the joint gap is the thinnest
/// direction); then the mean of the two facing surface normals there. `None` without a facet
/// joint landmark within 40 mm or without bone on both sides.
pub fn facet_joint_normal(region: &Region, target: [f64; 3]) -> Option<DVec3> {
    let t = DVec3::from_array(target);
    let (_, centre) = region
        .landmarks
        .iter()
        .filter(|(k, _)| k.contains("facet_joint"))
        .map(|(k, p)| (k, DVec3::from_array(*p)))
        .min_by(|a, b| a.1.distance(t).total_cmp(&b.1.distance(t)))?;
    if centre.distance(t) > 40.0 {
        return None;
    }
    let bones = region.bones();
    use sim_core::needle::BoneSurface;
    const N: usize = 2000;
    const REACH_MM: f64 = 8.0;
    let mut best: Option<(f64, DVec3, DVec3, DVec3)> = None;
    for k in 0..N {
        // Fibonacci sphere, upper half only (a line and its reverse are the same probe).
        let z = 1.0 - (k as f64 + 0.5) / N as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = k as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
        let (Some(a), Some(b)) = (
            bones.first_hit(centre, d, REACH_MM),
            bones.first_hit(centre, -d, REACH_MM),
        ) else {
            continue;
        };
        let width = a.t_mm + b.t_mm;
        if best.is_none_or(|(w, ..)| width < w) {
            best = Some((width, d, a.normal, b.normal));
        }
    }
    let (_, d, na, nb) = best?;
    // Surfaces facing the gap have outward normals against the probe: -na along d, nb along -d.
    let n = (nb - na).normalize_or_zero();
    if n == DVec3::ZERO { Some(d) } else { Some(n) }
}
