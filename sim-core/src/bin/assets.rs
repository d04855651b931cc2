//! `assets`: builds and checks anatomy asset folders.
//!
//! ```text
//! assets build --ct ct.nii.gz --masks segmentations/ --out assets/<region> [options]
//! assets build --ct ct.nii.gz --multilabel seg.nii.gz [--label-map map.json] --out assets/<region> [options]
//! assets verify assets/<region>
//!
//! options:
//!   --name NAME            region name (default: the output folder's name)
//!   --include a,b,c        only these structures
//!   --upsample N           up-sampling factor before extraction (default 1)
//!   --smooth N             N Taubin (0.5 / -0.53) pairs, 1 mm cap, 2 % volume guard (default off)
//!   --decimate F           keep about fraction F of the triangles (default off)
//!   --decimate-error MM    largest deviation decimation may introduce, mm (default 0.3)
//!   --licence SPDX         licence of the derived asset (default: NOASSERTION)
//!   --attribution TEXT     attribution that travels with the asset
//!   --lumbar               lumbar region (per-structure masks only): crop in plane to the body,
//!                          landmarks from the vertebra masks, authored canal contents, skin, fat
//!                          and muscle (see `sim_core::anatomy::lumbar_ct`)
//! ```
//!
//! Errors name the offending file; the output folder is written atomically, so a failed build
//! leaves nothing behind (an existing folder is kept as it was).

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use sim_core::anatomy::asset::RegionAsset;
use sim_core::anatomy::decimate::DecimationParams;
use sim_core::anatomy::lumbar_ct::import_lumbar_ct;
use sim_core::anatomy::pipeline::{PipelineParams, Progress};
use sim_core::anatomy::smooth::TaubinParams;
use sim_core::anatomy::totalseg::{ImportOptions, MaskSource, import_ct};

const USAGE: &str = "usage:
  assets build --ct CT.nii[.gz] (--masks DIR | --multilabel FILE [--label-map MAP.json]) --out DIR
               [--name NAME] [--include a,b,c] [--upsample N] [--smooth N] [--decimate F] [--decimate-error MM]
               [--licence SPDX] [--attribution TEXT] [--lumbar]
  assets verify DIR";

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(args: &[String]) -> Result<(), String> {
    match args.first().map(String::as_str) {
        Some("build") => build(&args[1..]),
        Some("verify") => {
            let dir = args.get(1).ok_or(USAGE)?;
            let region = RegionAsset::load(&PathBuf::from(dir)).map_err(|e| e.to_string())?;
            // Written through a locked handle so that a closed pipe (`| head`) ends the listing
            // quietly instead of panicking.
            let mut out = std::io::stdout().lock();
            let mut lines = vec![format!(
                "{}: {} structures, grid {:?} at {:?} mm, all file hashes verified",
                region.name,
                region.structures.len(),
                region.grid().dims,
                region.grid().spacing_mm
            )];
            for s in &region.structures {
                lines.push(format!(
                    "  {:<28} {:<14} {:>7} triangles  mesh {:>10.1} mm^3  mask {:>10.1} mm^3",
                    s.name,
                    s.material.name(),
                    s.mesh.triangles.len(),
                    s.mesh.signed_volume_mm3(),
                    s.mask_volume_mm3
                ));
            }
            for l in &region.landmarks {
                let p = l.position_mm;
                lines.push(format!(
                    "  landmark {:<40} [{:8.2}, {:8.2}, {:8.2}] mm",
                    l.name, p[0], p[1], p[2]
                ));
            }
            for line in lines {
                if writeln!(out, "{line}").is_err() {
                    break;
                }
            }
            Ok(())
        }
        _ => Err(USAGE.to_string()),
    }
}

fn build(args: &[String]) -> Result<(), String> {
    let mut ct = None;
    let mut masks = None;
    let mut multilabel = None;
    let mut label_map = None;
    let mut out = None;
    let mut name = None;
    let mut include = None;
    let mut params = PipelineParams::default();
    let mut licence = "NOASSERTION".to_string();
    let mut attribution = String::new();
    let mut lumbar = false;
    let mut decimate_error_mm = None;
    let mut it = args.iter();
    while let Some(flag) = it.next() {
        let mut value = || {
            it.next()
                .cloned()
                .ok_or_else(|| format!("{flag} needs a value\n{USAGE}"))
        };
        match flag.as_str() {
            "--ct" => ct = Some(PathBuf::from(value()?)),
            "--masks" => masks = Some(PathBuf::from(value()?)),
            "--multilabel" => multilabel = Some(PathBuf::from(value()?)),
            "--label-map" => label_map = Some(PathBuf::from(value()?)),
            "--out" => out = Some(PathBuf::from(value()?)),
            "--name" => name = Some(value()?),
            "--include" => {
                include = Some(value()?.split(',').map(str::to_string).collect::<Vec<_>>())
            }
            "--upsample" => {
                params.upsample = value()?.parse().map_err(|e| format!("--upsample: {e}"))?
            }
            "--smooth" => {
                let n: u32 = value()?.parse().map_err(|e| format!("--smooth: {e}"))?;
                params.smoothing = (n > 0).then(|| TaubinParams {
                    iterations: n,
                    ..TaubinParams::default()
                });
            }
            "--decimate" => {
                let f: f64 = value()?.parse().map_err(|e| format!("--decimate: {e}"))?;
                params.decimation = Some(DecimationParams {
                    target_fraction: f,
                    ..DecimationParams::default()
                });
            }
            "--decimate-error" => {
                let mm: f64 = value()?
                    .parse()
                    .map_err(|e| format!("--decimate-error: {e}"))?;
                decimate_error_mm = Some(mm);
            }
            "--licence" => licence = value()?,
            "--attribution" => attribution = value()?,
            "--lumbar" => lumbar = true,
            other => return Err(format!("unknown option {other}\n{USAGE}")),
        }
    }
    if let (Some(d), Some(mm)) = (params.decimation.as_mut(), decimate_error_mm) {
        d.max_error_mm = mm;
    }
    let ct = ct.ok_or_else(|| format!("--ct is required\n{USAGE}"))?;
    let out = out.ok_or_else(|| format!("--out is required\n{USAGE}"))?;
    let source = match (masks, multilabel) {
        (Some(dir), None) => MaskSource::Folder(dir),
        (None, Some(file)) => MaskSource::Multilabel { file, label_map },
        _ => {
            return Err(format!(
                "give exactly one of --masks and --multilabel\n{USAGE}"
            ));
        }
    };
    let region_name = name.unwrap_or_else(|| {
        out.file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "region".into())
    });
    let options = ImportOptions {
        region_name,
        params,
        include,
        licence,
        attribution,
    };
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} {msg:<36!} [{bar:30}] {pos}/{len}")
            .map_err(|e| e.to_string())?
            .progress_chars("=> "),
    );
    let start = Instant::now();
    let mut on_progress = |p: &Progress| {
        bar.set_length(p.total as u64);
        bar.set_position(p.done as u64);
        bar.set_message(format!("{}: {}", p.stage, p.item));
    };
    let region = if lumbar {
        import_lumbar_ct(&ct, &source, &options, &mut on_progress)
    } else {
        import_ct(&ct, &source, &options, &mut on_progress)
    }
    .map_err(|e| e.to_string())?;
    let built = start.elapsed();
    bar.set_message("writing");
    let provenance = region.write_to(&out).map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    let triangles: usize = region
        .structures
        .iter()
        .map(|s| s.mesh.triangles.len())
        .sum();
    println!(
        "wrote {} ({} structures, {triangles} triangles, grid {:?}) in {:.2} s (import and meshing {:.2} s)",
        out.display(),
        region.structures.len(),
        region.grid().dims,
        start.elapsed().as_secs_f64(),
        built.as_secs_f64()
    );
    for n in &provenance.notes {
        println!("  note: {n}");
    }
    Ok(())
}
