//! Ray queries against closed triangle meshes: a bounding-volume hierarchy with a watertight
//! ray/triangle test.
//!
//! Used by the fluoroscopy reference (chord lengths per material along every detector ray) and by
//! the needle (first contact with bone). Both need the same guarantee: a ray that passes exactly
//! through a shared edge or vertex of a closed mesh crosses the surface exactly once there, neither
//! slipping through the crack (a missed crossing turns a chord inside out) nor counting the
//! crossing twice (a doubled crossing unbalances entering and leaving).
//!
//! The triangle test is Woop, Benthin and Wald, "Watertight Ray/Triangle Intersection", JCGT 2(1),
//! 2013: the ray is sheared onto the +z axis, and each triangle edge is tested with a 2-D edge
//! function of its two end points only, so two triangles sharing an edge evaluate bit-identical
//! (negated) edge functions. Where the paper falls back to higher precision for an edge function
//! that is exactly zero, we are already in `f64` and instead break the tie with a fixed symbolic
//! perturbation of the ray (the rasteriser's top-left rule), which assigns a ray through an edge
//! or through a vertex of a non-folded fan to exactly one triangle. The hit distance `t` is
//! computed in `f64`; its error is a few ulp of the distance.
//!
//! ```
//! use sim_core::geom::Bvh;
//! use sim_core::mesh::TriMesh;
//! let cube = TriMesh::axis_aligned_box([-1.0; 3], [1.0; 3]);
//! let bvh = Bvh::new(&cube);
//! // A ray along +x through the exact centre of the cube: it crosses the shared diagonal edge of
//! // the two triangles of each face, and still meets the surface exactly twice.
//! let mut hits = Vec::new();
//! bvh.all_hits([-5.0, 0.0, 0.0], [1.0, 0.0, 0.0], 0.0, f64::INFINITY, &mut hits);
//! assert_eq!(hits.len(), 2);
//! assert!(hits[0].entering && !hits[1].entering);
//! assert!((hits[1].t_mm - hits[0].t_mm - 2.0).abs() < 1e-12);
//! ```

mod bvh;
mod shapes;
mod triangle;

pub use bvh::{
    BVH_BUILDER_VERSION, Bvh, BvhTopology, Hit, SurfaceHit, TopologyError, inside_intervals,
};
pub use shapes::{capped_cylinder, equal_area_vertex_radius};
pub use triangle::{RayPrecomp, intersect_triangle};
