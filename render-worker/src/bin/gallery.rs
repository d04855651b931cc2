//! `gallery`: renders AP, 30 degree oblique and lateral fluoroscopy shots of every region a
//! station uses (or of the regions named) to PNG files, for review of the anatomy; and the AP
//! and lateral with scatter, the anti-scatter grid in and out (`<stem>_ap_grid.png`,
//! `<stem>_ap_nogrid.png`, ...). The stem is the region's name, with the habitus for the
//! lumbar phantom's variants (`lumbar-phantom-average`, `lumbar-phantom-slim`,
//! `lumbar-phantom-obese`).
//!
//! ```text
//! gallery [--assets DIR] [--out DIR] [--regions a,b,c]
//! ```
//!
//! `--assets` is the folder of region folders and `stations/` (default `assets`); the phantom
//! regions are built there on first use, as the platform does. `--out` defaults to `gallery`.
//! Shots come from the CPU reference renderer with the platform's default C-arm and beam (see
//! `render_worker::gallery`), so they are the same on every machine.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use render_worker::gallery;
use render_worker::session::loader::load_region;
use sim_core::rubric::load_station_dir;

const USAGE: &str = "usage: gallery [--assets DIR] [--out DIR] [--regions a,b,c]";

fn main() -> ExitCode {
    match run(&std::env::args().skip(1).collect::<Vec<_>>()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &[String]) -> Result<(), String> {
    let (mut assets, mut out, mut regions) = (PathBuf::from("assets"), PathBuf::from("gallery"), None);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().cloned().ok_or_else(|| format!("{a} needs a value\n{USAGE}"));
        match a.as_str() {
            "--assets" => assets = PathBuf::from(value()?),
            "--out" => out = PathBuf::from(value()?),
            "--regions" => regions = Some(value()?.split(',').map(str::to_owned).collect::<BTreeSet<_>>()),
            "-h" | "--help" => {
                println!("{USAGE}");
                return Ok(());
            }
            other => return Err(format!("unknown argument {other:?}\n{USAGE}")),
        }
    }
    let regions = match regions {
        Some(r) => r,
        None => load_station_dir(&assets.join("stations"))
            .map_err(|e| e.to_string())?
            .into_iter()
            .map(|f| f.station.region_asset())
            .collect(),
    };
    let settings = gallery::settings(0);
    for name in &regions {
        let t = Instant::now();
        let region = load_region(&assets, name, &mut |p| eprintln!("{name}: {p:?}")).map_err(|e| e.to_string())?;
        let loaded = t.elapsed();
        let mut shots = gallery::shots(&region, &settings).map_err(|e| e.to_string())?;
        shots.extend(gallery::scatter_shots(&region, &settings).map_err(|e| e.to_string())?);
        for path in gallery::write(&region, &shots, &out).map_err(|e| e.to_string())? {
            println!("{}", path.display());
        }
        eprintln!("{name}: loaded in {loaded:.1?}, rendered {} views in {:.1?}", shots.len(), t.elapsed() - loaded);
    }
    Ok(())
}
