//! The anatomy gallery: its PNG shots, and landmark-level facts a reader of lumbar fluoroscopy
//! checks on them (pedicles inside the body outline in AP, an open interlaminar window, the
//! endplates squaring at the tilt the meshes say).

use std::sync::OnceLock;

use glam::DVec3;
use render_worker::gallery::{self, AP, Shot, View};
use render_worker::session::anatomy::{angle_to_plane_deg, endplate_normal};
use render_worker::session::region::Region;
use sim_core::fluoro::{Projection, render_transmission};
use sim_core::needle::BoneSurface;

use crate::needle_handling::region;

/// AP, oblique and lateral shots of the 2 mm phantom, rendered once.
fn shots() -> &'static [Shot] {
    static SHOTS: OnceLock<Vec<Shot>> = OnceLock::new();
    SHOTS.get_or_init(|| gallery::shots(&region(), &gallery::settings(0)).expect("gallery renders"))
}

fn landmark(region: &Region, name: &str) -> DVec3 {
    DVec3::from_array(*region.landmarks.get(name).unwrap_or_else(|| panic!("landmark {name}")))
}

/// Millimetres at the isocentre per detector pixel (the default detector's pitch over the
/// isocentre magnification).
fn mm_per_px(p: &Projection) -> f64 {
    p.pixel_pitch_mm[0] / p.isocentre_magnification()
}

#[test]
fn gallery_writes_three_views_per_region_as_png_that_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let region = region();
    let paths = gallery::write(&region, shots(), dir.path()).unwrap();
    let names: Vec<String> = paths.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(
        names,
        ["lumbar-phantom-average_ap.png", "lumbar-phantom-average_lao30.png", "lumbar-phantom-average_lateral.png"]
    );
    for (path, shot) in paths.iter().zip(shots()) {
        let (w, h, pixels) = gallery::png::decode_grey(&std::fs::read(path).unwrap()).expect("a valid PNG");
        assert_eq!((w, h), (shot.image.width, shot.image.height));
        assert!(pixels == shot.image.pixels, "{} reads back bit for bit", path.display());
        // Anatomy, not a blank frame: the grey levels span a real range.
        let (lo, hi) = (pixels.iter().min().unwrap(), pixels.iter().max().unwrap());
        assert!(hi - lo > 100, "{}: grey range {lo}..{hi}", path.display());
    }
    assert!(gallery::png::decode_grey(b"not a png").is_none());
}

/// Each lumbar level in AP: the body's outline is its widest extent over the rows within 4 mm
/// of its centre (its waist, clear of the transverse processes and articular processes), each
/// edge the outermost strong grey step 10-35 mm from the midline; both pedicle "eyes" project
/// inside it.
#[test]
fn ap_pedicles_project_inside_their_body_outline() {
    let region = region();
    let ap = &shots()[0];
    assert_eq!(ap.view, AP);
    let px_mm = mm_per_px(&ap.projection);
    for level in ["L1", "L2", "L3", "L4", "L5"] {
        let centre = landmark(&region, &format!("{level}_body_centre"));
        let c = ap.project(centre).unwrap();
        let grey = |x: f64, row: f64| f64::from(ap.grey_at([x, row]).unwrap_or(0));
        // The outermost step of at least half the strongest: the body's lateral cortex, not the
        // canal or pedicle walls inside it.
        let edge = |sign: f64, row: f64| {
            let (from, to) = ((10.0 / px_mm) as i32, (35.0 / px_mm) as i32);
            let steps: Vec<(f64, f64)> = (from..to)
                .map(|k| {
                    let x = c[0] + sign * f64::from(k);
                    (x, (grey(x + sign, row) - grey(x - sign, row)).abs())
                })
                .collect();
            let strongest = steps.iter().map(|s| s.1).fold(0.0, f64::max);
            steps.iter().rev().find(|s| s.1 >= 0.5 * strongest).map_or(c[0], |s| s.0)
        };
        let (mut left_x, mut right_x) = (c[0], c[0]);
        let half_rows = (4.0 / px_mm) as i32;
        for k in -half_rows..=half_rows {
            let row = c[1].floor() + f64::from(k);
            left_x = left_x.min(edge(-1.0, row));
            right_x = right_x.max(edge(1.0, row));
        }
        let width_mm = (right_x - left_x) * px_mm;
        for side in ["left", "right"] {
            let p = ap.project(landmark(&region, &format!("{level}_pedicle_{side}"))).unwrap();
            let inside_mm = (p[0] - left_x).min(right_x - p[0]) * px_mm;
            eprintln!("{level} {side}: body outline {width_mm:.1} mm wide, pedicle eye {inside_mm:.1} mm inside it");
            // One pixel (0.33 mm at the isocentre) of edge-finding error.
            assert!(inside_mm > px_mm, "{level} {side} pedicle projects {inside_mm:.1} mm inside the body outline");
        }
    }
}

/// L3-L4 and L4-L5 in AP: the straight line from the interlaminar window's centre back to the
/// source meets no bone, and the window is brighter (less attenuating) on the image than the
/// spinous processes above and below it on the midline.
#[test]
fn ap_interlaminar_windows_are_open() {
    let region = region();
    let ap = &shots()[0];
    for (upper, lower) in [("L3", "L4"), ("L4", "L5")] {
        let w = landmark(&region, &format!("{upper}_{lower}_interlaminar_window_centre"));
        let px = ap.project(w).unwrap();
        let ray = ap.projection.pixel_ray(px);
        let towards_source = -DVec3::from_array(ray.dir);
        let hit = region.bones().first_hit(w, towards_source, 150.0);
        assert!(hit.is_none(), "{upper}-{lower}: bone {:.1} mm behind the window centre on the AP ray", hit.map_or(0.0, |h| h.t_mm));
        let window = f64::from(ap.grey_at(px).unwrap());
        let sp = |level: &str| {
            let c = landmark(&region, &format!("{level}_body_centre"));
            let p = ap.project(DVec3::new(w.x, c.y, c.z)).unwrap();
            f64::from(ap.grey_at([px[0], p[1]]).unwrap())
        };
        let (above, below) = (sp(upper), sp(lower));
        eprintln!("{upper}-{lower}: window grey {window}, spinous processes {above} / {below}");
        // Ten grey levels: well above the one-level rounding of the display.
        assert!(window > above + 10.0 && window > below + 10.0, "{upper}-{lower} window {window} vs {above} / {below}");
    }
}

/// Tilting the AP view cranio-caudally, the L4 inferior endplate's edge is sharpest (the
/// endplate is "square") at the tilt where the beam lies in its plane as measured on the meshes.
#[test]
fn endplates_square_at_the_tilt_the_meshes_give() {
    let region = region();
    let normal = endplate_normal(&region, "L4", "L5").expect("L4 inferior endplate");
    let c4 = landmark(&region, "L4_body_centre");
    let c5 = landmark(&region, "L5_body_centre");
    let centre = 0.5 * (c4 + c5);
    let beam = |deg: f64| {
        let p = gallery::projection(View { name: "tilt", orbital_deg: 0.0, angular_deg: deg }, centre);
        DVec3::from_array(p.frame().normal)
    };
    // The expected tilt: the beam in the endplate's plane, to 0.1 degree.
    let expected = (-300..=300)
        .map(|k| f64::from(k) * 0.1)
        .min_by(|a, b| angle_to_plane_deg(beam(*a), normal).total_cmp(&angle_to_plane_deg(beam(*b), normal)))
        .unwrap();
    let settings = gallery::settings(0);
    // A 96 x 96 pixel window (0.5 mm pitch, 34 mm at the isocentre) over the disc; the columns
    // 6-14 mm either side of the midline (the body, clear of the spinous process and pedicles).
    let contrast = |deg: f64| {
        let mut p = gallery::projection(View { name: "tilt", orbital_deg: 0.0, angular_deg: deg }, centre);
        let pitch = 0.5;
        p.pixel_pitch_mm = [pitch; 2];
        p.detector_pixels = [96, 96];
        let t = render_transmission(&region.scene, None, &p, &settings).unwrap();
        let mag = p.isocentre_magnification();
        let cols: Vec<usize> = (0..96).filter(|&i| {
            let x_mm = (i as f64 + 0.5 - 48.0) * pitch / mag;
            (6.0..=14.0).contains(&x_mm.abs())
        }).collect();
        let rows: Vec<f64> = (0..96)
            .map(|j| cols.iter().map(|&i| t.transmission[j * 96 + i].max(1e-12).ln()).sum::<f64>() / cols.len() as f64)
            .collect();
        // The sharpest row-to-row step of the profile: squared endplates are seen edge-on, a
        // crisp line; tilted, each one is smeared over its projected depth.
        // Only the cranial half of the window (above the disc's middle): the L4 endplate, not
        // the L5 one (tilted 13 degrees more).
        rows[..48].windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max)
    };
    let tilts: Vec<f64> = (-10..=10).map(|k| expected.round() + 2.0 * f64::from(k)).collect();
    let scores: Vec<f64> = tilts.iter().map(|d| contrast(*d)).collect();
    let best = tilts[scores.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).unwrap().0];
    eprintln!("L4 inferior endplate: mesh says square at {expected:.1} deg, the image at {best:.0} deg; edge sharpness {scores:.3?}");
    // The 2 degree sampling step of the scan.
    assert!((best - expected).abs() <= 2.0, "image squares at {best} deg, meshes at {expected:.1} deg");
}

/// The scatter gallery: AP and lateral with the grid in and out, written beside the plain
/// views; without the grid the fog narrows the grey range of the spine's middle.
#[test]
fn scatter_gallery_shows_ap_and_lateral_with_and_without_the_grid() {
    let region = region();
    let shots = gallery::scatter_shots(&region, &gallery::settings(0)).expect("renders");
    let dir = tempfile::tempdir().unwrap();
    let paths = gallery::write(&region, &shots, dir.path()).unwrap();
    let names: Vec<String> = paths.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(
        names,
        [
            "lumbar-phantom-average_ap_grid.png",
            "lumbar-phantom-average_ap_nogrid.png",
            "lumbar-phantom-average_lateral_grid.png",
            "lumbar-phantom-average_lateral_nogrid.png"
        ]
    );
    // The 10th to 90th percentile of the middle quarter of the image.
    let spread = |s: &Shot| {
        let n = s.image.width as usize;
        let mut v: Vec<u8> = (n * 3 / 8..n * 5 / 8)
            .flat_map(|j| (n * 3 / 8..n * 5 / 8).map(move |i| (i, j)))
            .map(|(i, j)| s.image.pixels[j * n + i])
            .collect();
        v.sort_unstable();
        i32::from(v[v.len() * 9 / 10]) - i32::from(v[v.len() / 10])
    };
    for pair in shots.chunks(2) {
        let (grid, nogrid) = (spread(&pair[0]), spread(&pair[1]));
        assert!(nogrid < grid, "{}: spread {grid} with the grid, {nogrid} without", pair[0].view.name);
    }
}
