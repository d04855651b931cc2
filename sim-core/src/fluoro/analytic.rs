//! Analytic reference solids (sphere, finite cylinder, convex polyhedron) with the same priority
//! nesting as [`super::Scene`]: the ground truth that mesh chords (CPU and GPU) are validated
//! against.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::attenuation::{FluoroMaterial, MaterialChords};
use crate::mesh::TriMesh;

/// An analytic solid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Solid {
    /// A ball.
    Sphere {
        /// Centre, mm.
        center_mm: [f64; 3],
        /// Radius, mm.
        radius_mm: f64,
    },
    /// A finite circular cylinder with flat caps.
    Cylinder {
        /// Centre of one cap, mm.
        base_mm: [f64; 3],
        /// Centre of the other cap, mm.
        tip_mm: [f64; 3],
        /// Radius, mm.
        radius_mm: f64,
    },
    /// A convex polyhedron as the intersection of half-spaces `n . x <= d` (n need not be unit).
    Convex {
        /// `(n, d)` per face.
        planes: Vec<([f64; 3], f64)>,
    },
}

impl Solid {
    /// The exact convex polyhedron of a closed, outward-wound convex mesh (one half-space per
    /// triangle); used to separate discretisation error from intersection error.
    pub fn convex_hull_of(mesh: &TriMesh) -> Solid {
        let planes = (0..mesh.triangle_count())
            .map(|i| {
                let [a, b, c] = mesh.triangle(i).map(DVec3::from);
                let n = (b - a).cross(c - a);
                (n.to_array(), n.dot(a))
            })
            .collect();
        Solid::Convex { planes }
    }

    /// The parameter interval `[t0, t1]` where `origin + t dir` is inside, if any.
    pub fn interval(&self, o: [f64; 3], d: [f64; 3]) -> Option<(f64, f64)> {
        let (o, d) = (DVec3::from(o), DVec3::from(d));
        match self {
            Solid::Sphere {
                center_mm,
                radius_mm,
            } => {
                let oc = o - DVec3::from(*center_mm);
                let a = d.dot(d);
                let b = d.dot(oc);
                let c = oc.dot(oc) - radius_mm * radius_mm;
                let disc = b * b - a * c;
                if disc <= 0.0 {
                    return None;
                }
                let s = disc.sqrt();
                // Stable roots (no cancellation for the near root).
                let q = -(b + b.signum() * s);
                let (r1, r2) = (q / a, c / q);
                Some((r1.min(r2), r1.max(r2)))
            }
            Solid::Cylinder {
                base_mm,
                tip_mm,
                radius_mm,
            } => {
                let base = DVec3::from(*base_mm);
                let axis = DVec3::from(*tip_mm) - base;
                let len = axis.length();
                let w = axis / len;
                let ob = o - base;
                // Caps: 0 <= (o + t d - base) . w <= len.
                let (dw, ow) = (d.dot(w), ob.dot(w));
                let (mut t0, mut t1) = if dw == 0.0 {
                    if ow < 0.0 || ow > len {
                        return None;
                    }
                    (f64::NEG_INFINITY, f64::INFINITY)
                } else {
                    let (ta, tb) = (-ow / dw, (len - ow) / dw);
                    (ta.min(tb), ta.max(tb))
                };
                // Side: |perp(o + t d - base)|^2 <= r^2.
                let dp = d - w * dw;
                let op = ob - w * ow;
                let a = dp.dot(dp);
                let b = dp.dot(op);
                let c = op.dot(op) - radius_mm * radius_mm;
                if a == 0.0 {
                    if c > 0.0 {
                        return None;
                    }
                } else {
                    let disc = b * b - a * c;
                    if disc <= 0.0 {
                        return None;
                    }
                    let s = disc.sqrt();
                    t0 = t0.max((-b - s) / a);
                    t1 = t1.min((-b + s) / a);
                }
                (t0 < t1).then_some((t0, t1))
            }
            Solid::Convex { planes } => {
                let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                for &(n, dist) in planes {
                    let n = DVec3::from(n);
                    let nd = n.dot(d);
                    let slack = dist - n.dot(o);
                    if nd == 0.0 {
                        if slack < 0.0 {
                            return None;
                        }
                    } else if nd > 0.0 {
                        t1 = t1.min(slack / nd);
                    } else {
                        t0 = t0.max(slack / nd);
                    }
                }
                (t0 < t1).then_some((t0, t1))
            }
        }
    }
}

/// Analytic solids with materials and priorities (higher wins, later wins ties), like a Scene.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct AnalyticScene {
    /// `(solid, material, priority)`.
    pub solids: Vec<(Solid, FluoroMaterial, i32)>,
}

impl AnalyticScene {
    /// Adds a solid with the material's default priority.
    pub fn add(&mut self, solid: Solid, material: FluoroMaterial) {
        self.solids
            .push((solid, material, material.default_priority()));
    }

    /// Exact chords per material along `origin + t dir`, `0 <= t <= t_max` (`dir` a unit vector),
    /// each point given to the highest-priority solid containing it. No cancellous clamp (the
    /// reference scenes have no marrow inset).
    pub fn ray_chords(&self, o: [f64; 3], d: [f64; 3], t_max: f64) -> MaterialChords {
        let mut iv: Vec<(f64, f64, usize)> = Vec::new();
        for (k, (s, _, _)) in self.solids.iter().enumerate() {
            if let Some((a, b)) = s.interval(o, d) {
                let (a, b) = (a.max(0.0), b.min(t_max));
                if a < b {
                    iv.push((a, b, k));
                }
            }
        }
        let mut cuts: Vec<f64> = iv.iter().flat_map(|&(a, b, _)| [a, b]).collect();
        cuts.sort_unstable_by(f64::total_cmp);
        let mut chords = [0.0; FluoroMaterial::COUNT];
        for w in cuts.windows(2) {
            let mid = 0.5 * (w[0] + w[1]);
            let owner = iv
                .iter()
                .filter(|&&(a, b, _)| a <= mid && mid <= b)
                .max_by(|x, y| {
                    self.solids[x.2]
                        .2
                        .cmp(&self.solids[y.2].2)
                        .then(x.2.cmp(&y.2))
                });
            if let Some(&(_, _, k)) = owner {
                chords[self.solids[k].1.index()] += w[1] - w[0];
            }
        }
        chords
    }
}

/// The validation phantom: a soft-tissue sphere (radius 100 mm) holding a bone sphere (radius
/// 30 mm, off-centre) and a steel needle (0.72 mm, 22 G: ISO 9626's regular-wall 22 G tube is
/// 0.698 to 0.730 mm across) that runs from the tissue into the bone. Simulator choice: the
/// three materials of a spinal injection in shapes whose chords are known in closed form, a
/// torso-sized sphere and a vertebra-sized one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SpherePhantom {
    /// Icosphere subdivisions of both sphere meshes (7: 327,680 triangles each).
    pub subdivisions: u32,
    /// Scale each icosphere so its volume equals the sphere's (otherwise vertices lie on the
    /// sphere and the inscribed mesh is smaller).
    pub volume_matched: bool,
    /// Sides of the needle prism (its vertex radius keeps the round shaft's cross-section).
    pub needle_segments: u32,
}

/// Soft-tissue sphere radius, mm.
pub const PHANTOM_SOFT_RADIUS_MM: f64 = 100.0;
/// Bone sphere radius, mm.
pub const PHANTOM_BONE_RADIUS_MM: f64 = 30.0;
/// Bone sphere centre, mm (off-centre so no symmetry hides an error).
pub const PHANTOM_BONE_CENTER_MM: [f64; 3] = [12.0, -8.0, 20.0];
/// Needle outer radius, mm (22 G: 0.72 mm outer diameter).
pub const PHANTOM_NEEDLE_RADIUS_MM: f64 = 0.36;
/// Needle hub end, mm.
pub const PHANTOM_NEEDLE_BASE_MM: [f64; 3] = [-60.0, -70.0, -30.0];
/// Needle tip (inside the bone), mm.
pub const PHANTOM_NEEDLE_TIP_MM: [f64; 3] = [15.0, -10.0, 25.0];

impl SpherePhantom {
    /// The mesh scene and its analytic counterpart (round spheres and a round needle).
    pub fn build(&self) -> (super::Scene, AnalyticScene) {
        use crate::geom::{capped_cylinder, equal_area_vertex_radius};
        use crate::material::MaterialClass;
        let sphere = |c: [f64; 3], r: f64| {
            let mut m = TriMesh::icosphere(c, r, self.subdivisions);
            if self.volume_matched {
                let exact = 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
                let k = (exact / m.signed_volume_mm3()).cbrt();
                m.map_vertices(|v| std::array::from_fn(|a| c[a] + k * (v[a] - c[a])));
            }
            m
        };
        let soft = FluoroMaterial::Tissue(MaterialClass::SoftTissue);
        let bone = FluoroMaterial::Tissue(MaterialClass::CorticalBone);
        let mut scene = super::Scene::new();
        scene.add("soft", soft, &sphere([0.0; 3], PHANTOM_SOFT_RADIUS_MM));
        scene.add(
            "bone",
            bone,
            &sphere(PHANTOM_BONE_CENTER_MM, PHANTOM_BONE_RADIUS_MM),
        );
        let r = equal_area_vertex_radius(PHANTOM_NEEDLE_RADIUS_MM, self.needle_segments);
        scene.add(
            "needle",
            FluoroMaterial::Steel,
            &capped_cylinder(
                PHANTOM_NEEDLE_BASE_MM,
                PHANTOM_NEEDLE_TIP_MM,
                r,
                self.needle_segments,
            ),
        );
        let mut reference = AnalyticScene::default();
        reference.add(
            Solid::Sphere {
                center_mm: [0.0; 3],
                radius_mm: PHANTOM_SOFT_RADIUS_MM,
            },
            soft,
        );
        reference.add(
            Solid::Sphere {
                center_mm: PHANTOM_BONE_CENTER_MM,
                radius_mm: PHANTOM_BONE_RADIUS_MM,
            },
            bone,
        );
        reference.add(
            Solid::Cylinder {
                base_mm: PHANTOM_NEEDLE_BASE_MM,
                tip_mm: PHANTOM_NEEDLE_TIP_MM,
                radius_mm: PHANTOM_NEEDLE_RADIUS_MM,
            },
            FluoroMaterial::Steel,
        );
        (scene, reference)
    }
}

/// Relative error statistics of `-ln T` over the pixels whose analytic `-ln T` is positive.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ErrorStats {
    /// Pixels compared.
    pub pixels: usize,
    /// Median of `|(-ln T_mesh) - (-ln T_exact)| / (-ln T_exact)`.
    pub median: f64,
    /// 99th percentile of the same.
    pub p99: f64,
    /// Maximum.
    pub max: f64,
}

impl ErrorStats {
    /// Statistics of a list of relative errors.
    pub fn of(mut errors: Vec<f64>) -> ErrorStats {
        errors.sort_unstable_by(f64::total_cmp);
        let n = errors.len();
        let q = |f: f64| {
            if n == 0 {
                f64::NAN
            } else {
                errors[((n - 1) as f64 * f).round() as usize]
            }
        };
        ErrorStats {
            pixels: n,
            median: q(0.5),
            p99: q(0.99),
            max: q(1.0),
        }
    }
}

/// Per-pixel relative error of `-ln T` (pixel centres, no supersampling) between mesh chords and
/// analytic chords under `model`.
pub fn neg_log_t_errors(
    chords: &[super::RayChords],
    reference: &AnalyticScene,
    projection: &super::Projection,
    model: &super::SpectralModel,
) -> Vec<f64> {
    use super::attenuation::basis_depths;
    let w = projection.detector_pixels[0] as usize;
    chords
        .iter()
        .enumerate()
        .filter_map(|(p, c)| {
            let ray = projection.pixel_ray([(p % w) as f64 + 0.5, (p / w) as f64 + 0.5]);
            let exact = reference.ray_chords(ray.origin_mm, ray.dir, ray.detector_t_mm);
            let te = -model.transmission(&basis_depths(&exact, 0.0)).ln();
            let tm = -model.transmission(&basis_depths(&c.chords_mm, 0.0)).ln();
            (te > 0.0).then(|| (tm - te).abs() / te)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::capped_cylinder;
    use crate::material::MaterialClass;

    #[test]
    fn shapes_give_the_textbook_chords() {
        let s = Solid::Sphere {
            center_mm: [0.0, 0.0, 0.0],
            radius_mm: 5.0,
        };
        let (a, b) = s.interval([3.0, -10.0, 0.0], [0.0, 1.0, 0.0]).unwrap();
        assert!((b - a - 8.0).abs() < 1e-12);
        let c = Solid::Cylinder {
            base_mm: [0.0, 0.0, -5.0],
            tip_mm: [0.0, 0.0, 5.0],
            radius_mm: 1.0,
        };
        let (a, b) = c.interval([0.6, -10.0, 0.0], [0.0, 1.0, 0.0]).unwrap();
        assert!((b - a - 1.6).abs() < 1e-12);
        let (a, b) = c.interval([0.5, 0.0, -20.0], [0.0, 0.0, 1.0]).unwrap();
        assert!((b - a - 10.0).abs() < 1e-12);
        assert!(c.interval([0.0, 0.0, 6.0], [1.0, 0.0, 0.0]).is_none());
        // The convex hull of a prism mesh has the prism's chord.
        let prism =
            Solid::convex_hull_of(&capped_cylinder([0.0, 0.0, -5.0], [0.0, 0.0, 5.0], 1.0, 4));
        let (a, b) = prism.interval([0.0, -10.0, 0.0], [0.0, 1.0, 0.0]).unwrap();
        // Four segments: a square with vertices on the x and y axes (radius 1), so 2 mm along y.
        assert!((b - a - 2.0).abs() < 1e-12);
    }

    #[test]
    fn nesting_replaces() {
        let mut s = AnalyticScene::default();
        s.add(
            Solid::Sphere {
                center_mm: [0.0; 3],
                radius_mm: 100.0,
            },
            FluoroMaterial::Tissue(MaterialClass::SoftTissue),
        );
        s.add(
            Solid::Sphere {
                center_mm: [0.0; 3],
                radius_mm: 10.0,
            },
            FluoroMaterial::Tissue(MaterialClass::CorticalBone),
        );
        let c = s.ray_chords([0.0, -500.0, 0.0], [0.0, 1.0, 0.0], 1000.0);
        assert!(
            (c[FluoroMaterial::Tissue(MaterialClass::SoftTissue).index()] - 180.0).abs() < 1e-9
        );
        assert!(
            (c[FluoroMaterial::Tissue(MaterialClass::CorticalBone).index()] - 20.0).abs() < 1e-9
        );
    }
}
