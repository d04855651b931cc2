//! Architecture invariant: the dev profile builds exactly the build-time-only crates unoptimised.
//!
//! The workspace manifest optimises every dependency in the dev profile (`package."*"`, so tests
//! of the numeric code run fast) and names each crate that only runs at build time (proc macros,
//! build-script helpers and their own dependencies) with `opt-level = 0`: they cost a quarter of
//! a cold build at opt-level 2 and nothing of theirs runs in a test. A named crate that some
//! binary links would run unoptimised; a new proc macro left unnamed would cost build time. Both
//! fail here.

use std::collections::{BTreeSet, HashMap};

use cargo_metadata::{DependencyKind, MetadataCommand, PackageId};

/// Names of the crates a workspace binary, library or test links on Linux: normal and dev edges
/// from the workspace crates, then normal edges, never into a proc macro or through a build
/// dependency (both run on the build host only).
fn linked_and_build_only() -> (BTreeSet<String>, BTreeSet<String>) {
    let meta = MetadataCommand::new()
        .manifest_path(concat!(env!("CARGO_MANIFEST_DIR"), "/../Cargo.toml"))
        .other_options(vec![
            "--filter-platform".to_owned(),
            "x86_64-unknown-linux-gnu".to_owned(),
        ])
        .exec()
        .expect("cargo metadata");
    let resolve = meta.resolve.as_ref().expect("resolved graph");
    let nodes: HashMap<&PackageId, _> = resolve.nodes.iter().map(|n| (&n.id, n)).collect();
    let packages: HashMap<&PackageId, _> = meta.packages.iter().map(|p| (&p.id, p)).collect();
    let proc_macro = |id: &PackageId| packages[id].targets.iter().any(|t| t.is_proc_macro());
    let members: BTreeSet<&PackageId> = meta.workspace_members.iter().collect();
    let mut linked: BTreeSet<&PackageId> = BTreeSet::new();
    let mut stack: Vec<&PackageId> = members.iter().copied().collect();
    while let Some(id) = stack.pop() {
        if !linked.insert(id) {
            continue;
        }
        for dep in &nodes[id].deps {
            let follows = dep.dep_kinds.iter().any(|k| match k.kind {
                DependencyKind::Normal => true,
                DependencyKind::Development => members.contains(id),
                _ => false,
            });
            if follows && !proc_macro(&dep.pkg) {
                stack.push(&dep.pkg);
            }
        }
    }
    let name = |id: &PackageId| packages[id].name.to_string();
    let linked_names: BTreeSet<String> = linked.iter().map(|id| name(id)).collect();
    let build_only = nodes
        .keys()
        .filter(|id| !linked.contains(*id))
        .map(|id| name(id))
        .filter(|n| !linked_names.contains(n))
        .collect();
    (linked_names, build_only)
}

/// Crates named in `[profile.dev.package.<name>]` with `opt-level = 0` in the root manifest.
fn unoptimised_in_dev() -> BTreeSet<String> {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../Cargo.toml"))
        .expect("read the workspace manifest");
    let manifest: toml::Table = text.parse().expect("the workspace manifest is TOML");
    let packages = manifest
        .get("profile")
        .and_then(|p| p.get("dev"))
        .and_then(|d| d.get("package"))
        .and_then(|p| p.as_table())
        .expect("[profile.dev.package] tables");
    packages
        .iter()
        .filter(|(_, t)| t.get("opt-level").and_then(toml::Value::as_integer) == Some(0))
        .map(|(name, _)| name.clone())
        .collect()
}

#[test]
fn exactly_the_build_only_crates_are_unoptimised_in_dev() {
    let (linked, build_only) = linked_and_build_only();
    let unoptimised = unoptimised_in_dev();
    let linked_but_unoptimised: Vec<_> = unoptimised.intersection(&linked).collect();
    assert!(
        linked_but_unoptimised.is_empty(),
        "crates linked into a binary or test but built with opt-level 0 in dev: \
         {linked_but_unoptimised:?}"
    );
    let unnamed: Vec<_> = build_only.difference(&unoptimised).collect();
    assert!(
        unnamed.is_empty(),
        "build-time-only crates optimised in dev (name each in Cargo.toml with \
         `[profile.dev.package.<name>] opt-level = 0`): {unnamed:?}"
    );
    let stale: Vec<_> = unoptimised
        .iter()
        .filter(|n| !build_only.contains(*n))
        .collect();
    assert!(
        stale.is_empty(),
        "named unoptimised but not in the Linux build graph: {stale:?}"
    );
}
