//! C-arm projection geometry: the one type that maps detector pixels to rays and 3-D points to
//! pixels, shared by the renderer (CPU and GPU), picking and the scorers.
//!
//! # Frames
//! *Model frame* (the anatomy assets' frame, RAS like the NIfTI world of imported CT),
//! millimetres: **x = patient right, y = anterior, z = cranial (superior)**; right-handed. The
//! patient lies supine on the table with the long axis along z.
//!
//! *C-arm*: a point source [`SOURCE_TO_ISOCENTRE_MM`] from the isocentre and a flat detector
//! [`ISOCENTRE_TO_DETECTOR_MM`] on the other side (figures of the methods page of the system that
//! inspired us). With both angles zero the tube is under the table (posterior) and the detector
//! above the patient (anterior): the central ray runs along +y. The unit vector from isocentre to
//! detector centre is
//! `n = (-sin(orbital) cos(angular), cos(orbital) cos(angular), sin(angular))`:
//! a positive `orbital_deg` is LAO (detector towards the patient's left, -x), negative is RAO; a
//! positive `angular_deg` is cranial (detector towards the head), negative is caudal.
//!
//! *Image*: pixel columns run to the screen's right, rows downwards; in the neutral (AP) view the
//! head is at the top and the patient's right on the screen's left (the radiological convention).
//! Screen-right is `u = (-cos(orbital), -sin(orbital), 0)` (orbital rotation about z carries it),
//! screen-up is `cos(angular) z - sin(angular) n_orbital`, so `u x up = n`.
//!
//! *Continuous pixel coordinates* `[x, y]`: pixel `(i, j)` (column `i`, row `j`) covers
//! `[i, i+1) x [j, j+1)`, its centre is `[i + 0.5, j + 0.5]`, the image's top-left corner is
//! `[0, 0]`.
//!
//! *Table translation*: moving the table by `d` moves the patient by `d` relative to the C-arm, so
//! a point `p` is imaged where `p + d` would be with the table at zero.

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// Source to isocentre, mm (methods page: "a nominal source 730 mm from isocentre").
pub const SOURCE_TO_ISOCENTRE_MM: f64 = 730.0;
/// Isocentre to detector, mm (methods page: "the detector 750 mm on the opposite side").
pub const ISOCENTRE_TO_DETECTOR_MM: f64 = 750.0;

/// Collimator opening in the detector plane, millimetres from the detector centre, x to the
/// screen's right and y downwards (the pixel axes). Pixels whose centre is outside receive no
/// primary beam.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Collimation {
    /// Left blade, mm (negative: left of the centre).
    pub x_min_mm: f64,
    /// Right blade, mm.
    pub x_max_mm: f64,
    /// Top blade, mm (negative: above the centre).
    pub y_min_mm: f64,
    /// Bottom blade, mm.
    pub y_max_mm: f64,
    /// Circular iris radius around the detector centre, mm (an image intensifier's round field),
    /// or `None` for none.
    pub iris_radius_mm: Option<f64>,
}

impl Collimation {
    /// Fully open: no blade inside the detector.
    pub const OPEN: Collimation = Collimation {
        x_min_mm: f64::NEG_INFINITY,
        x_max_mm: f64::INFINITY,
        y_min_mm: f64::NEG_INFINITY,
        y_max_mm: f64::INFINITY,
        iris_radius_mm: None,
    };

    /// Whether the detector-plane point `(x, y)` (mm from the centre) is inside the opening.
    pub fn is_open(&self, x_mm: f64, y_mm: f64) -> bool {
        x_mm >= self.x_min_mm
            && x_mm <= self.x_max_mm
            && y_mm >= self.y_min_mm
            && y_mm <= self.y_max_mm
            && self
                .iris_radius_mm
                .is_none_or(|r| x_mm * x_mm + y_mm * y_mm <= r * r)
    }
}

/// A C-arm pose plus detector: everything that decides where a point appears in the image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Projection {
    /// Source to isocentre, mm.
    pub source_to_isocentre_mm: f64,
    /// Isocentre to detector plane, mm.
    pub isocentre_to_detector_mm: f64,
    /// Orbital rotation, degrees: positive LAO, negative RAO.
    pub orbital_deg: f64,
    /// Angular rotation, degrees: positive cranial, negative caudal.
    pub angular_deg: f64,
    /// Model-frame point at the C-arm isocentre when the table is at zero, mm.
    pub isocentre_mm: [f64; 3],
    /// Table translation in model-frame axes, mm (see the module doc).
    pub table_translation_mm: [f64; 3],
    /// Detector size in pixels: `[columns, rows]`.
    pub detector_pixels: [u32; 2],
    /// Pixel pitch in the detector plane, mm: `[column pitch, row pitch]`.
    pub pixel_pitch_mm: [f64; 2],
    /// Collimator opening.
    pub collimation: Collimation,
}

impl Default for Projection {
    /// AP view centred on the model origin, 512 x 512 pixels over a 300 mm square detector
    /// (simulator choice: the size of a common 30 cm flat panel).
    fn default() -> Self {
        Projection {
            source_to_isocentre_mm: SOURCE_TO_ISOCENTRE_MM,
            isocentre_to_detector_mm: ISOCENTRE_TO_DETECTOR_MM,
            orbital_deg: 0.0,
            angular_deg: 0.0,
            isocentre_mm: [0.0; 3],
            table_translation_mm: [0.0; 3],
            detector_pixels: [512, 512],
            pixel_pitch_mm: [300.0 / 512.0; 2],
            collimation: Collimation::OPEN,
        }
    }
}

/// A ray from the source: `origin_mm + t * dir`, `dir` a unit vector (so `t` is in mm).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Ray {
    /// The focal spot, mm.
    pub origin_mm: [f64; 3],
    /// Unit direction.
    pub dir: [f64; 3],
    /// Distance from the source to the detector along this ray, mm.
    pub detector_t_mm: f64,
}

/// The derived detector frame of a [`Projection`] (all model-frame millimetres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DetectorFrame {
    /// Focal spot.
    pub source_mm: [f64; 3],
    /// Centre of the detector plane.
    pub detector_centre_mm: [f64; 3],
    /// Unit vector from the isocentre towards the detector (the central ray's direction).
    pub normal: [f64; 3],
    /// Unit vector of increasing column (screen right).
    pub u: [f64; 3],
    /// Unit vector of increasing row (screen down).
    pub v: [f64; 3],
    /// Centre of pixel (0, 0) on the detector.
    pub pixel00_mm: [f64; 3],
    /// Step from one column to the next on the detector (`u * column pitch`).
    pub step_u_mm: [f64; 3],
    /// Step from one row to the next on the detector (`v * row pitch`).
    pub step_v_mm: [f64; 3],
}

/// What a GPU needs to generate exactly the CPU's rays, in `f32`, relative to the source (so no
/// large absolute coordinates lose precision): the ray through continuous pixel coordinates
/// `[x, y]` starts at `source_mm` and has direction
/// `pixel00_from_source_mm + (x - 0.5) * step_u_mm + (y - 0.5) * step_v_mm` (not normalised; its
/// length is the source-to-detector distance along that ray).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GpuRayFrame {
    /// Focal spot, model frame, mm.
    pub source_mm: [f32; 3],
    /// Centre of pixel (0, 0) minus the source, mm.
    pub pixel00_from_source_mm: [f32; 3],
    /// Per-column step on the detector, mm.
    pub step_u_mm: [f32; 3],
    /// Per-row step on the detector, mm.
    pub step_v_mm: [f32; 3],
}

impl Projection {
    /// Source-to-image distance, mm.
    pub fn source_to_detector_mm(&self) -> f64 {
        self.source_to_isocentre_mm + self.isocentre_to_detector_mm
    }

    /// Magnification of an object at the isocentre (SID / SOD; 1480 / 730 = 2.03 by default).
    pub fn isocentre_magnification(&self) -> f64 {
        self.source_to_detector_mm() / self.source_to_isocentre_mm
    }

    /// Detector size `[width, height]` in mm.
    pub fn detector_size_mm(&self) -> [f64; 2] {
        [
            self.detector_pixels[0] as f64 * self.pixel_pitch_mm[0],
            self.detector_pixels[1] as f64 * self.pixel_pitch_mm[1],
        ]
    }

    /// The isocentre in the model frame once the table translation is applied.
    pub fn effective_isocentre_mm(&self) -> [f64; 3] {
        std::array::from_fn(|a| self.isocentre_mm[a] - self.table_translation_mm[a])
    }

    /// The detector frame of this pose.
    pub fn frame(&self) -> DetectorFrame {
        let (sa, ca) = self.orbital_deg.to_radians().sin_cos();
        let (sb, cb) = self.angular_deg.to_radians().sin_cos();
        let n_orbital = [-sa, ca, 0.0];
        let normal = [-sa * cb, ca * cb, sb];
        let u = [-ca, -sa, 0.0];
        let up = [-sb * n_orbital[0], -sb * n_orbital[1], cb];
        let v = up.map(|x| -x);
        let iso = self.effective_isocentre_mm();
        let source_mm = std::array::from_fn(|a| iso[a] - self.source_to_isocentre_mm * normal[a]);
        let detector_centre_mm =
            std::array::from_fn(|a| iso[a] + self.isocentre_to_detector_mm * normal[a]);
        let step_u_mm = u.map(|x| x * self.pixel_pitch_mm[0]);
        let step_v_mm = v.map(|x| x * self.pixel_pitch_mm[1]);
        let half = [
            self.detector_pixels[0] as f64 / 2.0 - 0.5,
            self.detector_pixels[1] as f64 / 2.0 - 0.5,
        ];
        let pixel00_mm = std::array::from_fn(|a| {
            detector_centre_mm[a] - half[0] * step_u_mm[a] - half[1] * step_v_mm[a]
        });
        DetectorFrame {
            source_mm,
            detector_centre_mm,
            normal,
            u,
            v,
            pixel00_mm,
            step_u_mm,
            step_v_mm,
        }
    }

    /// Detector-plane offset `(x, y)` in mm from the detector centre of continuous pixel
    /// coordinates (x to the right, y down), the coordinates [`Collimation`] uses.
    pub fn pixel_to_detector_offset_mm(&self, px: [f64; 2]) -> [f64; 2] {
        [
            (px[0] - self.detector_pixels[0] as f64 / 2.0) * self.pixel_pitch_mm[0],
            (px[1] - self.detector_pixels[1] as f64 / 2.0) * self.pixel_pitch_mm[1],
        ]
    }

    /// The point on the detector at continuous pixel coordinates `px`.
    pub fn detector_point_mm(&self, px: [f64; 2]) -> [f64; 3] {
        let f = self.frame();
        let [x, y] = self.pixel_to_detector_offset_mm(px);
        std::array::from_fn(|a| f.detector_centre_mm[a] + x * f.u[a] + y * f.v[a])
    }

    /// The ray from the source through continuous pixel coordinates `px` (picking: every model
    /// point on it images at `px`).
    pub fn pixel_ray(&self, px: [f64; 2]) -> Ray {
        ray_through(&self.frame(), self, px)
    }

    /// Continuous pixel coordinates where the model point `p_mm` is imaged, or `None` when it is
    /// not in front of the source.
    pub fn project_point(&self, p_mm: [f64; 3]) -> Option<[f64; 2]> {
        let f = self.frame();
        let q = DVec3::from(p_mm) - DVec3::from(f.source_mm);
        let depth = q.dot(f.normal.into());
        if depth <= 0.0 {
            return None;
        }
        let s = self.source_to_detector_mm() / depth;
        Some([
            q.dot(f.u.into()) * s / self.pixel_pitch_mm[0] + self.detector_pixels[0] as f64 / 2.0,
            q.dot(f.v.into()) * s / self.pixel_pitch_mm[1] + self.detector_pixels[1] as f64 / 2.0,
        ])
    }

    /// The 3 x 4 matrix `P` with `P * (x, y, z, 1) = (px * w, py * w, w)`: continuous pixel
    /// coordinates after division by `w`, the depth along the central ray from the source (mm).
    pub fn projection_matrix(&self) -> [[f64; 4]; 3] {
        let f = self.frame();
        let sid = self.source_to_detector_mm();
        let cx = self.detector_pixels[0] as f64 / 2.0;
        let cy = self.detector_pixels[1] as f64 / 2.0;
        let row_x: [f64; 3] =
            std::array::from_fn(|a| f.u[a] * sid / self.pixel_pitch_mm[0] + cx * f.normal[a]);
        let row_y: [f64; 3] =
            std::array::from_fn(|a| f.v[a] * sid / self.pixel_pitch_mm[1] + cy * f.normal[a]);
        let row_w = f.normal;
        let t = |r: [f64; 3]| [r[0], r[1], r[2], -DVec3::from(r).dot(f.source_mm.into())];
        [t(row_x), t(row_y), t(row_w)]
    }

    /// The `f32` ray generator a GPU shader needs to reproduce [`Projection::pixel_ray`].
    pub fn gpu_ray_frame(&self) -> GpuRayFrame {
        let f = self.frame();
        GpuRayFrame {
            source_mm: f.source_mm.map(|x| x as f32),
            pixel00_from_source_mm: std::array::from_fn(|a| {
                (f.pixel00_mm[a] - f.source_mm[a]) as f32
            }),
            step_u_mm: f.step_u_mm.map(|x| x as f32),
            step_v_mm: f.step_v_mm.map(|x| x as f32),
        }
    }

    /// Whether the beam reaches continuous pixel coordinates `px` (inside the collimator opening).
    pub fn is_exposed(&self, px: [f64; 2]) -> bool {
        let [x, y] = self.pixel_to_detector_offset_mm(px);
        self.collimation.is_open(x, y)
    }
}

/// Ray through `px` given a precomputed frame (the renderer computes the frame once per image).
pub(crate) fn ray_through(f: &DetectorFrame, p: &Projection, px: [f64; 2]) -> Ray {
    let [x, y] = p.pixel_to_detector_offset_mm(px);
    let d: [f64; 3] =
        std::array::from_fn(|a| f.detector_centre_mm[a] + x * f.u[a] + y * f.v[a] - f.source_mm[a]);
    let d = DVec3::from(d);
    let len = d.length();
    Ray {
        origin_mm: f.source_mm,
        // Divided by the length, not multiplied by its reciprocal (glam's `normalize`): the rays,
        // and so every frame, keep the values they had before glam was used here.
        dir: (d / len).to_array(),
        detector_t_mm: len,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn poses() -> Vec<Projection> {
        let mut v = Vec::new();
        for (orb, ang) in [
            (0.0, 0.0),
            (30.0, 0.0),
            (-45.0, 20.0),
            (90.0, -25.0),
            (12.5, 33.0),
        ] {
            v.push(Projection {
                orbital_deg: orb,
                angular_deg: ang,
                isocentre_mm: [10.0, -20.0, 150.0],
                table_translation_mm: [3.0, -7.0, 40.0],
                detector_pixels: [640, 480],
                pixel_pitch_mm: [0.4, 0.45],
                ..Projection::default()
            });
        }
        v
    }

    #[test]
    fn pixel_to_ray_to_pixel_round_trips_to_far_below_a_pixel() {
        for p in poses() {
            for &px in &[[0.5, 0.5], [320.0, 240.0], [639.5, 0.25], [17.3, 401.9]] {
                let r = p.pixel_ray(px);
                // Any point along the ray (before, inside and beyond the patient) maps back.
                for t in [100.0, 730.0, 1400.0] {
                    let q = std::array::from_fn(|a| r.origin_mm[a] + t * r.dir[a]);
                    let back = p.project_point(q).unwrap();
                    // 1e-9 px: pure f64 rounding over a ~1.5 m lever arm.
                    assert!(
                        (back[0] - px[0]).abs() < 1e-9 && (back[1] - px[1]).abs() < 1e-9,
                        "{back:?} {px:?}"
                    );
                    // And the 3x4 matrix agrees.
                    let m = p.projection_matrix();
                    let h: [f64; 3] = std::array::from_fn(|k| {
                        m[k][0] * q[0] + m[k][1] * q[1] + m[k][2] * q[2] + m[k][3]
                    });
                    assert!(
                        (h[0] / h[2] - px[0]).abs() < 1e-9 && (h[1] / h[2] - px[1]).abs() < 1e-9
                    );
                }
                // The ray ends on the detector point of that pixel.
                let end: [f64; 3] =
                    std::array::from_fn(|a| r.origin_mm[a] + r.detector_t_mm * r.dir[a]);
                let det = p.detector_point_mm(px);
                assert!((0..3).all(|a| (end[a] - det[a]).abs() < 1e-9));
            }
        }
    }

    #[test]
    fn ap_view_follows_the_radiological_convention() {
        let p = Projection::default();
        let f = p.frame();
        assert_eq!(f.source_mm, [0.0, -730.0, 0.0]);
        assert_eq!(f.detector_centre_mm, [0.0, 750.0, 0.0]);
        let c = p.project_point([0.0; 3]).unwrap();
        assert_eq!(c, [256.0, 256.0]);
        // Patient's left (-x) appears on the screen's right; cranial (+z) at the top.
        let left = p.project_point([-10.0, 0.0, 0.0]).unwrap();
        let head = p.project_point([0.0, 0.0, 10.0]).unwrap();
        assert!(left[0] > 256.0 && (left[1] - 256.0).abs() < 1e-12);
        assert!(head[1] < 256.0 && (head[0] - 256.0).abs() < 1e-12);
        // Magnification at the isocentre: 10 mm becomes 10 * 1480/730 mm on the detector.
        let px_per_mm = (left[0] - 256.0) / 10.0;
        assert!((px_per_mm * p.pixel_pitch_mm[0] - 1480.0 / 730.0).abs() < 1e-12);
    }

    #[test]
    fn orbital_and_angular_rotations_move_the_detector_as_named() {
        let lao = Projection {
            orbital_deg: 90.0,
            ..Projection::default()
        }
        .frame();
        assert!(
            lao.detector_centre_mm[0] < -749.0,
            "LAO 90: detector on the patient's left"
        );
        let rao = Projection {
            orbital_deg: -30.0,
            ..Projection::default()
        }
        .frame();
        assert!(rao.detector_centre_mm[0] > 0.0);
        let cra = Projection {
            angular_deg: 20.0,
            ..Projection::default()
        }
        .frame();
        assert!(cra.detector_centre_mm[2] > 0.0);
        for f in [lao, rao, cra] {
            // u x (-v) = n: a right-handed screen frame whose normal faces the viewer.
            let up = f.v.map(|x| -x);
            let c = [
                f.u[1] * up[2] - f.u[2] * up[1],
                f.u[2] * up[0] - f.u[0] * up[2],
                f.u[0] * up[1] - f.u[1] * up[0],
            ];
            assert!((0..3).all(|a| (c[a] - f.normal[a]).abs() < 1e-12));
        }
    }

    #[test]
    fn table_translation_moves_the_patient_relative_to_the_beam() {
        let d = [5.0, -3.0, 40.0];
        let moved = Projection {
            table_translation_mm: d,
            orbital_deg: 25.0,
            ..Projection::default()
        };
        let fixed = Projection {
            orbital_deg: 25.0,
            ..Projection::default()
        };
        let p = [12.0, 30.0, -8.0];
        let a = moved.project_point(p).unwrap();
        let b = fixed
            .project_point(std::array::from_fn(|k| p[k] + d[k]))
            .unwrap();
        assert!((a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9);
    }

    #[test]
    fn gpu_frame_reproduces_the_rays_in_f32() {
        let p = poses()[2];
        let g = p.gpu_ray_frame();
        for px in [[0.5, 0.5], [100.5, 300.5], [639.5, 479.5]] {
            let r = p.pixel_ray(px);
            let d: [f32; 3] = std::array::from_fn(|a| {
                g.pixel00_from_source_mm[a]
                    + (px[0] as f32 - 0.5) * g.step_u_mm[a]
                    + (px[1] as f32 - 0.5) * g.step_v_mm[a]
            });
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            // f32 has 24 bits: 1e-6 relative is a few ulp of the ~1.5 m ray.
            assert!((len as f64 - r.detector_t_mm).abs() < 1e-6 * r.detector_t_mm);
            assert!((0..3).all(|a| ((d[a] / len) as f64 - r.dir[a]).abs() < 1e-6));
        }
    }

    #[test]
    fn collimation_and_serde() {
        let p = Projection {
            collimation: Collimation {
                x_min_mm: -50.0,
                x_max_mm: 60.0,
                y_min_mm: -40.0,
                y_max_mm: 40.0,
                iris_radius_mm: Some(70.0),
            },
            ..Projection::default()
        };
        assert!(p.is_exposed([256.0, 256.0]));
        assert!(!p.is_exposed([0.5, 256.0]));
        // Inside the blades, outside the iris (corner at x 60, y 40 mm: radius 72 mm).
        let px_per_mm = 512.0 / 300.0;
        assert!(!p.is_exposed([256.0 + 59.0 * px_per_mm, 256.0 + 39.0 * px_per_mm]));
        let json = serde_json::to_string(&p).unwrap();
        assert_eq!(serde_json::from_str::<Projection>(&json).unwrap(), p);
    }
}
