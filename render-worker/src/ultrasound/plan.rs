//! The CPU part of a GPU frame: everything the passes need that is computed once per frame, in
//! f64 and with sim-core's own expressions (padding, beam tables, convolution weights, the
//! lattice bounds of the deposit, the point targets, the uniforms), and the frame assembled from
//! what the passes read back.
//!
//! [`plan_frame`] runs the steps in order: [`frame_shape`], [`lateral_weights`] and the axial
//! taps, [`lattice_placement`], [`point_targets`], then [`uniforms`], which only packs what the
//! earlier steps computed into the layout of `Params` in `common.wgsl`.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use sim_core::ultrasound::needle::{
    NEEDLE_ROUGHNESS, REVERB_COUNT, REVERB_RATIO, SPECULAR_LOBE_DEG, STEEL_REFLECTION,
};
use sim_core::ultrasound::scatter::{LatticeBounds, lattice_bounds};
use sim_core::ultrasound::{
    BModeFrame, Beam, Envelope, ProbeKind, ScanGeometry, ScanRequest, needle_view,
};
use sim_core::volume::VolumeGrid;

use super::tables::{
    ELEV_REACH_FWHM, INTERFACE_LOBE_DEG, MIN_INTERFACE_R, NORMAL_STEP_MM, NP_PER_DB, Tables,
    amplitude_norm, conv_sigma, gaussian_taps, v4,
};

/// Fixed-point scale of the deposit grid: one unit is `2^-24` of a unit amplitude (simulator
/// choice). A node overflows at 128 (a hundred coincident unit point targets); tissue scatterers
/// are below 0.01 each.
pub const FIXED_POINT_SCALE: f32 = 16_777_216.0;

/// The sizes of one frame: they decide the frame buffers (a new shape makes new buffers).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Shape {
    pub(super) lines: usize,
    pub(super) samples: usize,
    /// Padding of the deposit grid on each side, lines and samples: the reach of the lateral and
    /// axial PSF (3.5 sigma, as sim-core pads).
    pub(super) pad_l: usize,
    pub(super) pad_s: usize,
    /// March steps per line.
    pub(super) n_march: usize,
    /// Scan-converted image, pixels.
    pub(super) width: usize,
    pub(super) height: usize,
}

impl Shape {
    /// Samples per padded line.
    pub(super) fn stride(&self) -> usize {
        self.samples + 2 * self.pad_s
    }

    /// Nodes of the padded deposit grid.
    pub(super) fn grid_len(&self) -> usize {
        (self.lines + 2 * self.pad_l) * self.stride()
    }
}

/// The uniforms of every pass (layout of `Params` in `common.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
pub(super) struct Params {
    geo_u: [u32; 4],
    pad_u: [u32; 4],
    geo_f: [f32; 4],
    samp_f: [f32; 4],
    lateral: [f32; 4],
    beam: [f32; 4],
    elevation: [f32; 4],
    vorigin: [f32; 4],
    inv_spacing: [f32; 4],
    dims: [u32; 4],
    axes: [u32; 4],
    seed: [u32; 4],
    idx: [i32; 4],
    n0: [i32; 4],
    /// Lattice columns across the two axes the deposit runs over (its dispatch size).
    pub(super) cols: [u32; 4],
    q_zero: [f32; 4],
    unit_a: [f32; 4],
    unit_b: [f32; 4],
    unit_m: [f32; 4],
    vlattice: [f32; 4],
    reach: [f32; 4],
    elev_beam: [f32; 4],
    display: [f32; 4],
    display_u: [u32; 4],
    display_f: [f32; 4],
    tgc_a: [f32; 4],
    tgc_b: [f32; 4],
    needle_a: [f32; 4],
    needle_b: [f32; 4],
    needle_c: [f32; 4],
    march_f: [f32; 4],
    march_u: [u32; 4],
}

/// Everything of one frame computed on the CPU before the passes.
pub(super) struct FramePlan {
    pub(super) geo: ScanGeometry,
    pub(super) beam: Beam,
    pub(super) shape: Shape,
    pub(super) params: Params,
    /// The beam tables per sample, as the shaders read them.
    pub(super) tables: Vec<[f32; 4]>,
    pub(super) lat_weights: Vec<f32>,
    pub(super) axial_taps: Vec<f32>,
    /// Weighted, phase-rotated point targets: `(line, sample, I, Q)`.
    pub(super) points: Vec<[f32; 4]>,
    /// Sample spacing along a line, mm.
    pub(super) dz: f64,
    /// Image position of pixel (0, 0), mm.
    pub(super) origin_mm: [f64; 2],
}

/// The CPU part of a frame: sim-core's padding, tables, weights and lattice bounds (the same
/// expressions as `sim_core::ultrasound::scan` and `scatter::deposit_scatterers`).
pub(super) fn plan_frame(
    req: &ScanRequest<'_>,
    geo: ScanGeometry,
    beam: Beam,
    grid: &VolumeGrid,
) -> FramePlan {
    let samples = req.sampling.samples_per_line;
    let tables = Tables::new(&beam, geo.depth_mm, samples);
    let dz = tables.dz;
    let shape = frame_shape(req, &geo, &tables);
    let lat_weights = lateral_weights(&geo, &tables, &shape);
    let axial_taps = gaussian_taps(conv_sigma(tables.axial_sigma_mm / dz), shape.pad_s);
    let lattice = lattice_placement(req, &geo, &beam, &tables, grid);
    let points = point_targets(req, &geo, &beam, &tables);
    let params = uniforms(req, &geo, &beam, &tables, &shape, &lattice, grid);
    let (x0, _, y0, _) = geo.image_extent_mm();
    FramePlan {
        geo,
        beam,
        shape,
        params,
        tables: tables.rows.iter().map(|r| r.map(|x| x as f32)).collect(),
        lat_weights,
        axial_taps,
        points,
        dz,
        origin_mm: [x0, y0],
    }
}

/// Step 1: the frame's sizes. The grid is padded by the widest lateral PSF (in lines) and the
/// axial PSF (in samples), so that the convolutions never read outside it.
fn frame_shape(req: &ScanRequest<'_>, geo: &ScanGeometry, tables: &Tables) -> Shape {
    let samples = req.sampling.samples_per_line;
    let dz = tables.dz;
    let max_lat_lines = (0..samples)
        .map(|s| tables.rows[s][2] / geo.line_spacing_mm(s as f64 * dz))
        .fold(0.0f64, f64::max);
    let (x0, x1, y0, y1) = geo.image_extent_mm();
    let pixel_mm = req.sampling.pixel_mm;
    Shape {
        lines: geo.lines,
        samples,
        pad_l: (3.5 * conv_sigma(max_lat_lines)).ceil() as usize + 1,
        pad_s: (3.5 * conv_sigma(tables.axial_sigma_mm / dz)).ceil() as usize + 1,
        n_march: (geo.depth_mm / req.sampling.march_step_mm).ceil() as usize + 1,
        width: ((x1 - x0) / pixel_mm).floor() as usize + 1,
        height: ((y1 - y0) / pixel_mm).floor() as usize + 1,
    }
}

/// Step 2: the lateral convolution's weights per padded sample (sim-core's
/// `convolve_lateral`): Gaussian taps across lines at that depth's lateral width, times its
/// lateral energy. Tap `t` of padded sample `sp` is at `t * stride + sp`.
fn lateral_weights(geo: &ScanGeometry, tables: &Tables, shape: &Shape) -> Vec<f32> {
    let (samples, pad_l, pad_s, st) = (shape.samples, shape.pad_l, shape.pad_s, shape.stride());
    let ntap = 2 * pad_l + 1;
    let mut lat_weights = vec![0f32; ntap * st];
    for sp in 0..st {
        let s = sp as isize - pad_s as isize;
        let z = s as f64 * tables.dz;
        let si = (s.max(0) as usize).min(samples - 1);
        let sig = conv_sigma(tables.rows[si][2] / geo.line_spacing_mm(z.max(0.0)));
        let taps = gaussian_taps(sig, pad_l);
        let en = tables.rows[si][3] as f32;
        for t in 0..ntap {
            lat_weights[t * st + sp] = taps[t] * en;
        }
    }
    lat_weights
}

/// Where the deposit's lattice lies relative to the probe and the medium.
struct LatticePlacement {
    bounds: LatticeBounds,
    /// Scatter cell size, mm.
    h: f64,
    /// Elevation reach, mm.
    t_e: f64,
    /// Widening of the elevation reach along a column that is not parallel to the elevation
    /// axis, mm: the column drifts across the beam as it goes.
    drift_reach_mm: f64,
    /// Region axes in the probe frame.
    unit: [DVec3; 3],
    /// The lattice point nearest the probe, in cells.
    n0: [i64; 3],
    /// That point in the probe frame, mm.
    q_zero: DVec3,
    /// Probe origin and lattice point `n0` in voxel units of the medium grid.
    vorigin: DVec3,
    vlattice: DVec3,
    /// Scatterer amplitude normalisation (sim-core's).
    norm: f64,
}

/// Step 3: the lattice cells the deposit visits, with sim-core's own bounds
/// (`scatter::lattice_bounds`) so both visit the same cells, and the reference points the GPU
/// measures positions from. Positions on the GPU are small offsets from the lattice point nearest
/// the probe, which keeps their f32 phase error small.
fn lattice_placement(
    req: &ScanRequest<'_>,
    geo: &ScanGeometry,
    beam: &Beam,
    tables: &Tables,
    grid: &VolumeGrid,
) -> LatticePlacement {
    let f = &geo.frame;
    let h = req.sampling.scatter_cell_mm;
    let (x0, x1, y0, y1) = geo.image_extent_mm();
    let t_e = ELEV_REACH_FWHM * tables.max_elev_fwhm_mm;
    let m = 1.5 * tables.max_lat_fwhm_mm + 4.0 * tables.axial_sigma_mm;
    let bounds = lattice_bounds(f, (x0 - m, x1 + m, y0 - m, y1 + m), t_e, h);
    let am = bounds.column_axis;
    let unit: [DVec3; 3] = std::array::from_fn(|a| f.to_probe(f.origin + DVec3::AXES[a]));
    let drift = unit[am].x.hypot(unit[am].y) / unit[am].z.abs();
    let lip = beam.elevation_aperture_mm / beam.elevation_focus_mm / std::f64::consts::SQRT_2;
    let wander = t_e * drift;
    let n0: [i64; 3] = std::array::from_fn(|a| (f.origin[a] / h).round() as i64);
    let n0_mm = DVec3::new(n0[0] as f64 * h, n0[1] as f64 * h, n0[2] as f64 * h);
    let spacing = DVec3::from(grid.spacing_mm);
    let grid_origin = DVec3::from(grid.origin_mm);
    LatticePlacement {
        bounds,
        h,
        t_e,
        drift_reach_mm: ELEV_REACH_FWHM * lip * wander,
        unit,
        n0,
        q_zero: f.to_probe(n0_mm),
        vorigin: (f.origin - grid_origin) / spacing,
        vlattice: (n0_mm - grid_origin) / spacing,
        norm: amplitude_norm(beam, tables, h),
    }
}

/// Step 4: the point targets of the request, weighted by the elevation profile and
/// phase-rotated here in f64 (as sim-core's `scan` does), as `(line, sample, I, Q)`.
fn point_targets(
    req: &ScanRequest<'_>,
    geo: &ScanGeometry,
    beam: &Beam,
    tables: &Tables,
) -> Vec<[f32; 4]> {
    let f = &geo.frame;
    let k0 = 2.0 * std::f64::consts::PI / beam.wavelength_mm();
    req.targets
        .iter()
        .map(|t| {
            let q = f.to_probe(t.position_mm);
            let (u, z) = geo.plane_to_line(q.x, q.y);
            let w = t.amplitude * tables.elevation_weight(q.z, z);
            let (sn, cs) = (2.0 * k0 * z).sin_cos();
            [
                u as f32,
                (z / tables.dz) as f32,
                (w * cs) as f32,
                (w * sn) as f32,
            ]
        })
        .collect()
}

/// Step 5: the uniforms, packed from the steps above and the request's settings.
fn uniforms(
    req: &ScanRequest<'_>,
    geo: &ScanGeometry,
    beam: &Beam,
    tables: &Tables,
    shape: &Shape,
    lattice: &LatticePlacement,
    grid: &VolumeGrid,
) -> Params {
    let f = &geo.frame;
    let (dz, step) = (tables.dz, req.sampling.march_step_mm);
    let (pad_l, pad_s) = (shape.pad_l, shape.pad_s);
    let (x0, _, y0, _) = geo.image_extent_mm();
    let LatticeBounds {
        lo_cell,
        hi_cell,
        column_axis: am,
        across: (aa, ab),
    } = lattice.bounds;
    let (n0, unit) = (lattice.n0, lattice.unit);
    let (needle_a, needle_b) = match &req.needle {
        Some(n) => (
            v4(n.hub_mm - f.origin, n.diameter_mm),
            v4(n.tip_mm - n.hub_mm, 0.0),
        ),
        None => ([0.0; 4], [0.0; 4]),
    };
    let tgc = req.settings.tgc_db;
    let i32_of = |x: i64| x.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
    Params {
        geo_u: [
            u32::from(geo.spec.kind == ProbeKind::Curvilinear),
            geo.lines as u32,
            shape.samples as u32,
            shape.n_march as u32,
        ],
        pad_u: [
            pad_l as u32,
            pad_s as u32,
            shape.stride() as u32,
            (geo.lines + 2 * pad_l) as u32,
        ],
        geo_f: [
            geo.spec.footprint_mm as f32,
            geo.spec.radius_mm as f32,
            geo.half_sector_rad() as f32,
            geo.depth_mm as f32,
        ],
        samp_f: [
            dz as f32,
            step as f32,
            (2.0 / beam.wavelength_mm()) as f32,
            tables.axial_sigma_mm as f32,
        ],
        lateral: v4(f.lateral, 0.0),
        beam: v4(f.beam, 0.0),
        elevation: v4(f.elevation, 0.0),
        vorigin: v4(lattice.vorigin, 0.0),
        inv_spacing: v4(DVec3::ONE / DVec3::from(grid.spacing_mm), 0.0),
        dims: [
            grid.dims[0] as u32,
            grid.dims[1] as u32,
            grid.dims[2] as u32,
            0,
        ],
        axes: [aa as u32, ab as u32, am as u32, 0],
        seed: [
            req.seed as u32,
            (req.seed >> 32) as u32,
            FIXED_POINT_SCALE.to_bits(),
            0,
        ],
        idx: [
            i32_of(lo_cell[aa]),
            i32_of(lo_cell[ab]),
            i32_of(lo_cell[am]),
            i32_of(hi_cell[am]),
        ],
        n0: [i32_of(n0[0]), i32_of(n0[1]), i32_of(n0[2]), 0],
        cols: [
            (hi_cell[aa] - lo_cell[aa] + 1).max(0) as u32,
            (hi_cell[ab] - lo_cell[ab] + 1).max(0) as u32,
            0,
            0,
        ],
        q_zero: v4(lattice.q_zero, lattice.h),
        unit_a: v4(unit[aa], 0.0),
        unit_b: v4(unit[ab], 0.0),
        unit_m: v4(unit[am], 0.0),
        vlattice: v4(lattice.vlattice, 0.0),
        reach: [
            lattice.t_e as f32,
            lattice.drift_reach_mm as f32,
            pad_l as f32,
            (pad_s as f64 * dz) as f32,
        ],
        elev_beam: [
            beam.wavelength_mm() as f32,
            beam.elevation_focus_mm as f32,
            beam.elevation_aperture_mm as f32,
            lattice.norm as f32,
        ],
        display: [
            req.sampling.pixel_mm as f32,
            x0 as f32,
            y0 as f32,
            req.settings.gain_db as f32,
        ],
        display_u: [shape.width as u32, shape.height as u32, 0, 0],
        display_f: [
            req.settings.dynamic_range_db as f32,
            (geo.depth_mm / sim_core::ultrasound::TGC_BANDS as f64) as f32,
            0.0,
            0.0,
        ],
        tgc_a: [tgc[0] as f32, tgc[1] as f32, tgc[2] as f32, tgc[3] as f32],
        tgc_b: [tgc[4] as f32, tgc[5] as f32, 0.0, 0.0],
        needle_a,
        needle_b,
        needle_c: [
            STEEL_REFLECTION as f32,
            SPECULAR_LOBE_DEG.to_radians() as f32,
            NEEDLE_ROUGHNESS as f32,
            REVERB_RATIO as f32,
        ],
        march_f: [
            MIN_INTERFACE_R as f32,
            INTERFACE_LOBE_DEG.to_radians() as f32,
            NORMAL_STEP_MM as f32,
            (2.0 * beam.frequency_mhz * step * 0.1 * NP_PER_DB) as f32,
        ],
        march_u: [
            REVERB_COUNT as u32,
            sim_core::ultrasound::sphere_directions().len() as u32,
            0,
            0,
        ],
    }
}

/// The frame from the read-back envelope and pixel words.
pub(super) fn finish_frame(
    req: &ScanRequest<'_>,
    plan: &FramePlan,
    envelope: Vec<f32>,
    words: &[u32],
) -> BModeFrame {
    let s = plan.shape;
    BModeFrame {
        width: s.width,
        height: s.height,
        pixel_mm: req.sampling.pixel_mm,
        origin_mm: plan.origin_mm,
        pixels: words.iter().map(|&w| (w & 0xFF) as u8).collect(),
        inside: words.iter().map(|&w| w & 0x100 != 0).collect(),
        envelope: Envelope {
            lines: s.lines,
            samples: s.samples,
            sample_mm: plan.dz,
            data: envelope,
        },
        needle: req
            .needle
            .as_ref()
            .map(|n| needle_view(n, &plan.geo, &plan.beam)),
        settings: req.settings,
    }
}
