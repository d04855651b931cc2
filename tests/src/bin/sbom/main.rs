//! Writes a software bill of materials for the whole platform as CycloneDX 1.5 JSON: every crate
//! in Cargo.lock (through `cargo metadata`, with the SHA-256 checksums Cargo.lock records) and
//! every package in the web client's package-lock.json (with its SHA-512 integrity), each with a
//! package URL, its declared licence and its scope, plus the dependency graph of both.
//!
//! ```text
//! cargo run -p tests --bin sbom -- [--out FILE] [--target TRIPLE]
//! ```
//!
//! `--out` writes to FILE instead of standard output. `--target` keeps only the crates that
//! build for one target triple (cargo's `--filter-platform`); by default the bill lists every
//! crate Cargo.lock locks, for every platform (what cargo-cyclonedx calls `--target all`), so
//! that it accounts for the whole lockfile.
//!
//! Components have scope "required" when a shipped program links them (reached from a
//! workspace crate through normal dependencies only) and "excluded" when only tests, build
//! scripts or the browser tests use them: CycloneDX 1.5 reserves "excluded" for components that
//! serve tests and other purposes outside run time.

mod bom;
mod cargo_deps;
mod npm_deps;
mod vendored;

use std::path::{Path, PathBuf};

struct Args {
    out: Option<PathBuf>,
    target: Option<String>,
}

fn parse_args() -> anyhow::Result<Args> {
    let mut args = Args {
        out: None,
        target: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--out" => {
                args.out = Some(
                    it.next()
                        .ok_or_else(|| anyhow::anyhow!("--out FILE"))?
                        .into(),
                )
            }
            "--target" => {
                args.target = Some(
                    it.next()
                        .ok_or_else(|| anyhow::anyhow!("--target TRIPLE"))?,
                )
            }
            "-h" | "--help" => {
                println!("usage: sbom [--out FILE] [--target TRIPLE]");
                std::process::exit(0);
            }
            other => anyhow::bail!(
                "unknown argument {other:?} (usage: sbom [--out FILE] [--target TRIPLE])"
            ),
        }
    }
    Ok(args)
}

fn main() -> anyhow::Result<()> {
    let args = parse_args()?;
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let (mut components, mut roots) = cargo_deps::components(&root, args.target.as_deref())?;
    let (npm, npm_root) = npm_deps::components(&root.join("web-client"))?;
    components.extend(npm);
    roots.push(npm_root);
    // Files copied into the web client are roots of their own: nothing in a lockfile names them.
    let vendored = vendored::components(&root.join("web-client").join("vendor"))?;
    roots.extend(vendored.iter().map(|c| c.bom_ref.clone()));
    components.extend(vendored);
    let crates = components
        .iter()
        .filter(|c| {
            c.purl
                .as_deref()
                .is_some_and(|p| p.starts_with("pkg:cargo/"))
        })
        .count();
    let packages = components
        .iter()
        .filter(|c| c.purl.as_deref().is_some_and(|p| p.starts_with("pkg:npm/")))
        .count();
    let text = serde_json::to_string_pretty(&bom::document(components, roots)?)? + "\n";
    match &args.out {
        Some(path) => {
            std::fs::write(path, text)?;
            eprintln!(
                "sbom: {crates} crates and {packages} npm packages written to {}",
                path.display()
            );
        }
        None => print!("{text}"),
    }
    Ok(())
}
