//! The deterministic part of each line: interface echoes, transmission and two-way attenuation.
//!
//! One amplitude signal model for everything: an echo from depth `z` has amplitude
//! `source x reflection x (product of two-way transmissions 1 - R^2 of the interfaces above) x
//! exp(-2 alpha f z)` (alpha in Np/cm/MHz: attenuation acts on the way in AND on the way back).
//! Speckle is multiplied by the same loss profile, so bulk scatter, interfaces, point targets and
//! the needle share one scale (0 dB = a perfect plane reflector at the skin).

use glam::DVec3;

use super::beam::Beam;
use super::needle::{LineHit, NeedleShaft, REVERB_COUNT, REVERB_RATIO, STEEL_REFLECTION, line_hit};
use super::probe::ScanGeometry;
use super::scatter::BeamTables;
use super::tissue::{AcousticMedium, AcousticProps};

/// Nepers per decibel (amplitude): ln 10 / 20.
const NP_PER_DB: f64 = std::f64::consts::LN_10 / 20.0;
/// Reflections weaker than this are not drawn as interfaces (they still cost transmission).
const MIN_INTERFACE_R: f64 = 0.01;
/// Angular half-width of the specular interface lobe, degrees (our choice: the aperture accepts
/// reflections within about this angle of normal incidence).
const INTERFACE_LOBE_DEG: f64 = 15.0;
/// Step of the finite-difference normal at an interface, mm.
const NORMAL_STEP_MM: f64 = 1.0;
/// Deepest air under the face that counts as coupling gel, mm (see [`GEL`]). Our choice: a
/// convex face pressed onto a curved back leaves gaps of up to about 10 mm at the sector's edges,
/// which gel and the deformed skin fill on a real scanner.
pub const GEL_MAX_MM: f64 = 15.0;
/// Coupling gel: air within [`GEL_MAX_MM`] of the face (between the face and the skin, and in
/// the staircase of a voxelised skin surface) is taken as gel, acoustically water
/// (1000 kg/m^3 x 1480 m/s; water's attenuation, 0.002 dB/cm/MHz, is negligible over
/// millimetres), anechoic. Without it a face that does not touch the skin everywhere would image
/// nothing through the air gap. (No air lies that close under the skin of the back.)
pub const GEL: AcousticProps = AcousticProps {
    impedance_mrayl: 1.48,
    speed_m_s: 1480.0,
    attenuation_db_cm_mhz: 0.002,
    echogenicity_db: -120.0,
    scatter_density: 0.0,
    roughness: 0.0,
    texture: super::tissue::Texture::Speckle,
};
/// Below this impedance a point is air (MRayl): air is 0.0004, the lightest tissue (fat) 1.3.
pub const AIR_BELOW_MRAYL: f64 = 0.1;

/// `props` at depth `z` under the face, with air within [`GEL_MAX_MM`] replaced by [`GEL`].
pub(crate) fn coupled(props: AcousticProps, z: f64) -> AcousticProps {
    if props.impedance_mrayl < AIR_BELOW_MRAYL && z <= GEL_MAX_MM {
        GEL
    } else {
        props
    }
}

/// Inputs shared by every line.
pub(crate) struct LineContext<'a> {
    pub geo: &'a ScanGeometry,
    pub beam: &'a Beam,
    pub tables: &'a BeamTables,
    pub medium: &'a dyn AcousticMedium,
    pub needle: Option<&'a NeedleShaft>,
    pub march_step_mm: f64,
}

/// One line's specular echoes (I and Q per sample), each a pulse of the axial PSF evaluated
/// exactly at the samples (no deposit-and-convolve, so a plane reflector's peak is `R`).
pub(crate) struct LineEchoes<'a> {
    pub re: &'a mut [f32],
    pub im: &'a mut [f32],
}

impl LineEchoes<'_> {
    fn pulse(&mut self, t: &BeamTables, z: f64, amp: f64, k0: f64) {
        let (c, s) = super::scatter::cis(2.0 * k0 * z);
        let sigma = t.axial_sigma_mm;
        let reach = 4.0 * sigma;
        let n = self.re.len();
        let s0 = (((z - reach) / t.dz).ceil().max(0.0)) as usize;
        let s1 = (((z + reach) / t.dz).floor().max(-1.0) + 1.0) as usize;
        for i in s0..s1.min(n) {
            let d = i as f64 * t.dz - z;
            let g = amp * super::scatter::exp_neg(d * d / (2.0 * sigma * sigma));
            self.re[i] += (g * c) as f32;
            self.im[i] += (g * s) as f32;
        }
    }
}

/// Marches line `j`: adds its interface and needle echoes to `echoes` and returns the
/// two-way loss factor (amplitude) at each sample.
pub(crate) fn march_line(ctx: &LineContext<'_>, j: usize, echoes: &mut LineEchoes<'_>) -> Vec<f32> {
    let (o, d) = ctx.geo.line_ray(j as f64);
    let depth = ctx.geo.depth_mm;
    let t = ctx.tables;
    let f = ctx.beam.frequency_mhz;
    let k0 = 2.0 * std::f64::consts::PI / ctx.beam.wavelength_mm();
    let hit: Option<LineHit> = ctx
        .needle
        .and_then(|n| line_hit(n, o, d, depth, ctx.beam, t, ctx.geo.frame.elevation));
    let step = ctx.march_step_mm;
    let n_march = (depth / step).ceil() as usize + 1;
    let mut log_gain = Vec::with_capacity(n_march);
    let mut log_t = 0.0f64;
    let mut loss_np = 0.0f64;
    let mut prev: AcousticProps = coupled(ctx.medium.props(o), 0.0);
    let mut needle_done = hit.is_none();
    log_gain.push(0.0);
    for k in 1..n_march {
        let z = k as f64 * step;
        let p = o + d * z;
        let cur = coupled(ctx.medium.props(p), z);
        let zm = z - 0.5 * step;
        if let (false, Some(h)) = (needle_done, hit) {
            if h.z <= z {
                needle_done = true;
                let g = (log_t - loss_np).exp();
                let amp = STEEL_REFLECTION * h.specular * h.overlap * g;
                for r in 0..=REVERB_COUNT {
                    let zr = h.z + r as f64 * ctx.needle.map_or(0.0, |n| n.diameter_mm);
                    echoes.pulse(t, zr, amp * REVERB_RATIO.powi(r as i32), k0);
                }
                log_t += (1.0 - h.overlap * STEEL_REFLECTION * STEEL_REFLECTION)
                    .max(1e-12)
                    .ln();
            }
        }
        let (z1, z2) = (prev.impedance_mrayl, cur.impedance_mrayl);
        let r = (z2 - z1) / (z2 + z1);
        if r.abs() >= MIN_INTERFACE_R {
            let pm = o + d * zm;
            let w = alignment(ctx.medium, pm, d, prev.roughness.max(cur.roughness));
            echoes.pulse(t, zm, r * w * (log_t - loss_np).exp(), k0);
        }
        log_t += (1.0 - r * r).max(1e-12).ln();
        let alpha = 0.5 * (prev.attenuation_db_cm_mhz + cur.attenuation_db_cm_mhz);
        // Two-way: 2 x alpha [dB/cm/MHz] x f [MHz] x step [mm -> cm].
        loss_np += 2.0 * alpha * f * step * 0.1 * NP_PER_DB;
        log_gain.push(log_t - loss_np);
        prev = cur;
    }
    (0..t.elev_inv2s2.len())
        .map(|s| {
            let x = s as f64 * t.dz / step;
            let i = (x as usize).min(n_march - 2);
            let fr = x - i as f64;
            (log_gain[i] * (1.0 - fr) + log_gain[i + 1] * fr).exp() as f32
        })
        .collect()
}

/// Weight of a specular interface echo: the diffuse `roughness` plus a Gaussian lobe in the angle
/// between the beam and the impedance gradient (the surface normal).
fn alignment(medium: &dyn AcousticMedium, p: DVec3, d: DVec3, roughness: f64) -> f64 {
    // The impedance gradient from a sphere of radius h sampled in 48 near-uniform (Fibonacci)
    // directions: on a voxelised (step) surface a 6-point stencil quantises the normal to 0 /
    // 45 / 55 degrees, and a cube stencil is biased towards its axes; the sphere follows the
    // true tilt to a few degrees.
    let h = NORMAL_STEP_MM;
    let mut g = DVec3::ZERO;
    for &u in sphere_directions() {
        g += u * medium.props(p + u * h).impedance_mrayl;
    }
    let cos = match g.try_normalize() {
        Some(n) => n.dot(d).abs().min(1.0),
        None => 1.0,
    };
    let theta = cos.acos();
    let lobe = INTERFACE_LOBE_DEG.to_radians();
    roughness + (1.0 - roughness) * (-(theta * theta) / (2.0 * lobe * lobe)).exp()
}

/// 48 near-uniform unit vectors (a Fibonacci sphere): the directions of the interface-normal
/// estimate (also uploaded by the GPU path).
pub fn sphere_directions() -> &'static [DVec3] {
    static D: std::sync::OnceLock<Vec<DVec3>> = std::sync::OnceLock::new();
    D.get_or_init(|| {
        let n = 48;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        (0..n)
            .map(|i| {
                let z = 1.0 - (2 * i + 1) as f64 / n as f64;
                let r = (1.0 - z * z).sqrt();
                let (s, c) = (golden * i as f64).sin_cos();
                DVec3::new(r * c, r * s, z)
            })
            .collect()
    })
}
