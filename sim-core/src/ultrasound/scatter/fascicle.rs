//! The texture of a nerve: a honeycomb of fascicles fixed to the tissue, and the anisotropy that
//! makes a nerve fade when the beam runs along its fibres.

use glam::DVec3;

use super::amplitude::{cell_hash, iq_of_hash};
use crate::rng::splitmix64;

/// Spacing of the fascicle honeycomb, mm (our choice: lumbar roots and plexus nerves show
/// fascicles of a few tenths of a millimetre).
pub const FASCICLE_CELL_MM: f64 = 0.8;
/// Radius of a fascicle, mm (our choice).
pub const FASCICLE_RADIUS_MM: f64 = 0.3;
/// Scatter amplitude inside a fascicle and in the perineurium between them (our choice: the
/// honeycomb contrast of a nerve in short axis, about 14 dB).
pub const FASCICLE_INSIDE: f64 = 0.35;
/// See [`FASCICLE_INSIDE`].
pub const FASCICLE_OUTSIDE: f64 = 1.75;
/// Nerve echo with the beam along the fibres, relative to perpendicular (our choice: about
/// -12 dB, the anisotropy that makes nerves fade when the probe is tilted).
pub const NERVE_ANISOTROPY_FLOOR: f64 = 0.25;

/// Texture and anisotropy factor of a nerve scatterer at `p` seen along beam direction `dir`.
/// Fascicles are tubes along `axis` centred on a jittered square lattice (cell
/// [`FASCICLE_CELL_MM`]) in the plane across it, all fixed to the tissue by the seed; without
/// an axis they are blobs on a 3D lattice and there is no anisotropy.
pub(crate) fn fascicle_factor(p: DVec3, axis: Option<DVec3>, dir: DVec3, seed: u64) -> f64 {
    let c = FASCICLE_CELL_MM;
    let (coords, dims, aniso) = match axis.and_then(DVec3::try_normalize) {
        Some(a) => {
            let r = if a.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
            let b1 = (r - a * r.dot(a)).normalize();
            let b2 = a.cross(b1);
            let along = dir.dot(a);
            let aniso =
                NERVE_ANISOTROPY_FLOOR + (1.0 - NERVE_ANISOTROPY_FLOOR) * (1.0 - along * along);
            (DVec3::new(p.dot(b1), p.dot(b2), 0.0), 2, aniso)
        }
        None => (p, 3, 1.0),
    };
    let cell = (coords / c).floor();
    let mut best = f64::INFINITY;
    let range = |d: usize| if d < dims { -1..=1 } else { 0..=0 };
    for i in range(0) {
        for j in range(1) {
            for k in range(2) {
                let n = cell + DVec3::new(f64::from(i), f64::from(j), f64::from(k));
                let h = cell_hash(seed ^ 0xF45C_1C1E, n.x as i64, n.y as i64, n.z as i64);
                let (jx, jy) = iq_of_hash(h);
                let jz = if dims == 3 {
                    crate::rng::unit_f64(splitmix64(h)) - 0.5
                } else {
                    0.0
                };
                let centre = (n + DVec3::new(0.5 + 0.4 * jx, 0.5 + 0.4 * jy, 0.5 + jz * 0.8)) * c;
                let mut d = coords - centre;
                if dims == 2 {
                    d.z = 0.0;
                }
                best = best.min(d.length());
            }
        }
    }
    let inside = if best < FASCICLE_RADIUS_MM {
        FASCICLE_INSIDE
    } else {
        FASCICLE_OUTSIDE
    };
    inside * aniso
}
