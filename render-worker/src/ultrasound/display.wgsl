// Pass 5: log compression and scan conversion to square pixels (sim_core ultrasound::frame::
// scan_convert): grey = 255 (dB + gain + TGC + DR) / DR, clamped; grey | inside << 8 per pixel.

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(14) var<storage, read> envelope: array<f32>;
@group(0) @binding(15) var<storage, read_write> pixels: array<u32>;

fn tgc_db(z: f32) -> f32 {
    let band = P.display_f.y;
    let t = clamp(z / band - 0.5, 0.0, 5.0);
    let i = min(u32(t), 4u);
    let f = t - f32(i);
    let tgc = array<f32, 6>(P.tgc_a.x, P.tgc_a.y, P.tgc_a.z, P.tgc_a.w, P.tgc_b.x, P.tgc_b.y);
    return tgc[i] * (1.0 - f) + tgc[i + 1u] * f;
}

@compute @workgroup_size(64)
fn display(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = P.display_u.x;
    let x = id.x;
    let y = id.y;
    if (x >= width || y >= P.display_u.y) {
        return;
    }
    let px = P.display.x;
    let xm = P.display.y + f32(x) * px;
    let ym = P.display.z + f32(y) * px;
    let uz = plane_to_line(P, xm, ym);
    let lines = P.geo_u.y;
    let n = P.geo_u.z;
    let u = uz.x;
    let s = uz.y / P.samp_f.x;
    var out = 0u;
    if (u >= 0.0 && u <= f32(lines - 1u) && s >= 0.0 && s <= f32(n - 1u)) {
        let u0 = min(u32(u), lines - 2u);
        let s0 = min(u32(s), n - 2u);
        let fu = u - f32(u0);
        let fs = s - f32(s0);
        let r0 = u0 * n + s0;
        let r1 = r0 + n;
        let a = (envelope[r0] * (1.0 - fs) + envelope[r0 + 1u] * fs) * (1.0 - fu)
            + (envelope[r1] * (1.0 - fs) + envelope[r1 + 1u] * fs) * fu;
        let db = 20.0 * log2(max(a, 1e-12)) * 0.30102999 + P.display.w + tgc_db(uz.y);
        let dr = P.display_f.x;
        let g = clamp((db + dr) / dr, 0.0, 1.0) * 255.0;
        out = u32(g + 0.5) | 256u;
    }
    pixels[y * width + x] = out;
}
