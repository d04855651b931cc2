//! The Rust side of the bill: workspace crates and every crate they resolve to, read from
//! `cargo metadata` (names, versions, licences, the resolved graph) and Cargo.lock (checksums).

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::Path;

use cargo_metadata::{DependencyKind, MetadataCommand, Package, PackageId};

use crate::bom::{Component, License, purl_encode};

/// SHA-256 checksums of registry crates by (name, version), as Cargo.lock records them (cargo
/// verifies each downloaded archive against this digest).
fn lock_checksums(root: &Path) -> anyhow::Result<HashMap<(String, String), String>> {
    let lock: toml::Table = std::fs::read_to_string(root.join("Cargo.lock"))?.parse()?;
    let mut sums = HashMap::new();
    for package in lock
        .get("package")
        .and_then(|p| p.as_array())
        .into_iter()
        .flatten()
    {
        let field = |key: &str| package.get(key).and_then(|v| v.as_str()).map(str::to_owned);
        if let (Some(name), Some(version), Some(sum)) =
            (field("name"), field("version"), field("checksum"))
        {
            sums.insert((name, version), sum);
        }
    }
    Ok(sums)
}

/// A crate's licence as an SPDX expression. Cargo documents `/` as the old separator between
/// alternatives ("MIT/Apache-2.0"), which SPDX spells `OR`; a crate with only a licence file is
/// described by that file's name.
fn license(package: &Package) -> Option<License> {
    if let Some(expression) = &package.license {
        let spdx = expression
            .split('/')
            .map(str::trim)
            .collect::<Vec<_>>()
            .join(" OR ");
        return Some(License::Expression(spdx));
    }
    package
        .license_file
        .as_ref()
        .map(|file| License::Named(format!("see {file} in the {} crate", package.name)))
}

/// Components for every crate in the resolved graph, and the bom-refs of the workspace crates.
/// `target` limits the graph to the crates one target triple builds.
pub fn components(
    root: &Path,
    target: Option<&str>,
) -> anyhow::Result<(Vec<Component>, Vec<String>)> {
    let mut command = MetadataCommand::new();
    command.manifest_path(root.join("Cargo.toml"));
    let mut options = vec!["--locked".to_owned()];
    if let Some(triple) = target {
        options.extend(["--filter-platform".to_owned(), triple.to_owned()]);
    }
    command.other_options(options);
    let meta = command.exec()?;
    let resolve = meta
        .resolve
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("cargo metadata gave no resolved graph"))?;
    let packages: HashMap<&PackageId, &Package> =
        meta.packages.iter().map(|p| (&p.id, p)).collect();
    let members: HashSet<&PackageId> = meta.workspace_members.iter().collect();
    let sums = lock_checksums(root)?;

    let mut refs: HashMap<&PackageId, String> = HashMap::new();
    for node in &resolve.nodes {
        let p = packages[&node.id];
        let bom_ref = if members.contains(&node.id) {
            format!("pain-sim/{}@{}", p.name, p.version)
        } else if p.source.as_ref().is_some_and(|s| s.is_crates_io()) {
            format!(
                "pkg:cargo/{}@{}",
                purl_encode(&p.name),
                purl_encode(&p.version.to_string())
            )
        } else {
            // deny.toml admits crates.io alone; a crate from anywhere else has no package URL
            // this generator could vouch for, so it stops rather than describe it vaguely.
            anyhow::bail!(
                "{} {} comes from {:?}, not crates.io",
                p.name,
                p.version,
                p.source
            );
        };
        refs.insert(&node.id, bom_ref);
    }

    // Required: reached from a shipped workspace crate through normal (linked) dependencies
    // only. This crate holds the whole-system tests and tools such as this generator, and
    // nothing of it ships, so it is no starting point.
    let nodes: BTreeMap<&PackageId, _> = resolve.nodes.iter().map(|n| (&n.id, n)).collect();
    let mut required: HashSet<&PackageId> = members
        .iter()
        .copied()
        .filter(|id| packages[id].name.as_str() != env!("CARGO_PKG_NAME"))
        .collect();
    let mut stack: Vec<&PackageId> = required.iter().copied().collect();
    while let Some(id) = stack.pop() {
        for dep in &nodes[id].deps {
            let linked = dep
                .dep_kinds
                .iter()
                .any(|k| k.kind == DependencyKind::Normal);
            if linked && required.insert(&dep.pkg) {
                stack.push(&dep.pkg);
            }
        }
    }

    let mut out = Vec::new();
    for (id, node) in &nodes {
        let p = packages[id];
        let member = members.contains(id);
        let version = p.version.to_string();
        let hashes = sums
            .get(&(p.name.to_string(), version.clone()))
            .map(|sum| vec![("SHA-256", sum.clone())])
            .unwrap_or_default();
        out.push(Component {
            bom_ref: refs[id].clone(),
            kind: if member && p.targets.iter().any(|t| t.is_bin()) {
                "application"
            } else {
                "library"
            },
            group: None,
            name: p.name.to_string(),
            version,
            purl: (!member).then(|| refs[id].clone()),
            license: license(p),
            hashes,
            required: required.contains(id),
            depends_on: node.deps.iter().map(|d| refs[&d.pkg].clone()).collect(),
        });
    }
    let mut roots: Vec<String> = members.iter().map(|id| refs[id].clone()).collect();
    roots.sort();
    Ok((out, roots))
}
