//! The tissue the scanner sees: a region's structures painted into a CT-like volume (HU per
//! voxel) with label overrides, on a crop around the station's site, built once per process
//! for each region and crop and only when a session first scans.
//!
//! Painting: every structure's mesh is filled column by column (the crossings of a ray along
//! +z through each voxel column, kept by their entering/leaving sense), in the scene's nesting
//! order (priority, then asset order; later paint wins), so the volume agrees with what the
//! fluoroscopy renderer and the needle see. Each voxel gets the CT number of its structure's
//! material (the phantom's own `TissueHu` table where the region is a phantom, the default
//! table otherwise); classes with their own acoustic entry (bone, vessel, nerve, dura/CSF,
//! epidural fat, muscle, ligament, disc) are also labelled, so their properties come from the
//! class table and fat and other soft tissue from the HU mapping (`sim_core::ultrasound::tissue`).
//!
//! The CPU reference reads the same tissue through a palette (`IndexedMedium`: one byte per
//! voxel, in cache-line bricks, and the properties of each distinct tissue computed once), which
//! gives the same properties at every point (`ultrasound_session` bench, the palette alone:
//! 62 -> 42 ms square, 114 -> 86 ms rocked; with the later changes to the deposit, 34 and 71).

use std::sync::{Arc, Mutex};

use sim_core::anatomy::phantom::TissueHu;
use sim_core::fluoro::FluoroMaterial;
use sim_core::geom::Hit;
use sim_core::material::MaterialClass;
use sim_core::ultrasound::indexed::MAX_TISSUES;
use sim_core::ultrasound::{CtMedium, IndexedMedium};
use sim_core::volume::{Volume, VolumeGrid};

use crate::session::region::Region;

/// Voxel side of the acoustic volume, mm. Simulator choice: a third of the phantom's 1.5 mm CT
/// grid, finer than the curvilinear probe's axial resolution (about 0.45 mm FWHM at 3.5 MHz is
/// the scale of the speckle, not of the anatomy) and a quarter of the lumbar cortex thickness.
pub const VOXEL_MM: f64 = 0.5;
/// Half extents of the area where the probe face may be put, around the site, across (x) and
/// along (z) the body, mm. Simulator choice: 60 mm each way covers a paramedian scan of the
/// target level and its two neighbours from the midline to beyond the transverse processes.
pub const PROBE_AREA_HALF_MM: [f64; 2] = [60.0, 60.0];
/// Half extents of the painted crop, mm: wider than the probe area across the body by 40 mm, so
/// a curvilinear sector (80 mm half-width at its default 100 mm depth) from a probe at the edge
/// of the area sees tissue, not the crop's edge, over most of its width. Along the body the
/// sector does not spread (the slice is thin), so the probe area suffices.
pub const CROP_HALF_MM: [f64; 2] = [100.0, 60.0];
/// Depth of the crop beyond the site (anterior), mm. Simulator choice: the posterior half of
/// the vertebral body and the psoas lie within 50 mm of a posterior-element target.
pub const BEYOND_SITE_MM: f64 = 50.0;
/// Air left outside the skin at the back of the crop, mm (the probe face sits on the skin).
pub const AIR_MARGIN_MM: f64 = 5.0;

/// A region's acoustic volume on a crop.
#[derive(Debug)]
pub struct AcousticVolume {
    /// CT numbers, HU.
    pub hu: Volume<f32>,
    /// [`MaterialClass::label`] per voxel where a class overrides the HU mapping, else 0.
    pub labels: Volume<u8>,
    /// Lower corner of the crop (outer voxel faces), mm.
    pub lo_mm: [f64; 3],
    /// Upper corner, mm.
    pub hi_mm: [f64; 3],
    /// Identifies this volume among the cached ones (for renderers that upload it once).
    pub key: u64,
    /// The same tissue as a palette of properties per (label, HU) pair (one byte per voxel):
    /// what the CPU reference reads, equal to [`medium`](Self::medium) bit for bit and faster
    /// per lookup. A painted volume always has one: it holds at most a pair per material class
    /// and air (see `paint`).
    pub indexed: IndexedMedium,
}

impl AcousticVolume {
    /// The medium the scanner reads (CT numbers and labels, what the GPU path uploads).
    pub fn medium(&self) -> CtMedium<'_> {
        CtMedium {
            hu: &self.hu,
            labels: Some(&self.labels),
        }
    }
}

/// Classes that carry their own acoustic properties (label overrides: the class, not the HU).
fn overrides(class: MaterialClass) -> bool {
    !matches!(class, MaterialClass::Fat | MaterialClass::SoftTissue)
}

/// The area (x and z ranges, mm) of `site_mm` where the probe face may be put.
pub fn probe_area(site_mm: [f64; 3]) -> ([f64; 2], [f64; 2]) {
    (
        [
            site_mm[0] - PROBE_AREA_HALF_MM[0],
            site_mm[0] + PROBE_AREA_HALF_MM[0],
        ],
        [
            site_mm[2] - PROBE_AREA_HALF_MM[1],
            site_mm[2] + PROBE_AREA_HALF_MM[1],
        ],
    )
}

/// The painted crop around `site_mm`: [`CROP_HALF_MM`] across and along the body, from
/// [`AIR_MARGIN_MM`] behind the skin's posterior extent to [`BEYOND_SITE_MM`] in front of the
/// site.
pub fn crop_of(region: &Region, site_mm: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let back = region
        .entry("skin")
        .and_then(|i| region.scene.entries()[i].bvh.bounds_mm())
        .map_or(site_mm[1] - 100.0, |(lo, _)| lo[1]);
    (
        [
            site_mm[0] - CROP_HALF_MM[0],
            back - AIR_MARGIN_MM,
            site_mm[2] - CROP_HALF_MM[1],
        ],
        [
            site_mm[0] + CROP_HALF_MM[0],
            site_mm[1] + BEYOND_SITE_MM,
            site_mm[2] + CROP_HALF_MM[1],
        ],
    )
}

type Cache = Mutex<Vec<(String, Arc<AcousticVolume>)>>;
static VOLUMES: Cache = Mutex::new(Vec::new());

/// The cache key of the crop `lo..hi` of `region`.
fn cache_key(region: &Region, lo: [f64; 3], hi: [f64; 3]) -> String {
    format!(
        "{}|{}|{lo:?}|{hi:?}",
        region.name,
        serde_json::to_string(&region.asset_sha256).unwrap_or_default()
    )
}

/// Whether the acoustic volume of `region` around `site_mm` is painted (held by this process's
/// cache), without painting it.
pub fn is_painted(region: &Region, site_mm: [f64; 3]) -> bool {
    let (lo, hi) = crop_of(region, site_mm);
    let key = cache_key(region, lo, hi);
    let cache = VOLUMES.lock().unwrap_or_else(|e| e.into_inner());
    cache.iter().any(|(k, _)| *k == key)
}

/// The acoustic volume of `region` on the crop around `site_mm`, painted on first use and
/// shared by every session of this process that scans the same region and site.
pub fn acoustic_volume(region: &Region, site_mm: [f64; 3]) -> Arc<AcousticVolume> {
    let (lo, hi) = crop_of(region, site_mm);
    let key = cache_key(region, lo, hi);
    // Painting holds the lock: two sessions asking at once paint once.
    let mut cache = VOLUMES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, v)) = cache.iter().find(|(k, _)| *k == key) {
        return Arc::clone(v);
    }
    let id = cache.len() as u64 + 1;
    let v = Arc::new(paint(region, lo, hi, id));
    // Six regions and sites per process at most (about 100 MB each).
    if cache.len() >= 6 {
        cache.remove(0);
    }
    cache.push((key, Arc::clone(&v)));
    v
}

/// Paints the crop `lo..hi` (see the module docs).
pub fn paint(region: &Region, lo: [f64; 3], hi: [f64; 3], key: u64) -> AcousticVolume {
    let dims: [usize; 3] =
        std::array::from_fn(|a| ((hi[a] - lo[a]) / VOXEL_MM).ceil().max(1.0) as usize);
    let grid = VolumeGrid {
        dims,
        spacing_mm: [VOXEL_MM; 3],
        origin_mm: std::array::from_fn(|a| lo[a] + 0.5 * VOXEL_MM),
    };
    let table = region
        .phantom
        .as_ref()
        .map_or_else(TissueHu::default, |p| p.hu);
    // Air: the phantom's own value (the knot of the acoustic HU map is -400).
    let air_hu = -1000.0f32;
    let mut hu = Volume::filled(grid, air_hu);
    let mut labels = Volume::filled(grid, 0u8);
    let entries = region.scene.entries();
    let mut order: Vec<usize> = (0..entries.len()).collect();
    order.sort_by_key(|&i| (entries[i].priority, i));
    let mut hits: Vec<Hit> = Vec::new();
    let nz = dims[2];
    for i in order {
        let e = &entries[i];
        let FluoroMaterial::Tissue(class) = e.material else {
            continue;
        };
        let Some((blo, bhi)) = e.bvh.bounds_mm() else {
            continue;
        };
        let value = table.of(class) as f32;
        let label = if overrides(class) { class.label() } else { 0 };
        let range = |a: usize| {
            let first = ((blo[a] - grid.origin_mm[a]) / VOXEL_MM).floor().max(0.0) as usize;
            let last = ((bhi[a] - grid.origin_mm[a]) / VOXEL_MM).ceil() + 1.0;
            first..(last.max(0.0) as usize).min(dims[a])
        };
        // From outside the mesh, so the parity starts at zero.
        let z0 = blo[2].min(lo[2]) - 1.0;
        for j in range(1) {
            for ii in range(0) {
                // Off the voxel centres by irrational-looking amounts, so grid-aligned meshes
                // are not met edge-on.
                let x = grid.origin_mm[0] + ii as f64 * VOXEL_MM + 1.234_567e-4;
                let y = grid.origin_mm[1] + j as f64 * VOXEL_MM + 2.345_678e-4;
                e.bvh.all_hits(
                    [x, y, z0],
                    [0.0, 0.0, 1.0],
                    0.0,
                    hi[2] - z0 + 1.0,
                    &mut hits,
                );
                if hits.is_empty() {
                    continue;
                }
                hits.sort_by(|a, b| a.t_mm.total_cmp(&b.t_mm));
                // Depth of nesting along the column: +1 entering, -1 leaving; inside while > 0.
                let mut depth = 0i32;
                let mut h = 0;
                for k in 0..nz {
                    let t = grid.origin_mm[2] + k as f64 * VOXEL_MM - z0;
                    while h < hits.len() && hits[h].t_mm <= t {
                        depth += if hits[h].entering { 1 } else { -1 };
                        h += 1;
                    }
                    if depth > 0 {
                        let idx = grid.index(ii, j, k);
                        hu.data[idx] = value;
                        labels.data[idx] = label;
                    }
                }
            }
        }
    }
    // Every voxel holds air or its structure class's CT number and label: at most one
    // (label, HU) pair per class and air, which a palette always takes.
    const _: () = assert!(MaterialClass::ALL.len() < MAX_TISSUES);
    let indexed = IndexedMedium::from_ct(&CtMedium {
        hu: &hu,
        labels: Some(&labels),
    })
    .expect("a painted volume holds at most a (label, HU) pair per class and air");
    AcousticVolume {
        hu,
        labels,
        lo_mm: lo,
        hi_mm: hi,
        key,
        indexed,
    }
}
