//! The nesting plan of an L-buffer renderer: which mesh lies directly inside which, and what
//! each mesh adds to and removes from the per-material chords.
//!
//! [`Scene::ray_chords`] assigns each point of a ray to the highest-priority mesh containing it.
//! An L-buffer only sees per-mesh chords, so every mesh gets its *direct container* (the
//! smallest mesh holding 90 % of points sampled just inside it, tested with the container's
//! [`crate::geom::Bvh::contains`]) and the *effective* material of its interior (the highest
//! priority on its chain of containers; on equal priority the later entry wins, as in
//! [`Scene::ray_chords`]). A mesh adds its chord to its effective material and subtracts it from
//! its container's: for a laminar family of meshes (every pair disjoint or nested) this is
//! exactly the priority rule ("own chord minus the chords of the meshes directly inside").
//! Meshes whose effective material equals their container's add nothing and are left out.
//! Partially overlapping meshes are *not* resolved by priority: their overlap counts twice.
//!
//! Everything here is CPU geometry on the scene's `f64` triangles; the GPU renderer in
//! `render-worker` draws the plan [`nesting_plan`] returns.

use glam::DVec3;

use super::{FluoroMaterial, Scene};
use crate::fluoro::Basis;

/// One mesh of the plan: its raw chord is added to `effective` and subtracted from `container`.
#[derive(Debug, Clone, PartialEq)]
pub struct NestedMesh {
    /// Index of the scene entry.
    pub entry: usize,
    /// Scene entry name.
    pub name: String,
    /// Effective material of its interior (after nesting).
    pub effective: FluoroMaterial,
    /// Effective material of its direct container, if any.
    pub container: Option<FluoroMaterial>,
    /// Centre of its triangles' bounding box, mm (an L-buffer's reference depth).
    pub centre_mm: [f64; 3],
}

impl NestedMesh {
    /// Whether both materials it changes (its effective one and its container's) are in the
    /// water basis (soft tissue inside soft tissue, or in nothing): its net contribution then
    /// touches only the water-basis depth, never the bone basis or the cancellous clamp.
    pub fn water_basis_only(&self) -> bool {
        let water = |m: FluoroMaterial| m.basis() == Basis::Water;
        water(self.effective) && self.container.is_none_or(water)
    }
}

/// The plan of `scene`, in entry order: every non-steel entry that changes some material after
/// nesting (steel entries are the needle, subtracted separately).
pub fn nesting_plan(scene: &Scene) -> Vec<NestedMesh> {
    let entries = scene.entries();
    let container = direct_containers(scene);
    let effective = |m: usize| effective_material(scene, &container, m);
    let mut plan = Vec::new();
    for m in anatomy(scene) {
        let eff = effective(m);
        let cont = container[m].map(effective);
        if cont == Some(eff) {
            continue; // Adds and removes the same material: invisible.
        }
        let (lo, hi) = soup_box(entries[m].bvh.triangles_mm());
        plan.push(NestedMesh {
            entry: m,
            name: entries[m].name.clone(),
            effective: eff,
            container: cont,
            centre_mm: std::array::from_fn(|a| 0.5 * (lo[a] + hi[a])),
        });
    }
    plan
}

/// The non-steel entries of `scene`.
fn anatomy(scene: &Scene) -> Vec<usize> {
    let entries = scene.entries();
    (0..entries.len())
        .filter(|&e| entries[e].material != FluoroMaterial::Steel)
        .collect()
}

/// Each entry's direct container: the smallest (by enclosed volume) larger non-steel mesh whose
/// bounding box holds the entry's and which contains at least 90 % of its
/// [`inner_points`]. `None` for steel entries, uncontained ones and degenerate ones.
pub fn direct_containers(scene: &Scene) -> Vec<Option<usize>> {
    let entries = scene.entries();
    let anatomy = anatomy(scene);
    let volumes: Vec<f64> = entries
        .iter()
        .map(|e| soup_volume(e.bvh.triangles_mm()).abs())
        .collect();
    let mut container: Vec<Option<usize>> = vec![None; entries.len()];
    for &m in &anatomy {
        let pts = inner_points(entries[m].bvh.triangles_mm());
        if pts.is_empty() {
            continue;
        }
        let (lo, hi) = soup_box(entries[m].bvh.triangles_mm());
        container[m] = anatomy
            .iter()
            .copied()
            .filter(|&c| c != m && volumes[c] > volumes[m])
            .filter(|&c| {
                let Some((clo, chi)) = entries[c].bvh.bounds_mm() else {
                    return false;
                };
                if (0..3).any(|a| lo[a] < clo[a] || hi[a] > chi[a]) {
                    return false;
                }
                let inside = pts.iter().filter(|&&p| entries[c].bvh.contains(p)).count();
                inside * 10 >= pts.len() * 9
            })
            .min_by(|&a, &b| volumes[a].total_cmp(&volumes[b]));
    }
    container
}

/// The effective material of entry `m`'s interior: the highest `(priority, index)` on its chain
/// of containers (`container` from [`direct_containers`]).
pub fn effective_material(scene: &Scene, container: &[Option<usize>], m: usize) -> FluoroMaterial {
    let entries = scene.entries();
    let mut best = m;
    let mut cur = container[m];
    while let Some(c) = cur {
        if (entries[c].priority, c) > (entries[best].priority, best) {
            best = c;
        }
        cur = container[c];
    }
    entries[best].material
}

/// Signed volume enclosed by a closed, outward-wound triangle soup, mm^3 (sum of the signed
/// tetrahedra spanned with the origin).
pub fn soup_volume(tris: &[[[f64; 3]; 3]]) -> f64 {
    tris.iter()
        .map(|&[a, b, c]| DVec3::from(a).dot(DVec3::from(b).cross(DVec3::from(c))) / 6.0)
        .sum()
}

/// Axis-aligned bounding box `(min, max)` of a triangle soup, mm (infinite and inverted when
/// empty).
pub fn soup_box(tris: &[[[f64; 3]; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for t in tris {
        for v in t {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
    }
    (lo, hi)
}

/// The cross product `(b - a) x (c - a)` of a triangle's edges: along its outward normal for an
/// outward-wound triangle, twice its area long.
#[inline]
pub fn triangle_cross([a, b, c]: [[f64; 3]; 3]) -> DVec3 {
    let a = DVec3::from(a);
    (DVec3::from(b) - a).cross(DVec3::from(c) - a)
}

/// Up to 48 points just inside a closed, outward-wound soup (triangle centroids moved 0.01 mm
/// against the outward normal), spread evenly over its triangles; degenerate triangles give
/// none.
pub fn inner_points(tris: &[[[f64; 3]; 3]]) -> Vec<[f64; 3]> {
    let n = tris.len().min(48);
    (0..n)
        .filter_map(|k| {
            let t = tris[k * tris.len() / n];
            let nrm = triangle_cross(t);
            let len = nrm.length();
            let [a, b, c] = t.map(DVec3::from);
            (len > 0.0).then(|| ((a + b + c) / 3.0 - 0.01 * nrm / len).to_array())
        })
        .collect()
}
