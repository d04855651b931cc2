//! The module graph of one crate target, built from [`rust_scan`](super::rust_scan) results, and
//! its cycles.
//!
//! A node is a module file (`mod.rs` is its directory's module; inline `mod x { ... }` blocks
//! belong to their file's node). There is an edge A -> B when A names a path into B: an item
//! defined in B, or B itself. Paths are resolved the way rustc resolves them, as far as a scanner
//! can: `crate::`, `super::`, `self::`, child modules, names brought in by `use` (private or
//! public, followed through re-exports and globs to the module that defines the item). A name a
//! module only re-exports therefore leads to the module that defines it, and a re-export
//! (`pub use child::X;`) or a `mod child;` declaration is not by itself an edge: a facade module
//! does not depend on what it re-exports. Any other `use`, and every path in code, is an edge,
//! including one to the module's own ancestors (a child importing its parent's state while the
//! parent builds a router from the child's handlers is a cycle).

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::{Path, PathBuf};

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

/// One strongly connected component of more than one module.
#[derive(Debug)]
pub struct Cycle {
    /// `"<target>: <module>, <module>, ..."`, members sorted: names the component exactly.
    pub key: String,
    /// A readable account: one shortest cycle, then every edge inside the component with the
    /// file and line where it first occurs.
    pub report: String,
}

/// Recursion limit for following `use` chains (re-exports of re-exports); real chains are short.
const FUEL: u32 = 16;

pub struct ModuleGraph {
    name: String,
    /// Module path and file of each node.
    nodes: Vec<(ModPath, PathBuf)>,
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
        let mut queue = vec![(vec![root.to_path_buf()], Vec::new(), root_dir)];
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
            nodes.push((path.clone(), file));
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
            nodes,
            edges,
        }
    }

    fn node_name(&self, node: usize) -> String {
        let path = &self.nodes[node].0;
        if path.is_empty() {
            "crate".to_owned()
        } else {
            path.join("::")
        }
    }

    /// Every edge as `"from -> to"` (for tests).
    pub fn edge_names(&self) -> BTreeSet<String> {
        self.edges
            .keys()
            .map(|&(a, b)| format!("{} -> {}", self.node_name(a), self.node_name(b)))
            .collect()
    }

    /// Strongly connected components of more than one module, sorted by key.
    pub fn cycles(&self) -> Vec<Cycle> {
        let mut cycles: Vec<Cycle> = self
            .components()
            .into_iter()
            .filter(|c| c.len() > 1)
            .map(|members| self.describe(&members))
            .collect();
        cycles.sort_by(|a, b| a.key.cmp(&b.key));
        cycles
    }

    fn successors(&self, node: usize) -> impl Iterator<Item = usize> + '_ {
        self.edges
            .range((node, 0)..(node + 1, 0))
            .map(|(&(_, to), _)| to)
    }

    /// Tarjan's strongly connected components.
    fn components(&self) -> Vec<Vec<usize>> {
        struct State {
            index: Vec<Option<usize>>,
            low: Vec<usize>,
            on_stack: Vec<bool>,
            stack: Vec<usize>,
            next: usize,
            out: Vec<Vec<usize>>,
        }
        fn visit(g: &ModuleGraph, s: &mut State, v: usize) {
            s.index[v] = Some(s.next);
            s.low[v] = s.next;
            s.next += 1;
            s.stack.push(v);
            s.on_stack[v] = true;
            for w in g.successors(v) {
                match s.index[w] {
                    None => {
                        visit(g, s, w);
                        s.low[v] = s.low[v].min(s.low[w]);
                    }
                    Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                    Some(_) => {}
                }
            }
            if Some(s.low[v]) == s.index[v] {
                let mut component = Vec::new();
                while let Some(w) = s.stack.pop() {
                    s.on_stack[w] = false;
                    component.push(w);
                    if w == v {
                        break;
                    }
                }
                s.out.push(component);
            }
        }
        let n = self.nodes.len();
        let mut s = State {
            index: vec![None; n],
            low: vec![0; n],
            on_stack: vec![false; n],
            stack: Vec::new(),
            next: 0,
            out: Vec::new(),
        };
        for v in 0..n {
            if s.index[v].is_none() {
                visit(self, &mut s, v);
            }
        }
        s.out
    }

    fn describe(&self, members: &[usize]) -> Cycle {
        let inside: BTreeSet<usize> = members.iter().copied().collect();
        let mut names: Vec<(String, usize)> =
            members.iter().map(|&m| (self.node_name(m), m)).collect();
        names.sort();
        let key = format!(
            "{}: {}",
            self.name,
            names
                .iter()
                .map(|(n, _)| n.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
        // The shortest cycle through the first member, by breadth-first search inside the component.
        let start = names[0].1;
        let mut previous: BTreeMap<usize, usize> = BTreeMap::new();
        let mut queue = VecDeque::from([start]);
        'search: while let Some(v) = queue.pop_front() {
            for w in self.successors(v).filter(|w| inside.contains(w)) {
                if w == start {
                    previous.insert(start, v);
                    break 'search;
                }
                if let std::collections::btree_map::Entry::Vacant(e) = previous.entry(w) {
                    e.insert(v);
                    queue.push_back(w);
                }
            }
        }
        let mut cycle = vec![start];
        let mut at = previous[&start];
        while at != start {
            cycle.push(at);
            at = previous[&at];
        }
        cycle.push(start);
        cycle.reverse();
        let mut report = format!(
            "{key}\n    cycle: {}\n",
            cycle
                .iter()
                .map(|&m| self.node_name(m))
                .collect::<Vec<_>>()
                .join(" -> ")
        );
        let mut lines: Vec<String> = self
            .edges
            .iter()
            .filter(|((from, to), _)| inside.contains(from) && inside.contains(to))
            .map(|(&(from, to), evidence)| {
                let (file, line, text) =
                    (self.nodes[from].1.display(), evidence.line, &evidence.text);
                format!(
                    "    {} -> {}   {file}:{line}: {text}\n",
                    self.node_name(from),
                    self.node_name(to)
                )
            })
            .collect();
        lines.sort();
        report.extend(lines);
        Cycle { key, report }
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
                let target = match self.resolve(&[path.as_slice(), scope].concat(), segments, FUEL)
                {
                    Target::Item(m) => m,
                    // `use a::b;` of a module only binds a name; a glob or a path in code that
                    // ends at a module uses it.
                    Target::Module(m) if module_counts => m,
                    Target::Module(_) | Target::External => continue,
                };
                let to = self.modules[&target].node;
                if to == from {
                    continue;
                }
                let evidence = Evidence { line, text };
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
        edges
    }

    /// Resolves `path` as written in module `ctx`.
    fn resolve(&self, ctx: &[String], path: &[String], fuel: u32) -> Target {
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
            name => match self.lookup(ctx, name, fuel - 1) {
                Some(Target::Module(m)) => (m, &path[1..]),
                Some(other) => return other,
                // A local name, a type, an extern crate.
                None => return Target::External,
            },
        };
        for segment in rest {
            match self.lookup(&module, segment, fuel - 1) {
                Some(Target::Module(m)) => module = m,
                Some(other) => return other,
                // Not found by the scanner (made by a macro, say): it is named in this module.
                None => return Target::Item(module),
            }
        }
        Target::Module(module)
    }

    /// What `name` means in `module`: a child module, an item defined there, a name it imports
    /// or re-exports (followed to its definition), or a name from one of its glob imports.
    fn lookup(&self, module: &[String], name: &str, fuel: u32) -> Option<Target> {
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
            return Some(self.resolve(module, bound, fuel - 1));
        }
        here.globs
            .iter()
            .find_map(|glob| match self.resolve(module, glob, fuel - 1) {
                Target::Module(m) if m != module => self.lookup(&m, name, fuel - 1),
                _ => None,
            })
    }
}
