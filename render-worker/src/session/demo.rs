//! A small analytic "region" and station for tests and benches: boxes standing in for a body, two
//! vertebral bodies, a dural sac and one facet joint, with exactly known geometry (so scorers can
//! be checked against hand-computed angles) and a scene that renders in milliseconds.
//!
//! Geometry (model frame, mm): body envelope 300 x 240 x 300 centred at the origin; `L4`
//! vertebral body 40 x 30 x 26 centred at the origin (cortex, with a cancellous inset of 1.8 mm);
//! `L5` the same 36 mm lower; a dural sac 16 x 15 x 100 behind them (y from -35 to -20); a right
//! facet joint at [`FACET_CENTRE_MM`] made of two 4 x 14 x 16 mm bone blocks either side of a
//! 2 mm gap whose normal is horizontal at [`FACET_NORMAL_AZIMUTH_DEG`] from +x.

use std::collections::BTreeMap;

use sim_core::anatomy::asset::StructureAsset;
use sim_core::material::MaterialClass;
use sim_core::mesh::TriMesh;
use sim_core::rubric::Station;

use super::region::Region;

/// Centre of the demo facet joint gap, mm.
pub const FACET_CENTRE_MM: [f64; 3] = [20.0, -40.0, -10.0];
/// Direction of the facet joint normal in the axial plane, degrees from +x towards +y.
pub const FACET_NORMAL_AZIMUTH_DEG: f64 = -40.0;
/// Facet joint gap, mm.
pub const FACET_GAP_MM: f64 = 2.0;

fn boxed(min: [f64; 3], max: [f64; 3]) -> TriMesh {
    TriMesh::axis_aligned_box(min, max)
}

/// Box in a frame rotated about z by `azimuth_deg`, centred at `centre` (local u along the
/// rotated x axis).
fn rotated_box(
    centre: [f64; 3],
    azimuth_deg: f64,
    u: [f64; 2],
    v: [f64; 2],
    w: [f64; 2],
) -> TriMesh {
    let mut m = TriMesh::axis_aligned_box([u[0], v[0], w[0]], [u[1], v[1], w[1]]);
    let (s, c) = azimuth_deg.to_radians().sin_cos();
    m.map_vertices(|p| {
        [
            centre[0] + c * p[0] - s * p[1],
            centre[1] + s * p[0] + c * p[1],
            centre[2] + p[2],
        ]
    });
    m
}

fn structure(name: &str, material: MaterialClass, mesh: TriMesh) -> StructureAsset {
    StructureAsset {
        name: name.to_string(),
        material,
        mask_volume_mm3: mesh.signed_volume_mm3(),
        mesh,
    }
}

/// Name of the demo region.
pub const DEMO_REGION_NAME: &str = "demo-region";

/// The demo region (named [`DEMO_REGION_NAME`]).
pub fn demo_region() -> Region {
    let half_gap = 0.5 * FACET_GAP_MM;
    let structures = vec![
        structure(
            "skin",
            MaterialClass::SoftTissue,
            boxed([-150.0, -120.0, -150.0], [150.0, 120.0, 150.0]),
        ),
        structure(
            "dural_sac",
            MaterialClass::DuraCsf,
            boxed([-8.0, -35.0, -60.0], [8.0, -20.0, 40.0]),
        ),
        structure(
            "L4_cortical",
            MaterialClass::CorticalBone,
            boxed([-20.0, -15.0, -13.0], [20.0, 15.0, 13.0]),
        ),
        structure(
            "L4_cancellous",
            MaterialClass::Cancellous,
            boxed([-18.2, -13.2, -11.2], [18.2, 13.2, 11.2]),
        ),
        structure(
            "L5_cortical",
            MaterialClass::CorticalBone,
            boxed([-20.0, -15.0, -49.0], [20.0, 15.0, -23.0]),
        ),
        structure(
            "L5_cancellous",
            MaterialClass::Cancellous,
            boxed([-18.2, -13.2, -47.2], [18.2, 13.2, -24.8]),
        ),
        structure(
            "L4_inferior_articular_right",
            MaterialClass::CorticalBone,
            rotated_box(
                FACET_CENTRE_MM,
                FACET_NORMAL_AZIMUTH_DEG,
                [half_gap, half_gap + 4.0],
                [-7.0, 7.0],
                [-8.0, 8.0],
            ),
        ),
        structure(
            "L5_superior_articular_right",
            MaterialClass::CorticalBone,
            rotated_box(
                FACET_CENTRE_MM,
                FACET_NORMAL_AZIMUTH_DEG,
                [-half_gap - 4.0, -half_gap],
                [-7.0, 7.0],
                [-8.0, 8.0],
            ),
        ),
    ];
    let landmarks: BTreeMap<String, [f64; 3]> = [
        ("L4_body_centre".to_string(), [0.0, 0.0, 0.0]),
        ("L5_body_centre".to_string(), [0.0, 0.0, -36.0]),
        ("L4_L5_facet_joint_right".to_string(), FACET_CENTRE_MM),
    ]
    .into_iter()
    .collect();
    let hashes = [(
        "meshes".to_string(),
        "demo-region-analytic-boxes-v1".to_string(),
    )]
    .into_iter()
    .collect();
    Region::from_structures(
        DEMO_REGION_NAME,
        &structures,
        landmarks,
        hashes,
        "demo boxes".into(),
    )
}

/// A demo station over the demo region: fluoroscopy (plus whatever `extra_modalities` lists),
/// a spinal needle, a target 3 mm behind the L4 body at x = 12 mm, and a rubric reading the
/// fluoroscopy and needle measurements.
pub fn demo_station_toml(extra_modalities: &[&str]) -> String {
    let mut modalities = vec!["\"fluoroscopy\"".to_string()];
    modalities.extend(extra_modalities.iter().map(|m| format!("\"{m}\"")));
    format!(
        r#"
id = "demo-station"
revision = 1
title = "Demo station"
region = "demo-region"
frame_note = "Model frame of the demo region."
modalities = [{}]

[[instruments]]
id = "spinal-22g"
kind = "spinal-needle"
gauge = 22
length_mm = 89.0

[[instruments]]
id = "contrast-syringe"
kind = "contrast-syringe"

[[targets]]
name = "behind_l4"
position_mm = [12.0, -18.0, 0.0]

[rubric]
revision = 1
pass_threshold = 0.75

[[rubric.criteria]]
id = "ap_endplate_alignment"
description = "AP view squared to the L4 inferior endplate."
measurement = "ap_endplate_tilt_deg"
unit = "deg"
weight = 1.0
tolerance = {{ law = "lower_is_better", pass_within = 2.0, fail_beyond = 8.0 }}

[[rubric.criteria]]
id = "joint_space_open"
description = "Beam in the facet joint plane."
measurement = "beam_to_joint_plane_deg"
unit = "deg"
weight = 1.0
tolerance = {{ law = "lower_is_better", pass_within = 5.0, fail_beyond = 15.0 }}

[[rubric.criteria]]
id = "tip_at_target"
description = "Tip distance to the target."
measurement = "tip_to_target_mm"
unit = "mm"
weight = 3.0
target = "behind_l4"
tolerance = {{ law = "lower_is_better", pass_within = 2.0, fail_beyond = 7.0 }}

[[rubric.criteria]]
id = "no_dural_puncture"
description = "The tip never entered the dural sac."
measurement = "dural_puncture_bool"
unit = "bool"
weight = 1.0
critical = true
tolerance = {{ law = "boolean", expected = false }}

[[rubric.criteria]]
id = "image_economy"
description = "Few acquisitions."
measurement = "fluoro_acquisitions_count"
unit = "count"
weight = 0.5
tolerance = {{ law = "lower_is_better", pass_within = 10.0, fail_beyond = 35.0 }}
"#,
        modalities.join(", ")
    )
}

/// The demo station, parsed, with the SHA-256 of its text.
pub fn demo_station(extra_modalities: &[&str]) -> (Station, String) {
    let text = demo_station_toml(extra_modalities);
    let station = Station::from_toml_str(&text).unwrap_or_else(|e| panic!("demo station: {e}"));
    (station, super::sha256_hex(text.as_bytes()))
}
