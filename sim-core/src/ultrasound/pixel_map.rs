//! Where each image pixel falls on the scan lines, computed once per image geometry and
//! shared: a curvilinear array's pixel needs an `atan2` and a square root (a large part of its
//! scan conversion), and a session shows thousands of frames of the same geometry. The map
//! holds exactly what [`ScanGeometry::plane_to_line`] gives, so a frame is the same bit for
//! bit with or without it.

use std::sync::{Arc, Mutex};

use super::parallel;
use super::probe::{ProbeKind, ScanGeometry};

/// Maps kept, most recently used last (our choice: a draft's and a full frame's geometry for a
/// couple of probes or depths; a curvilinear map of the default 820 x 554 pixels is 7.3 MB).
const MAPS_KEPT: usize = 4;
/// Largest image with a map, pixels (our choice: 4 times the default image; a finer pixel
/// pitch asked of the library is converted pixel by pixel, so the maps stay under 32 MB each).
pub(crate) const MAP_PIXELS_MAX: usize = 2_000_000;

/// What a map depends on: the array, its lines, and the pixel grid (origin, pitch, size).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct MapKey {
    kind: ProbeKind,
    footprint_bits: u64,
    radius_bits: u64,
    sector_bits: u64,
    lines: usize,
    origin_bits: [u64; 2],
    pixel_bits: u64,
    size: [usize; 2],
}

/// Fractional line index and depth (mm) of every pixel centre, row-major.
pub(crate) struct PixelMap {
    key: MapKey,
    pub line_depth: Vec<(f64, f64)>,
}

/// The kept maps, most recently used last.
struct MapCache {
    maps: Vec<Arc<PixelMap>>,
    kept: usize,
}

impl MapCache {
    /// The kept map of `key`, now the most recently used.
    fn get(&mut self, key: &MapKey) -> Option<Arc<PixelMap>> {
        let i = self.maps.iter().position(|m| m.key == *key)?;
        let m = self.maps.remove(i);
        self.maps.push(Arc::clone(&m));
        Some(m)
    }

    /// Keeps `m`, dropping the least recently used map beyond `kept`.
    fn keep(&mut self, m: &Arc<PixelMap>) {
        if self.maps.len() >= self.kept {
            self.maps.remove(0);
        }
        self.maps.push(Arc::clone(m));
    }
}

static MAPS: Mutex<MapCache> = Mutex::new(MapCache {
    maps: Vec::new(),
    kept: MAPS_KEPT,
});

/// The map of the `width` x `height` pixels of pitch `pixel_mm` from `origin` (mm, image
/// coordinates) over `geo`'s lines: a kept one, or computed (on two threads) and kept.
pub(crate) fn pixel_map(
    geo: &ScanGeometry,
    origin: [f64; 2],
    pixel_mm: f64,
    size: (usize, usize),
) -> Arc<PixelMap> {
    let key = MapKey::of(geo, origin, pixel_mm, size);
    if let Some(m) = MAPS.lock().ok().and_then(|mut c| c.get(&key)) {
        return m;
    }
    let m = Arc::new(compute(geo, key, origin, pixel_mm, size));
    if let Ok(mut c) = MAPS.lock() {
        // Another thread may have made the same map meanwhile: one copy is kept.
        if let Some(kept) = c.get(&key) {
            return kept;
        }
        c.keep(&m);
    }
    m
}

impl MapKey {
    fn of(geo: &ScanGeometry, origin: [f64; 2], pixel_mm: f64, (w, h): (usize, usize)) -> MapKey {
        MapKey {
            kind: geo.spec.kind,
            footprint_bits: geo.spec.footprint_mm.to_bits(),
            radius_bits: geo.spec.radius_mm.to_bits(),
            sector_bits: geo.spec.sector_deg.to_bits(),
            lines: geo.lines,
            origin_bits: origin.map(f64::to_bits),
            pixel_bits: pixel_mm.to_bits(),
            size: [w, h],
        }
    }
}

/// `plane_to_line` of every pixel centre, rows split over two threads.
fn compute(
    geo: &ScanGeometry,
    key: MapKey,
    origin: [f64; 2],
    pixel_mm: f64,
    (width, height): (usize, usize),
) -> PixelMap {
    let mut line_depth = vec![(0.0, 0.0); width * height];
    parallel::in_two(&mut line_depth, width.max(1), |rows, y_first| {
        for (i, row) in rows.chunks_mut(width.max(1)).enumerate() {
            let ym = origin[1] + (y_first + i) as f64 * pixel_mm;
            for (x, out) in row.iter_mut().enumerate() {
                *out = geo.plane_to_line(origin[0] + x as f64 * pixel_mm, ym);
            }
        }
    });
    PixelMap { key, line_depth }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ultrasound::probe::ProbePose;
    use glam::DVec3;

    /// A map holds `plane_to_line` of every pixel bit for bit, for both arrays.
    #[test]
    fn the_pixel_map_is_plane_to_line_bit_for_bit() {
        for kind in [ProbeKind::Linear, ProbeKind::Curvilinear] {
            let geo = geometry(kind, 97);
            let (origin, pixel, size) = ([-31.5, -7.25], 0.37, (171, 143));
            let a = pixel_map(&geo, origin, pixel, size);
            for y in 0..size.1 {
                for x in 0..size.0 {
                    let want = geo
                        .plane_to_line(origin[0] + x as f64 * pixel, origin[1] + y as f64 * pixel);
                    let got = a.line_depth[y * size.0 + x];
                    assert_eq!(
                        (got.0.to_bits(), got.1.to_bits()),
                        (want.0.to_bits(), want.1.to_bits()),
                        "{kind:?} pixel ({x}, {y})"
                    );
                }
            }
        }
    }

    /// The cache gives back the map of a geometry it keeps, and another for a different
    /// geometry (lines, pitch); beyond its size the least recently used map goes.
    #[test]
    fn the_pixel_map_is_kept_per_geometry() {
        let mut cache = MapCache {
            maps: Vec::new(),
            kept: 2,
        };
        let mut get = |geo: &ScanGeometry, pixel: f64| {
            let key = MapKey::of(geo, [0.0, 0.0], pixel, (8, 6));
            cache.get(&key).unwrap_or_else(|| {
                let m = Arc::new(compute(geo, key, [0.0, 0.0], pixel, (8, 6)));
                cache.keep(&m);
                m
            })
        };
        let a = geometry(ProbeKind::Curvilinear, 97);
        let b = geometry(ProbeKind::Curvilinear, 98);
        let first = get(&a, 0.5);
        assert!(Arc::ptr_eq(&first, &get(&a, 0.5)), "kept");
        let other = get(&b, 0.5);
        assert!(!Arc::ptr_eq(&first, &other), "another number of lines");
        assert!(Arc::ptr_eq(&first, &get(&a, 0.5)), "both kept");
        let third = get(&a, 0.25);
        assert!(!Arc::ptr_eq(&first, &third), "another pitch");
        // Kept: `a` at 0.5 (used just before the third) and the third; `b` went.
        assert!(Arc::ptr_eq(&first, &get(&a, 0.5)));
        assert!(
            !Arc::ptr_eq(&other, &get(&b, 0.5)),
            "the least recently used went"
        );
    }

    fn geometry(kind: ProbeKind, lines: usize) -> ScanGeometry {
        ScanGeometry {
            spec: kind.spec(),
            frame: ProbePose::from_rotation(DVec3::ZERO, DVec3::Z, 0.0)
                .frame()
                .unwrap(),
            lines,
            depth_mm: 50.0,
        }
    }
}
