//! The independent reference of the scatter model: a photon Monte Carlo through a water slab.
//!
//! Photons of the committed tube spectrum (energies at the 1 keV bin centres) enter a laterally
//! infinite water slab, either as a pencil along the axis or from a point source over a
//! rectangular field at the detector. Between interactions they fly exponential distances
//! (water's total attenuation); photoabsorption is taken by implicit capture (the weight falls by
//! the scattering albedo at each interaction, and Russian roulette ends light photons);
//! incoherent scattering samples the Klein-Nishina cross section by Kahn's rejection (binding
//! effects kept only in the total cross section); coherent scattering samples the Thomson
//! factor times the water molecule's squared form factor (independent atoms), by inverting the
//! form factor's cumulative in `x^2` as PENELOPE does (Salvat, PENELOPE-2018, section 2.1).
//! Every photon that leaves the far face after at least one interaction is carried straight to
//! the detector plane(s) and scored with the weight of an energy-integrating detector (its
//! energy), and once more behind the anti-scatter grid. The primary is exact (Beer-Lambert over
//! the spectrum), not sampled.
//!
//! Runs are split into fixed chunks with their own seeds and summed in order, so a result does
//! not depend on the number of threads.

use glam::DVec3;

use super::grid::AntiScatterGrid;
use super::tables::{HC_KEV_ANGSTROM, ScatterTables};
use crate::fluoro::spectrum::{Spectrum, UnknownKvp};
use crate::rng::{SplitMix64, splitmix64};

/// Electron rest energy, keV (CODATA 2018: 510.998 95 keV).
const ELECTRON_KEV: f64 = 510.998_95;
/// Photons below this energy are absorbed where they are, keV (water's photoabsorption is
/// then over 99 % of its attenuation and their range under 1 mm).
const CUTOFF_KEV: f64 = 5.0;
/// Russian roulette below this weight: survive with probability [`ROULETTE_SURVIVAL`].
const ROULETTE_WEIGHT: f64 = 0.02;
const ROULETTE_SURVIVAL: f64 = 0.2;
/// Photons per chunk (one seed each).
const CHUNK: usize = 4096;

/// How the beam enters the slab.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Beam {
    /// A parallel pencil along the axis through the slab's centre (a scatter kernel).
    Pencil,
    /// A point source `source_to_detector_mm` from the detector, irradiating a rectangle of
    /// half-sides `half_x_mm` (across the grid's strips) and `half_y_mm` at the detector.
    Field {
        /// Focal spot to detector, mm.
        source_to_detector_mm: f64,
        /// Half width of the field at the detector (row direction), mm.
        half_x_mm: f64,
        /// Half height of the field at the detector (column direction), mm.
        half_y_mm: f64,
    },
}

/// A slab problem.
#[derive(Debug, Clone, PartialEq)]
pub struct SlabSetup {
    /// Tube voltage, kVp (a committed spectrum).
    pub kvp: u32,
    /// Water thickness, mm.
    pub water_mm: f64,
    /// Distances from the slab's exit face to the detector planes scored, mm (several at
    /// once for a pencil; a field is scored at the first only).
    pub air_gaps_mm: Vec<f64>,
    /// The beam.
    pub beam: Beam,
    /// The anti-scatter grid scored behind (the scores without it are kept too).
    pub grid: AntiScatterGrid,
    /// Photons to run.
    pub photons: usize,
    /// Seed of the run.
    pub seed: u64,
}

/// Scores of a broad field at the detector centre (a disc of radius [`Tally::disc_radius_mm`]),
/// relative to the open field's energy fluence there: primary (exact), scatter without and
/// with the grid (mean and standard error over chunks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CentreScore {
    /// Primary transmission at the centre (energy-integrating), no grid.
    pub primary: f64,
    /// Primary transmission behind the grid.
    pub primary_grid: f64,
    /// Scatter, no grid: mean and standard error.
    pub scatter: (f64, f64),
    /// Scatter behind the grid: mean and standard error.
    pub scatter_grid: (f64, f64),
}

impl CentreScore {
    /// Scatter-to-primary ratio without the grid and its standard error.
    pub fn spr(&self) -> (f64, f64) {
        (self.scatter.0 / self.primary, self.scatter.1 / self.primary)
    }

    /// Scatter-to-primary ratio behind the grid and its standard error.
    pub fn spr_grid(&self) -> (f64, f64) {
        (
            self.scatter_grid.0 / self.primary_grid,
            self.scatter_grid.1 / self.primary_grid,
        )
    }
}

/// Radial scores of a pencil: per air gap, the scatter within radius `r_k = (k+1) * RING_MM`
/// of the axis, without and with the grid, per unit incident energy.
#[derive(Debug, Clone, PartialEq)]
pub struct PencilScore {
    /// Primary transmission along the axis.
    pub primary: f64,
    /// `[gap][k]`: cumulative scatter within `r_k`, no grid.
    pub cumulative: Vec<Vec<f64>>,
    /// `[gap][k]`: the same behind the grid.
    pub cumulative_grid: Vec<Vec<f64>>,
}

/// Ring width of a pencil's radial score, mm.
pub const RING_MM: f64 = 5.0;
/// Rings of a pencil's radial score (to 500 mm).
pub const RINGS: usize = 100;

/// What each chunk scores.
#[derive(Debug, Clone)]
struct Tally {
    disc_radius_mm: f64,
    /// Field: `[no grid, grid]` in the disc. Pencil: rings per gap.
    centre: [f64; 2],
    rings: Vec<[f64; 2]>,
}

impl Tally {
    fn new(gaps: usize, disc_radius_mm: f64) -> Tally {
        Tally {
            disc_radius_mm,
            centre: [0.0; 2],
            rings: vec![[0.0; 2]; gaps * RINGS],
        }
    }
}

/// Runs `setup` and scores a broad field at the centre of the detector, within a disc of
/// `disc_radius_mm`.
///
/// # Panics
/// If the beam is a pencil or `kvp` has no spectrum.
pub fn field_centre(setup: &SlabSetup, disc_radius_mm: f64) -> Result<CentreScore, UnknownKvp> {
    let Beam::Field {
        source_to_detector_mm,
        half_x_mm,
        half_y_mm,
    } = setup.beam
    else {
        panic!("field_centre needs a field beam");
    };
    let run = Run::new(setup)?;
    let chunks = run.chunks(disc_radius_mm);
    let area = 4.0 * half_x_mm * half_y_mm;
    let disc = std::f64::consts::PI * disc_radius_mm * disc_radius_mm;
    // Per chunk: scatter energy in the disc per disc area, over the open field's energy
    // fluence (photons / field area x mean weighted energy).
    let per_chunk =
        |c: &Tally, k: usize, n: usize| c.centre[k] / disc / (n as f64 / area * run.mean_energy);
    let stats = |k: usize| mean_and_error(chunks.iter().map(|(c, n)| per_chunk(c, k, *n)));
    // Primary along the central ray: the slab's thickness at normal incidence.
    let _ = source_to_detector_mm;
    let primary = run.transmission(setup.water_mm);
    let tp = setup.grid.primary_transmission();
    Ok(CentreScore {
        primary,
        primary_grid: primary * tp,
        scatter: stats(0),
        scatter_grid: stats(1),
    })
}

/// Runs a pencil beam through `setup`'s slab and scores the scatter radially at every air gap.
///
/// # Panics
/// If the beam is not a pencil.
pub fn pencil(setup: &SlabSetup) -> Result<PencilScore, UnknownKvp> {
    assert_eq!(setup.beam, Beam::Pencil, "pencil needs a pencil beam");
    let run = Run::new(setup)?;
    let chunks = run.chunks(0.0);
    let total: usize = chunks.iter().map(|(_, n)| n).sum();
    let norm = 1.0 / (total as f64 * run.mean_energy);
    let gaps = setup.air_gaps_mm.len();
    let mut cumulative = vec![vec![0.0; RINGS]; gaps];
    let mut cumulative_grid = vec![vec![0.0; RINGS]; gaps];
    for g in 0..gaps {
        let (mut a, mut b) = (0.0, 0.0);
        for k in 0..RINGS {
            for (c, _) in &chunks {
                a += c.rings[g * RINGS + k][0];
                b += c.rings[g * RINGS + k][1];
            }
            cumulative[g][k] = a * norm;
            cumulative_grid[g][k] = b * norm;
        }
    }
    Ok(PencilScore {
        primary: run.transmission(setup.water_mm),
        cumulative,
        cumulative_grid,
    })
}

fn mean_and_error(xs: impl Iterator<Item = f64>) -> (f64, f64) {
    let v: Vec<f64> = xs.collect();
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, (var / n).sqrt())
}

/// A prepared run: the spectrum's sampling table and the geometry.
struct Run<'a> {
    setup: &'a SlabSetup,
    tables: &'static ScatterTables,
    energies_kev: Vec<f64>,
    /// Cumulative photon probability per bin.
    cdf: Vec<f64>,
    /// Fluence-weighted mean energy (the open field's energy per photon), keV.
    mean_energy: f64,
    /// Cumulative of `F^2` in `x^2` on the form factor's grid: `(x^2, A(x^2))`.
    coherent_cdf: Vec<(f64, f64)>,
}

impl<'a> Run<'a> {
    fn new(setup: &'a SlabSetup) -> Result<Run<'a>, UnknownKvp> {
        let s = Spectrum::tungsten(setup.kvp)?;
        let total: f64 = s.fluence.iter().sum();
        let mut acc = 0.0;
        let cdf = s
            .fluence
            .iter()
            .map(|f| {
                acc += f / total;
                acc
            })
            .collect();
        let mean_energy = s.mean_energy_kev();
        let tables = ScatterTables::get();
        let mut coherent_cdf = vec![(0.0, 0.0)];
        let step = 0.01;
        let mut k = 1;
        loop {
            let (x0, x1) = ((k - 1) as f64 * step, k as f64 * step);
            let (f0, f1) = (tables.form_factor_ratio(x0), tables.form_factor_ratio(x1));
            if f1 == 0.0 && k > 1 {
                break;
            }
            let a = coherent_cdf.last().expect("seeded").1 + 0.5 * (f0 + f1) * (x1 * x1 - x0 * x0);
            coherent_cdf.push((x1 * x1, a));
            k += 1;
        }
        Ok(Run {
            setup,
            tables,
            energies_kev: s.energies_kev,
            cdf,
            mean_energy,
            coherent_cdf,
        })
    }

    /// Energy-integrating transmission of `mm` of water at normal incidence.
    fn transmission(&self, mm: f64) -> f64 {
        let mut prev = 0.0;
        let mut sum = 0.0;
        for (e, c) in self.energies_kev.iter().zip(&self.cdf) {
            let p = c - prev;
            prev = *c;
            sum += p * e * (-self.tables.water(*e).total_per_mm() * mm).exp();
        }
        sum / self.mean_energy
    }

    /// All chunks, on scoped threads, in order: each chunk's tally and photon count.
    fn chunks(&self, disc_radius_mm: f64) -> Vec<(Tally, usize)> {
        let n = self.setup.photons;
        let count = n.div_ceil(CHUNK);
        let threads = std::thread::available_parallelism()
            .map_or(1, |t| t.get())
            .min(count.max(1));
        let mut out: Vec<Option<(Tally, usize)>> = vec![None; count];
        let per = count.div_ceil(threads.max(1));
        std::thread::scope(|s| {
            for (block, slots) in out.chunks_mut(per.max(1)).enumerate() {
                s.spawn(move || {
                    for (k, slot) in slots.iter_mut().enumerate() {
                        let c = block * per + k;
                        let photons = CHUNK.min(n - c * CHUNK);
                        *slot = Some((self.chunk(c as u64, photons, disc_radius_mm), photons));
                    }
                });
            }
        });
        out.into_iter()
            .map(|c| c.expect("every chunk ran"))
            .collect()
    }

    fn chunk(&self, index: u64, photons: usize, disc_radius_mm: f64) -> Tally {
        let mut rng = SplitMix64::new(splitmix64(self.setup.seed ^ splitmix64(index)));
        let mut tally = Tally::new(self.setup.air_gaps_mm.len(), disc_radius_mm);
        for _ in 0..photons {
            self.photon(&mut rng, &mut tally);
        }
        tally
    }

    fn sample_energy(&self, rng: &mut SplitMix64) -> f64 {
        let u = rng.next_f64();
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .min(self.cdf.len() - 1);
        self.energies_kev[i]
    }

    /// One photon's history.
    fn photon(&self, rng: &mut SplitMix64, tally: &mut Tally) {
        let setup = self.setup;
        let t = setup.water_mm;
        let (mut pos, mut dir, mut weight) = match setup.beam {
            Beam::Pencil => (DVec3::ZERO, DVec3::Z, 1.0),
            Beam::Field {
                source_to_detector_mm: sid,
                half_x_mm,
                half_y_mm,
            } => {
                // Slab from z = 0 to t; the source sits sid - gap - t before it.
                let gap = setup.air_gaps_mm[0];
                let x = (2.0 * rng.next_f64() - 1.0) * half_x_mm;
                let y = (2.0 * rng.next_f64() - 1.0) * half_y_mm;
                let d = DVec3::new(x, y, sid).normalize();
                let src_to_entry = sid - gap - t;
                // Uniform over the detector area; an isotropic source puts cos^3 of that there.
                let w = d.z * d.z * d.z;
                (
                    d * (src_to_entry / d.z) - DVec3::new(0.0, 0.0, src_to_entry),
                    d,
                    w,
                )
            }
        };
        // Entry point in slab coordinates (z = 0 at the entrance face).
        pos.z = 0.0;
        let mut e = self.sample_energy(rng);
        let mut scattered = false;
        loop {
            let mu = self.tables.water(e);
            let mu_t = mu.total_per_mm();
            let s = -rng.next_f64_nonzero().ln() / mu_t;
            let z = pos.z + s * dir.z;
            if z >= t {
                if scattered {
                    let exit = pos + dir * ((t - pos.z) / dir.z);
                    self.score(exit, dir, e, weight, tally);
                }
                return;
            }
            if z < 0.0 {
                return;
            }
            pos += dir * s;
            scattered = true;
            weight *= 1.0 - mu.photo_per_mm / mu_t;
            let scatter = mu.incoherent_per_mm + mu.coherent_per_mm;
            let cos = if rng.next_f64() * scatter < mu.incoherent_per_mm {
                let (cos, e_out) = klein_nishina(rng, e);
                e = e_out;
                cos
            } else {
                self.coherent(rng, e)
            };
            dir = rotate(dir, cos, std::f64::consts::TAU * rng.next_f64());
            if e < CUTOFF_KEV {
                return;
            }
            if weight < ROULETTE_WEIGHT {
                if rng.next_f64() >= ROULETTE_SURVIVAL {
                    return;
                }
                weight /= ROULETTE_SURVIVAL;
            }
        }
    }

    /// Scores a scattered photon leaving the exit face at `exit` along `dir`.
    fn score(&self, exit: DVec3, dir: DVec3, e: f64, weight: f64, tally: &mut Tally) {
        let grid = &self.setup.grid;
        let w = weight * e;
        match self.setup.beam {
            Beam::Pencil => {
                let tan_x = dir.x / dir.z;
                let through = grid.transmission(tan_x, dir.z, e, self.tables);
                for (g, gap) in self.setup.air_gaps_mm.iter().enumerate() {
                    let p = exit + dir * (gap / dir.z);
                    let ring = ((p.x.hypot(p.y)) / RING_MM) as usize;
                    if ring < RINGS {
                        let r = &mut tally.rings[g * RINGS + ring];
                        r[0] += w;
                        r[1] += w * through;
                    }
                }
            }
            Beam::Field {
                source_to_detector_mm: sid,
                ..
            } => {
                let gap = self.setup.air_gaps_mm[0];
                let p = exit + dir * (gap / dir.z);
                if p.x.hypot(p.y) < tally.disc_radius_mm {
                    // The grid is focused on the source: the angle is against the line from
                    // the detector point to the focal spot, in the row plane.
                    let tan_x = ((dir.x / dir.z).atan() - (p.x / sid).atan()).tan();
                    let through = grid.transmission(tan_x, dir.z, e, self.tables);
                    tally.centre[0] += w;
                    tally.centre[1] += w * through;
                }
            }
        }
    }

    /// Coherent scattering: `cos theta` from `(1 + cos^2) / 2 F^2(x)`, `x^2` from the form
    /// factor's cumulative, the Thomson factor by rejection.
    fn coherent(&self, rng: &mut SplitMix64, e: f64) -> f64 {
        let k = e / HC_KEV_ANGSTROM;
        let x2_max = k * k;
        let a_max = cumulative_at(&self.coherent_cdf, x2_max);
        loop {
            let x2 = inverse_cumulative(&self.coherent_cdf, rng.next_f64() * a_max);
            let cos = 1.0 - 2.0 * x2 / x2_max;
            if 2.0 * rng.next_f64() <= 1.0 + cos * cos {
                return cos.clamp(-1.0, 1.0);
            }
        }
    }
}

fn cumulative_at(table: &[(f64, f64)], x2: f64) -> f64 {
    let i = table.partition_point(|p| p.0 <= x2);
    if i == 0 {
        return 0.0;
    }
    if i >= table.len() {
        return table[table.len() - 1].1;
    }
    let (a, b) = (table[i - 1], table[i]);
    a.1 + (b.1 - a.1) * (x2 - a.0) / (b.0 - a.0)
}

fn inverse_cumulative(table: &[(f64, f64)], a: f64) -> f64 {
    let i = table.partition_point(|p| p.1 <= a);
    if i == 0 {
        return 0.0;
    }
    if i >= table.len() {
        return table[table.len() - 1].0;
    }
    let (p, q) = (table[i - 1], table[i]);
    p.0 + (q.0 - p.0) * (a - p.1) / (q.1 - p.1)
}

/// Samples a Compton scattering of a photon of `e_kev` from the Klein-Nishina cross section by
/// Kahn's rejection method (H. Kahn, "Applications of Monte Carlo", RAND AECU-3259, 1954; as
/// given by Lux and Koblinger, "Monte Carlo Particle Transport Methods", 1991): `(cos theta,
/// scattered energy keV)`.
pub fn klein_nishina(rng: &mut SplitMix64, e_kev: f64) -> (f64, f64) {
    let k = e_kev / ELECTRON_KEV;
    loop {
        let (r1, r2, r3) = (rng.next_f64(), rng.next_f64(), rng.next_f64());
        let eta;
        if r1 <= (1.0 + 2.0 * k) / (9.0 + 2.0 * k) {
            eta = 1.0 + 2.0 * k * r2;
            if r3 > 4.0 * (1.0 / eta - 1.0 / (eta * eta)) {
                continue;
            }
        } else {
            eta = (1.0 + 2.0 * k) / (1.0 + 2.0 * k * r2);
            let cos = 1.0 - (eta - 1.0) / k;
            if r3 > 0.5 * (cos * cos + 1.0 / eta) {
                continue;
            }
        }
        let cos = (1.0 - (eta - 1.0) / k).clamp(-1.0, 1.0);
        return (cos, e_kev / eta);
    }
}

/// `dir` turned by polar angle `acos(cos)` and azimuth `phi`.
fn rotate(dir: DVec3, cos: f64, phi: f64) -> DVec3 {
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let (sp, cp) = phi.sin_cos();
    // An orthonormal pair perpendicular to dir.
    let a = if dir.z.abs() < 0.9 {
        DVec3::Z
    } else {
        DVec3::X
    };
    let u = dir.cross(a).normalize();
    let v = dir.cross(u);
    (dir * cos + (u * cp + v * sp) * sin).normalize()
}
