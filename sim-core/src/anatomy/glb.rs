//! Binary glTF 2.0 (`.glb`) writing and reading for structure meshes.
//!
//! Layout written: one node and one mesh per structure, both named after the structure, each with
//! `extras = {"material": "<class>", "structure": "<name>"}`; one triangle primitive with a float
//! VEC3 `POSITION` accessor (millimetres in the model frame) and `u32` indices. glTF itself is
//! unit-less (nominally metres); the top-level `asset.extras.units = "mm"` says what ours are, and
//! no node transform is used, so coordinates are read as stored. Reading goes through the `gltf`
//! crate, so anything we write is checked by an independent parser in the tests.

use std::collections::BTreeMap;
use std::path::Path;

use serde_json::json;

use super::error::AnatomyError;
use super::structure::StructureAsset;
use crate::material::MaterialClass;
use crate::mesh::TriMesh;

const GLB_MAGIC: u32 = 0x4654_6C67; // "glTF"
const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"
const COMPONENT_F32: u32 = 5126;
const COMPONENT_U32: u32 = 5125;
const TARGET_ARRAY_BUFFER: u32 = 34962;
const TARGET_ELEMENT_ARRAY_BUFFER: u32 = 34963;

/// Serializes structures to a `.glb` byte string (deterministic).
pub(crate) fn write_glb(structures: &[StructureAsset]) -> Result<Vec<u8>, AnatomyError> {
    let mut bin: Vec<u8> = Vec::new();
    let mut nodes = Vec::new();
    let mut meshes = Vec::new();
    let mut accessors = Vec::new();
    let mut views = Vec::new();
    for (i, s) in structures.iter().enumerate() {
        if s.mesh.triangles.is_empty() || s.mesh.vertices_mm.is_empty() {
            return Err(AnatomyError::Mesh {
                structure: s.name.clone(),
                message: "empty mesh cannot be stored".into(),
            });
        }
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        let pos_offset = bin.len();
        for v in &s.mesh.vertices_mm {
            for a in 0..3 {
                let x = v[a] as f32;
                if !x.is_finite() {
                    return Err(AnatomyError::Mesh {
                        structure: s.name.clone(),
                        message: "non-finite vertex".into(),
                    });
                }
                lo[a] = lo[a].min(x);
                hi[a] = hi[a].max(x);
                bin.extend_from_slice(&x.to_le_bytes());
            }
        }
        let pos_len = bin.len() - pos_offset;
        let idx_offset = bin.len();
        for t in &s.mesh.triangles {
            for &k in t {
                bin.extend_from_slice(&k.to_le_bytes());
            }
        }
        let idx_len = bin.len() - idx_offset;
        views.push(json!({"buffer": 0, "byteOffset": pos_offset, "byteLength": pos_len, "target": TARGET_ARRAY_BUFFER}));
        views.push(json!({"buffer": 0, "byteOffset": idx_offset, "byteLength": idx_len, "target": TARGET_ELEMENT_ARRAY_BUFFER}));
        accessors.push(json!({
            "bufferView": 2 * i, "componentType": COMPONENT_F32, "count": s.mesh.vertices_mm.len(),
            "type": "VEC3", "min": lo, "max": hi
        }));
        accessors.push(json!({
            "bufferView": 2 * i + 1, "componentType": COMPONENT_U32, "count": 3 * s.mesh.triangles.len(),
            "type": "SCALAR"
        }));
        let extras = json!({"material": s.material.name(), "structure": s.name});
        meshes.push(json!({
            "name": s.name,
            "primitives": [{"attributes": {"POSITION": 2 * i}, "indices": 2 * i + 1, "mode": 4}],
            "extras": extras
        }));
        nodes.push(json!({"name": s.name, "mesh": i, "extras": extras}));
    }
    let doc = json!({
        "asset": {
            "version": "2.0",
            "generator": concat!("sim-core ", env!("CARGO_PKG_VERSION"), " anatomy pipeline"),
            "extras": {"units": "mm", "winding": "counter-clockwise seen from outside"}
        },
        "scene": 0,
        "scenes": [{"nodes": (0..structures.len()).collect::<Vec<_>>()}],
        "nodes": nodes,
        "meshes": meshes,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}]
    });
    let mut json_bytes =
        serde_json::to_vec(&doc).map_err(|e| AnatomyError::invalid("meshes.glb", e.to_string()))?;
    while !json_bytes.len().is_multiple_of(4) {
        json_bytes.push(b' ');
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json_bytes.len() + 8 + bin.len();
    let total_u32 = u32::try_from(total)
        .map_err(|_| AnatomyError::invalid("meshes.glb", "larger than 4 GiB"))?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(&GLB_MAGIC.to_le_bytes());
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total_u32.to_le_bytes());
    out.extend_from_slice(&(json_bytes.len() as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
    out.extend_from_slice(&json_bytes);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
    out.extend_from_slice(&bin);
    Ok(out)
}

/// Parses a `.glb` written by [`write_glb`] into (material, mesh) by structure name.
pub(crate) fn read_glb(
    bytes: &[u8],
    path: &Path,
) -> Result<BTreeMap<String, (MaterialClass, TriMesh)>, AnatomyError> {
    let gltf = gltf::Gltf::from_slice(bytes)
        .map_err(|e| AnatomyError::bad_file(path, format!("invalid glTF: {e}")))?;
    let blob = gltf
        .blob
        .as_deref()
        .ok_or_else(|| AnatomyError::bad_file(path, "no binary chunk"))?;
    let mut out = BTreeMap::new();
    for mesh in gltf.document.meshes() {
        let name = mesh
            .name()
            .ok_or_else(|| AnatomyError::bad_file(path, "unnamed mesh"))?
            .to_string();
        let extras = mesh
            .extras()
            .as_ref()
            .ok_or_else(|| AnatomyError::bad_file(path, format!("mesh {name} has no extras")))?;
        let extras: serde_json::Value = serde_json::from_str(extras.get())
            .map_err(|e| AnatomyError::bad_file(path, format!("mesh {name}: extras: {e}")))?;
        let material = extras
            .get("material")
            .and_then(|m| m.as_str())
            .and_then(MaterialClass::from_name)
            .ok_or_else(|| {
                AnatomyError::bad_file(path, format!("mesh {name} has no known material class"))
            })?;
        let mut tri = TriMesh::default();
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                return Err(AnatomyError::bad_file(
                    path,
                    format!("mesh {name}: primitive is not a triangle list"),
                ));
            }
            let reader = prim.reader(|b| (b.index() == 0).then_some(blob));
            let base = tri.vertices_mm.len() as u32;
            let positions = reader.read_positions().ok_or_else(|| {
                AnatomyError::bad_file(path, format!("mesh {name}: no positions"))
            })?;
            tri.vertices_mm
                .extend(positions.map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])]));
            let indices: Vec<u32> = reader
                .read_indices()
                .ok_or_else(|| AnatomyError::bad_file(path, format!("mesh {name}: no indices")))?
                .into_u32()
                .collect();
            if !indices.len().is_multiple_of(3)
                || indices
                    .iter()
                    .any(|&k| k + base >= tri.vertices_mm.len() as u32)
            {
                return Err(AnatomyError::bad_file(
                    path,
                    format!("mesh {name}: bad index list"),
                ));
            }
            tri.triangles.extend(
                indices
                    .chunks_exact(3)
                    .map(|c| [c[0] + base, c[1] + base, c[2] + base]),
            );
        }
        if out.insert(name.clone(), (material, tri)).is_some() {
            return Err(AnatomyError::bad_file(
                path,
                format!("two meshes named {name}"),
            ));
        }
    }
    Ok(out)
}
