//! Ultrasound: the CPU reference of the B-mode image (deterministic, `f64` geometry).
//!
//! Data flow of [`scan`], per frame:
//! 1. [`probe`]: the pose gives the probe frame and the scan lines (parallel for the linear
//!    array, diverging for the curvilinear one).
//! 2. [`scatter`]: lattice scatterers fixed to the tissue (hashed per cell, scaled by the
//!    [`tissue`] echogenicity) are weighted by the elevation profile, phase-rotated and convolved
//!    with the [`beam`] PSF, whose widths are millimetres at every depth.
//! 3. [`echo`]: each line is marched through the tissue: interface echoes
//!    `(Z2 - Z1) / (Z2 + Z1)` weighted by beam/normal alignment, transmission `1 - R^2` per
//!    interface, two-way attenuation `exp(-2 alpha f z)`, and the [`needle`] (specular shaft,
//!    reverberation tail, shadow).
//! 4. [`frame`]: envelope `sqrt(I^2 + Q^2)`, gain, TGC and log compression into the dynamic
//!    range, scan conversion to square millimetre-scaled pixels.
//!
//! Threads and time: the deposit of step 2 runs on two threads (two fixed halves of the
//! lattice, summed in a fixed order); then each line on its own (lateral and axial convolution,
//! march, envelope) and each image row, both split over two threads. Every value is computed the
//! same way whichever thread does it, so frames are bit-identical run to run. About 85 % of a
//! frame's instructions are the deposit: per scatterer a hash, a medium lookup, a table exp and
//! two multiply-adds, about 150 instructions with the column set-up (callgrind, the bench scene
//! of `benches/ultrasound.rs`).
//!
//! ```
//! use glam::DVec3;
//! use sim_core::ultrasound::{ProbeKind, ProbePose, Sampling, ScanRequest, Settings, UniformMedium, scan};
//! use sim_core::ultrasound::tissue::MUSCLE;
//! let probe = ProbeKind::Linear;
//! let settings = Settings { depth_mm: 20.0, focus_mm: 10.0, ..Settings::default_for(&probe.spec()) };
//! let sampling = Sampling { lines: 64, ..Sampling::for_settings(&probe.spec(), &settings) };
//! let req = ScanRequest {
//!     probe,
//!     // On the skin at the origin, looking along +z, orientation marker towards +x.
//!     pose: ProbePose { position_mm: DVec3::ZERO, beam_dir: DVec3::Z, marker_dir: DVec3::X },
//!     settings,
//!     sampling,
//!     medium: &UniformMedium(MUSCLE),
//!     needle: None,
//!     targets: &[],
//!     seed: 1,
//! };
//! let frame = scan(&req).unwrap();
//! // Square pixels of `pixel_mm`; column 0 is the marker side, row 0 the probe face.
//! assert_eq!(frame.width, (38.0 / frame.pixel_mm) as usize + 1);
//! assert!(frame.envelope.data.iter().all(|a| a.is_finite()));
//! ```
//!
//! Not modelled: refraction and speed-of-sound aberration (depth assumes 1540 m/s), multiple
//! scattering except the needle's reverberation, side lobes, tissue deformation.

mod angle;
pub mod beam;
mod decibel;
mod echo;
pub mod error;
pub mod frame;
pub mod indexed;
pub mod needle;
mod parallel;
mod pixel_map;
pub mod probe;
pub mod scatter;
pub mod settings;
pub mod tissue;

use glam::DVec3;

pub use beam::Beam;
pub use error::UltrasoundError;
pub use frame::{BModeFrame, Envelope};
pub use indexed::IndexedMedium;
pub use needle::{NeedleShaft, NeedleView, needle_view};
pub use probe::{ProbeFrame, ProbeKind, ProbePose, ProbeSpec, ScanGeometry};
pub use settings::{Sampling, Settings, TGC_BANDS};
pub use tissue::{
    AcousticMedium, AcousticProps, CtMedium, LatticeColumn, ScatterProps, Texture, UniformMedium,
};

pub use echo::{AIR_BELOW_MRAYL, GEL, GEL_MAX_MM, sphere_directions};
use echo::{LineContext, LineEchoes, march_line};
use scatter::{
    BeamTables, IqGrid, LateralKernel, ScatterField, axial_taps, conv_sigma, convolve_axial_row,
    deposit_scatterers,
};

/// A point reflector (calibration and PSF tests), amplitude relative to a perfect plane
/// reflector, seen through the PSF like a scatterer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointTarget {
    /// Region frame, mm.
    pub position_mm: DVec3,
    /// Echo amplitude at the focus, relative to a perfect plane reflector.
    pub amplitude: f64,
}

/// Everything one frame depends on.
#[derive(Clone, Copy)]
pub struct ScanRequest<'a> {
    /// Transducer.
    pub probe: ProbeKind,
    /// Where it is.
    pub pose: ProbePose,
    /// Its controls.
    pub settings: Settings,
    /// How finely to compute.
    pub sampling: Sampling,
    /// The tissue.
    pub medium: &'a dyn AcousticMedium,
    /// The needle shaft, if one is in the body.
    pub needle: Option<NeedleShaft>,
    /// Extra point reflectors.
    pub targets: &'a [PointTarget],
    /// Seed of the tissue's scatterer field (fixed per patient/session, not per frame).
    pub seed: u64,
}

impl ScanRequest<'_> {
    /// The scan geometry and beam after validating every input.
    pub fn geometry(&self) -> Result<(ScanGeometry, Beam), UltrasoundError> {
        let spec = self.probe.spec();
        let frame = self.pose.frame()?;
        self.settings.validate(&spec)?;
        self.sampling.validate()?;
        if let Some(n) = &self.needle {
            n.validate()?;
        }
        for t in self.targets {
            error::check_finite3("targets.position_mm", t.position_mm)?;
            error::check_range("targets.amplitude", t.amplitude, 0.0, 1.0)?;
        }
        let geo = ScanGeometry {
            spec,
            frame,
            lines: self.sampling.lines,
            depth_mm: self.settings.depth_mm,
        };
        let beam = self.settings.beam(&spec);
        Ok((geo, beam))
    }
}

/// Computes one B-mode frame. Bit-identical for identical requests.
pub fn scan(req: &ScanRequest<'_>) -> Result<BModeFrame, UltrasoundError> {
    Ok(scan_unless(req, &|| false)?.expect("a scan that is never stopped ends with a frame"))
}

/// [`scan`], given up (`Ok(None)`) once `stop` says so: a caller whose frame was superseded
/// (the probe moved again while it was computed) asks for the next one instead. `stop` is asked
/// between rows of the scatterer deposit (a few hundred per frame, each well under a
/// millisecond) and between the frame's stages; a frame that is not stopped is the one [`scan`]
/// computes, bit for bit.
pub fn scan_unless(
    req: &ScanRequest<'_>,
    stop: &(dyn Fn() -> bool + Sync),
) -> Result<Option<BModeFrame>, UltrasoundError> {
    let (geo, beam) = req.geometry()?;
    let samples = req.sampling.samples_per_line;
    let tables = BeamTables::new(&beam, geo.depth_mm, samples);
    let max_lat_lines = (0..samples)
        .map(|s| tables.lat_sigma_mm[s] / geo.line_spacing_mm(s as f64 * tables.dz))
        .fold(0.0f64, f64::max);
    let pad_l = (3.5 * conv_sigma(max_lat_lines)).ceil() as usize + 1;
    let pad_s = (3.5 * conv_sigma(tables.axial_sigma_mm / tables.dz)).ceil() as usize + 1;

    // Speckle: two fixed halves of the lattice on two threads, summed in a fixed order.
    let deposit = |part: u64| {
        let mut g = IqGrid::new(geo.lines, samples, pad_l, pad_s);
        deposit_scatterers(
            &mut g,
            &geo,
            &beam,
            &tables,
            req.medium,
            ScatterField {
                cell_mm: req.sampling.scatter_cell_mm,
                seed: req.seed,
            },
            part,
            stop,
        );
        g
    };
    let mut grid = std::thread::scope(|s| {
        let other = s.spawn(|| deposit(1));
        let mine = deposit(0);
        let mut g = mine;
        g.add(&other.join().expect("scatter thread"));
        g
    });
    if stop() {
        return Ok(None);
    }
    let k0 = 2.0 * std::f64::consts::PI / beam.wavelength_mm();
    for t in req.targets {
        let q = geo.frame.to_probe(t.position_mm);
        let (u, z) = geo.plane_to_line(q.x, q.y);
        let w = t.amplitude * tables.elevation_weight(q.z, z);
        let (cs, sn) = scatter::cis(2.0 * k0 * z);
        grid.deposit(u, z / tables.dz, w * cs, w * sn);
    }
    let lateral = LateralKernel::new(&grid, &tables, &|z| geo.line_spacing_mm(z));
    let taps = axial_taps(&grid, &tables);

    // Lines, each on its own: the lateral then the axial convolution of the speckle, the losses,
    // interfaces and the needle, and the envelope.
    let ctx = LineContext {
        geo: &geo,
        beam: &beam,
        tables: &tables,
        medium: req.medium,
        needle: req.needle.as_ref(),
        march_step_mm: req.sampling.march_step_mm,
    };
    let mut data = vec![0f32; geo.lines * samples];
    parallel::in_two(&mut data, samples, |out, j0| {
        let st = grid.stride();
        let (mut row_re, mut row_im) = (vec![0f32; st], vec![0f32; st]);
        let (mut sre, mut sim) = (vec![0f32; samples], vec![0f32; samples]);
        let (mut pre, mut pim) = (vec![0f32; samples], vec![0f32; samples]);
        for (i, line) in out.chunks_mut(samples).enumerate() {
            let j = j0 + i;
            lateral.row(&grid, j, &mut row_re, &mut row_im);
            convolve_axial_row(&taps, &row_re, &row_im, &mut sre, &mut sim);
            pre.fill(0.0);
            pim.fill(0.0);
            let gain = march_line(
                &ctx,
                j,
                &mut LineEchoes {
                    re: &mut pre,
                    im: &mut pim,
                },
            );
            for (s, e) in line.iter_mut().enumerate() {
                let a = gain[s] * sre[s] + pre[s];
                let b = gain[s] * sim[s] + pim[s];
                *e = (a * a + b * b).sqrt();
            }
        }
    });
    if stop() {
        return Ok(None);
    }
    let envelope = Envelope {
        lines: geo.lines,
        samples,
        sample_mm: tables.dz,
        data,
    };
    let view = req.needle.as_ref().map(|n| needle_view(n, &geo, &beam));
    Ok(Some(frame::scan_convert(
        &geo,
        &req.settings,
        req.sampling.pixel_mm,
        envelope,
        view,
    )))
}

/// A scanner that honours freeze: while `settings.frozen` it returns the last live frame.
#[derive(Debug, Clone, Default)]
pub struct Scanner {
    last: Option<BModeFrame>,
}

impl Scanner {
    /// A scanner with no frame yet.
    pub fn new() -> Scanner {
        Scanner::default()
    }

    /// The next frame: a fresh one, or the held one while frozen (a frozen scanner with no frame
    /// yet computes one). Inputs are validated either way.
    pub fn scan(&mut self, req: &ScanRequest<'_>) -> Result<&BModeFrame, UltrasoundError> {
        req.geometry()?;
        if !(req.settings.frozen && self.last.is_some()) {
            self.last = Some(scan(req)?);
        }
        Ok(self.last.as_ref().expect("a frame was just stored"))
    }
}
