//! The module graph of one crate target, built from [`rust_scan`](super::rust_scan) results, and
//! its cycles between files and between folders.
//!
//! A node is a module file (`mod.rs` is its directory's module; inline `mod x { ... }` blocks
//! belong to their file's node). There is an edge A -> B when A names a path into B: an item
//! defined in B, or B itself. Paths are resolved the way rustc resolves them, as far as a scanner
//! can: `crate::`, `super::`, `self::`, child modules, names brought in by `use` (private or
//! public, followed through re-exports and globs to the module that defines the item). A path
//! that reaches its item through another module's `use` (a re-export, a glob) depends on that
//! module too: `use crate::x::Y`, where `x/mod.rs` re-exports `Y` from `x/z.rs`, is an edge to
//! `x/mod.rs` and one to `x/z.rs`. The re-export itself (`pub use z::Y;` in `x/mod.rs`) and a
//! `mod z;` declaration are not edges: a facade module does not depend on what it re-exports.
//! Any other `use`, and every path in code, is an edge, including one to the module's own
//! ancestors (a child importing its parent's state while the parent builds a router from the
//! child's handlers is a cycle).
//!
//! Folders: every folder below the target's root folder (`src/` for a library) is also looked at
//! as a unit. Inside a folder F, each entry (a file of F, or a subfolder of F with everything
//! under it) is a node, and a file edge a -> b is an edge between the entries of F that hold a
//! and b, where F is the deepest folder holding both. A cycle between entries of a folder that
//! passes through a subfolder is a folder cycle even when no single file cycle exists: a
//! subfolder imports a sibling file that imports back into the subfolder. (A cycle of files only
//! is already a file cycle and is not reported twice.) `x.rs` next to its folder `x/` is the
//! folder's module file, as `x/mod.rs` would be.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Component, Path, PathBuf};

use super::digraph::{Cycle, Digraph};
use super::rust_scan::{self, Binding, FileScan};

type ModPath = Vec<String>;

/// Where a path leads.
#[derive(Clone, Debug, PartialEq)]
enum Target {
    /// A module itself (`use crate::a;` binds it, `a::f` then goes on from it).
    Module(ModPath),
    /// An item defined in this module (or, if the scanner cannot find the name, named there).
    Item(ModPath),
    /// Outside the crate (`std::`, another crate, `::x`), or nothing the scanner can resolve.
    External,
}

/// What one module (file or inline) declares.
#[derive(Default)]
struct Module {
    node: usize,
    children: BTreeSet<String>,
    items: BTreeSet<String>,
    /// Names bound by `use` (public or not), with the path as written.
    bindings: BTreeMap<String, Vec<String>>,
    globs: Vec<Vec<String>>,
}

/// The first place an edge occurs in its source file.
#[derive(Clone, Debug)]
pub struct Evidence {
    pub line: u32,
    pub text: String,
}

/// One module file.
struct Node {
    path: ModPath,
    file: PathBuf,
    /// The folders holding the file, below the target's root folder, then the file's name. A
    /// file with child modules in a folder of its own (`x.rs` beside `x/`) is placed inside it.
    place: Vec<String>,
}

/// Recursion limit for following `use` chains (re-exports of re-exports). Simulator choice: real
/// chains are two or three deep, and the limit only stops a pathological loop of re-exports.
const FUEL: u32 = 16;

pub struct ModuleGraph {
    name: String,
    /// The target's root folder (`src/` for a library), as given.
    root_dir: PathBuf,
    nodes: Vec<Node>,
    edges: BTreeMap<(usize, usize), Evidence>,
}

impl ModuleGraph {
    /// Builds the graph of the crate target named `name` whose root file is `root`, reading
    /// files with `read` (paths are joined from `root`'s directory, as given).
    pub fn build(name: &str, root: &Path, read: impl Fn(&Path) -> Option<String>) -> Self {
        let mut nodes = Vec::new();
        let mut modules: BTreeMap<ModPath, Module> = BTreeMap::new();
        let mut scans: Vec<(ModPath, FileScan)> = Vec::new();
        let root_dir = root.parent().unwrap_or(Path::new("")).to_path_buf();
        // (candidate files, module path, directory of its child modules' files)
        let mut queue = vec![(vec![root.to_path_buf()], Vec::new(), root_dir.clone())];
        while let Some((candidates, path, child_dir)) = queue.pop() {
            let (file, src) = candidates
                .iter()
                .find_map(|f| read(f).map(|src| (f.clone(), src)))
                .unwrap_or_else(|| {
                    panic!(
                        "{name}: module {} has no file among {candidates:?}",
                        path.join("::")
                    )
                });
            let scan = rust_scan::scan(&src);
            if scan.test_only {
                continue;
            }
            let node = nodes.len();
            let folder = if scan.mods.is_empty() {
                file.parent().unwrap_or(Path::new("")).to_path_buf()
            } else {
                child_dir.clone()
            };
            let file_name = file
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let place = folder
                .strip_prefix(&root_dir)
                .unwrap_or(&folder)
                .components()
                .filter_map(|c| match c {
                    Component::Normal(c) => Some(c.to_string_lossy().into_owned()),
                    _ => None,
                })
                .chain([file_name])
                .collect();
            nodes.push(Node {
                path: path.clone(),
                file,
                place,
            });
            modules.insert(
                path.clone(),
                Module {
                    node,
                    ..Module::default()
                },
            );
            for inline in &scan.inline_mods {
                modules.insert(
                    [path.as_slice(), inline].concat(),
                    Module {
                        node,
                        ..Module::default()
                    },
                );
            }
            for decl in &scan.mods {
                let dir: PathBuf = decl.scope.iter().fold(child_dir.clone(), |d, s| d.join(s));
                let flat = dir.join(format!("{}.rs", decl.name));
                let nested = dir.join(&decl.name).join("mod.rs");
                let child = [
                    path.as_slice(),
                    &decl.scope,
                    std::slice::from_ref(&decl.name),
                ]
                .concat();
                queue.push((vec![flat, nested], child, dir.join(&decl.name)));
            }
            scans.push((path, scan));
        }
        let paths: Vec<ModPath> = modules.keys().cloned().collect();
        for path in paths {
            if let Some((name, parent)) = path.split_last() {
                modules
                    .get_mut(parent)
                    .expect("parent module")
                    .children
                    .insert(name.clone());
            }
        }
        for (path, scan) in &scans {
            for (scope, item) in &scan.items {
                modules
                    .get_mut(&[path.as_slice(), scope].concat())
                    .expect("scope")
                    .items
                    .insert(item.clone());
            }
            for leaf in &scan.uses {
                let module = modules
                    .get_mut(&[path.as_slice(), &leaf.scope].concat())
                    .expect("scope");
                match &leaf.binding {
                    Binding::Name(bound) => {
                        module.bindings.insert(bound.clone(), leaf.path.clone());
                    }
                    Binding::Glob => module.globs.push(leaf.path.clone()),
                    Binding::Hidden => {}
                }
            }
        }
        let edges = Resolver { modules: &modules }.edges(&scans);
        Self {
            name: name.to_owned(),
            root_dir,
            nodes,
            edges,
        }
    }

    fn node_name(&self, node: usize) -> String {
        let path = &self.nodes[node].path;
        if path.is_empty() {
            "crate".to_owned()
        } else {
            path.join("::")
        }
    }

    /// The file graph: one node per module file, named by its module path.
    fn file_graph(&self) -> Digraph {
        let mut g = Digraph::new((0..self.nodes.len()).map(|n| self.node_name(n)).collect());
        for (&(from, to), e) in &self.edges {
            let file = self.nodes[from].file.display();
            g.add(from, to, format!("{file}:{}: {}", e.line, e.text));
        }
        g
    }

    /// Every edge between files as `"from -> to"`, by module path (for tests).
    pub fn edge_names(&self) -> BTreeSet<String> {
        self.file_graph().edge_names()
    }

    /// Cycles between module files (strongly connected components of more than one file),
    /// sorted by key.
    pub fn cycles(&self) -> Vec<Cycle> {
        self.file_graph().cycles(&self.name, |_| true)
    }

    /// The graph of each folder's entries, by folder (components below the root folder). An
    /// entry is named `name/` for a subfolder and by its file name for a file.
    fn folder_graphs(&self) -> BTreeMap<Vec<String>, Digraph> {
        // (folder, from entry, to entry) -> (from file, line, text) of each file edge, with the
        // files it reaches (one line can reach a facade and the file behind it).
        type Key<'a> = (&'a [String], String, String);
        type Occurrences<'a> = BTreeMap<(&'a Path, u32, &'a str), Vec<&'a Path>>;
        let mut found: BTreeMap<Key<'_>, Occurrences<'_>> = BTreeMap::new();
        for (&(a, b), e) in &self.edges {
            let (pa, pb) = (&self.nodes[a].place, &self.nodes[b].place);
            let (fa, fb) = (&pa[..pa.len() - 1], &pb[..pb.len() - 1]);
            let k = fa.iter().zip(fb).take_while(|(x, y)| x == y).count();
            let entry = |place: &[String], folders: &[String]| match folders.get(k) {
                Some(sub) => format!("{sub}/"),
                None => place[place.len() - 1].clone(),
            };
            found
                .entry((&fa[..k], entry(pa, fa), entry(pb, fb)))
                .or_default()
                .entry((&self.nodes[a].file, e.line, &e.text))
                .or_default()
                .push(&self.nodes[b].file);
        }
        let mut by_folder: BTreeMap<&[String], Vec<(String, String, Occurrences<'_>)>> =
            BTreeMap::new();
        for ((folder, from, to), occurrences) in found {
            by_folder
                .entry(folder)
                .or_default()
                .push((from, to, occurrences));
        }
        let mut graphs = BTreeMap::new();
        for (folder, edges) in by_folder {
            let names: Vec<String> = edges
                .iter()
                .flat_map(|(from, to, _)| [from.clone(), to.clone()])
                .collect::<BTreeSet<String>>()
                .into_iter()
                .collect();
            let id = |name: &String| names.binary_search(name).expect("an entry of the folder");
            let mut g = Digraph::new(names.clone());
            for (from, to, occurrences) in &edges {
                for ((file, line, text), targets) in occurrences {
                    let mut targets: Vec<String> =
                        targets.iter().map(|t| t.display().to_string()).collect();
                    targets.sort();
                    let file = file.display();
                    let targets = targets.join(", ");
                    g.add(
                        id(from),
                        id(to),
                        format!("{file}:{line}: {text} (to {targets})"),
                    );
                }
            }
            graphs.insert(folder.to_vec(), g);
        }
        graphs
    }

    /// Cycles between the entries of a folder that pass through at least one subfolder, every
    /// folder of the target, sorted by key. The key names the target and the folder.
    pub fn folder_cycles(&self) -> Vec<Cycle> {
        let mut out = Vec::new();
        for (folder, g) in self.folder_graphs() {
            let dir = folder.iter().fold(self.root_dir.clone(), |d, s| d.join(s));
            let prefix = format!("{}, folder {}/", self.name, dir.display());
            out.extend(g.cycles(&prefix, |members| {
                members.iter().any(|&m| g.name(m).ends_with('/'))
            }));
        }
        out.sort_by(|a, b| a.key.cmp(&b.key));
        out
    }

    /// Every edge between entries of a folder as `"folder: from -> to"` (for tests; the root
    /// folder is `.`).
    pub fn folder_edge_names(&self) -> BTreeSet<String> {
        let mut out = BTreeSet::new();
        for (folder, g) in self.folder_graphs() {
            let folder = if folder.is_empty() {
                ".".to_owned()
            } else {
                folder.join("/")
            };
            out.extend(g.edge_names().into_iter().map(|e| format!("{folder}: {e}")));
        }
        out
    }
}

struct Resolver<'a> {
    modules: &'a BTreeMap<ModPath, Module>,
}

impl Resolver<'_> {
    /// Edges of every file, each with its first occurrence.
    fn edges(&self, scans: &[(ModPath, FileScan)]) -> BTreeMap<(usize, usize), Evidence> {
        let mut edges: BTreeMap<(usize, usize), Evidence> = BTreeMap::new();
        for (path, scan) in scans {
            let from = self.modules[path].node;
            let uses = scan.uses.iter().filter(|leaf| !leaf.reexport).map(|leaf| {
                let suffix = if leaf.binding == Binding::Glob {
                    "::*"
                } else {
                    ""
                };
                (
                    &leaf.scope,
                    &leaf.path,
                    leaf.line,
                    format!("use {}{suffix}", leaf.path.join("::")),
                    leaf.binding == Binding::Glob,
                )
            });
            let paths = scan
                .paths
                .iter()
                .map(|p| (&p.scope, &p.path, p.line, p.path.join("::"), true));
            for (scope, segments, line, text, module_counts) in uses.chain(paths) {
                let ctx = [path.as_slice(), scope].concat();
                let mut via = Vec::new();
                let target = match self.resolve(&ctx, segments, FUEL, &mut via) {
                    Target::Item(m) => Some(m),
                    // `use a::b;` of a module only binds a name; a glob or a path in code that
                    // ends at a module uses it.
                    Target::Module(m) if module_counts => Some(m),
                    Target::Module(_) => continue,
                    // Something outside the crate, reached through a module's `use` (a prelude
                    // of re-exports): an edge to that module only.
                    Target::External => None,
                };
                for module in via.iter().chain(&target) {
                    let to = self.modules[module].node;
                    if to == from {
                        continue;
                    }
                    let evidence = Evidence {
                        line,
                        text: text.clone(),
                    };
                    edges
                        .entry((from, to))
                        .and_modify(|e| {
                            if line < e.line {
                                *e = evidence.clone()
                            }
                        })
                        .or_insert(evidence);
                }
            }
        }
        edges
    }

    /// Resolves `path` as written in module `ctx`. Each module whose `use` (a binding or a glob)
    /// the resolution goes through is added to `via`.
    fn resolve(
        &self,
        ctx: &[String],
        path: &[String],
        fuel: u32,
        via: &mut Vec<ModPath>,
    ) -> Target {
        let Some(first) = path.first() else {
            return Target::External;
        };
        if fuel == 0 {
            return Target::External;
        }
        let (mut module, rest): (ModPath, &[String]) = match first.as_str() {
            "::" => return Target::External,
            "crate" => (Vec::new(), &path[1..]),
            "self" => (ctx.to_vec(), &path[1..]),
            "super" => {
                let ups = path.iter().take_while(|s| *s == "super").count();
                if ups > ctx.len() {
                    return Target::External;
                }
                (ctx[..ctx.len() - ups].to_vec(), &path[ups..])
            }
            name => match self.lookup(ctx, name, fuel - 1, via) {
                Some(Target::Module(m)) => (m, &path[1..]),
                Some(other) => return other,
                // A local name, a type, an extern crate.
                None => return Target::External,
            },
        };
        for segment in rest {
            match self.lookup(&module, segment, fuel - 1, via) {
                Some(Target::Module(m)) => module = m,
                Some(other) => return other,
                // Not found by the scanner (made by a macro, say): it is named in this module.
                None => return Target::Item(module),
            }
        }
        Target::Module(module)
    }

    /// What `name` means in `module`: a child module, an item defined there, a name it imports
    /// or re-exports (followed to its definition, with `module` added to `via`), or a name from
    /// one of its glob imports (likewise).
    fn lookup(
        &self,
        module: &[String],
        name: &str,
        fuel: u32,
        via: &mut Vec<ModPath>,
    ) -> Option<Target> {
        let here = self.modules.get(module)?;
        if here.children.contains(name) {
            return Some(Target::Module([module, &[name.to_owned()]].concat()));
        }
        if here.items.contains(name) {
            return Some(Target::Item(module.to_vec()));
        }
        if fuel == 0 {
            return None;
        }
        if let Some(bound) = here.bindings.get(name) {
            via.push(module.to_vec());
            return Some(self.resolve(module, bound, fuel - 1, via));
        }
        here.globs.iter().find_map(|glob| {
            // Only the glob that provides the name counts: try each on a copy of `via`.
            let mut tried = vec![module.to_vec()];
            let found = match self.resolve(module, glob, fuel - 1, &mut tried) {
                Target::Module(m) if m != module => self.lookup(&m, name, fuel - 1, &mut tried),
                _ => None,
            }?;
            via.extend(tried);
            Some(found)
        })
    }
}
