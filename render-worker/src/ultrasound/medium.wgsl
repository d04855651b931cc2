// The tissue: per-voxel codes (HU, or LABEL_BASE + label) and the property table built on the
// CPU from sim_core's own `hu_props` / `class_props` (see `medium` in mod.rs for the layout).

@group(0) @binding(1) var<storage, read> medium: array<f32>;
@group(0) @binding(2) var<storage, read> lut: array<vec4<f32>>;

// Table rows (two vec4 per entry): AIR at 0, class c at c (labels 1 ..= 11), HU h at
// HU_ROW + (h + 400) for h = -400 ..= 1000.
const HU_ROW: u32 = 16u;
// The coupling gel (sim_core::ultrasound::GEL).
const GEL_ROW: u32 = 15u;
const HU_MIN: f32 = -400.0;
const HU_MAX: f32 = 1000.0;
const LABEL_BASE: f32 = 1000000.0;

struct Tissue {
    // impedance_mrayl, attenuation_db_cm_mhz, echogenicity_db, scatter_density
    a: vec4<f32>,
    // roughness, fascicular (1) or speckle (0), 0, 0
    b: vec4<f32>,
}

fn lut_row(i: u32) -> Tissue {
    return Tissue(lut[2u * i], lut[2u * i + 1u]);
}

// Index of the nearest voxel to voxel coordinates v, or 0xFFFFFFFF outside the grid.
fn voxel_index(p: Params, v: vec3<f32>) -> u32 {
    let r = floor(v + vec3<f32>(0.5));
    let d = vec3<f32>(p.dims.xyz);
    if (!(all(r >= vec3<f32>(0.0)) && all(r < d))) {
        return 0xFFFFFFFFu;
    }
    let ijk = vec3<u32>(r);
    return ijk.x + p.dims.x * (ijk.y + p.dims.y * ijk.z);
}

// Properties of a voxel (outside is air).
fn tissue_of(index: u32) -> Tissue {
    if (index == 0xFFFFFFFFu) {
        return lut_row(0u);
    }
    let code = medium[index];
    if (code >= LABEL_BASE) {
        return lut_row(u32(code - LABEL_BASE));
    }
    if (code <= HU_MIN) {
        return lut_row(0u);
    }
    if (code >= HU_MAX) {
        return lut_row(HU_ROW + u32(HU_MAX - HU_MIN));
    }
    let t = code - HU_MIN;
    let i = min(u32(t), u32(HU_MAX - HU_MIN) - 1u);
    let f = t - f32(i);
    let lo = lut_row(HU_ROW + i);
    let hi = lut_row(HU_ROW + i + 1u);
    return Tissue(mix(lo.a, hi.a, f), vec4<f32>(mix(lo.b.x, hi.b.x, f), lo.b.y, 0.0, 0.0));
}

// Properties at voxel coordinates v (voxel centres at integers; nearest voxel; outside is air).
fn tissue_at(p: Params, v: vec3<f32>) -> Tissue {
    return tissue_of(voxel_index(p, v));
}
