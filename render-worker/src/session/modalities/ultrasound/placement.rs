//! The placement view: the patient's back seen from outside (the skin surface, shaded), the
//! probe on it with its orientation marker, the needle's hub and the shaft outside the skin,
//! and, at stations with a C-arm, its central beam. The learner drags the probe on this view (`probe_drag`): a pixel maps to the skin
//! point it shows.
//!
//! A small CPU ray caster: the skin's depth and shading per pixel are computed once per region
//! and camera (the camera is fixed per station site) and cached; each frame then only casts the
//! pixels the probe and the needle cover, depth-tested against the skin.

use std::sync::{Arc, Mutex};

use glam::DVec3;
use sim_core::ultrasound::{ProbeKind, ProbePose};

use crate::session::image::ViewImage;
use crate::session::region::Region;
use crate::session::world::World;

/// Placement view size, pixels. Simulator choice: enough to place a probe to a few millimetres
/// (about 0.7 mm per pixel at the site).
pub const WIDTH: u32 = 384;
/// Height, pixels.
pub const HEIGHT: u32 = 288;
/// Camera distance from the site, mm, and its vertical field of view, degrees (simulator choice:
/// the lower back from the lowest ribs to the sacrum fills the view).
pub const CAMERA_DISTANCE_MM: f64 = 330.0;
/// Vertical field of view, degrees.
pub const FOV_DEG: f64 = 45.0;
/// Probe body height above the skin and thickness across the slice, mm (a typical probe head).
pub const PROBE_HEIGHT_MM: f64 = 45.0;
/// Probe thickness across the slice, mm.
pub const PROBE_THICKNESS_MM: f64 = 14.0;
/// Drawn radius of the needle shaft, mm: thicker than the real 0.36 mm so it covers a pixel.
pub const SHAFT_DRAW_RADIUS_MM: f64 = 0.9;
/// Hub radius and length, mm (a spinal needle's plastic hub).
pub const HUB_RADIUS_MM: f64 = 3.5;
/// Hub length, mm.
pub const HUB_LENGTH_MM: f64 = 16.0;
/// The C-arm beam is drawn from this far before the isocentre to this far (mm along the beam,
/// source side): from inside the body out past the skin of the back.
pub const CARM_ROD_MM: [f64; 2] = [40.0, 200.0];
/// Grey of the background.
const BACKGROUND: u8 = 24;

/// A pinhole camera looking at the site from behind, from the patient's left and from above.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye, mm.
    pub eye: DVec3,
    /// Unit viewing direction.
    pub forward: DVec3,
    /// Image right.
    pub right: DVec3,
    /// Image up.
    pub up: DVec3,
    /// Focal length in pixels.
    pub focal_px: f64,
}

impl Camera {
    /// The camera of a station site: looking at the skin over the site from posterior (-y),
    /// 25 degrees from the patient's left side and 20 degrees from cranial, head up.
    pub fn for_site(region: &Region, site_mm: [f64; 3]) -> Camera {
        let site = DVec3::from_array(site_mm);
        let back = region
            .entry("skin")
            .and_then(|i| region.scene.entries()[i].bvh.bounds_mm())
            .map_or(site.y - 60.0, |(lo, _)| lo[1]);
        let look_at = DVec3::new(site.x, back + 20.0, site.z);
        let (s1, c1) = 25f64.to_radians().sin_cos();
        let (s2, c2) = 20f64.to_radians().sin_cos();
        // From posterior (-y), turned towards the patient's left (-x) and head (+z).
        let from = DVec3::new(-s1 * c2, -c1 * c2, s2).normalize();
        let eye = look_at + from * CAMERA_DISTANCE_MM;
        let forward = (look_at - eye).normalize();
        let right = forward.cross(DVec3::Z).normalize();
        let up = right.cross(forward);
        Camera {
            eye,
            forward,
            right,
            up,
            focal_px: 0.5 * f64::from(HEIGHT) / (0.5 * FOV_DEG.to_radians()).tan(),
        }
    }

    /// Unit ray direction through continuous pixel `(x, y)`.
    pub fn ray(&self, x: f64, y: f64) -> DVec3 {
        (self.forward + self.right * ((x - 0.5 * f64::from(WIDTH)) / self.focal_px)
            - self.up * ((y - 0.5 * f64::from(HEIGHT)) / self.focal_px))
            .normalize()
    }

    /// Continuous pixel of a point in front of the camera.
    pub fn project(&self, p: DVec3) -> Option<[f64; 2]> {
        let v = p - self.eye;
        let z = v.dot(self.forward);
        (z > 1.0).then(|| {
            [
                0.5 * f64::from(WIDTH) + self.focal_px * v.dot(self.right) / z,
                0.5 * f64::from(HEIGHT) - self.focal_px * v.dot(self.up) / z,
            ]
        })
    }
}

/// The skin point and its outward normal under pixel `(x, y)`.
pub fn skin_at_pixel(region: &Region, cam: &Camera, pixel: [f64; 2]) -> Option<(DVec3, DVec3)> {
    let skin = region.entry("skin")?;
    let d = cam.ray(pixel[0], pixel[1]);
    let h = region.scene.entries()[skin].bvh.first_hit(
        cam.eye.to_array(),
        d.to_array(),
        0.0,
        4.0 * CAMERA_DISTANCE_MM,
    )?;
    h.hit
        .entering
        .then(|| (DVec3::from_array(h.point_mm), DVec3::from_array(h.normal)))
}

/// Skin depth (ray parameter, mm; infinite where no skin) and grey per pixel.
#[derive(Debug)]
struct SkinBuffer {
    depth: Vec<f64>,
    grey: Vec<u8>,
}

type Cache = Mutex<Vec<(String, Arc<SkinBuffer>)>>;
static SKINS: Cache = Mutex::new(Vec::new());

/// Light direction (towards the light), from behind the camera's shoulder.
fn light(cam: &Camera) -> DVec3 {
    (-cam.forward + cam.up * 0.6 + cam.right * 0.3).normalize()
}

fn lambert(n: DVec3, cam: &Camera, albedo: f64) -> u8 {
    let l = n.dot(light(cam)).max(0.0);
    ((0.18 + 0.82 * l) * albedo * 255.0).clamp(0.0, 255.0) as u8
}

fn skin_buffer(region: &Region, cam: &Camera) -> Arc<SkinBuffer> {
    let key = format!(
        "{}|{}|{:?}",
        region.name,
        serde_json::to_string(&region.asset_sha256).unwrap_or_default(),
        cam.eye.to_array()
    );
    let mut cache = SKINS.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, b)) = cache.iter().find(|(k, _)| *k == key) {
        return Arc::clone(b);
    }
    let n = (WIDTH * HEIGHT) as usize;
    let mut depth = vec![f64::INFINITY; n];
    let mut grey = vec![BACKGROUND; n];
    if let Some(skin) = region.entry("skin") {
        let bvh = &region.scene.entries()[skin].bvh;
        for y in 0..HEIGHT {
            for x in 0..WIDTH {
                let d = cam.ray(f64::from(x) + 0.5, f64::from(y) + 0.5);
                if let Some(h) = bvh.first_hit(
                    cam.eye.to_array(),
                    d.to_array(),
                    0.0,
                    4.0 * CAMERA_DISTANCE_MM,
                ) {
                    let i = (y * WIDTH + x) as usize;
                    depth[i] = h.hit.t_mm;
                    grey[i] = lambert(DVec3::from_array(h.normal), cam, 0.62);
                }
            }
        }
    }
    let b = Arc::new(SkinBuffer { depth, grey });
    if cache.len() >= 16 {
        cache.remove(0);
    }
    cache.push((key, Arc::clone(&b)));
    b
}

/// An oriented box: centre, unit axes and half sizes.
struct Obb {
    centre: DVec3,
    axes: [DVec3; 3],
    half: [f64; 3],
}

impl Obb {
    fn corners(&self) -> impl Iterator<Item = DVec3> + '_ {
        (0..8).map(move |k| {
            (0..3).fold(self.centre, |p, a| {
                let s = if k >> a & 1 == 1 { 1.0 } else { -1.0 };
                p + self.axes[a] * (s * self.half[a])
            })
        })
    }

    /// Entry distance and outward normal of a ray.
    fn hit(&self, o: DVec3, d: DVec3) -> Option<(f64, DVec3)> {
        let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
        let mut n = DVec3::ZERO;
        for a in 0..3 {
            let ax = self.axes[a];
            let e = ax.dot(self.centre - o);
            let f = ax.dot(d);
            if f.abs() < 1e-12 {
                if (-e - self.half[a]) > 0.0 || (-e + self.half[a]) < 0.0 {
                    return None;
                }
                continue;
            }
            let (mut ta, mut tb) = ((e + self.half[a]) / f, (e - self.half[a]) / f);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            if ta > t0 {
                t0 = ta;
                n = if f > 0.0 { -ax } else { ax };
            }
            t1 = t1.min(tb);
            if t0 > t1 {
                return None;
            }
        }
        (t0 > 0.0).then_some((t0, n))
    }
}

/// Distance along the ray to the closest approach with segment `a..b`, and that distance.
fn ray_segment(o: DVec3, d: DVec3, a: DVec3, b: DVec3) -> Option<(f64, f64)> {
    let u = b - a;
    let w = o - a;
    let (uu, ud, uw, dw) = (u.dot(u), u.dot(d), u.dot(w), d.dot(w));
    let denom = uu - ud * ud;
    let s = if denom > 1e-12 {
        ((uw - ud * dw) / denom).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let t = (s * ud - dw).max(0.0);
    let s = ((t * ud + uw) / uu).clamp(0.0, 1.0);
    let t = (s * ud - dw).max(0.0);
    let gap = (o + d * t).distance(a + u * s);
    Some((t, gap))
}

/// Something drawn over the skin.
enum Shape {
    Box(Obb, f64),
    Rod(DVec3, DVec3, f64, f64),
}

impl Shape {
    fn bounds(&self) -> Vec<DVec3> {
        match self {
            Shape::Box(b, _) => b.corners().collect(),
            Shape::Rod(a, b, r, _) => [*a, *b]
                .iter()
                .flat_map(|p| {
                    [-1.0, 1.0]
                        .into_iter()
                        .flat_map(move |s| [DVec3::X, DVec3::Y, DVec3::Z].map(|e| *p + e * (s * r)))
                })
                .collect(),
        }
    }

    /// Distance along the ray and grey where it is hit.
    fn hit(&self, cam: &Camera, o: DVec3, d: DVec3) -> Option<(f64, u8)> {
        match self {
            Shape::Box(b, albedo) => b.hit(o, d).map(|(t, n)| (t, lambert(n, cam, *albedo))),
            Shape::Rod(a, b, r, albedo) => {
                let (t, gap) = ray_segment(o, d, *a, *b)?;
                if gap > *r {
                    return None;
                }
                // Shade as a cylinder seen across: brighter on the axis.
                let c = (1.0 - (gap / r).powi(2)).sqrt();
                Some((t - r * c, ((0.35 + 0.65 * c) * albedo * 255.0) as u8))
            }
        }
    }
}

/// The shapes of the probe (body and marker ridge) and the needle (shaft and hub).
fn shapes(pose: &ProbePose, probe: ProbeKind, world: &World) -> Vec<Shape> {
    let mut out = Vec::new();
    if let Ok(f) = pose.frame() {
        let footprint = match probe {
            ProbeKind::Linear => probe.spec().footprint_mm + 8.0,
            ProbeKind::Curvilinear => {
                let s = probe.spec();
                2.0 * s.radius_mm * (0.5 * s.sector_deg.to_radians()).sin() + 10.0
            }
        };
        let marker = -f.lateral;
        out.push(Shape::Box(
            Obb {
                centre: f.origin - f.beam * (0.5 * PROBE_HEIGHT_MM),
                axes: [f.lateral, f.beam, f.elevation],
                half: [
                    0.5 * footprint,
                    0.5 * PROBE_HEIGHT_MM,
                    0.5 * PROBE_THICKNESS_MM,
                ],
            },
            0.55,
        ));
        // The orientation marker: a bright ridge on the marker end.
        out.push(Shape::Box(
            Obb {
                centre: f.origin - f.beam * (0.6 * PROBE_HEIGHT_MM)
                    + marker * (0.5 * footprint + 2.0),
                axes: [f.lateral, f.beam, f.elevation],
                half: [2.5, 6.0, 2.5],
            },
            1.0,
        ));
    }
    if let Some(c) = &world.carm {
        // The C-arm's central beam: a rod entering the body from the source side, with a
        // thicker collar where the beam leaves the tube.
        let d = DVec3::from_array(c.beam_dir);
        let iso = DVec3::from_array(c.isocentre_mm);
        out.push(Shape::Rod(
            iso - d * CARM_ROD_MM[1],
            iso - d * CARM_ROD_MM[0],
            1.5,
            0.95,
        ));
        out.push(Shape::Rod(
            iso - d * (CARM_ROD_MM[1] + 20.0),
            iso - d * CARM_ROD_MM[1],
            6.0,
            0.9,
        ));
    }
    if let Some(n) = &world.needle {
        let line = n.state.shaft_polyline(2.0);
        for w in line.windows(2) {
            out.push(Shape::Rod(w[0], w[1], SHAFT_DRAW_RADIUS_MM, 1.0));
        }
        if let (Some(&hub), Some(&next)) = (line.first(), line.get(1)) {
            let axis = (next - hub).normalize_or_zero();
            out.push(Shape::Rod(
                hub - axis * HUB_LENGTH_MM,
                hub,
                HUB_RADIUS_MM,
                0.8,
            ));
        }
    }
    out
}

/// Renders the placement view.
pub fn render(
    region: &Region,
    cam: &Camera,
    pose: &ProbePose,
    probe: ProbeKind,
    world: &World,
) -> ViewImage {
    let skin = skin_buffer(region, cam);
    let mut pixels = skin.grey.clone();
    let mut depth = skin.depth.clone();
    for shape in shapes(pose, probe, world) {
        let pts: Vec<[f64; 2]> = shape
            .bounds()
            .iter()
            .filter_map(|p| cam.project(*p))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in &pts {
            x0 = x0.min(p[0]);
            x1 = x1.max(p[0]);
            y0 = y0.min(p[1]);
            y1 = y1.max(p[1]);
        }
        let xs = (x0.floor().max(0.0) as u32)..(x1.ceil().max(0.0) as u32 + 1).min(WIDTH);
        let ys = (y0.floor().max(0.0) as u32)..(y1.ceil().max(0.0) as u32 + 1).min(HEIGHT);
        for y in ys {
            for x in xs.clone() {
                let d = cam.ray(f64::from(x) + 0.5, f64::from(y) + 0.5);
                if let Some((t, g)) = shape.hit(cam, cam.eye, d) {
                    let i = (y * WIDTH + x) as usize;
                    if t < depth[i] {
                        depth[i] = t;
                        pixels[i] = g;
                    }
                }
            }
        }
    }
    ViewImage {
        width: WIDTH,
        height: HEIGHT,
        pixels,
    }
}
