//! Architecture invariants from ARCHITECTURE.md, checked against `cargo metadata` and the sources.
//!
//! Each test names the invariant it enforces. The dependency tests read the real dependency graph
//! (normal and build dependencies, transitively), so an indirect path through another crate
//! counts too. The tidy tests read the sources: import cycles inside a crate between files and
//! between folders (`module_graph`, built by the `rust_scan` scanner, cycles found by `digraph`)
//! and file length.

mod digraph;
mod ignored;
mod module_graph;
mod profiles;
mod rust_scan;
mod scanner_tests;
mod signatures;
mod sources;

use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

use cargo_metadata::{DependencyKind, Metadata, MetadataCommand, PackageId};
use digraph::Cycle;
use module_graph::ModuleGraph;

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
    let names: HashMap<&PackageId, &str> = meta
        .packages
        .iter()
        .map(|p| (&p.id, p.name.as_str()))
        .collect();
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
            let shipped = dep
                .dep_kinds
                .iter()
                .any(|k| matches!(k.kind, DependencyKind::Normal | DependencyKind::Build));
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
        "tokio",
        "axum",
        "sqlx",
        "sqlx-core",
        "wgpu",
        "wgpu-core",
        "wgpu-hal",
        "hyper",
        "async-std",
        "render-worker",
        "server",
    ];
    let found: Vec<_> = forbidden.iter().filter(|f| deps.contains(**f)).collect();
    assert!(
        found.is_empty(),
        "sim-core must not depend (even indirectly) on {found:?}"
    );
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
            assert!(
                !deps.contains("sqlx") && !deps.contains("sqlx-core"),
                "{name} must not depend on sqlx"
            );
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
        let folder = pkg
            .manifest_path
            .parent()
            .and_then(|p| p.file_name())
            .unwrap_or_default();
        assert_eq!(folder, pkg.name.as_str(), "folder name = crate name");
    }
}

/// Architecture invariant: a binary that hosts sessions leaves through
/// `render_worker::exit::after_shutdown` once it has stopped, never by returning from `main`
/// after its runtime ran: the C library's exit handlers tear down the graphics driver while
/// threads that `main` does not join (the start-up calibration) may still be inside it.
#[test]
fn session_hosting_binaries_leave_without_exit_handlers() {
    let root = metadata().workspace_root.into_std_path_buf();
    for main in [
        "server/src/main.rs",
        "render-worker/src/bin/render-worker.rs",
    ] {
        let src = std::fs::read_to_string(root.join(main)).expect(main);
        let (_, serving) = src
            .split_once("block_on(")
            .unwrap_or_else(|| panic!("{main} runs its server on a runtime"));
        assert!(
            serving.contains("render_worker::exit::after_shutdown("),
            "{main} leaves through render_worker::exit::after_shutdown once served"
        );
        assert!(
            !serving.contains("ExitCode") && !src.contains("process::exit("),
            "{main} returns no ExitCode once served, and never calls std::process::exit"
        );
    }
}

/// Architecture invariant: wgpu is pinned to one exact version in the workspace manifest.
#[test]
fn wgpu_is_pinned_exactly() {
    let manifest =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../Cargo.toml")).unwrap();
    let line = manifest
        .lines()
        .find(|l| l.trim_start().starts_with("wgpu "))
        .expect("wgpu in [workspace.dependencies]");
    assert!(line.contains("\"="), "wgpu must be pinned with `=`: {line}");
}

/// The module graph of every lib and bin target of every workspace crate.
fn workspace_module_graphs() -> Vec<ModuleGraph> {
    let meta = metadata();
    let root = meta.workspace_root.as_std_path();
    let mut graphs = Vec::new();
    for pkg in meta.workspace_packages() {
        for target in pkg.targets.iter().filter(|t| t.is_lib() || t.is_bin()) {
            let name = if target.is_lib() {
                pkg.name.to_string()
            } else {
                format!("{} (bin {})", pkg.name, target.name)
            };
            let src = target
                .src_path
                .as_std_path()
                .strip_prefix(root)
                .expect("target inside the workspace");
            graphs.push(ModuleGraph::build(&name, src, |p| {
                std::fs::read_to_string(root.join(p)).ok()
            }));
        }
    }
    graphs
}

/// Prints each cycle and fails if there is one.
fn assert_no_cycles(what: &str, cycles: &[Cycle]) {
    for cycle in cycles {
        println!("{}", cycle.report);
    }
    let reports: Vec<&str> = cycles.iter().map(|c| c.report.as_str()).collect();
    assert!(
        reports.is_empty(),
        "{} {what} (break each by moving what both sides need into a module of its own, or \
         by passing it in):\n{}",
        reports.len(),
        reports.join("\n"),
    );
}

/// Architecture invariant: no import cycles between the files of a crate. Every lib and bin
/// target of every workspace crate is scanned (`src/**/*.rs` reached through `mod`
/// declarations, test modules excluded); a failure prints each cycle with the file and line of
/// every edge in it (see `module_graph` for what counts as an edge: a path that reaches its item
/// through a re-export depends on the re-exporting file too).
#[test]
fn no_import_cycles_between_modules() {
    let cycles: Vec<Cycle> = workspace_module_graphs()
        .iter()
        .flat_map(ModuleGraph::cycles)
        .collect();
    assert_no_cycles("file cycles", &cycles);
}

/// Architecture invariant: no import cycles between the folders of a crate. In each folder
/// below a target's root folder, the files and subfolders (each with everything under it) are
/// units, and no two of them import each other, directly or around a ring, through a
/// subfolder (a folder that imports a sibling file that imports back into the folder is a
/// cycle even when no file cycle exists). A failure prints each cycle with the file and line of
/// the file edges that make each folder edge.
#[test]
fn no_import_cycles_between_folders() {
    let cycles: Vec<Cycle> = workspace_module_graphs()
        .iter()
        .flat_map(ModuleGraph::folder_cycles)
        .collect();
    assert_no_cycles("folder cycles", &cycles);
}

/// The learning records know nothing of the integrations built on them: no module of
/// `server::records` names `xapi`, `lti`, `outbox` or `dispatch` (integrations learn of new
/// records through database triggers and queues, in the records' own transactions).
#[test]
fn learning_records_never_import_the_integrations() {
    let meta = metadata();
    let root = meta.workspace_root.as_std_path();
    let server = meta
        .workspace_packages()
        .into_iter()
        .find(|p| p.name.as_str() == "server")
        .expect("the server package");
    let lib = server
        .targets
        .iter()
        .find(|t| t.is_lib())
        .expect("server lib");
    let src = lib
        .src_path
        .as_std_path()
        .strip_prefix(root)
        .expect("target inside the workspace");
    let graph = ModuleGraph::build("server", src, |p| {
        std::fs::read_to_string(root.join(p)).ok()
    });
    let edges = graph.edge_names();
    assert!(
        edges.iter().any(|e| e.starts_with("records")),
        "the graph sees the records' imports: {edges:?}"
    );
    let bad: Vec<&String> = edges
        .iter()
        .filter(|e| {
            let (from, to) = e.split_once(" -> ").expect("edge");
            from.starts_with("records")
                && ["xapi", "lti", "outbox", "dispatch"]
                    .iter()
                    .any(|m| to == *m || to.starts_with(&format!("{m}::")))
        })
        .collect();
    assert!(bad.is_empty(), "records import integrations: {bad:?}");
}

/// Longest a source file may be, in lines, unless listed in [`OVERSIZED_FILES`]. Project rule
/// (ARCHITECTURE.md): a file over 1,000 lines is split along a seam of its design.
const LINE_LIMIT: usize = 1_000;

/// Length, in lines, from which a file is reported (printed, not failed). Project rule (the
/// developers' guide): new files stay under 800 lines, so a file past it is due for a split
/// before it reaches [`LINE_LIMIT`].
const LINE_WARNING: usize = 800;

/// The source files the length rule covers, by extension: Rust, the web client's JavaScript
/// (scripts and `.mjs` test modules), style sheets and pages.
const SOURCE_EXTENSIONS: [&str; 5] = ["rs", "js", "mjs", "css", "html"];

/// Files allowed over [`LINE_LIMIT`], relative to the workspace root, each with its reason. A
/// listed file that is back under the limit (or gone) fails the test, so the list stays honest.
/// Empty since the last long files were split; an entry needs a reason a reviewer accepts.
const OVERSIZED_FILES: &[(&str, &str)] = &[];

/// Every file under `dir` whose extension is one of `extensions`, skipping build outputs
/// (`target/`), installed packages (`node_modules/`) and hidden folders.
fn files_with_extensions(dir: &Path, extensions: &[&str], out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.expect("directory entry").path();
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default();
        if path.is_dir() {
            if !name.starts_with('.') && name != "target" && name != "node_modules" {
                files_with_extensions(&path, extensions, out);
            }
        } else if path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| extensions.contains(&e))
        {
            out.push(path);
        }
    }
}

/// Every `*.rs` file under `dir` (see [`files_with_extensions`] for what is skipped).
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    files_with_extensions(dir, &["rs"], out);
}

/// Architecture invariant: no source file is longer than 1,000 lines, except the justified
/// exceptions listed in `OVERSIZED_FILES`; files from 800 lines on are printed as due for a
/// split. Every `*.rs`, `*.js`, `*.mjs`, `*.css` and `*.html` file of the workspace counts
/// (crate sources, tests, benches, build scripts, the web client and its tests).
#[test]
fn no_source_file_over_1000_lines() {
    let meta = metadata();
    let root = meta.workspace_root.as_std_path();
    let mut files = Vec::new();
    files_with_extensions(root, &SOURCE_EXTENSIONS, &mut files);
    assert!(
        files.iter().any(|f| f.ends_with("web-client/app.js")),
        "the walk reaches the web client"
    );
    files.sort();
    let mut over = Vec::new();
    for file in files {
        let lines = std::fs::read_to_string(&file)
            .expect("source file")
            .lines()
            .count();
        let relative = file
            .strip_prefix(root)
            .expect("inside the workspace")
            .to_string_lossy()
            .into_owned();
        if lines > LINE_LIMIT {
            println!("over {LINE_LIMIT} lines: {relative}: {lines} lines");
            over.push(relative);
        } else if lines >= LINE_WARNING {
            println!(
                "warning: {relative}: {lines} lines (split it before it reaches {LINE_LIMIT})"
            );
        }
    }
    let unlisted: Vec<&String> = over
        .iter()
        .filter(|f| !OVERSIZED_FILES.iter().any(|(o, _)| o == f))
        .collect();
    let stale: Vec<&str> = OVERSIZED_FILES
        .iter()
        .map(|(f, _)| *f)
        .filter(|f| !over.iter().any(|o| o == f))
        .collect();
    assert!(
        unlisted.is_empty() && stale.is_empty(),
        "files over {LINE_LIMIT} lines (split them, or list them in OVERSIZED_FILES with a \
         reason): {unlisted:?}\nOVERSIZED_FILES entries now under the limit or gone (remove \
         them): {stale:?}"
    );
}

/// Architecture invariant: no test of what ships is ignored in CI. An `#[ignore]`d test that holds
/// an assertion (see `ignored` for what counts) must be run by `.ci/test` with `--ignored`, by
/// name; ignored tests without assertions (reports, pictures for a person) may stay ignored.
#[test]
fn no_asserting_test_is_ignored_unless_ci_runs_it() {
    let meta = metadata();
    let root = meta.workspace_root.as_std_path();
    let ci = std::fs::read_to_string(root.join(".ci/test")).expect(".ci/test");
    let mut files = Vec::new();
    for krate in ["sim-core", "render-worker", "server", "tests"] {
        rust_files(&root.join(krate), &mut files);
    }
    files.sort();
    let (mut seen, mut hidden) = (0, Vec::new());
    for file in &files {
        let src = std::fs::read_to_string(file).expect("source file");
        for t in ignored::ignored_tests(&src) {
            seen += 1;
            if t.asserts && !ignored::ci_runs_ignored(&ci, &t.name) {
                hidden.push(format!(
                    "{}:{} {}",
                    file.strip_prefix(root).unwrap_or(file).display(),
                    t.line,
                    t.name
                ));
            }
        }
    }
    assert!(seen > 0, "the scan finds the workspace's ignored tests");
    assert!(
        hidden.is_empty(),
        "ignored tests that assert something, which CI never runs: {hidden:?} (un-ignore them, \
         or run them from .ci/test with `--ignored` and their name)"
    );
}
