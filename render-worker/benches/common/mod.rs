//! What the session benches share: the procedural phantom as a region and a station resolved on
//! it.

use std::sync::Arc;

use render_worker::session::{Region, StationContext, sha256_hex};

/// The phantom meshed at `voxel_mm`, built in memory.
pub fn phantom_region(voxel_mm: f64) -> Arc<Region> {
    let asset = sim_core::anatomy::phantom::build(
        &sim_core::anatomy::phantom::PhantomParams::with_voxel_mm(voxel_mm),
        &mut |_| {},
    )
    .expect("phantom");
    Arc::new(Region::from_asset(&asset))
}

/// Station `id` from `assets/stations` with its targets resolved on `region`.
pub fn station(id: &str, region: &Region) -> Arc<StationContext> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/stations");
    let file = sim_core::rubric::load_station_dir(&dir)
        .expect("stations")
        .into_iter()
        .find(|f| f.station.id == id)
        .unwrap_or_else(|| panic!("station {id}"));
    Arc::new(StationContext::new(
        file.station,
        sha256_hex(file.text.as_bytes()),
        region,
    ))
}
