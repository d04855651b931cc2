//! Restart: how long the server binary takes from its start to every region of its stations
//! ready, when its caches are warm (the phantom built, the database cluster made), with the
//! scenes' stored BVH trees present, deleted, or corrupted by one flipped byte (then rebuilt,
//! never served).
//!
//! Regions: the default lumbar phantom (the tests' and the other benches' cache of it, built
//! here on first use) and the shipped real-CT region (copied), with every shipped station on
//! them. Times are from spawning the process to `/healthz` reporting the anatomy ready, polled
//! every 20 ms; the per-region figures are the server's own `prepare_s`.
//!
//! `BENCH_QUICK=1`: two restarts with stored trees; else five.

#[allow(dead_code)]
#[path = "../tests/server_process.rs"]
mod server_process;

use std::path::Path;
use std::time::{Duration, Instant};

use server_process::{health, spawn_server};
use sim_core::fluoro::scene_store::STORE_FILE;

const REGIONS: [&str; 2] = [sim_core::anatomy::phantom::REGION_NAME, "lumbar-ct"];

/// One start: seconds from spawn to every region ready, and each region's `prepare_s`.
fn start_once(data: &Path, env: &[(&str, String)]) -> (f64, Vec<(String, f64)>) {
    let started = Instant::now();
    let server = spawn_server(data, None, env);
    let h = loop {
        let h = health(&server.addr);
        if h["anatomy"]["ready"] == true {
            break h;
        }
        if let Some(failed) = h["anatomy"]["regions"]
            .as_object()
            .and_then(|m| m.values().find(|r| r["state"] == "failed"))
        {
            panic!("a region failed: {failed}");
        }
        assert!(
            started.elapsed() < Duration::from_secs(900),
            "regions not ready: {h}"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let ready_s = started.elapsed().as_secs_f64();
    let regions = h["anatomy"]["regions"]
        .as_object()
        .map(|m| {
            m.iter()
                .map(|(k, v)| (k.clone(), v["prepare_s"].as_f64().unwrap_or(f64::NAN)))
                .collect()
        })
        .unwrap_or_default();
    server.sigterm_and_wait();
    (ready_s, regions)
}

fn row(what: &str, runs: &[(f64, Vec<(String, f64)>)]) {
    let mut ready: Vec<f64> = runs.iter().map(|r| r.0).collect();
    ready.sort_by(f64::total_cmp);
    let median = ready[ready.len() / 2];
    let last = &runs[runs.len() - 1].1;
    let per_region = last
        .iter()
        .map(|(k, s)| format!("{k} {s:.2}"))
        .collect::<Vec<_>>()
        .join(", ");
    println!(
        "| {what} | {} | {:.2} | {median:.2} | {per_region} |",
        runs.len(),
        ready[0]
    );
}

fn main() {
    let quick = std::env::var("BENCH_QUICK").is_ok_and(|v| v == "1");
    let restarts = if quick { 2 } else { 5 };
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");

    let cache = Path::new(env!("CARGO_TARGET_TMPDIR")).join("regions");
    let phantom_dir = cache.join(REGIONS[0]);
    std::fs::create_dir_all(&phantom_dir).expect("region cache folder");
    let assets = tempfile::tempdir().expect("assets folder");
    std::os::unix::fs::symlink(&phantom_dir, assets.path().join(REGIONS[0]))
        .expect("link the phantom cache");
    let ct = assets.path().join(REGIONS[1]);
    std::fs::create_dir_all(&ct).expect("region folder");
    for entry in std::fs::read_dir(shipped.join(REGIONS[1])).expect("shipped CT region") {
        let path = entry.expect("entry").path();
        let name = path.file_name().expect("name").to_owned();
        if path.is_file() && name != STORE_FILE {
            std::fs::copy(&path, ct.join(name)).expect("copy");
        }
    }
    let stations = tempfile::tempdir().expect("stations folder");
    let mut station_count = 0;
    for f in sim_core::rubric::load_station_dir(&shipped.join("stations")).expect("stations") {
        if REGIONS.contains(&f.station.region_asset().as_str()) {
            let name = f.path.file_name().expect("station file name");
            std::fs::write(stations.path().join(name), &f.text).expect("station file");
            station_count += 1;
        }
    }
    let data = tempfile::tempdir().expect("data folder");
    let env = vec![
        ("PAINSIM_ASSETS_DIR", assets.path().display().to_string()),
        (
            "PAINSIM_STATIONS_DIR",
            stations.path().display().to_string(),
        ),
        ("RUST_LOG", "error".into()),
    ];
    let stores = || REGIONS.map(|r| assets.path().join(r).join(STORE_FILE));

    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "## Server restart to regions ready ({cores} cores; {} and {}, {station_count} stations)\n",
        REGIONS[0], REGIONS[1]
    );
    println!("| start | runs | fastest s | median s | prepare_s per region (last run) |");
    println!("|---|---:|---:|---:|---|");
    // The first start makes the database cluster (and the phantom, if no test built it yet).
    let first = start_once(data.path(), &env);
    row("first start (cluster made here)", &[first]);
    let stored: Vec<_> = (0..restarts)
        .map(|_| start_once(data.path(), &env))
        .collect();
    row("restart, trees stored", &stored);
    let good: Vec<Vec<u8>> = stores()
        .iter()
        .map(|p| std::fs::read(p).expect("stored trees"))
        .collect();

    for p in stores() {
        std::fs::remove_file(p).expect("delete the stored trees");
    }
    let deleted = start_once(data.path(), &env);
    row("restart, trees deleted (built, stored)", &[deleted]);

    for p in stores() {
        let mut bytes = std::fs::read(&p).expect("stored trees");
        let at = bytes.len() / 2;
        bytes[at] ^= 1;
        std::fs::write(&p, bytes).expect("corrupt the stored trees");
    }
    let corrupt = start_once(data.path(), &env);
    row("restart, trees corrupt (rebuilt, stored)", &[corrupt]);
    for (p, g) in stores().iter().zip(&good) {
        assert!(
            std::fs::read(p).expect("rewritten trees") == *g,
            "{} was not rewritten as built",
            p.display()
        );
    }
    let again = start_once(data.path(), &env);
    row("restart after the rebuild", &[again]);
    println!("\nGoal: regions ready <= 3 s after a restart with warm caches, on 2 cores.");
}
