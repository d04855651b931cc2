//! What the benches share: the GPU context (or a skipped run without one), the procedural
//! phantom as a region and a station resolved on it.

use std::sync::Arc;

use render_worker::gpu::GpuContext;
use render_worker::session::{Region, StationContext, sha256_hex};

/// The headless GPU context (a real GPU or lavapipe), or `None` after saying that the bench is
/// skipped because no adapter opened.
pub fn gpu_or_skip() -> Option<GpuContext> {
    GpuContext::new_headless()
        .inspect_err(|e| println!("no GPU adapter, benchmark skipped: {e}"))
        .ok()
}

/// The phantom meshed at `voxel_mm`, cached by parameter hash in the workspace's test scratch
/// folder under the name the tests use (`phantom-lumbar-<voxel>mm`), so a bench run after the
/// tests loads their build (what is timed here is the session, not the meshing).
pub fn phantom_region(voxel_mm: f64) -> Arc<Region> {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("phantom-lumbar-{voxel_mm}mm"));
    let asset = sim_core::anatomy::phantom::ensure_built_with(
        &dir,
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
