//! Each phantom structure as a level set: the signed distance bound of the space the painting
//! order leaves to it, clipped to the grid's extent, and its volume by adaptive integration.
//!
//! Structure `i` owns the points inside its solid and outside every solid painted after it, so
//! its level set is `g_i = max(f_i, max_{j > i} -f_j, b)` where `b` is the distance bound of the
//! grid's outer box (a nested structure, see [`super::model::PhantomPart::nested`], keeps its whole
//! solid: `g_i = max(f_i, b)`). A maximum of 1-Lipschitz bounds is a 1-Lipschitz bound with the
//! exact zero set, which is what both uses below need:
//!
//! - the meshing places every vertex on the zero set of `g_i` along its lattice edge (see
//!   `pipeline::build_region_on_level_sets`), so a thin structure's faces are where its solids
//!   put them, not where the linear interpolation of voxel samples does;
//! - [`StructureLevelSet::volume_mm3`] integrates the occupancy of `g_i <= 0` on an octree that
//!   settles whole cells by the Lipschitz bound and refines only cells the surface may cross: the
//!   structure's analytic volume, independent of the meshing lattice, against which the meshes
//!   are measured.
//!
//! Later solids are only consulted where their bounding box reaches: outside it a solid's bound is
//! positive, so `-f_j` is negative and cannot change the sign of `g_i` (the zero set is
//! unchanged; for the octree's Lipschitz culling a later solid is kept for a whole cell whenever
//! its box meets the cell). Within its box, a later solid is evaluated only where the lower bound
//! of its coarse lattice ([`CoarseBound`]) is below `-g`: elsewhere `-f_j` cannot raise `g`, so
//! the value is the same bit for bit. (A box is a loose fit for some solids: each iliac wing's
//! box holds the lumbar canal and the sacrum, where the wing is 60 mm or more away; evaluating
//! the four iliac solids there was half the cost of meshing the spine's structures.)

use std::sync::Arc;

use glam::DVec3;

use super::model::Anatomy;
use super::sdf::{Aabb, CoarseBound, Sdf};
use crate::volume::VolumeGrid;

/// The level set of one phantom structure (see the module documentation).
#[derive(Debug, Clone)]
pub struct StructureLevelSet<'a> {
    solid: &'a Sdf,
    /// Solids painted later whose boxes meet this structure's box, with those boxes and their
    /// coarse lower bounds (shared between the structures).
    later: Vec<(&'a Sdf, Aabb, Arc<CoarseBound>)>,
    /// The grid's outer faces.
    extent: Aabb,
    /// Where `g <= 0` may hold: the solid's box within the extent.
    bounds: Aabb,
}

/// The level sets of every structure of `anatomy`, in painting order, clipped to the outer faces
/// of `grid`.
pub fn level_sets<'a>(anatomy: &'a Anatomy, grid: &VolumeGrid) -> Vec<StructureLevelSet<'a>> {
    let extent = grid_extent(grid);
    let boxes: Vec<Aabb> = anatomy.parts.iter().map(|p| p.sdf.bounds()).collect();
    let later_of = |i: usize| -> Vec<usize> {
        if anatomy.parts[i].nested {
            return Vec::new();
        }
        let bounds = boxes[i].intersect(extent);
        (i + 1..anatomy.parts.len())
            .filter(|&j| !boxes[j].intersect(bounds).is_empty())
            .collect()
    };
    let lists: Vec<Vec<usize>> = (0..anatomy.parts.len()).map(later_of).collect();
    // The lattice of every solid that is some structure's later solid, over its box within the
    // extent (where the structures that consult it can be), built in parallel.
    let mut used = vec![false; anatomy.parts.len()];
    lists.iter().flatten().for_each(|&j| used[j] = true);
    let coarse: Vec<Option<Arc<CoarseBound>>> = crate::par::par_map(
        anatomy.parts.len(),
        &|j| {
            used[j].then(|| {
                Arc::new(CoarseBound::new(
                    &anatomy.parts[j].sdf,
                    boxes[j].intersect(extent),
                ))
            })
        },
        &mut |_| {},
    );
    anatomy
        .parts
        .iter()
        .enumerate()
        .map(|(i, part)| StructureLevelSet {
            solid: &part.sdf,
            later: lists[i]
                .iter()
                .map(|&j| {
                    let lattice = coarse[j].clone();
                    let lattice = lattice.expect("every later solid has its lattice");
                    (&anatomy.parts[j].sdf, boxes[j], lattice)
                })
                .collect(),
            extent,
            bounds: boxes[i].intersect(extent),
        })
        .collect()
}

/// Structures below this volume get the finer reference leaf (see [`reference_leaf_mm`]), mm^3.
pub const SMALL_STRUCTURE_MM3: f64 = 20_000.0;

/// The smallest octree cell of a structure's analytic volume on a grid of `voxel_mm`, given its
/// volume at a quarter voxel: a quarter voxel, or an eighth for structures under
/// [`SMALL_STRUCTURE_MM3`]. Halving the chosen leaf moves no structure of the phantoms by more
/// than 0.5 % (the flavum moves 1.3 % from a quarter to an eighth of the default voxel, then
/// 0.1 %; the large structures move under 0.05 % from a quarter; the tests' `mesh_volume` checks
/// the thinnest). Simulator choice: an eighth everywhere would take 260 s on two cores, most
/// of it in the iliac wings' loose bounds.
pub fn reference_leaf_mm(voxel_mm: f64, quarter_voxel_volume_mm3: f64) -> f64 {
    if quarter_voxel_volume_mm3 < SMALL_STRUCTURE_MM3 {
        voxel_mm / 8.0
    } else {
        voxel_mm / 4.0
    }
}

/// Every structure's analytic volume on `grid` (name, mm^3), in painting order: the octree
/// integral of [`StructureLevelSet::volume_mm3`] with the leaf of [`reference_leaf_mm`].
pub fn structure_volumes_mm3(anatomy: &Anatomy, grid: &VolumeGrid) -> Vec<(String, f64)> {
    let voxel = grid.min_spacing_mm();
    level_sets(anatomy, grid)
        .iter()
        .zip(&anatomy.parts)
        .map(|(s, p)| {
            let coarse = s.volume_mm3(voxel / 4.0);
            let leaf = reference_leaf_mm(voxel, coarse);
            let v = if leaf < voxel / 4.0 {
                s.volume_mm3(leaf)
            } else {
                coarse
            };
            (p.name.clone(), v)
        })
        .collect()
}

/// The box of the grid's outer voxel faces, mm.
pub fn grid_extent(grid: &VolumeGrid) -> Aabb {
    let o = DVec3::from(grid.origin_mm);
    let h = DVec3::from(grid.spacing_mm);
    let n = DVec3::new(
        grid.dims[0] as f64,
        grid.dims[1] as f64,
        grid.dims[2] as f64,
    );
    Aabb {
        min: o - 0.5 * h,
        max: o + (n - 0.5) * h,
    }
}

fn overlaps(a: &Aabb, lo: DVec3, hi: DVec3) -> bool {
    !(a.min.cmpgt(hi).any() || a.max.cmplt(lo).any())
}

impl StructureLevelSet<'_> {
    /// `g` at `p`, mm: negative where the structure owns the point (see the module documentation).
    ///
    /// A later solid `j` enters as `-max(f_j, d_j)`, with `d_j` the exact signed distance to its
    /// box: inside the box that is `-f_j` (a bound is no deeper than the box), outside it is at
    /// most `-d_j`, so the solid is skipped wherever `-d_j` cannot raise `g` (no evaluation of
    /// `f_j`). `g` stays 1-Lipschitz everywhere, which the sampling's settling of whole blocks
    /// from one value relies on: leaving a solid out wherever its box did not contain the point
    /// made `g` too deep just outside that box, and a block centred there was settled inside
    /// while a corner of it was in the later solid (a piece of the L3 root inside the psoas
    /// without a cavity around it, 0.85 mm of doubled tissue on a ray).
    ///
    /// A later solid is evaluated only where its coarse lower bound is below `-g` (where it
    /// could be deeper than `-g`): elsewhere `-max(f_j, d_j) <= -f_j <= g` leaves `g` as it is.
    pub fn eval(&self, p: DVec3) -> f64 {
        let mut g = self.solid.eval(p).max(self.extent.signed_distance_mm(p));
        for (s, b, coarse) in &self.later {
            let d = b.signed_distance_mm(p);
            if -d > g && coarse.lower(p) < -g {
                g = g.max(-s.eval(p).max(d));
            }
        }
        g
    }

    /// [`StructureLevelSet::eval`] without the coarse bounds: every later solid whose box
    /// allows it is evaluated (the reference the bounds are tested against).
    pub fn eval_unbounded(&self, p: DVec3) -> f64 {
        let mut g = self.solid.eval(p).max(self.extent.signed_distance_mm(p));
        for (s, b, _) in &self.later {
            let d = b.signed_distance_mm(p);
            if -d > g {
                g = g.max(-s.eval(p).max(d));
            }
        }
        g
    }

    /// Where the structure may be: its solid's box within the grid's extent.
    pub fn bounds(&self) -> Aabb {
        self.bounds
    }

    /// The structure's volume, mm^3: the integral of its occupancy on an octree of cubes whose
    /// smallest cells have edge `leaf_mm`. A cell is settled whole where the Lipschitz bound
    /// shows the surface cannot reach it; a smallest cell crossed by the surface counts
    /// `clamp(1/2 - g(centre) / leaf, 0, 1)` of itself (exact for a face parallel to the cell's,
    /// and unbiased on average for any other: its integral across the surface is that of the
    /// step). The error falls with the leaf (see [`reference_leaf_mm`]).
    ///
    /// The octree is rooted at the grid's lower outer corner, so cells whose edge divides the grid
    /// spacing never straddle its faces.
    pub fn volume_mm3(&self, leaf_mm: f64) -> f64 {
        assert!(leaf_mm > 0.0 && leaf_mm.is_finite(), "leaf {leaf_mm} mm");
        if self.bounds.is_empty() {
            return 0.0;
        }
        // Root cells of 2^ROOT_LEVELS leaves, tiling the bounds from the extent's lower corner.
        const ROOT_LEVELS: u32 = 5;
        let root = leaf_mm * f64::from(1u32 << ROOT_LEVELS);
        let first = ((self.bounds.min - self.extent.min) / root).floor();
        let last = ((self.bounds.max - self.extent.min) / root).floor();
        let n = (last - first + DVec3::ONE).max(DVec3::ZERO);
        let (nx, ny, nz) = (n.x as usize, n.y as usize, n.z as usize);
        let all: Vec<u16> = (0..self.later.len() as u16).collect();
        let slabs = crate::par::par_map(
            nz,
            &|k| {
                let mut sum = 0.0;
                let mut scratch = Vec::new();
                for j in 0..ny {
                    for i in 0..nx {
                        let lo = self.extent.min
                            + (first + DVec3::new(i as f64, j as f64, k as f64)) * root;
                        sum += self.cell(lo, root, leaf_mm, &all, true, &mut scratch);
                    }
                }
                sum
            },
            &mut |_| {},
        );
        slabs.iter().sum()
    }

    /// Occupied volume of the cube at `lo` with edge `size`, mm^3.
    fn cell(
        &self,
        lo: DVec3,
        size: f64,
        leaf: f64,
        parent: &[u16],
        parent_clip: bool,
        scratch: &mut Vec<Vec<u16>>,
    ) -> f64 {
        let hi = lo + DVec3::splat(size);
        if !overlaps(&self.bounds, lo, hi) {
            return 0.0;
        }
        let clip =
            parent_clip && !(lo.cmpge(self.extent.min).all() && hi.cmple(self.extent.max).all());
        let c = lo + DVec3::splat(0.5 * size);
        let reach = 0.5 * size * 3f64.sqrt();
        let volume = size * size * size;
        // g at the centre, keeping for the children only the later solids whose surface may
        // reach into the cell: one whose bound exceeds the reach at the centre is outside the
        // whole cell (its -f is negative there, so it cannot change g's sign anywhere in the
        // cell, and leaving it out keeps a surface that does not enter the cell out of the
        // leaves' occupancies); one below -reach covers the whole cell, which is then empty.
        let mut g = self.solid.eval(c);
        if clip {
            g = g.max(self.extent.signed_distance_mm(c));
        }
        let mut cands = scratch.pop().unwrap_or_default();
        cands.clear();
        for &k in parent {
            let (s, b, _) = &self.later[usize::from(k)];
            if !overlaps(b, lo, hi) {
                continue;
            }
            let f = s.eval(c);
            if f > reach {
                continue;
            }
            if f < -reach {
                scratch.push(cands);
                return 0.0;
            }
            g = g.max(-f);
            cands.push(k);
        }
        let out = if g >= reach {
            0.0
        } else if g <= -reach {
            volume
        } else if size <= leaf * 1.000_001 {
            (0.5 - g / size).clamp(0.0, 1.0) * volume
        } else {
            let half = 0.5 * size;
            let mut sum = 0.0;
            for o in 0..8u8 {
                let d = DVec3::new(
                    f64::from(o & 1),
                    f64::from((o >> 1) & 1),
                    f64::from((o >> 2) & 1),
                );
                sum += self.cell(lo + d * half, half, leaf, &cands, clip, scratch);
            }
            sum
        };
        scratch.push(cands);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::anatomy::phantom::model::PhantomPart;
    use crate::material::MaterialClass;

    fn part(name: &str, sdf: Sdf, nested: bool) -> PhantomPart {
        PhantomPart {
            name: name.into(),
            material: MaterialClass::SoftTissue,
            sdf,
            nested,
        }
    }

    #[test]
    fn a_sphere_minus_a_later_sphere_has_the_analytic_volume() {
        // A ball of radius 20 mm; a later ball of radius 8 mm centred 15 mm off takes a lens
        // from it: V = 4/3 pi R^3 - lens(R, r, d).
        let (r1, r2, d) = (20.0f64, 8.0f64, 15.0f64);
        let anatomy = Anatomy {
            parts: vec![
                part("big", Sdf::Sphere { radius: r1 }, false),
                part(
                    "small",
                    Sdf::Sphere { radius: r2 }.at(DVec3::new(d, 0.0, 0.0)),
                    false,
                ),
            ],
            landmarks: vec![],
        };
        let g = VolumeGrid::centred_cube(40, 1.5);
        let sets = level_sets(&anatomy, &g);
        // Lens of two spheres (radii R, r, centre distance d).
        let lens = std::f64::consts::PI
            * (r1 + r2 - d).powi(2)
            * (d * d + 2.0 * d * r2 - 3.0 * r2 * r2 + 2.0 * d * r1 + 6.0 * r1 * r2 - 3.0 * r1 * r1)
            / (12.0 * d);
        let big = 4.0 / 3.0 * std::f64::consts::PI * r1.powi(3) - lens;
        let small = 4.0 / 3.0 * std::f64::consts::PI * r2.powi(3);
        let vb = sets[0].volume_mm3(0.25);
        let vs = sets[1].volume_mm3(0.25);
        // Quadrature of a curved surface by 0.25 mm cells: well under 0.1 % (measured 0.01 %).
        assert!((vb - big).abs() < 1e-3 * big, "{vb} vs {big}");
        assert!((vs - small).abs() < 1e-3 * small, "{vs} vs {small}");
        // Sign and zero set: inside the lens the big sphere's set is positive.
        assert!(sets[0].eval(DVec3::new(15.0, 0.0, 0.0)) > 0.0);
        assert!(sets[0].eval(DVec3::ZERO) < 0.0);
    }

    #[test]
    fn a_later_solid_off_a_block_centre_still_cuts_the_sampled_lattice() {
        // A later ball of 1.6 mm at a lattice point that starts an 8^3 block of the sampling,
        // whose centre (6 mm away, outside the ball's box) is 18 mm deep in the earlier ball:
        // the block must not be settled inside, so the lattice point in the later ball is outside
        // the earlier structure, as everywhere else its sampled sign is the level set's.
        let anatomy = Anatomy {
            parts: vec![
                part("big", Sdf::Sphere { radius: 18.0 }, false),
                part(
                    "small",
                    Sdf::Sphere { radius: 1.6 }.at(DVec3::splat(-3.5)),
                    false,
                ),
            ],
            landmarks: vec![],
        };
        let g = VolumeGrid::centred_cube(40, 1.0);
        assert_eq!(g.voxel_center_mm(16, 16, 16), [-3.5; 3]);
        let sets = level_sets(&anatomy, &g);
        let f = |p: [f64; 3]| sets[0].eval(DVec3::from(p));
        let (values, _) = crate::anatomy::level_set_mesh::sample_level_set(&f, &g);
        for (idx, &v) in values.iter().enumerate() {
            let [i, j, k] = g.ijk(idx);
            let inside = f(g.voxel_center_mm(i, j, k)) < 0.0;
            assert_eq!(v > 0.5, inside, "{i} {j} {k}");
        }
        assert!(values[g.index(16, 16, 16)] <= 0.5);
    }

    #[test]
    fn a_solid_cut_by_the_grid_counts_only_inside_the_extent() {
        // A nested slab of 10 mm crossing the whole 30 mm grid: 10 x 30 x 30 mm inside.
        let anatomy = Anatomy {
            parts: vec![part(
                "slab",
                Sdf::RoundBox {
                    half: DVec3::new(5.0, 100.0, 100.0),
                    round: 0.0,
                },
                true,
            )],
            landmarks: vec![],
        };
        let g = VolumeGrid::centred_cube(20, 1.5);
        let sets = level_sets(&anatomy, &g);
        let v = sets[0].volume_mm3(0.375);
        assert!((v - 9000.0).abs() < 1e-6 * 9000.0, "{v}");
        // Outside the extent the level set is positive even inside the solid.
        assert!(sets[0].eval(DVec3::new(0.0, 15.5, 0.0)) > 0.0);
        assert!(sets[0].eval(DVec3::new(0.0, 14.5, 0.0)) < 0.0);
    }

    /// The coarse bounds only skip later solids that cannot change `g`: on the shipped lumbar
    /// phantom and the neck phantom, `eval` equals `eval_unbounded` bit for bit at points
    /// scattered through every structure's box and at points on and near every solid's surface
    /// (the lattice points of the meshing are where the bounds matter).
    #[test]
    fn the_coarse_bounds_change_no_value() {
        use crate::anatomy::phantom::{self, PhantomParams, cervical};
        let mut rng = crate::rng::SplitMix64::new(0x2545_f491_4f6c_dd1d);
        let mut next = move || rng.next_f64();
        for params in [PhantomParams::default(), cervical::default_params()] {
            let anatomy = if params == cervical::default_params() {
                cervical::anatomy(&params)
            } else {
                phantom::anatomy(&params)
            };
            let sets = level_sets(&anatomy, &params.grid());
            let (mut skipped_somewhere, mut near) = (false, 0usize);
            for set in &sets {
                let b = set.bounds();
                if b.is_empty() {
                    continue;
                }
                for n in 0..4000 {
                    let t = DVec3::new(next(), next(), next());
                    let mut p = b.min + t * (b.max - b.min);
                    // Every other point is pulled onto the structure's own zero set along a
                    // random direction (a few steps of the bound), where the roots are found.
                    if n % 2 == 1 {
                        for _ in 0..6 {
                            let g = set.eval_unbounded(p);
                            p -= g * DVec3::new(next() - 0.5, next() - 0.5, next() - 0.5)
                                .normalize_or(DVec3::X);
                        }
                        near += usize::from(set.eval_unbounded(p).abs() < 1.0);
                    }
                    let (a, r) = (set.eval(p), set.eval_unbounded(p));
                    assert_eq!(a.to_bits(), r.to_bits(), "{p:?}: {a} vs {r}");
                    skipped_somewhere |= set
                        .later
                        .iter()
                        .any(|(_, bx, c)| -bx.signed_distance_mm(p) > r && c.lower(p) >= -r);
                }
            }
            assert!(skipped_somewhere, "the bounds skip some later solid");
            assert!(near > 1000, "{near} points near a surface");
        }
    }
}
