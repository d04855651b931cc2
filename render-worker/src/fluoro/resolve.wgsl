// Resolve pass: L-buffer channels to chords (steel subtraction, cancellous clamp), basis optical
// depths, iodine column, and the spectral sum T = sum_E w_E exp(-sum_b A_b R_b(E)).

struct Params {
    // Ray generator (relative to the source), mm: pixel (0, 0) centre, per-column, per-row step.
    p00: vec4<f32>,
    step_u: vec4<f32>,
    step_v: vec4<f32>,
    // Focal spot, mm.
    source: vec4<f32>,
    // Collimator blades in the detector plane, mm: x_min, x_max, y_min, y_max.
    blades: vec4<f32>,
    // (iris radius squared mm^2 or -1, column pitch mm, row pitch mm, cortical shell mm).
    misc: vec4<f32>,
    // (columns, rows, spectral bins, iodine present); w is unread (the pipeline variant decides).
    dims: vec4<u32>,
    // 60 keV coefficients per cm: cortical, cancellous, steel, stock iodine.
    mu: vec4<f32>,
    // Iodine grid: origin of voxel (0,0,0) centre mm (w: march step mm), 1 / spacing per mm,
    // dimensions.
    iod_origin: vec4<f32>,
    iod_inv_spacing: vec4<f32>,
    iod_dims: vec4<u32>,
    // ln T table over (A_water, A_bone): 1 / step per axis; (columns, rows, enabled, 0).
    lut_scale: vec4<f32>,
    // Sampled region: (first pixel column, first row, 1 / samples per pixel axis, 0); sample
    // (i, j) is at continuous pixel coordinates first + (i + 0.5, j + 0.5) / n.
    region: vec4<f32>,
    // Whole detector (columns, rows, needle present, 0); z is unread (the pipeline variant
    // decides, see `resolve_sample`).
    full: vec4<u32>,
    lut_dims: vec4<u32>,
    // Resolved rectangle of samples: (first column, first row, columns, rows). Unread here (the
    // pass's scissor rectangles select the samples); kept for the layout.
    rect: vec4<u32>,
    // The projection's depth row: w = row_w . (point - source), the L-buffer's axial depth.
    row_w: vec4<f32>,
}

// Pipeline constant: false builds the resolve without the iodine ray march (frames without a
// contrast field). A SIMD implementation runs a branch whose condition is a uniform value for
// every invocation, masked, even when no invocation takes it (lavapipe spent about a quarter of
// the resolve there); a pipeline without the branch does not.
override has_iodine: bool = true;
// Pipeline constant: false builds the resolve without the needle's inputs (its chord and the
// displaced L-buffer, both zero outside the needle's pixel box), for the rest of the image.
override has_needle: bool = true;

@group(0) @binding(0) var<uniform> params: Params;
// (water-basis mu_60 L, bone-basis mu_60 L, cortical L, cancellous L), mm / cm, in axial depth
// (times (row_w . d) / |d| along the sample's ray d; see `fs_anatomy`).
@group(0) @binding(1) var lbuf: texture_2d<f32>;
@group(0) @binding(2) var needle_chord: texture_2d<f32>;
// Per bin: (R_water, R_bone, R_iodine, R_iron) * log2(e), then (w_E, 0, 0, 0).
@group(0) @binding(3) var<storage, read> bins: array<vec4<f32>>;
@group(0) @binding(4) var iodine: texture_3d<f32>;
@group(0) @binding(5) var<storage, read_write> out_t: array<f32>;
// ln T on a grid of (A_water, A_bone), row-major with A_water fastest.
@group(0) @binding(6) var<storage, read> lut: array<f32>;
// Displaced part of the L-buffer (zero outside the needle's pixel box), added to `lbuf`.
@group(0) @binding(7) var dbuf: texture_2d<f32>;
// The scalar meshes' water-basis channel (axial depth, like `lbuf`), added to `lbuf.x`.
@group(0) @binding(8) var sbuf: texture_2d<f32>;

fn voxel(c: vec3<i32>) -> f32 {
    return textureLoad(iodine, c, 0).x;
}

// Trilinear stock fraction at continuous voxel coordinates inside the box of voxel centres.
fn trilinear(v: vec3<f32>) -> f32 {
    let dims = vec3<i32>(params.iod_dims.xyz);
    let top = max(dims - vec3<i32>(2), vec3<i32>(0));
    let c = clamp(vec3<i32>(floor(v)), vec3<i32>(0), top);
    let f = select(vec3<f32>(0.0), clamp(v - vec3<f32>(c), vec3<f32>(0.0), vec3<f32>(1.0)), dims > vec3<i32>(1));
    let n = select(vec3<i32>(0), vec3<i32>(1), dims > vec3<i32>(1));
    let c000 = voxel(c);
    let c100 = voxel(c + vec3<i32>(n.x, 0, 0));
    let c010 = voxel(c + vec3<i32>(0, n.y, 0));
    let c110 = voxel(c + vec3<i32>(n.x, n.y, 0));
    let c001 = voxel(c + vec3<i32>(0, 0, n.z));
    let c101 = voxel(c + vec3<i32>(n.x, 0, n.z));
    let c011 = voxel(c + vec3<i32>(0, n.y, n.z));
    let c111 = voxel(c + n);
    let x00 = mix(c000, c100, f.x);
    let x10 = mix(c010, c110, f.x);
    let x01 = mix(c001, c101, f.x);
    let x11 = mix(c011, c111, f.x);
    return mix(mix(x00, x10, f.y), mix(x01, x11, f.y), f.z);
}

// Stock-equivalent iodine column along source + t * dir (dir unit), 0 <= t <= t_max, by the
// midpoint rule with steps of at most params.iod_origin.w mm.
fn iodine_column(dir: vec3<f32>, t_max: f32) -> f32 {
    let inv = params.iod_inv_spacing.xyz;
    let dims = vec3<f32>(params.iod_dims.xyz);
    // In voxel coordinates the ray is a + t * b.
    let a = (params.source.xyz - params.iod_origin.xyz) * inv;
    let b = dir * inv;
    var t0 = 0.0;
    var t1 = t_max;
    for (var k = 0; k < 3; k++) {
        if (abs(b[k]) < 1e-12) {
            if (a[k] < 0.0 || a[k] > dims[k] - 1.0) {
                return 0.0;
            }
        } else {
            let ta = (0.0 - a[k]) / b[k];
            let tb = (dims[k] - 1.0 - a[k]) / b[k];
            t0 = max(t0, min(ta, tb));
            t1 = min(t1, max(ta, tb));
        }
    }
    if (t1 <= t0) {
        return 0.0;
    }
    let n = max(1u, u32(ceil((t1 - t0) / params.iod_origin.w)));
    let h = (t1 - t0) / f32(n);
    var acc = 0.0;
    for (var i = 0u; i < n; i++) {
        acc += trilinear(a + (t0 + (f32(i) + 0.5) * h) * b);
    }
    return acc * h;
}

// The resolve runs as a fragment shader over one triangle covering the region's target,
// scissored to the resolved rectangle (or to the needle's box, for the variant with the needle's
// inputs). Its colour output is unused (the target's write mask is empty); `out_t` is the result.
@vertex
fn vs_cover(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let x = f32(i & 1u) * 4.0 - 1.0;
    let y = f32(i >> 1u) * 4.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs_resolve(@builtin(position) pos: vec4<f32>) -> @location(0) f32 {
    resolve_sample(vec2<u32>(pos.xy));
    return 0.0;
}

// Resolves sample `id` of the region (inside `params.rect`).
fn resolve_sample(id: vec2<u32>) {
    let w = params.dims.x;
    let p = vec2<i32>(id);
    let idx = id.y * w + id.x;
    // Continuous pixel coordinates of this sample; collimation is decided at its pixel's centre
    // (detector-plane mm from the centre, x right, y down), as on the CPU.
    let px = params.region.x + (f32(id.x) + 0.5) * params.region.z;
    let py = params.region.y + (f32(id.y) + 0.5) * params.region.z;
    let ox = (floor(px) + 0.5 - 0.5 * f32(params.full.x)) * params.misc.y;
    let oy = (floor(py) + 0.5 - 0.5 * f32(params.full.y)) * params.misc.z;
    let inside_blades = ox >= params.blades.x && ox <= params.blades.y && oy >= params.blades.z && oy <= params.blades.w;
    let inside_iris = params.misc.x < 0.0 || ox * ox + oy * oy <= params.misc.x;
    if (!(inside_blades && inside_iris)) {
        out_t[idx] = 0.0;
        return;
    }
    // The sample's ray (from the source to its detector point) and the geometric part's scale
    // from axial depth to distance along it.
    let d = params.p00.xyz + (px - 0.5) * params.step_u.xyz + (py - 0.5) * params.step_v.xyz;
    let len = length(d);
    let geometric = textureLoad(lbuf, p, 0) + vec4<f32>(textureLoad(sbuf, p, 0).x, 0.0, 0.0, 0.0);
    var a = geometric * (len / dot(params.row_w.xyz, d));
    var steel = 0.0;
    // Branch on pipeline constants only, never on a uniform value: lavapipe inlines uniforms
    // that decide an `if` holding texture reads and builds the shader again whenever the
    // uniform buffer changes (every frame), keeping every build: with `params.full.z != 0u`
    // here a session grew by 1.4 MB per frame with a needle. The variant with the needle's
    // inputs is only drawn over the needle's box, the iodine variant only with a field.
    if (has_needle) {
        steel = max(textureLoad(needle_chord, p, 0).x, 0.0);
        a += textureLoad(dbuf, p, 0);
    }
    // Cancellous clamp on the pixel's bone total (see the module doc); the excess becomes cortex.
    let total = max(a.z + a.w, 0.0);
    let c = clamp(a.w, 0.0, max(total - 2.0 * params.misc.w, 0.0));
    // 60 keV optical depths (mm * per cm * 0.1).
    let a_water = max(a.x, 0.0) * 0.1;
    let a_bone = max(a.y + (params.mu.x - params.mu.y) * (a.w - c), 0.0) * 0.1;
    let a_iron = params.mu.z * steel * 0.1;
    var a_iod = 0.0;
    if (has_iodine) {
        a_iod = params.mu.w * iodine_column(d / len, len) * 0.1;
    }
    // Without steel or iodine, T depends on (A_water, A_bone) only: bilinear in the ln T table.
    let u = a_water * params.lut_scale.x;
    let v = a_bone * params.lut_scale.y;
    let nw = params.lut_dims.x;
    let nb = params.lut_dims.y;
    let in_lut = params.lut_dims.z != 0u && a_iron == 0.0 && a_iod == 0.0 && u < f32(nw - 1u) && v < f32(nb - 1u);
    // The spectral sum's trip count is per invocation (zero where the table applies): a SIMD
    // implementation (lavapipe runs 8 invocations per vector) then leaves the loop as soon as
    // none of its lanes needs it. A loop bounded by the uniform bin count with an early return
    // instead ran all bins, masked, for every pixel.
    let bins_here = select(params.dims.z, 0u, in_lut);
    var t = 0.0;
    let depth = vec4<f32>(a_water, a_bone, a_iod, a_iron);
    for (var k = 0u; k < bins_here; k++) {
        t += bins[2u * k + 1u].x * exp2(-dot(depth, bins[2u * k]));
    }
    if (in_lut) {
        let i = u32(u);
        let j = u32(v);
        let fu = u - f32(i);
        let fv = v - f32(j);
        let k = j * nw + i;
        let l0 = mix(lut[k], lut[k + 1u], fu);
        let l1 = mix(lut[k + nw], lut[k + nw + 1u], fu);
        t = exp(mix(l0, l1, fv));
    }
    out_t[idx] = t;
}
