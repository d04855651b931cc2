// Pass 1: the lattice scatterers (sim_core ultrasound::scatter::deposit_scatterers), one
// invocation per lattice column along the axis `am` closest to the elevation direction, and the
// point targets. Deposits are bilinear into a padded (line, sample) grid of fixed-point I/Q
// (integer atomics: the sum does not depend on the order, so frames repeat bit for bit).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(3) var<storage, read> tables: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> grid_re: array<atomic<i32>>;
@group(0) @binding(5) var<storage, read_write> grid_im: array<atomic<i32>>;
@group(0) @binding(6) var<storage, read> points: array<vec4<f32>>;

// Fascicle honeycomb (sim_core scatter::fascicle_factor without a fibre axis: blobs on a 3D
// lattice, no anisotropy); constants from sim_core via the override values.
override fascicle_cell_mm: f32;
override fascicle_radius_mm: f32;
override fascicle_inside: f32;
override fascicle_outside: f32;

// Adds the four weights of one bilinear footprint at padded node (u0, s0) in fixed point.
fn flush(u0: u32, s0: u32, acc: array<vec2<f32>, 4>) {
    let st = P.pad_u.z;
    let scale = bitcast<f32>(P.seed.z);
    for (var n = 0u; n < 4u; n++) {
        let i = (u0 + n / 2u) * st + s0 + n % 2u;
        let v = acc[n] * scale;
        atomicAdd(&grid_re[i], i32(round(v.x)));
        atomicAdd(&grid_im[i], i32(round(v.y)));
    }
}

// The padded node and bilinear weights of unpadded (u, s), or node.x = 0xFFFFFFFF off the grid
// (IqGrid::deposit).
struct Footprint {
    node: vec2<u32>,
    w: vec4<f32>,
}

fn footprint(u: f32, s: f32) -> Footprint {
    let off = Footprint(vec2<u32>(0xFFFFFFFFu, 0u), vec4<f32>(0.0));
    let up = u + f32(P.pad_u.x);
    let sp = s + f32(P.pad_u.y);
    if (!(up >= 0.0 && sp >= 0.0)) {
        return off;
    }
    let u0 = u32(up);
    let s0 = u32(sp);
    if (u0 + 1u >= P.pad_u.w || s0 + 1u >= P.pad_u.z) {
        return off;
    }
    let fu = up - f32(u0);
    let fs = sp - f32(s0);
    return Footprint(vec2<u32>(u0, s0), vec4<f32>((1.0 - fu) * (1.0 - fs), (1.0 - fu) * fs, fu * (1.0 - fs), fu * fs));
}

fn fascicle_factor(pos: vec3<f32>, seed: vec2<u32>) -> f32 {
    let c = fascicle_cell_mm;
    let cell = floor(pos / c);
    var best = 1e30;
    let fseed = seed ^ vec2<u32>(0xF45C1C1Eu, 0u);
    for (var i = -1; i <= 1; i++) {
        for (var j = -1; j <= 1; j++) {
            for (var k = -1; k <= 1; k++) {
                let n = cell + vec3<f32>(f32(i), f32(j), f32(k));
                let h = cell_hash(fseed, i32(n.x), i32(n.y), i32(n.z));
                let jxy = iq_of_hash(h);
                let jz = unit_of(splitmix64(h)) - 0.5;
                let centre = (n + vec3<f32>(0.5 + 0.4 * jxy.x, 0.5 + 0.4 * jxy.y, 0.5 + jz * 0.8)) * c;
                best = min(best, length(pos - centre));
            }
        }
    }
    return select(fascicle_outside, fascicle_inside, best < fascicle_radius_mm);
}

@compute @workgroup_size(8, 8)
fn deposit_lattice(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= P.cols.x || id.y >= P.cols.y) {
        return;
    }
    let ia = P.idx.x + i32(id.x);
    let ib = P.idx.y + i32(id.y);
    let n0 = P.n0.xyz;
    let aa = P.axes.x;
    let ab = P.axes.y;
    let am = P.axes.z;
    let h = P.q_zero.w;
    let seed = P.seed.xy;
    let um = P.unit_m.xyz;
    let em = um.z;
    // Lattice point (ia, ib, n0[am]) in the probe frame, from small relative indices.
    let c0 = P.q_zero.xyz + P.unit_a.xyz * (f32(ia - n0[aa]) * h) + P.unit_b.xyz * (f32(ib - n0[ab]) * h);
    // Where the column crosses the slice, and the elevation reach at that depth.
    let qc = c0 - um * (c0.z / em);
    let zc = plane_to_line(P, qc.x, qc.y).y;
    let depth = P.geo_f.w;
    let t_col = min(elevation_fwhm(P, clamp(zc, 0.0, depth)) + P.reach.y, P.reach.x);
    var a = (-t_col - c0.z) / em;
    var b = (t_col - c0.z) / em;
    if (a > b) {
        let t = a;
        a = b;
        b = t;
    }
    let k_lo = max(i32(ceil(a / h)), P.idx.z - n0[am]);
    let k_hi = min(i32(floor(b / h)), P.idx.w - n0[am]);
    if (k_lo > k_hi) {
        return;
    }
    // The hash's per-column prefix (cell_hash nests the indices x, y, z in that order).
    var prefix = seed;
    var idx = vec3<i32>(0);
    idx[aa] = ia;
    idx[ab] = ib;
    if (am == 2u) {
        prefix = splitmix64(splitmix64(seed ^ word_of(idx.x)) ^ word_of(idx.y));
    } else if (am == 1u) {
        prefix = splitmix64(seed ^ word_of(idx.x));
    }
    let lines_mx = f32(P.geo_u.y - 1u);
    let reach_u = P.reach.z;
    let reach_s = P.reach.w;
    let dz = P.samp_f.x;
    let norm = P.elev_beam.w;
    // Consecutive cells of a column usually share their footprint's node (exactly, when the
    // lattice axis is the elevation axis): sum there and flush when it changes.
    var node = vec2<u32>(0xFFFFFFFFu, 0u);
    var acc = array<vec2<f32>, 4>(vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0));
    // What depends only on the in-plane position, reused while it repeats (it does along a
    // column parallel to the elevation axis).
    var last_uz = vec2<f32>(1e30);
    var tab = vec4<f32>(0.0);
    var cs = vec2<f32>(0.0);
    var fp = Footprint(vec2<u32>(0xFFFFFFFFu, 0u), vec4<f32>(0.0));
    // The tissue and its amplitude, reused while the voxel repeats.
    var last_voxel = 0xFFFFFFFEu;
    var tissue = tissue_of(0xFFFFFFFFu);
    var amp = 0.0;
    var rel = vec3<f32>(0.0);
    rel[aa] = f32(ia - n0[aa]) * h;
    rel[ab] = f32(ib - n0[ab]) * h;
    for (var kk = k_lo; kk <= k_hi; kk++) {
        let q = c0 + um * (f32(kk) * h);
        let uz = plane_to_line(P, q.x, q.y);
        let u = uz.x;
        let z = uz.y;
        if (!(u >= -reach_u && u <= lines_mx + reach_u && z >= -reach_s && z <= depth + reach_s)) {
            continue;
        }
        let k = n0[am] + kk;
        var hsh: vec2<u32>;
        if (am == 2u) {
            hsh = splitmix64(prefix ^ word_of(k));
        } else if (am == 1u) {
            hsh = splitmix64(splitmix64(prefix ^ word_of(k)) ^ word_of(idx.z));
        } else {
            hsh = cell_hash(seed, k, idx.y, idx.z);
        }
        rel[am] = f32(kk) * h;
        let voxel = voxel_index(P, P.vlattice.xyz + rel * P.inv_spacing.xyz);
        if (voxel != last_voxel) {
            last_voxel = voxel;
            tissue = tissue_of(voxel);
            amp = norm * exp2(tissue.a.z * 0.16609640); // 10^(dB/20) = 2^(dB log2(10) / 20)
        }
        let density = tissue.a.w;
        if (density < 1.0) {
            if (unit_of(splitmix64(hsh)) >= density) {
                continue;
            }
        }
        if (any(uz != last_uz)) {
            last_uz = uz;
            tab = tables[sample_of(P, z)];
            cs = carrier(P, z);
            fp = footprint(u, z / dz);
        }
        if (fp.node.x == 0xFFFFFFFFu) {
            continue;
        }
        var w = amp * exp_neg(q.z * q.z * tab.x) * tab.y;
        if (tissue.b.y > 0.5) {
            var cell = vec3<i32>(0);
            cell[aa] = ia;
            cell[ab] = ib;
            cell[am] = k;
            w *= fascicle_factor(vec3<f32>(cell) * h, seed);
        }
        let ciq = iq_of_hash(hsh);
        let re = ciq.x * cs.x - ciq.y * cs.y;
        let im = ciq.x * cs.y + ciq.y * cs.x;
        if (any(fp.node != node)) {
            if (node.x != 0xFFFFFFFFu) {
                flush(node.x, node.y, acc);
            }
            node = fp.node;
            acc = array<vec2<f32>, 4>(vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0), vec2<f32>(0.0));
        }
        let v = vec2<f32>(re * w, im * w);
        acc[0] += v * fp.w.x;
        acc[1] += v * fp.w.y;
        acc[2] += v * fp.w.z;
        acc[3] += v * fp.w.w;
    }
    if (node.x != 0xFFFFFFFFu) {
        flush(node.x, node.y, acc);
    }
}

// Point targets, already weighted and phase-rotated on the CPU: (u, s, re, im).
@compute @workgroup_size(64)
fn deposit_points(@builtin(global_invocation_id) id: vec3<u32>) {
    if (id.x >= arrayLength(&points)) {
        return;
    }
    let t = points[id.x];
    let fp = footprint(t.x, t.y);
    if (fp.node.x == 0xFFFFFFFFu) {
        return;
    }
    let v = t.zw;
    flush(fp.node.x, fp.node.y, array<vec2<f32>, 4>(v * fp.w.x, v * fp.w.y, v * fp.w.z, v * fp.w.w));
}
