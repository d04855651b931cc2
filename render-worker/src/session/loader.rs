//! Where a worker's regions come from: a folder of `assets_root` per region, the procedural
//! phantom built (and cached) there on first use, or the analytic demo region.

use std::path::Path;

use sim_core::anatomy::AnatomyError;
use sim_core::anatomy::asset::RegionAsset;
use sim_core::anatomy::phantom;
use sim_core::anatomy::pipeline::Progress;

use super::demo::{DEMO_REGION_NAME, demo_region};
use super::region::Region;

/// Why a region could not be loaded or built.
#[derive(Debug, thiserror::Error)]
pub enum RegionLoadError {
    /// Its files could not be read, or its phantom could not be built.
    #[error("region {name}: {source}")]
    Asset {
        /// Region name.
        name: String,
        /// What went wrong.
        source: AnatomyError,
    },
    /// The host was given its regions ready-made and this is not one of them.
    #[error("region {0} is not loaded in this host")]
    NotLoaded(String),
}

/// Whether [`load_region`] of `name` would only read files (the region is built and cached, or
/// is a folder of files, or the in-memory demo region), not build a phantom first. For a
/// phantom region this reads its provenance record only.
pub fn is_built(assets_root: &Path, name: &str) -> bool {
    phantom_recipe(name).is_none_or(|(generator, params, _)| {
        phantom::is_cached_for(&assets_root.join(name), generator, &params)
    })
}

/// The generator, parameters and build function of `name` when it is a procedural phantom
/// region (the lumbar phantom and its habitus variants, the neck).
fn phantom_recipe(name: &str) -> Option<(&'static str, phantom::PhantomParams, phantom::BuildFn)> {
    if let Some(habitus) = phantom::habitus::Habitus::of_region(name) {
        let params = habitus.apply(&phantom::PhantomParams::default());
        Some((phantom::GENERATOR, params, phantom::build))
    } else if name == phantom::cervical::REGION_NAME {
        let params = phantom::cervical::default_params();
        Some((
            phantom::cervical::GENERATOR,
            params,
            phantom::cervical::build,
        ))
    } else {
        None
    }
}

/// Loads `assets_root/<name>`, reporting the phantom build's stages to `progress` (a region that
/// is cached or read from files reports nothing). The phantom regions (lumbar and cervical) are
/// built there first if missing or stale. The scene's trees are stored in the folder too and
/// reused while they match its meshes ([`Region::from_asset_in`]). The analytic demo region
/// ([`DEMO_REGION_NAME`], boxes of known geometry) is built in memory when no folder of that
/// name exists, so whole-process tests (the real server binary) can run sessions that render in
/// milliseconds.
pub fn load_region(
    assets_root: &Path,
    name: &str,
    progress: &mut dyn FnMut(&Progress),
) -> Result<Region, RegionLoadError> {
    let dir = assets_root.join(name);
    if name == DEMO_REGION_NAME && !dir.exists() {
        return Ok(demo_region());
    }
    let asset = match phantom_recipe(name) {
        Some((generator, params, build)) => {
            phantom::ensure_built_by(&dir, generator, &params, build, progress)
        }
        None => RegionAsset::load(&dir),
    }
    .map_err(|source| RegionLoadError::Asset {
        name: name.to_string(),
        source,
    })?;
    // A habitus variant of the phantom is built by the phantom's generator, which names every
    // build after the phantom: the region goes by the name it was asked for.
    let mut asset = asset;
    if phantom::habitus::Habitus::of_region(name).is_some() {
        asset.name = name.to_string();
    }
    let (region, outcome) = Region::from_asset_in(&asset, &dir);
    super::region::log_store_outcome(name, "scene trees", &outcome);
    Ok(region)
}
