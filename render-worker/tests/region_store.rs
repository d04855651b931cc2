//! A region's scene trees stored beside its meshes: a load after the first reuses them and makes
//! the same scene bit for bit; a corrupt, truncated or stale store is rebuilt, never served.

use std::path::{Path, PathBuf};

use render_worker::session::loader::load_region;
use render_worker::session::region::Region;
use sim_core::anatomy::asset::RegionAsset;
use sim_core::fluoro::scene_store::{STORE_FILE, StoreOutcome};
use sim_core::geom::Bvh;

/// A private copy of the shipped CT region (its files, not its stored trees).
fn copy_of_lumbar_ct(root: &Path, name: &str) -> PathBuf {
    let from = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/lumbar-ct");
    let to = root.join(name);
    std::fs::create_dir_all(&to).expect("region folder");
    for entry in std::fs::read_dir(&from).expect("shipped region") {
        let path = entry.expect("entry").path();
        if path.file_name().is_some_and(|n| n != STORE_FILE) && path.is_file() {
            std::fs::copy(&path, to.join(path.file_name().expect("name"))).expect("copy");
        }
    }
    to
}

fn trees(r: &Region) -> Vec<(String, Bvh)> {
    r.scene
        .entries()
        .iter()
        .map(|e| (e.name.clone(), e.bvh.clone()))
        .collect()
}

fn outcome_of(dir: &Path) -> (Region, StoreOutcome) {
    Region::from_asset_in(&RegionAsset::load(dir).expect("asset"), dir)
}

#[test]
fn stored_trees_are_reused_and_a_bad_store_is_rebuilt() {
    let root =
        Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("region-store-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let dir = copy_of_lumbar_ct(&root, "ct-copy");
    let built = trees(&Region::from_asset(
        &RegionAsset::load(&dir).expect("asset"),
    ));

    // Through the worker's loader: the first load builds and stores, the next one reuses.
    let first = load_region(&root, "ct-copy", &mut |_| {}).expect("first load");
    assert!(dir.join(STORE_FILE).is_file(), "the trees were stored");
    assert_eq!(trees(&first), built);
    let (again, outcome) = outcome_of(&dir);
    assert_eq!(outcome, StoreOutcome::Reused);
    assert_eq!(
        trees(&again),
        built,
        "reused trees are the built ones, bit for bit"
    );
    let good = std::fs::read(dir.join(STORE_FILE)).expect("store");

    // A flipped byte in the middle, a truncated file, an empty file: rebuilt and rewritten.
    let mut flipped = good.clone();
    flipped[good.len() / 2] ^= 1;
    for (what, bad) in [
        ("flipped", flipped),
        ("truncated", good[..good.len() / 3].to_vec()),
        ("empty", Vec::new()),
    ] {
        std::fs::write(dir.join(STORE_FILE), &bad).expect("spoil");
        let (r, outcome) = outcome_of(&dir);
        assert!(
            matches!(&outcome, StoreOutcome::Built { why, stored: Ok(()) }
                if why.contains("corrupt")),
            "{what}: {outcome:?}"
        );
        assert_eq!(trees(&r), built, "{what}");
        assert_eq!(
            std::fs::read(dir.join(STORE_FILE)).expect("store"),
            good,
            "{what}"
        );
    }

    // Stale: the same store beside other meshes (the cervical layout under this name would be
    // a different asset; here one structure fewer in the manifest is enough to change the key).
    let asset = RegionAsset::load(&dir).expect("asset");
    let mut fewer = asset.clone();
    fewer.structures.pop();
    let (r, outcome) = Region::from_asset_in(&fewer, &dir);
    assert!(
        matches!(&outcome, StoreOutcome::Built { why, .. } if why.contains("other meshes")),
        "{outcome:?}"
    );
    assert_eq!(trees(&r), built[..built.len() - 1].to_vec());

    // A store that cannot be written (a folder in its place): built, said, and loaded anyway.
    std::fs::remove_file(dir.join(STORE_FILE)).expect("remove the store");
    std::fs::create_dir(dir.join(STORE_FILE)).expect("a folder where the store goes");
    let (r, outcome) = outcome_of(&dir);
    assert!(
        matches!(&outcome, StoreOutcome::Built { stored: Err(_), .. }),
        "{outcome:?}"
    );
    assert_eq!(trees(&r), built);
    let again = load_region(&root, "ct-copy", &mut |_| {}).expect("loads without its store");
    assert_eq!(trees(&again), built);
    let _ = std::fs::remove_dir_all(&root);
}
