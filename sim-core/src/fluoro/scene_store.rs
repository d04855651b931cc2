//! A scene's BVH trees stored beside the meshes they index, so a restart rebuilds each tree in
//! one linear pass ([`Bvh::from_topology`]) instead of a SAH build (the default lumbar phantom:
//! 1.6 s of a 2.0 s warm region load on two cores).
//!
//! A stored file is reused only when its key matches: the caller's description of the meshes
//! (for a region asset, the SHA-256 of its mesh file and its structures) and
//! [`BVH_BUILDER_VERSION`]. A file that is truncated, altered (its SHA-256 trailer), stale or
//! whose trees do not fit the meshes is never served: the trees are built and the file rewritten.
//!
//! The same file format also holds scenes whose meshes are derived rather than read (the draft
//! scene, [`super::draft::draft_scene_stored`]): each entry may carry its mesh.
//!
//! Layout (little-endian): [`MAGIC`], the 32-byte SHA-256 of the key, the entry count, then per
//! entry its slot count, its node count, the slots (`u32` source triangle each), the nodes
//! (`u32` first, `u32` count each), and its mesh or none: a vertex count (`u32::MAX` for none),
//! a triangle count, the vertices (three `f64` bit patterns each) and the triangles (three `u32`
//! vertex indices each); last, the SHA-256 of everything before it.

use std::path::Path;

use sha2::{Digest, Sha256};

use super::attenuation::FluoroMaterial;
use super::scene::{Scene, SceneEntry};
use crate::geom::{BVH_BUILDER_VERSION, Bvh, BvhTopology};
use crate::mesh::TriMesh;
use crate::par::par_map_heaviest_first;

/// File name of the stored trees in a region folder.
pub const STORE_FILE: &str = "scene-bvh.bin";

/// First bytes of a stored-trees file (format 2).
pub const MAGIC: &[u8; 16] = b"painsim-bvh\0\0\0\0\x02";

/// What became of the stored trees when a scene was made.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StoreOutcome {
    /// Every tree came from the file.
    Reused,
    /// The trees were built, because the file was missing, stale or corrupt (`why`); `stored`
    /// says whether the new file was written (the scene is the same either way).
    Built {
        /// Why the file was not used.
        why: String,
        /// `Err` with the reason when the new file could not be written.
        stored: Result<(), String>,
    },
}

/// Why a stored file cannot be used.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Miss {
    Missing,
    Stale,
    Corrupt(String),
}

impl std::fmt::Display for Miss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Miss::Missing => write!(f, "nothing stored"),
            Miss::Stale => write!(f, "the store is for other meshes or another version"),
            Miss::Corrupt(why) => write!(f, "the store is corrupt ({why})"),
        }
    }
}

fn key_digest(key: &str) -> [u8; 32] {
    let mut h = Sha256::new();
    h.update(b"painsim scene BVH; builder version ");
    h.update(BVH_BUILDER_VERSION.to_le_bytes());
    h.update(b"; meshes ");
    h.update(key.as_bytes());
    h.finalize().into()
}

/// Marks an entry stored without its mesh.
const NO_MESH: u32 = u32::MAX;

/// The stored form of `entries` (each tree's shape, with its mesh when the reader cannot get it
/// elsewhere) under `key`.
pub(crate) fn encode(key: &str, entries: &[(&BvhTopology, Option<&TriMesh>)]) -> Vec<u8> {
    let size: usize = entries
        .iter()
        .map(|(t, m)| {
            16 + 4 * t.order.len()
                + 8 * t.nodes.len()
                + m.map_or(0, |m| 24 * m.vertices_mm.len() + 12 * m.triangles.len())
        })
        .sum();
    let mut out = Vec::with_capacity(MAGIC.len() + 32 + 4 + size + 32);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&key_digest(key));
    let put = |x: u32, out: &mut Vec<u8>| out.extend_from_slice(&x.to_le_bytes());
    put(entries.len() as u32, &mut out);
    for (t, mesh) in entries {
        put(t.order.len() as u32, &mut out);
        put(t.nodes.len() as u32, &mut out);
        for s in &t.order {
            put(*s, &mut out);
        }
        for (first, count) in &t.nodes {
            put(*first, &mut out);
            put(*count, &mut out);
        }
        match mesh {
            None => put(NO_MESH, &mut out),
            Some(m) => {
                put(m.vertices_mm.len() as u32, &mut out);
                put(m.triangles.len() as u32, &mut out);
                for v in &m.vertices_mm {
                    for c in v {
                        out.extend_from_slice(&c.to_bits().to_le_bytes());
                    }
                }
                for tri in &m.triangles {
                    for i in tri {
                        put(*i, &mut out);
                    }
                }
            }
        }
    }
    let trailer: [u8; 32] = Sha256::digest(&out).into();
    out.extend_from_slice(&trailer);
    out
}

/// Reads `u32`s off the front of a byte slice.
struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn u32(&mut self) -> Result<u32, Miss> {
        let (head, rest) = self
            .0
            .split_first_chunk::<4>()
            .ok_or_else(|| Miss::Corrupt("truncated".into()))?;
        self.0 = rest;
        Ok(u32::from_le_bytes(*head))
    }

    fn u32s(&mut self, n: usize) -> Result<Vec<u32>, Miss> {
        let bytes = n
            .checked_mul(4)
            .filter(|&b| b <= self.0.len())
            .ok_or_else(|| Miss::Corrupt("truncated".into()))?;
        let (head, rest) = self.0.split_at(bytes);
        self.0 = rest;
        Ok(head
            .chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// A stored mesh: every index in range, every coordinate finite.
    fn mesh(&mut self, vertices: usize) -> Result<TriMesh, Miss> {
        let triangles = self.u32()? as usize;
        let bits = self.u32s(
            vertices
                .checked_mul(6)
                .ok_or(Miss::Corrupt("truncated".into()))?,
        )?;
        let vertices_mm: Vec<[f64; 3]> = bits
            .chunks_exact(6)
            .map(|w| {
                std::array::from_fn(|a| {
                    f64::from_bits(u64::from(w[2 * a]) | (u64::from(w[2 * a + 1]) << 32))
                })
            })
            .collect();
        if vertices_mm.iter().flatten().any(|c| !c.is_finite()) {
            return Err(Miss::Corrupt("a stored vertex is not finite".into()));
        }
        let flat = self.u32s(
            triangles
                .checked_mul(3)
                .ok_or(Miss::Corrupt("truncated".into()))?,
        )?;
        if flat.iter().any(|&i| i as usize >= vertices) {
            return Err(Miss::Corrupt(
                "a stored triangle names a missing vertex".into(),
            ));
        }
        Ok(TriMesh {
            vertices_mm,
            triangles: flat.chunks_exact(3).map(|t| [t[0], t[1], t[2]]).collect(),
        })
    }
}

/// The entries stored in `bytes` under `key` (not yet checked against any mesh).
pub(crate) fn decode(bytes: &[u8], key: &str) -> Result<Vec<(BvhTopology, Option<TriMesh>)>, Miss> {
    let Some((body, trailer)) = bytes.split_last_chunk::<32>() else {
        return Err(Miss::Corrupt("shorter than its checksum".into()));
    };
    if body.len() < MAGIC.len() + 32 + 4 || &body[..MAGIC.len()] != MAGIC {
        return Err(Miss::Corrupt(
            "not a stored-trees file of this format".into(),
        ));
    }
    if <[u8; 32]>::from(Sha256::digest(body)) != *trailer {
        return Err(Miss::Corrupt(
            "its SHA-256 does not match its contents".into(),
        ));
    }
    if body[MAGIC.len()..MAGIC.len() + 32] != key_digest(key) {
        return Err(Miss::Stale);
    }
    let mut r = Reader(&body[MAGIC.len() + 32..]);
    let count = r.u32()? as usize;
    let mut out = Vec::with_capacity(count.min(1 << 16));
    for _ in 0..count {
        let slots = r.u32()? as usize;
        let nodes = r.u32()? as usize;
        let order = r.u32s(slots)?;
        let flat = r.u32s(
            nodes
                .checked_mul(2)
                .ok_or(Miss::Corrupt("truncated".into()))?,
        )?;
        let topology = BvhTopology {
            order,
            nodes: flat.chunks_exact(2).map(|p| (p[0], p[1])).collect(),
        };
        let mesh = match r.u32()? {
            NO_MESH => None,
            vertices => Some(r.mesh(vertices as usize)?),
        };
        out.push((topology, mesh));
    }
    if !r.0.is_empty() {
        return Err(Miss::Corrupt(format!(
            "{} bytes after the last tree",
            r.0.len()
        )));
    }
    Ok(out)
}

/// The trees stored in `stored` (the file's bytes, or `None` when there is none) under `key`,
/// one per entry named `names` (for errors), each rebuilt over its mesh: `own[i]` where the
/// caller has the meshes (the entries were stored without), else the mesh stored with entry `i`.
pub(crate) fn trees_from(
    stored: Option<&[u8]>,
    key: &str,
    names: &[&str],
    own: Option<&[&TriMesh]>,
) -> Result<Vec<Bvh>, Miss> {
    let entries = decode(stored.ok_or(Miss::Missing)?, key)?;
    if entries.len() != names.len() {
        return Err(Miss::Corrupt(format!(
            "{} trees for {} entries",
            entries.len(),
            names.len()
        )));
    }
    if entries.iter().any(|e| e.1.is_some() == own.is_some()) {
        return Err(Miss::Corrupt(if own.is_some() {
            "trees stored with meshes of their own".into()
        } else {
            "a tree stored without its mesh".into()
        }));
    }
    let mesh = |i: usize| own.map_or_else(|| entries[i].1.as_ref().expect("checked"), |m| m[i]);
    let weights: Vec<usize> = (0..entries.len())
        .map(|i| mesh(i).triangles.len())
        .collect();
    let trees = par_map_heaviest_first(&weights, &|i| Bvh::from_topology(mesh(i), &entries[i].0));
    trees
        .into_iter()
        .zip(names)
        .map(|(t, name)| t.map_err(|e| Miss::Corrupt(format!("{name}: {e}"))))
        .collect()
}

/// Stores `entries` (each tree's shape, with its mesh where the reader cannot get it
/// elsewhere) in `store` under `key` once `miss` had them built: what to report.
pub(crate) fn store_after_miss(
    store: &Path,
    key: &str,
    entries: &[(&BvhTopology, Option<&TriMesh>)],
    miss: Miss,
) -> StoreOutcome {
    let stored = write_atomically(store, &encode(key, entries))
        .map_err(|e| format!("{}: {e}", store.display()));
    StoreOutcome::Built {
        why: miss.to_string(),
        stored,
    }
}

/// Writes `bytes` to `path` through a temporary file in the same folder and a rename, so a
/// reader never sees half a file.
fn write_atomically(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let name = path
        .file_name()
        .map_or_else(|| "store".into(), |n| n.to_string_lossy().into_owned());
    let tmp = path.with_file_name(format!(
        ".{name}.{}.tmp",
        crate::anatomy::asset::unique_suffix()
    ));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path).inspect_err(|_| {
        let _ = std::fs::remove_file(&tmp);
    })
}

impl Scene {
    /// [`Scene::add_all`], with the trees taken from the file at `store` when it holds them
    /// under `key` (a description that changes whenever any of the meshes could), else built and
    /// stored there. The scene is the same either way, bit for bit.
    pub fn add_all_stored(
        &mut self,
        meshes: &[(String, FluoroMaterial, &TriMesh)],
        store: &Path,
        key: &str,
    ) -> (usize, StoreOutcome) {
        let bytes = std::fs::read(store).ok();
        let names: Vec<&str> = meshes.iter().map(|m| m.0.as_str()).collect();
        let own: Vec<&TriMesh> = meshes.iter().map(|m| m.2).collect();
        let trees = match trees_from(bytes.as_deref(), key, &names, Some(&own)) {
            Ok(trees) => trees,
            Err(miss) => {
                let first = self.add_all(meshes);
                let topologies: Vec<BvhTopology> = self.entries()[first..]
                    .iter()
                    .map(|e| e.bvh.topology())
                    .collect();
                let entries: Vec<_> = topologies.iter().map(|t| (t, None)).collect();
                return (first, store_after_miss(store, key, &entries, miss));
            }
        };
        let first = self.entries().len();
        for ((name, material, _), bvh) in meshes.iter().zip(trees) {
            self.push_entry(SceneEntry {
                name: name.clone(),
                material: *material,
                priority: material.default_priority(),
                bvh,
            });
        }
        (first, StoreOutcome::Reused)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::MaterialClass;

    fn meshes() -> Vec<TriMesh> {
        vec![
            TriMesh::icosphere([0.0, 0.0, 0.0], 30.0, 4),
            TriMesh::icosphere([5.0, 1.0, -2.0], 10.0, 3),
        ]
    }

    fn named(m: &[TriMesh]) -> Vec<(String, FluoroMaterial, &TriMesh)> {
        vec![
            (
                "body".into(),
                FluoroMaterial::Tissue(MaterialClass::SoftTissue),
                &m[0],
            ),
            (
                "bone".into(),
                FluoroMaterial::Tissue(MaterialClass::CorticalBone),
                &m[1],
            ),
        ]
    }

    fn scene_bits(s: &Scene) -> Vec<Bvh> {
        s.entries().iter().map(|e| e.bvh.clone()).collect()
    }

    #[test]
    fn stored_trees_are_the_built_ones_and_bad_files_are_rebuilt() {
        let dir = std::env::temp_dir().join(format!(
            "scene-store-{}",
            crate::anatomy::asset::unique_suffix()
        ));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let store = dir.join(STORE_FILE);
        let m = meshes();
        let mut built = Scene::new();
        built.add_all(&named(&m));

        let mut first = Scene::new();
        let (_, outcome) = first.add_all_stored(&named(&m), &store, "key-a");
        assert!(
            matches!(outcome, StoreOutcome::Built { ref why, stored: Ok(()) }
            if why == "nothing stored"),
            "{outcome:?}"
        );
        let mut again = Scene::new();
        let (_, outcome) = again.add_all_stored(&named(&m), &store, "key-a");
        assert_eq!(outcome, StoreOutcome::Reused);
        assert_eq!(scene_bits(&again), scene_bits(&built));
        assert_eq!(scene_bits(&first), scene_bits(&built));

        // Another key: stale, rebuilt and rewritten under the new key.
        let (_, outcome) = Scene::new().add_all_stored(&named(&m), &store, "key-b");
        assert!(matches!(outcome, StoreOutcome::Built { ref why, .. } if why.contains("other")));
        let (_, outcome) = Scene::new().add_all_stored(&named(&m), &store, "key-b");
        assert_eq!(outcome, StoreOutcome::Reused);

        // One flipped byte anywhere, or a truncation: corrupt, never served.
        let good = std::fs::read(&store).expect("stored");
        for at in [0, 20, good.len() / 2, good.len() - 1] {
            let mut bad = good.clone();
            bad[at] ^= 0x40;
            std::fs::write(&store, &bad).expect("write");
            let mut s = Scene::new();
            let (_, outcome) = s.add_all_stored(&named(&m), &store, "key-b");
            assert!(
                matches!(outcome, StoreOutcome::Built { ref why, stored: Ok(()) }
                    if why.contains("corrupt")),
                "byte {at}: {outcome:?}"
            );
            assert_eq!(scene_bits(&s), scene_bits(&built));
            assert_eq!(std::fs::read(&store).expect("rewritten"), good);
        }
        std::fs::write(&store, &good[..good.len() - 7]).expect("write");
        let (_, outcome) = Scene::new().add_all_stored(&named(&m), &store, "key-b");
        assert!(matches!(outcome, StoreOutcome::Built { ref why, .. } if why.contains("corrupt")));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The trees of the test meshes from `bytes` stored under key `k`.
    fn reuse(bytes: &[u8], m: &[TriMesh]) -> Result<Vec<Bvh>, Miss> {
        let meshes = named(m);
        let names: Vec<&str> = meshes.iter().map(|x| x.0.as_str()).collect();
        let own: Vec<&TriMesh> = meshes.iter().map(|x| x.2).collect();
        trees_from(Some(bytes), "k", &names, Some(&own))
    }

    #[test]
    fn a_checksummed_file_with_wrong_trees_is_refused() {
        let m = meshes();
        let good: Vec<BvhTopology> = named(&m).iter().map(|x| Bvh::new(x.2).topology()).collect();
        // Trees swapped between the meshes, a slot repeated, a node orphaned: each with a valid
        // checksum and key, each refused.
        let swapped = vec![good[1].clone(), good[0].clone()];
        let mut repeated = good.clone();
        repeated[0].order[1] = repeated[0].order[0];
        let mut orphan = good.clone();
        orphan[1].nodes.push((0, 1));
        let mut cycle = good.clone();
        cycle[0].nodes[0] = (0, 0);
        for (what, t) in [
            ("swapped", swapped),
            ("repeated", repeated),
            ("orphan", orphan),
            ("cycle", cycle),
        ] {
            let bytes = encode("k", &t.iter().map(|t| (t, None)).collect::<Vec<_>>());
            let r = reuse(&bytes, &m);
            assert!(matches!(r, Err(Miss::Corrupt(_))), "{what}: {r:?}");
        }
        let bytes = encode("k", &good.iter().map(|t| (t, None)).collect::<Vec<_>>());
        let trees = reuse(&bytes, &m).expect("good trees");
        assert_eq!(
            trees,
            good.iter()
                .zip(named(&m))
                .map(|(_, x)| Bvh::new(x.2))
                .collect::<Vec<_>>()
        );
    }
}
