// Shared by every ultrasound kernel: the frame's uniforms, 64-bit hashing on 32-bit words,
// the scan geometry (sim_core::ultrasound::probe) and the per-sample beam tables.

struct Params {
    // kind (0 linear, 1 curvilinear), lines, samples, n_march
    geo_u: vec4<u32>,
    // pad_l, pad_s, stride (samples + 2 pad_s), total_lines (lines + 2 pad_l)
    pad_u: vec4<u32>,
    // footprint_mm, radius_mm, half_sector_rad, depth_mm
    geo_f: vec4<f32>,
    // dz_mm, march_step_mm, 2 / wavelength (carrier turns per mm of depth), axial_sigma_mm
    samp_f: vec4<f32>,
    // probe axes in the region frame (xyz)
    lateral: vec4<f32>,
    beam: vec4<f32>,
    elevation: vec4<f32>,
    // (probe origin - grid origin) / spacing (voxel units)
    vorigin: vec4<f32>,
    // 1 / spacing_mm per axis
    inv_spacing: vec4<f32>,
    // nx, ny, nz, 0
    dims: vec4<u32>,
    // lattice: aa, ab, am, 0
    axes: vec4<u32>,
    // seed lo, seed hi, fixed-point scale bits (f32), 0
    seed: vec4<u32>,
    // lattice index of the column origin: ia_lo, ib_lo, k_lo (absolute, axis am), k_hi
    idx: vec4<i32>,
    // n0 (lattice index near the probe origin, per region axis), 0
    n0: vec4<i32>,
    // lattice columns along aa and ab, 0, 0
    cols: vec4<u32>,
    // q_zero: probe-frame coordinates of lattice point n0 (xyz), cell_mm (w)
    q_zero: vec4<f32>,
    // probe-frame images of the region axes aa, ab, am (xyz)
    unit_a: vec4<f32>,
    unit_b: vec4<f32>,
    unit_m: vec4<f32>,
    // (n0 h - grid origin) / spacing (voxel units)
    vlattice: vec4<f32>,
    // t_e, lip * wander, reach_u (lines), reach_s (mm)
    reach: vec4<f32>,
    // elevation beam: wavelength_mm, elevation_focus_mm, elevation_aperture_mm, amplitude norm
    elev_beam: vec4<f32>,
    // display: pixel_mm, x0, y0, gain_db
    display: vec4<f32>,
    // display: width, height, 0, 0
    display_u: vec4<u32>,
    // dynamic_range_db, tgc band (depth / bands), 0, 0
    display_f: vec4<f32>,
    tgc_a: vec4<f32>,
    tgc_b: vec4<f32>,
    // needle: hub - probe origin (xyz), diameter (w; 0 = no needle)
    needle_a: vec4<f32>,
    // needle: tip - hub (xyz), 0
    needle_b: vec4<f32>,
    // steel reflection, specular lobe rad, needle roughness, reverb ratio
    needle_c: vec4<f32>,
    // min interface R, interface lobe rad, normal step mm, attenuation factor (2 f 0.1 Np/dB)
    march_f: vec4<f32>,
    // reverb count, sphere directions, 0, 0
    march_u: vec4<u32>,
}

// ---- 64-bit words as vec2<u32>(lo, hi) ----

fn mul32(a: u32, b: u32) -> vec2<u32> {
    let a0 = a & 0xFFFFu;
    let a1 = a >> 16u;
    let b0 = b & 0xFFFFu;
    let b1 = b >> 16u;
    let p00 = a0 * b0;
    let p01 = a0 * b1;
    let p10 = a1 * b0;
    let p11 = a1 * b1;
    let mid = (p00 >> 16u) + (p01 & 0xFFFFu) + (p10 & 0xFFFFu);
    let lo = (p00 & 0xFFFFu) | (mid << 16u);
    let hi = p11 + (p01 >> 16u) + (p10 >> 16u) + (mid >> 16u);
    return vec2<u32>(lo, hi);
}

fn mul64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let p = mul32(a.x, b.x);
    return vec2<u32>(p.x, p.y + a.x * b.y + a.y * b.x);
}

fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

fn shr64(a: vec2<u32>, n: u32) -> vec2<u32> {
    return vec2<u32>((a.x >> n) | (a.y << (32u - n)), a.y >> n);
}

// sim_core::rng::splitmix64: mix(x + GOLDEN_GAMMA) with Vigna's finaliser.
fn splitmix64(x: vec2<u32>) -> vec2<u32> {
    var z = add64(x, vec2<u32>(0x7F4A7C15u, 0x9E3779B9u));
    z = mul64(z ^ shr64(z, 30u), vec2<u32>(0x1CE4E5B9u, 0xBF58476Du));
    z = mul64(z ^ shr64(z, 27u), vec2<u32>(0x133111EBu, 0x94D049BBu));
    return z ^ shr64(z, 31u);
}

// An i64 lattice index as a u64 word (two's complement).
fn word_of(i: i32) -> vec2<u32> {
    return vec2<u32>(bitcast<u32>(i), select(0u, 0xFFFFFFFFu, i < 0));
}

// sim_core scatter::cell_hash.
fn cell_hash(seed: vec2<u32>, i: i32, j: i32, k: i32) -> vec2<u32> {
    return splitmix64(splitmix64(splitmix64(seed ^ word_of(i)) ^ word_of(j)) ^ word_of(k));
}

// sim_core scatter::iq_of_hash: signed I and Q, each the sum of two 16-bit uniforms minus 1.
fn iq_of_hash(x: vec2<u32>) -> vec2<f32> {
    let s = 1.0 / 65536.0;
    let i = f32(x.x & 0xFFFFu) * s + f32(x.x >> 16u) * s - 1.0;
    let q = f32(x.y & 0xFFFFu) * s + f32(x.y >> 16u) * s - 1.0;
    return vec2<f32>(i, q);
}

// sim_core::rng::unit_f64 to f32 precision: the top bits as a uniform in [0, 1).
fn unit_of(x: vec2<u32>) -> f32 {
    return f32(x.y >> 8u) * (1.0 / 16777216.0);
}

// ---- geometry (sim_core ultrasound::probe::ScanGeometry) ----

fn lines_max(p: Params) -> f32 {
    return f32(max(p.geo_u.y, 2u) - 1u);
}

// (fractional line, depth mm) of an in-plane point.
fn plane_to_line(p: Params, x: f32, y: f32) -> vec2<f32> {
    let n = lines_max(p);
    if (p.geo_u.x == 0u) {
        return vec2<f32>((x / p.geo_f.x + 0.5) * n, y);
    }
    let r0 = p.geo_f.y;
    let yc = y + r0;
    let theta = atan2(x, yc);
    let r = sqrt(x * x + yc * yc);
    return vec2<f32>((theta / p.geo_f.z + 1.0) * 0.5 * n, r - r0);
}

// Start point (xy) and unit direction (zw) in the image plane of fractional line u.
fn line_in_plane(p: Params, u: f32) -> vec4<f32> {
    let t = u / f32(p.geo_u.y - 1u);
    if (p.geo_u.x == 0u) {
        return vec4<f32>((t - 0.5) * p.geo_f.x, 0.0, 0.0, 1.0);
    }
    let c = (2.0 * t - 1.0) * p.geo_f.z;
    let r = p.geo_f.y;
    let s = sin(c);
    let co = cos(c);
    return vec4<f32>(r * s, r * co - r, s, co);
}

// Nearest sample of depth z (clamped), as BeamTables::sample_of.
fn sample_of(p: Params, z: f32) -> u32 {
    return min(u32(max(z / p.samp_f.x + 0.5, 0.0)), p.geo_u.z - 1u);
}

// exp(-x) for x >= 0, zero from 16 on (as scatter::exp_neg).
fn exp_neg(x: f32) -> f32 {
    if (!(x < 16.0)) {
        return 0.0;
    }
    return exp(-max(x, 0.0));
}

// (cos, sin) of the two-way carrier phase 2 k z, reduced in turns first.
fn carrier(p: Params, z: f32) -> vec2<f32> {
    let turns = z * p.samp_f.z;
    let a = 6.2831853 * (turns - floor(turns));
    return vec2<f32>(cos(a), sin(a));
}

// Elevation FWHM (Beam::elevation_fwhm_mm).
fn elevation_fwhm(p: Params, z: f32) -> f32 {
    let lambda = p.elev_beam.x;
    let ze = p.elev_beam.y;
    let de = p.elev_beam.z;
    let focal = lambda * ze / de;
    let cone = de * (z - ze) / ze;
    return sqrt(focal * focal + cone * cone) * 0.70710678;
}
