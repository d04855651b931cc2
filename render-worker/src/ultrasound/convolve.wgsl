// Passes 2 and 3: the lateral Gaussian across lines (per-depth widths, weights from the CPU,
// sim_core scatter::convolve_lateral) and the axial pulse along each line (convolve_axial).

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(4) var<storage, read> grid_re: array<i32>;
@group(0) @binding(5) var<storage, read> grid_im: array<i32>;
// weights[t * stride + padded sample]
@group(0) @binding(7) var<storage, read> lat_weights: array<f32>;
// lateral result: lines x stride (unpadded lines, padded samples), re then im
@group(0) @binding(8) var<storage, read_write> lat: array<vec2<f32>>;
@group(0) @binding(9) var<storage, read> axial_taps: array<f32>;
// axial result: lines x samples
@group(0) @binding(10) var<storage, read_write> speckle: array<vec2<f32>>;

@compute @workgroup_size(64)
fn lateral(@builtin(global_invocation_id) id: vec3<u32>) {
    let st = P.pad_u.z;
    let sp = id.x;
    let j = id.y;
    if (sp >= st || j >= P.geo_u.y) {
        return;
    }
    let ntap = 2u * P.pad_u.x + 1u;
    let inv = 1.0 / bitcast<f32>(P.seed.z);
    var acc = vec2<f32>(0.0);
    for (var t = 0u; t < ntap; t++) {
        let src = (j + t) * st + sp;
        let w = lat_weights[t * st + sp];
        acc += w * vec2<f32>(f32(grid_re[src]) * inv, f32(grid_im[src]) * inv);
    }
    lat[j * st + sp] = acc;
}

@compute @workgroup_size(64)
fn axial(@builtin(global_invocation_id) id: vec3<u32>) {
    let n = P.geo_u.z;
    let s = id.x;
    let j = id.y;
    if (s >= n || j >= P.geo_u.y) {
        return;
    }
    let st = P.pad_u.z;
    let ntap = 2u * P.pad_u.y + 1u;
    var acc = vec2<f32>(0.0);
    for (var t = 0u; t < ntap; t++) {
        acc += axial_taps[t] * lat[j * st + s + t];
    }
    speckle[j * n + s] = acc;
}
