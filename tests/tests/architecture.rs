//! Architecture invariants from ARCHITECTURE.md, checked against `cargo metadata`.
//!
//! Each test names the invariant it enforces. They read the real dependency graph (normal and
//! build dependencies, transitively), so an indirect path through another crate counts too.

use std::collections::{BTreeSet, HashMap};

use cargo_metadata::{DependencyKind, Metadata, MetadataCommand, PackageId};

fn metadata() -> Metadata {
    MetadataCommand::new()
        .manifest_path(concat!(env!("CARGO_MANIFEST_DIR"), "/../Cargo.toml"))
        .exec()
        .expect("cargo metadata")
}

/// Names of every package `root` depends on (normal and build edges, transitively; dev-only
/// dependencies do not ship and are excluded).
fn runtime_closure(meta: &Metadata, root: &str) -> BTreeSet<String> {
    let resolve = meta.resolve.as_ref().expect("resolved graph");
    let nodes: HashMap<&PackageId, _> = resolve.nodes.iter().map(|n| (&n.id, n)).collect();
    let names: HashMap<&PackageId, &str> = meta.packages.iter().map(|p| (&p.id, p.name.as_str())).collect();
    let start = meta
        .workspace_packages()
        .into_iter()
        .find(|p| p.name.as_str() == root)
        .unwrap_or_else(|| panic!("no workspace crate {root}"))
        .id
        .clone();
    let mut seen = BTreeSet::new();
    let mut stack = vec![start];
    while let Some(id) = stack.pop() {
        for dep in &nodes[&id].deps {
            let shipped = dep.dep_kinds.iter().any(|k| matches!(k.kind, DependencyKind::Normal | DependencyKind::Build));
            if shipped && seen.insert(names[&dep.pkg].to_owned()) {
                stack.push(dep.pkg.clone());
            }
        }
    }
    seen
}

/// Architecture invariant: sim-core is pure computation. It knows nothing of async runtimes,
/// web frameworks, databases or the GPU.
#[test]
fn sim_core_has_no_io_frameworks_gpu_async_or_database() {
    let meta = metadata();
    let deps = runtime_closure(&meta, "sim-core");
    let forbidden = [
        "tokio", "axum", "sqlx", "sqlx-core", "wgpu", "wgpu-core", "wgpu-hal", "hyper", "async-std", "render-worker", "server",
    ];
    let found: Vec<_> = forbidden.iter().filter(|f| deps.contains(**f)).collect();
    assert!(found.is_empty(), "sim-core must not depend (even indirectly) on {found:?}");
}

/// Architecture invariant: only `server` talks to the database.
#[test]
fn only_server_depends_on_sqlx() {
    let meta = metadata();
    for pkg in meta.workspace_packages() {
        let name = pkg.name.as_str();
        let deps = runtime_closure(&meta, name);
        if name == "server" {
            assert!(deps.contains("sqlx"), "the server is the database owner");
        } else {
            assert!(!deps.contains("sqlx") && !deps.contains("sqlx-core"), "{name} must not depend on sqlx");
        }
    }
}

/// Architecture invariant: `render-worker` never depends on `server` (the server dispatches to
/// workers, not the other way round), and every crate folder is named after its crate.
#[test]
fn dependency_direction_and_folder_names() {
    let meta = metadata();
    assert!(!runtime_closure(&meta, "render-worker").contains("server"));
    for pkg in meta.workspace_packages() {
        let folder = pkg.manifest_path.parent().and_then(|p| p.file_name()).unwrap_or_default();
        assert_eq!(folder, pkg.name.as_str(), "folder name = crate name");
    }
}

/// Architecture invariant: wgpu is pinned to one exact version in the workspace manifest.
#[test]
fn wgpu_is_pinned_exactly() {
    let manifest = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../Cargo.toml")).unwrap();
    let line = manifest.lines().find(|l| l.trim_start().starts_with("wgpu ")).expect("wgpu in [workspace.dependencies]");
    assert!(line.contains("\"="), "wgpu must be pinned with `=`: {line}");
}
