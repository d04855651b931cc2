// L-buffer passes: closed meshes rasterised without a depth test; every fragment adds a signed
// depth (+ leaving, - entering) into additive float render targets: the axial depth in the
// geometric pass, the distance from the source along the sample's ray in the others. See
// `render_worker::fluoro` for the channel layout. The geometric pass
// (`fs_anatomy`) does not depend on the needle, so a session keeps it while only the needle
// moves; the displaced pass (`fs_displaced`) runs scissored to the needle's pixel box.

struct View {
    // Rows of the projection matrix applied to (point - source): (px * w, py * w, w).
    row_x: vec4<f32>,
    row_y: vec4<f32>,
    row_w: vec4<f32>,
    // Focal spot, model frame, mm.
    source: vec4<f32>,
    // (columns, rows, needle reference depth mm, unused).
    size: vec4<f32>,
    // Pixel box (x0, y0, x1, y1) holding the needle's projection (the displaced pass is
    // scissored to it; kept for the layout).
    needle_box: vec4<f32>,
    // Ray generator relative to the source (mm): pixel (0, 0) centre, per-column, per-row step.
    p00: vec4<f32>,
    step_u: vec4<f32>,
    step_v: vec4<f32>,
    // Rendered region: (first pixel column, first row, 1 / samples per pixel axis, 0).
    region: vec4<f32>,
}

@group(0) @binding(0) var<uniform> view: View;
// Per mesh, 3 vec4: geometric weights, displaced weights, (reference distance from the source
// mm, reference axial depth row_w . (centre - source) mm, 0, 0).
@group(0) @binding(1) var<storage, read> weights: array<vec4<f32>>;
// Needle hull per pixel: (nearest entering distance, -farthest leaving distance), mm.
@group(0) @binding(2) var needle_hull: texture_2d<f32>;

// "No needle" marker in the hull target (cleared to it; Min-blended).
const NO_NEEDLE: f32 = 1.0e30;

struct VOut {
    @builtin(position) clip: vec4<f32>,
    // xyz: vertex minus source, mm (perspective-correct: at a fragment it is the point of the
    // triangle on the pixel's ray); w: the mesh's reference depth (constant over a triangle).
    @location(0) rel: vec4<f32>,
    // The mesh's geometric and displaced weights, constant over the triangle.
    @location(1) @interpolate(flat) g: vec4<f32>,
    @location(2) @interpolate(flat) d: vec4<f32>,
    // The triangle's outward unit normal (xyz) and its plane's distance from the source (w).
    @location(3) @interpolate(flat) n: vec4<f32>,
}

// The geometric pass's (it draws every anatomy triangle): values constant over the triangle
// only. A software rasteriser sets up every interpolated value per triangle and evaluates the
// fragment shader per covered pixel, so both are kept minimal: the depth comes from the
// fragment position, which the rasteriser interpolates anyway.
struct GOut {
    @builtin(position) clip: vec4<f32>,
    // The mesh's geometric weights (the fragment shader negates them on front faces).
    @location(1) @interpolate(flat) g: vec4<f32>,
    // The mesh's reference depth along the view axis (row_w), mm.
    @location(4) @interpolate(flat) wref: f32,
}

// Pipeline constant: whether the fragment position's w is 1 / w_clip, as WGSL defines it.
// wgpu's D3D12 backend passes w_clip itself (gfx-rs/wgpu#4963, open for the pinned wgpu); the
// renderer sets this from the device's backend.
override position_w_is_reciprocal: bool = true;

// Axial depth w_clip = row_w . (point - source) of a fragment, mm, from its position's w: exact,
// since 1 / w_clip is affine in screen space and is what the rasteriser interpolates.
fn axial_depth(clip: vec4<f32>) -> f32 {
    if (position_w_is_reciprocal) {
        return 1.0 / clip.w;
    }
    return clip.w;
}

fn project(pos: vec3<f32>, n: vec3<f32>, tref: f32) -> VOut {
    let rel = pos - view.source.xyz;
    let px_w = dot(view.row_x.xyz, rel);
    let py_w = dot(view.row_y.xyz, rel);
    let w = dot(view.row_w.xyz, rel);
    var o: VOut;
    // Continuous pixel coordinates [0, W] x [0, H] (y down) to clip space (y up).
    o.clip = vec4<f32>(2.0 * px_w / view.size.x - w, w - 2.0 * py_w / view.size.y, 0.5 * w, w);
    o.rel = vec4<f32>(rel, tref);
    o.n = vec4<f32>(n, dot(n, rel));
    return o;
}

struct Crossing {
    t: f32,
    entering: bool,
}

// Distance from the source along the fragment's exact pixel ray to the triangle's plane, and
// whether the ray enters the mesh there (against the outward normal), for the needle and the
// displaced pass. Interpolated positions lose precision on long, thin triangles seen edge-on (a
// needle's sides); the plane does not. Triangles seen edge-on within 1e-4 rad, or degenerate
// (zero normal), fall back to the rasteriser's facing and to the interpolated point `rel`.
fn crossing(clip: vec4<f32>, rel: vec3<f32>, n: vec4<f32>, front: bool) -> Crossing {
    let px = view.region.x + clip.x * view.region.z;
    let py = view.region.y + clip.y * view.region.z;
    let d = view.p00.xyz + (px - 0.5) * view.step_u.xyz + (py - 0.5) * view.step_v.xyz;
    let len = length(d);
    let dn = dot(n.xyz, d);
    var c: Crossing;
    if (abs(dn) > 1e-4 * len) {
        c.t = n.w * len / dn;
        c.entering = dn < 0.0;
    } else {
        c.t = length(rel);
        c.entering = front;
    }
    return c;
}

@vertex
fn vs_geometry(@location(0) pos: vec3<f32>, @location(1) mesh: u32, @location(2) n: vec3<f32>) -> GOut {
    let v = project(pos, n, 0.0);
    var o: GOut;
    o.clip = v.clip;
    o.g = weights[3u * mesh];
    o.wref = weights[3u * mesh + 2u].y;
    return o;
}

@vertex
fn vs_anatomy(@location(0) pos: vec3<f32>, @location(1) mesh: u32, @location(2) n: vec3<f32>) -> VOut {
    var o = project(pos, n, weights[3u * mesh + 2u].x);
    o.g = weights[3u * mesh];
    o.d = weights[3u * mesh + 1u];
    return o;
}

@vertex
fn vs_needle(@location(0) pos: vec3<f32>, @location(1) mesh: u32, @location(2) n: vec3<f32>) -> VOut {
    var o = project(pos, n, view.size.z);
    o.g = vec4<f32>(0.0);
    o.d = vec4<f32>(0.0);
    return o;
}

// Geometric pass: the mesh's signed axial depths (see `axial_depth`) times its geometric weights:
// a reciprocal and a multiply-add per fragment, with no ray-plane intersection. Summed over a
// closed mesh, axial depths give the chord times (row_w . d) / |d|; the resolve (and
// `render_chords`) multiplies by the ray's |d| / (row_w . d). Facing is the rasteriser's (front:
// entering), the same decision that counts the triangle's coverage, so each closed mesh's
// entering and leaving fragments pair up on every ray.
@fragment
fn fs_anatomy(v: GOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    return select(v.g, -v.g, front) * (axial_depth(v.clip) - v.wref);
}

// The same for a scalar mesh (weights in the water-basis channel only) into a one-channel
// target (see `FMT_SCALAR`).
@fragment
fn fs_anatomy_scalar(v: GOut, @builtin(front_facing) front: bool) -> @location(0) f32 {
    return select(v.g.x, -v.g.x, front) * (axial_depth(v.clip) - v.wref);
}

// Displaced pass (scissored to the needle's pixel box): the signed part of this crossing inside
// the needle's [t0, t1], times the mesh's displaced weights. Summed over a closed mesh it is the
// length of the mesh's interior the needle occupies along this ray.
@fragment
fn fs_displaced(v: VOut, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let c = crossing(v.clip, v.rel.xyz, v.n, front);
    let s = select(1.0, -1.0, c.entering);
    let hull = textureLoad(needle_hull, vec2<i32>(v.clip.xy), 0).xy;
    let t0 = hull.x;
    let t1 = -hull.y;
    let td = select(0.0, s * (min(max(c.t, t0), t1) - t0), t1 > t0);
    return v.d * td;
}

struct NeedleOut {
    // Min-blended: (entering distance or NO_NEEDLE, -leaving distance or NO_NEEDLE).
    @location(0) hull: vec2<f32>,
    // Added: signed distance relative to the needle's reference depth.
    @location(1) chord: f32,
}

@fragment
fn fs_needle(v: VOut, @builtin(front_facing) front: bool) -> NeedleOut {
    let c = crossing(v.clip, v.rel.xyz, v.n, front);
    let t = c.t;
    var o: NeedleOut;
    o.hull = select(vec2<f32>(NO_NEEDLE, -t), vec2<f32>(t, NO_NEEDLE), c.entering);
    o.chord = select(1.0, -1.0, c.entering) * (t - v.rel.w);
    return o;
}
