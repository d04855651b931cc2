//! The radiation estimate of an attempt: incident air kerma at the skin where the central beam
//! enters, and the kerma-area product, summed over every shot and every second of live
//! fluoroscopy with the technique and C-arm pose of that moment.
//!
//! An estimate, not a dose record: the tube output is the committed SpekPy spectrum's air kerma
//! per mAs ([`sim_core::fluoro::dose`]), scaled by the inverse square to the skin, without
//! backscatter, table attenuation or automatic exposure control.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use sim_core::fluoro::Projection;
use sim_core::fluoro::dose::{DoseExposure, incident_dose};

use crate::session::region::Region;

/// Distance of the patient entrance reference point from the isocentre towards the focal
/// spot, mm (IEC 60601-2-43:2010, 203.5.2.4.5: 15 cm), used when the central ray misses the
/// skin.
pub const REFERENCE_POINT_FROM_ISOCENTRE_MM: f64 = 150.0;

/// Dose booked so far (part of the fluoroscopy state).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DoseTally {
    /// Incident air kerma at the skin, mGy.
    pub air_kerma_mgy: f64,
    /// Kerma-area product, Gy cm^2.
    pub kerma_area_product_gycm2: f64,
    /// Live fluoroscopy booked up to this time, ms (while live runs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub live_booked_to_ms: Option<u64>,
}

impl DoseTally {
    /// Nothing booked and no live run.
    pub fn is_empty(&self) -> bool {
        *self == DoseTally::default()
    }

    /// Adds `seconds` of exposure at `kvp`, `ma` with the C-arm at `projection`.
    pub fn book(
        &mut self,
        region: &Region,
        projection: &Projection,
        kvp: u32,
        ma: f64,
        seconds: f64,
    ) {
        let (k, kap) = dose_of(region, projection, kvp, ma, seconds);
        self.air_kerma_mgy += k;
        self.kerma_area_product_gycm2 += kap;
    }
}

/// Source-to-skin distance along the central ray, mm: where it first meets the skin, else the
/// IEC reference point.
pub fn source_to_skin_mm(region: &Region, projection: &Projection) -> f64 {
    let f = projection.frame();
    let source = DVec3::from_array(f.source_mm);
    let dir = DVec3::from_array(f.normal);
    let sid = projection.source_to_detector_mm();
    region.skin_entry(source, dir, sid).map_or(
        projection.source_to_isocentre_mm - REFERENCE_POINT_FROM_ISOCENTRE_MM,
        |p| p.distance(source),
    )
}

/// Collimated field area in the detector plane, mm^2 (the blades clipped to the detector, and
/// inside the iris when there is one).
pub fn field_area_at_detector_mm2(projection: &Projection) -> f64 {
    let [w, h] = projection.detector_size_mm();
    let c = &projection.collimation;
    let x = (c.x_max_mm.min(0.5 * w) - c.x_min_mm.max(-0.5 * w)).max(0.0);
    let y = (c.y_max_mm.min(0.5 * h) - c.y_min_mm.max(-0.5 * h)).max(0.0);
    match c.iris_radius_mm {
        // The blades' rectangle inside the iris's disc, exactly.
        Some(r) => super::collimator::rectangle_in_disc_mm2(
            c.x_min_mm.max(-0.5 * w),
            c.x_max_mm.min(0.5 * w),
            c.y_min_mm.max(-0.5 * h),
            c.y_max_mm.min(0.5 * h),
            r,
        ),
        None => x * y,
    }
}

/// Air kerma (mGy) and kerma-area product (Gy cm^2) of one exposure.
pub fn dose_of(
    region: &Region,
    projection: &Projection,
    kvp: u32,
    ma: f64,
    seconds: f64,
) -> (f64, f64) {
    let d = incident_dose(&DoseExposure {
        kvp: f64::from(kvp),
        ma,
        seconds,
        source_to_skin_mm: source_to_skin_mm(region, projection),
        field_area_at_detector_mm2: field_area_at_detector_mm2(projection),
        source_to_detector_mm: projection.source_to_detector_mm(),
    });
    (d.air_kerma_mgy, d.kerma_area_product_gycm2)
}
