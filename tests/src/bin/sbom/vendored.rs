//! Third-party files copied into the web client (`web-client/vendor/<name>/`), each described by
//! its `vendor.json`: name, version, package URL, SPDX licence and the SHA-256 of every file.
//! The generator checks each digest against the file on disk, so a bill never names a copy
//! that is not the one shipped.

use std::path::Path;

use serde_json::Value;

use crate::bom::{Component, License};

/// One component per vendored folder, in folder order (all served to browsers: required).
pub fn components(vendor: &Path) -> anyhow::Result<Vec<Component>> {
    let mut dirs: Vec<_> = match std::fs::read_dir(vendor) {
        Ok(d) => d.collect::<Result<_, _>>()?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(e.into()),
    };
    dirs.sort_by_key(|d| d.file_name());
    let mut out = Vec::new();
    for dir in dirs.iter().filter(|d| d.path().is_dir()) {
        let manifest = dir.path().join("vendor.json");
        let m: Value = serde_json::from_str(&std::fs::read_to_string(&manifest)?)
            .map_err(|e| anyhow::anyhow!("{}: {e}", manifest.display()))?;
        let field = |k: &str| {
            m[k].as_str()
                .map(str::to_owned)
                .ok_or_else(|| anyhow::anyhow!("{}: no string {k:?}", manifest.display()))
        };
        let files = m["files"]
            .as_object()
            .ok_or_else(|| anyhow::anyhow!("{}: no \"files\"", manifest.display()))?;
        let mut hashes = Vec::new();
        for (file, want) in files {
            let bytes = std::fs::read(dir.path().join(file))?;
            let got = hex::encode(<sha2::Sha256 as sha2::Digest>::digest(&bytes));
            anyhow::ensure!(
                Some(got.as_str()) == want.as_str(),
                "{}: {file} has SHA-256 {got}, the manifest says {want}",
                manifest.display()
            );
            hashes.push(("SHA-256", got));
        }
        let purl = field("purl")?;
        out.push(Component {
            bom_ref: purl.clone(),
            kind: "library",
            group: None,
            name: field("name")?,
            version: field("version")?,
            purl: Some(purl),
            license: Some(License::Expression(field("license")?)),
            hashes,
            required: true,
            depends_on: Vec::new(),
        });
    }
    Ok(out)
}
