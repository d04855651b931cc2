// Pass 4: one invocation per scan line (sim_core ultrasound::echo::march_line): interface
// echoes weighted by beam/normal alignment, transmission 1 - R^2, two-way attenuation, the
// needle (specular shaft, reverberation tail, shadow), then the envelope of
// gain x speckle + echoes at every sample.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(3) var<storage, read> tables: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read> speckle: array<vec2<f32>>;
@group(0) @binding(11) var<storage, read> sphere: array<vec4<f32>>;
// log gain per march step: lines x n_march
@group(0) @binding(12) var<storage, read_write> log_gain: array<f32>;
// specular echoes: lines x samples
@group(0) @binding(13) var<storage, read_write> echo: array<vec2<f32>>;
@group(0) @binding(14) var<storage, read_write> envelope: array<f32>;

const FWHM_PER_SIGMA: f32 = 2.3548200;

// Air within gel_max_mm of the face is coupling gel (sim_core ultrasound::echo::coupled).
override gel_max_mm: f32;
override air_below_mrayl: f32;

fn coupled(t: Tissue, z: f32) -> Tissue {
    if (t.a.x < air_below_mrayl && z <= gel_max_mm) {
        return lut_row(GEL_ROW);
    }
    return t;
}

fn voxel_of(rel: vec3<f32>) -> vec3<f32> {
    return P.vorigin.xyz + rel * P.inv_spacing.xyz;
}

// A pulse of the axial PSF at depth z, evaluated at the samples (LineEchoes::pulse).
fn pulse(row: u32, z: f32, amp: f32) {
    let cs = carrier(P, z);
    let sigma = P.samp_f.w;
    let reach = 4.0 * sigma;
    let dz = P.samp_f.x;
    let n = P.geo_u.z;
    let s0 = u32(max(ceil((z - reach) / dz), 0.0));
    let s1 = u32(max(floor((z + reach) / dz), -1.0) + 1.0);
    for (var i = s0; i < min(s1, n); i++) {
        let d = f32(i) * dz - z;
        let g = amp * exp_neg(d * d / (2.0 * sigma * sigma));
        echo[row + i] += g * cs;
    }
}

// Diffuse roughness plus a Gaussian lobe in the angle between the beam and the impedance
// gradient from a sphere of directions (echo::alignment).
fn alignment(rel: vec3<f32>, d: vec3<f32>, roughness: f32) -> f32 {
    let h = P.march_f.z;
    var g = vec3<f32>(0.0);
    for (var i = 0u; i < P.march_u.y; i++) {
        let u = sphere[i].xyz;
        g += u * tissue_at(P, voxel_of(rel + u * h)).a.x;
    }
    var c = 1.0;
    let len = length(g);
    if (len > 0.0 && len < 1e30) {
        c = min(abs(dot(g / len, d)), 1.0);
    }
    let theta = acos(c);
    let lobe = P.march_f.y;
    return roughness + (1.0 - roughness) * exp(-(theta * theta) / (2.0 * lobe * lobe));
}

struct Hit {
    z: f32,
    overlap: f32,
    specular: f32,
    ok: bool,
}

// Closest approach of the line (o, d) and the shaft (needle::line_hit).
fn line_hit(o: vec3<f32>, d: vec3<f32>) -> Hit {
    var none = Hit(0.0, 0.0, 0.0, false);
    let diameter = P.needle_a.w;
    if (diameter <= 0.0) {
        return none;
    }
    let depth = P.geo_f.w;
    let a = P.needle_a.xyz;
    let ab = P.needle_b.xyz;
    let len2 = dot(ab, ab);
    let w0 = o - a;
    let b = dot(d, ab);
    let dd = dot(d, w0);
    let e = dot(ab, w0);
    let f = len2;
    let denom = f - b * b;
    var s = 0.0;
    if (denom > 1e-12) {
        s = clamp((e - b * dd) / denom, 0.0, 1.0);
    }
    var z = clamp(s * b - dd, 0.0, depth);
    s = clamp((z * b + e) / f, 0.0, 1.0);
    z = clamp(s * b - dd, 0.0, depth);
    let v = a + ab * s - (o + d * z);
    let elev = P.elevation.xyz;
    let ev = dot(v, elev);
    let lv = length(v - d * dot(v, d) - elev * ev);
    let r = 0.5 * diameter;
    let se = elevation_fwhm(P, z) / FWHM_PER_SIGMA;
    let sl = tables[sample_of(P, z)].z;
    let ee = max(abs(ev) - r, 0.0);
    let ll = max(lv - r, 0.0);
    let overlap = exp(-(ee * ee) / (2.0 * se * se) - (ll * ll) / (2.0 * sl * sl));
    if (overlap < 1e-3) {
        return none;
    }
    let u = ab / sqrt(len2);
    let psi = asin(min(abs(dot(d, u)), 1.0));
    let lobe = P.needle_c.y;
    let rough = P.needle_c.z;
    let specular = rough + (1.0 - rough) * exp(-(psi * psi) / (2.0 * lobe * lobe));
    return Hit(z, overlap, specular, true);
}

@compute @workgroup_size(8)
fn march(@builtin(global_invocation_id) id: vec3<u32>) {
    let j = id.x;
    let lines = P.geo_u.y;
    if (j >= lines) {
        return;
    }
    let n = P.geo_u.z;
    let n_march = P.geo_u.w;
    let row = j * n;
    let lrow = j * n_march;
    for (var i = 0u; i < n; i++) {
        echo[row + i] = vec2<f32>(0.0);
    }
    let lp = line_in_plane(P, f32(j));
    let o = P.lateral.xyz * lp.x + P.beam.xyz * lp.y;
    let d = P.lateral.xyz * lp.z + P.beam.xyz * lp.w;
    let hit = line_hit(o, d);
    let step = P.samp_f.y;
    let steel = P.needle_c.x;
    let min_r = P.march_f.x;
    var log_t = 0.0;
    var loss = 0.0;
    var prev = coupled(tissue_at(P, voxel_of(o)), 0.0);
    var needle_done = !hit.ok;
    log_gain[lrow] = 0.0;
    for (var k = 1u; k < n_march; k++) {
        let z = f32(k) * step;
        let cur = coupled(tissue_at(P, voxel_of(o + d * z)), z);
        let zm = z - 0.5 * step;
        if (!needle_done && hit.z <= z) {
            needle_done = true;
            let g = exp(log_t - loss);
            let amp = steel * hit.specular * hit.overlap * g;
            var ar = amp;
            for (var r = 0u; r <= P.march_u.x; r++) {
                pulse(row, hit.z + f32(r) * P.needle_a.w, ar);
                ar *= P.needle_c.w;
            }
            log_t += log(max(1.0 - hit.overlap * steel * steel, 1e-12));
        }
        let z1 = prev.a.x;
        let z2 = cur.a.x;
        let r = (z2 - z1) / (z2 + z1);
        if (abs(r) >= min_r) {
            let w = alignment(o + d * zm, d, max(prev.b.x, cur.b.x));
            pulse(row, zm, r * w * exp(log_t - loss));
        }
        log_t += log(max(1.0 - r * r, 1e-12));
        loss += 0.5 * (prev.a.y + cur.a.y) * P.march_f.w;
        log_gain[lrow + k] = log_t - loss;
        prev = cur;
    }
    let dz = P.samp_f.x;
    for (var s = 0u; s < n; s++) {
        let x = f32(s) * dz / step;
        let i = min(u32(x), n_march - 2u);
        let fr = x - f32(i);
        let g = exp(log_gain[lrow + i] * (1.0 - fr) + log_gain[lrow + i + 1u] * fr);
        let sp = speckle[row + s];
        let e = echo[row + s];
        let a = g * sp + e;
        envelope[row + s] = sqrt(a.x * a.x + a.y * a.y);
    }
}
