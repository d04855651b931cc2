//! The anatomy gallery: AP, 30 degree oblique and lateral fluoroscopy shots of a region, made by
//! the CPU reference renderer (`sim_core::fluoro::render_frame`, so a shot is the same on every
//! machine), written as PNG files by the `gallery` binary for review, and checked for
//! landmark-level facts by the tests (`render-worker/tests/gallery.rs`).
//!
//! Every shot is centred on the mean of the region's vertebral body centres (landmarks named
//! `*_body_centre`), or on the middle of its structures' bounds when it has none, with the
//! platform's C-arm distances, a detector large enough for the whole region ([`projection`]),
//! the default 80 kVp beam and no quantum noise.

pub mod png;

use std::path::{Path, PathBuf};

use glam::DVec3;
use sim_core::fluoro::brightness::{METERING_RAYS_ACROSS, meter};
use sim_core::fluoro::render::finish_frame;
use sim_core::fluoro::scatter::superposition::ScatterSettings;
use sim_core::fluoro::spectrum::UnknownKvp;
use sim_core::fluoro::{Image, Projection, RenderSettings, render_frame, render_transmission};

use crate::session::region::Region;

/// Why a gallery shot could not be rendered or written.
#[derive(Debug, thiserror::Error)]
pub enum GalleryError {
    /// The beam's tube voltage has no spectrum.
    #[error(transparent)]
    Render(#[from] UnknownKvp),
    /// The output folder could not be created.
    #[error("creating {}: {source}", .dir.display())]
    CreateDir {
        /// The folder.
        dir: PathBuf,
        /// The file system's error.
        source: std::io::Error,
    },
    /// A shot could not be encoded as PNG.
    #[error("encoding {}: {source}", .path.display())]
    Encode {
        /// The file it was meant for.
        path: PathBuf,
        /// The encoder's error.
        source: std::io::Error,
    },
    /// A PNG file could not be written.
    #[error("writing {}: {source}", .path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The file system's error.
        source: std::io::Error,
    },
}

/// A C-arm position of the gallery.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// File-name part: `ap`, `lao30`, `lateral`.
    pub name: &'static str,
    /// Orbital rotation, degrees (positive LAO, as [`Projection::orbital_deg`]).
    pub orbital_deg: f64,
    /// Cranio-caudal rotation, degrees (positive cranial).
    pub angular_deg: f64,
}

/// AP.
pub const AP: View = View {
    name: "ap",
    orbital_deg: 0.0,
    angular_deg: 0.0,
};
/// 30 degree left anterior oblique: the obliquity at which the lumbar "scotty dog" shows (its
/// usual 25-35 degree range).
pub const OBLIQUE: View = View {
    name: "lao30",
    orbital_deg: 30.0,
    angular_deg: 0.0,
};
/// Lateral.
pub const LATERAL: View = View {
    name: "lateral",
    orbital_deg: 90.0,
    angular_deg: 0.0,
};
/// The gallery's three views, in order.
pub const VIEWS: [View; 3] = [AP, OBLIQUE, LATERAL];

/// One rendered view.
#[derive(Debug, Clone)]
pub struct Shot {
    /// The view.
    pub view: View,
    /// The geometry it was rendered with (to project landmarks onto it).
    pub projection: Projection,
    /// Grey levels, fluoroscopy polarity (bone dark).
    pub image: Image,
}

impl Shot {
    /// Grey level at continuous pixel coordinates (nearest pixel); `None` off the image.
    pub fn grey_at(&self, px: [f64; 2]) -> Option<u8> {
        let (w, h) = (self.image.width as f64, self.image.height as f64);
        if !(0.0..w).contains(&px[0]) || !(0.0..h).contains(&px[1]) {
            return None;
        }
        let i = px[1] as usize * self.image.width as usize + px[0] as usize;
        self.image.pixels.get(i).copied()
    }

    /// Where a model-frame point projects (continuous pixel coordinates).
    pub fn project(&self, p_mm: DVec3) -> Option<[f64; 2]> {
        self.projection.project_point(p_mm.to_array())
    }
}

/// The point every view of `region` is centred on (see the module docs).
pub fn centre_of(region: &Region) -> DVec3 {
    let centres: Vec<DVec3> = region
        .landmarks
        .iter()
        .filter(|(name, _)| name.ends_with("_body_centre"))
        .map(|(_, p)| DVec3::from_array(*p))
        .collect();
    if !centres.is_empty() {
        return centres.iter().sum::<DVec3>() / centres.len() as f64;
    }
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for e in region.scene.entries() {
        if let Some((a, b)) = e.bvh.bounds_mm() {
            lo = lo.min(DVec3::from_array(a));
            hi = hi.max(DVec3::from_array(b));
        }
    }
    if lo.is_finite() && hi.is_finite() {
        0.5 * (lo + hi)
    } else {
        DVec3::ZERO
    }
}

/// Detector of the gallery: 768 x 768 pixels over 512 mm, about 250 mm at the isocentre, so one
/// shot holds a whole region (L1 to the sacrum). A C-arm's panel is 300-400 mm; the gallery keeps
/// the C-arm's distances and takes a larger panel instead of several shots (simulator choice).
pub const GALLERY_PIXELS: u32 = 768;
/// Pixel pitch of the gallery's detector, mm.
pub const GALLERY_PITCH_MM: f64 = 512.0 / 768.0;

/// The projection of `view` centred on `centre`: the platform's C-arm distances, the gallery's
/// detector.
pub fn projection(view: View, centre: DVec3) -> Projection {
    Projection {
        orbital_deg: view.orbital_deg,
        angular_deg: view.angular_deg,
        isocentre_mm: centre.to_array(),
        detector_pixels: [GALLERY_PIXELS; 2],
        pixel_pitch_mm: [GALLERY_PITCH_MM; 2],
        ..Projection::default()
    }
}

/// The render settings of the gallery: the platform defaults (80 kVp, 4 x 4 adaptive
/// supersampling, no noise) on `threads` workers (0: all cores).
pub fn settings(threads: usize) -> RenderSettings {
    RenderSettings {
        threads,
        ..RenderSettings::default()
    }
}

/// Renders `view` of `region` centred on `centre`.
pub fn shot(
    region: &Region,
    view: View,
    centre: DVec3,
    settings: &RenderSettings,
) -> Result<Shot, GalleryError> {
    let projection = projection(view, centre);
    let image = render_frame(&region.scene, None, &projection, settings)?;
    Ok(Shot {
        view,
        projection,
        image,
    })
}

/// Renders every view of [`VIEWS`] of `region`.
pub fn shots(region: &Region, settings: &RenderSettings) -> Result<Vec<Shot>, GalleryError> {
    let centre = centre_of(region);
    VIEWS
        .iter()
        .map(|v| shot(region, *v, centre, settings))
        .collect()
}

/// AP with the anti-scatter grid in, and out; the same for the lateral.
pub const SCATTER_VIEWS: [(View, bool); 4] = [
    (
        View {
            name: "ap_grid",
            ..AP
        },
        true,
    ),
    (
        View {
            name: "ap_nogrid",
            ..AP
        },
        false,
    ),
    (
        View {
            name: "lateral_grid",
            ..LATERAL
        },
        true,
    ),
    (
        View {
            name: "lateral_nogrid",
            ..LATERAL
        },
        false,
    ),
];

/// The views of [`SCATTER_VIEWS`] with scatter added (`sim_core::fluoro::scatter`): each view's
/// air gap from the scene (the metering's central ray), the grid in or out, one transmission
/// per view finished twice.
pub fn scatter_shots(
    region: &Region,
    settings: &RenderSettings,
) -> Result<Vec<Shot>, GalleryError> {
    let centre = centre_of(region);
    let kvp = match settings.energy {
        sim_core::fluoro::EnergyModel::Spectral { kvp } => kvp,
        _ => 80,
    };
    let mut out = Vec::with_capacity(SCATTER_VIEWS.len());
    for pair in SCATTER_VIEWS.chunks(2) {
        let projection = projection(pair[0].0, centre);
        let t = render_transmission(&region.scene, None, &projection, settings)?;
        let gap = meter(&region.scene, &projection, METERING_RAYS_ACROSS).air_gap_mm;
        for &(view, grid) in pair {
            let with = RenderSettings {
                scatter: Some(ScatterSettings {
                    kvp,
                    grid,
                    air_gap_mm: gap,
                    pixel_pitch_mm: projection.pixel_pitch_mm[0],
                }),
                ..*settings
            };
            out.push(Shot {
                view,
                projection,
                image: finish_frame(&t, &with),
            });
        }
    }
    Ok(out)
}

/// The file name stem of `region`'s shots: its name, with the habitus named for every variant
/// of the lumbar phantom (`lumbar-phantom-average`, `lumbar-phantom-slim`, ...), so a reader
/// comparing bodies sees which is which.
pub fn file_stem(region: &Region) -> String {
    match sim_core::anatomy::phantom::habitus::Habitus::of_region(&region.name) {
        Some(h) => format!("{}-{}", sim_core::anatomy::phantom::REGION_NAME, h.name()),
        None => region.name.clone(),
    }
}

/// Writes `shots` of `region` into `dir` as `<stem>_<view>.png` ([`file_stem`]); returns the
/// paths.
pub fn write(region: &Region, shots: &[Shot], dir: &Path) -> Result<Vec<PathBuf>, GalleryError> {
    std::fs::create_dir_all(dir).map_err(|source| GalleryError::CreateDir {
        dir: dir.to_path_buf(),
        source,
    })?;
    shots
        .iter()
        .map(|s| {
            let path = dir.join(format!("{}_{}.png", file_stem(region), s.view.name));
            let bytes = match png::encode_grey(s.image.width, s.image.height, &s.image.pixels) {
                Ok(b) => b,
                Err(source) => return Err(GalleryError::Encode { path, source }),
            };
            if let Err(source) = std::fs::write(&path, bytes) {
                return Err(GalleryError::Write { path, source });
            }
            Ok(path)
        })
        .collect()
}
