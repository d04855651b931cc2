//! Tests of the source scanner and the module graph on small in-memory crates.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::module_graph::ModuleGraph;
use super::rust_scan::{Binding, scan};

/// A crate `t` rooted at `src/lib.rs` from `(path, source)` pairs.
fn graph(files: &[(&str, &str)]) -> ModuleGraph {
    let files: BTreeMap<PathBuf, String> = files
        .iter()
        .map(|(p, s)| (PathBuf::from(p), (*s).to_owned()))
        .collect();
    ModuleGraph::build("t", Path::new("src/lib.rs"), |p| files.get(p).cloned())
}

fn edges(g: &ModuleGraph) -> Vec<String> {
    g.edge_names().into_iter().collect()
}

fn keys(g: &ModuleGraph) -> Vec<String> {
    g.cycles().into_iter().map(|c| c.key).collect()
}

fn folder_keys(g: &ModuleGraph) -> Vec<String> {
    g.folder_cycles().into_iter().map(|c| c.key).collect()
}

#[test]
fn a_three_module_cycle_is_found_with_its_evidence() {
    let g = graph(&[
        ("src/lib.rs", "mod a;\nmod b;\nmod c;\n"),
        ("src/a.rs", "use crate::b::B;\npub struct A;\n"),
        (
            "src/b.rs",
            "pub struct B;\nfn f() {\n    crate::c::g();\n}\n",
        ),
        ("src/c.rs", "//! Doc.\n\nuse super::a::A;\npub fn g() {}\n"),
    ]);
    assert_eq!(edges(&g), ["a -> b", "b -> c", "c -> a"]);
    let cycles = g.cycles();
    assert_eq!(cycles.len(), 1);
    assert_eq!(cycles[0].key, "t: a, b, c");
    assert_eq!(
        cycles[0].report,
        "t: a, b, c\n    cycle: a -> b -> c -> a\n    a -> b   src/a.rs:1: use crate::b::B\n    \
         b -> c   src/b.rs:3: crate::c::g\n    c -> a   src/c.rs:3: use super::a::A\n"
    );
}

#[test]
fn a_parent_that_only_declares_and_re_exports_its_children_is_no_cycle() {
    let records = "mod attempts;\npub(crate) mod users;\npub use attempts::create;\npub use users::*;\n\
                   pub struct State;\n";
    let g = graph(&[
        (
            "src/lib.rs",
            "mod records;\nfn app() {\n    records::create();\n    records::list_users();\n}\n",
        ),
        ("src/records/mod.rs", records),
        (
            "src/records/attempts.rs",
            "use super::State;\npub fn create() {}\n",
        ),
        (
            "src/records/users.rs",
            "use crate::records::State;\npub fn list_users() {}\n",
        ),
    ]);
    // The root's calls go through the facade to the modules that define the functions, and
    // depend on the facade too; the facade's re-exports are no edges of its own.
    assert_eq!(
        edges(&g),
        [
            "crate -> records",
            "crate -> records::attempts",
            "crate -> records::users",
            "records::attempts -> records",
            "records::users -> records"
        ]
    );
    assert!(keys(&g).is_empty());
    assert!(folder_keys(&g).is_empty());

    // A parent that uses a child's function (to build a router, say) depends on it.
    let builds_router = format!("{records}fn router() {{\n    attempts::create();\n}}\n");
    let g = graph(&[
        ("src/lib.rs", "mod records;\n"),
        ("src/records/mod.rs", &builds_router),
        (
            "src/records/attempts.rs",
            "use super::State;\npub fn create() {}\n",
        ),
        ("src/records/users.rs", "pub fn list_users() {}\n"),
    ]);
    assert_eq!(keys(&g), ["t: records, records::attempts"]);
}

#[test]
fn use_super_glob_depends_on_the_parent() {
    let g = graph(&[
        ("src/lib.rs", "mod parent;\n"),
        (
            "src/parent/mod.rs",
            "mod child;\npub struct Shared;\nfn f() {\n    child::g();\n}\n",
        ),
        ("src/parent/child.rs", "use super::*;\npub fn g() {}\n"),
    ]);
    assert_eq!(
        edges(&g),
        ["parent -> parent::child", "parent::child -> parent"]
    );
    assert_eq!(keys(&g), ["t: parent, parent::child"]);
}

#[test]
fn grouped_imports_are_flattened_and_module_imports_only_bind_names() {
    let uses = scan("pub(crate) use crate::{a::{b, c as d, self}, e::*};\nuse ::f::G;\n").uses;
    let leaves: Vec<(String, Binding, bool, u32)> = uses
        .into_iter()
        .map(|u| (u.path.join("::"), u.binding, u.reexport, u.line))
        .collect();
    let name = |n: &str| Binding::Name(n.to_owned());
    assert_eq!(
        leaves,
        [
            ("crate::a::b".to_owned(), name("b"), true, 1),
            ("crate::a::c".to_owned(), name("d"), true, 1),
            ("crate::a".to_owned(), name("a"), true, 1),
            ("crate::e".to_owned(), Binding::Glob, true, 1),
            ("::::f::G".to_owned(), name("G"), false, 2),
        ]
    );

    let g = graph(&[
        ("src/lib.rs", "mod a;\nmod d;\nmod user;\n"),
        ("src/a.rs", "pub mod b;\npub struct C;\n"),
        ("src/a/b.rs", "pub struct Thing;\n"),
        ("src/d.rs", "pub fn g() {}\npub struct D;\n"),
        (
            "src/user.rs",
            "use crate::{a::{b::Thing, C}, d::{self, D as Renamed}};\nfn f() {\n    d::g();\n}\n",
        ),
    ]);
    assert_eq!(edges(&g), ["user -> a", "user -> a::b", "user -> d"]);
    // `d` alone (a module) is no edge; the call `d::g()` is.
    let g = graph(&[
        ("src/lib.rs", "mod d;\nmod user;\n"),
        ("src/d.rs", "pub fn g() {}\n"),
        ("src/user.rs", "use crate::d;\n"),
    ]);
    assert!(edges(&g).is_empty());
}

#[test]
fn inline_paths_in_code_are_edges() {
    let g = graph(&[
        ("src/lib.rs", "mod x;\nmod y;\nmod z;\n"),
        ("src/x.rs", "pub fn f() {}\npub struct Y;\n"),
        (
            "src/y.rs",
            "fn g() -> u8 {\n    crate::x::f();\n    let _v: Vec<self::super::x::Y> = Vec::<u8>::new();\n    0\n}\n",
        ),
        (
            "src/z.rs",
            "use std::sync::Arc;\nfn h() {\n    let _ = Arc::new(super::x::Y);\n    ::std::mem::drop(1);\n}\n",
        ),
    ]);
    assert_eq!(edges(&g), ["y -> x", "z -> x"]);
}

#[test]
fn test_code_is_ignored() {
    let g = graph(&[
        ("src/lib.rs", "mod a;\nmod b;\n#[cfg(test)]\nmod helpers;\n"),
        ("src/a.rs", "pub fn f() {\n    crate::b::g();\n}\n"),
        (
            "src/b.rs",
            "pub fn g() {}\n#[cfg(test)]\nuse crate::a::f;\n#[cfg(all(test, unix))]\nfn t() {\n    crate::a::f();\n}\n\
             #[cfg(test)]\n#[derive(Debug)]\nstruct S {\n    x: crate::a::T,\n}\n\
             #[cfg(test)]\nmod tests {\n    use super::*;\n    #[test]\n    fn x() {\n        crate::a::f();\n    }\n}\n",
        ),
    ]);
    // `helpers.rs` does not exist and is never read; `b`'s test items make no edge back to `a`.
    assert_eq!(edges(&g), ["a -> b"]);
    // `cfg(not(test))` code is not test code.
    let g = graph(&[
        ("src/lib.rs", "mod a;\nmod b;\n"),
        ("src/a.rs", "pub fn f() {\n    crate::b::g();\n}\n"),
        (
            "src/b.rs",
            "pub fn g() {}\n#[cfg(all(not(test), unix))]\nfn t() {\n    crate::a::f();\n}\n",
        ),
    ]);
    assert_eq!(keys(&g), ["t: a, b"]);
    assert!(scan("#![cfg(test)]\nuse crate::a::f;\n").test_only);
}

#[test]
fn comments_and_literals_are_not_paths() {
    let src = r####"
//! Module doc naming crate::a::b.
/// Item doc naming crate::a::c.
// crate::a::d
/* crate::a::e /* nested crate::a::f */ crate::a::g */
fn f<'a>(x: &'a str) -> char {
    let _s = "crate::a::h \" crate::a::i";
    let _r = r#"crate::a::j " crate::a::k"#;
    let _b = b"crate::a::l";
    let _c = ['"', '\'', b'"' as char, '\u{22}'];
    let _n = 1.5e3 + 0x1F as f64;
    'outer: loop { break 'outer; }
    crate::a::real()
}
"####;
    let paths: Vec<(String, u32)> = scan(src)
        .paths
        .into_iter()
        .map(|p| (p.path.join("::"), p.line))
        .collect();
    assert_eq!(paths, [("crate::a::real".to_owned(), 13)]);
}

#[test]
fn items_and_inline_modules_are_scoped() {
    let s = scan(
        "pub(crate) const fn one() {}\nstatic mut COUNT: u8 = 0;\nimpl X {\n    fn method() {}\n}\n\
         mod inner {\n    pub struct Inner;\n    use super::one;\n}\nmacro_rules! m { () => {} }\n",
    );
    let items: Vec<String> = s
        .items
        .iter()
        .map(|(scope, name)| [scope.clone(), vec![name.clone()]].concat().join("::"))
        .collect();
    assert_eq!(items, ["one", "COUNT", "inner::Inner", "m"]);
    assert_eq!(s.inline_mods, [vec!["inner".to_owned()]]);
    assert_eq!(s.uses[0].scope, ["inner"]);

    // `super` inside an inline module is the file's module; the edge belongs to the file.
    let g = graph(&[
        ("src/lib.rs", "mod a;\nmod b;\n"),
        (
            "src/a.rs",
            "pub fn f() {}\nmod inner {\n    fn g() {\n        super::super::b::h();\n    }\n}\n",
        ),
        ("src/b.rs", "pub fn h() {}\n"),
    ]);
    assert_eq!(edges(&g), ["a -> b"]);
}

/// A session folder whose modalities subfolder reaches the session's device registry through
/// the session's facade (`crate::session::Backends`, re-exported from `devices.rs`), while the
/// facade's own code calls into the modalities.
const SESSION_FACADE: &str = "pub mod devices;\npub mod modalities;\npub use devices::Backends;\n\
                              pub fn open() {\n    modalities::fluoro::start();\n}\n";

#[test]
fn a_folder_cycle_through_a_re_export_is_found_with_its_evidence() {
    let g = graph(&[
        ("src/lib.rs", "pub mod session;\n"),
        ("src/session/mod.rs", SESSION_FACADE),
        ("src/session/devices.rs", "pub struct Backends;\n"),
        (
            "src/session/modalities/mod.rs",
            "pub mod fluoro;\nmod modality;\npub use modality::Modality;\n",
        ),
        (
            "src/session/modalities/modality.rs",
            "use crate::session::Backends;\npub trait Modality {\n    fn b(&self) -> Backends;\n}\n",
        ),
        (
            "src/session/modalities/fluoro/mod.rs",
            "mod backend;\npub use backend::start;\n",
        ),
        (
            "src/session/modalities/fluoro/backend.rs",
            "pub fn start() {}\n",
        ),
    ]);
    // `use crate::session::Backends` depends on the facade that re-exports it and on the file
    // that defines it.
    assert_eq!(
        edges(&g),
        [
            "session -> session::modalities::fluoro",
            "session -> session::modalities::fluoro::backend",
            "session::modalities::modality -> session",
            "session::modalities::modality -> session::devices",
        ]
    );
    // No file cycle: the fluoroscopy backend imports nothing back.
    assert!(keys(&g).is_empty());
    assert_eq!(
        g.folder_edge_names().into_iter().collect::<Vec<_>>(),
        [
            "session: mod.rs -> modalities/",
            "session: modalities/ -> devices.rs",
            "session: modalities/ -> mod.rs",
        ]
    );
    // The subfolder and the facade file import each other: a folder cycle, reported with the
    // file and line of each file edge that makes it.
    let cycles = g.folder_cycles();
    assert_eq!(cycles.len(), 1);
    assert_eq!(
        cycles[0].report,
        "t, folder src/session/: mod.rs, modalities/\n    cycle: mod.rs -> modalities/ -> mod.rs\n    \
         mod.rs -> modalities/   src/session/mod.rs:5: modalities::fluoro::start (to \
         src/session/modalities/fluoro/backend.rs, src/session/modalities/fluoro/mod.rs)\n    \
         modalities/ -> mod.rs   src/session/modalities/modality.rs:1: use crate::session::Backends \
         (to src/session/mod.rs)\n"
    );

    // Importing the definition directly (`crate::session::devices::Backends`) leaves the facade
    // out, and the folder cycle goes with it.
    let direct = graph(&[
        ("src/lib.rs", "pub mod session;\n"),
        ("src/session/mod.rs", SESSION_FACADE),
        ("src/session/devices.rs", "pub struct Backends;\n"),
        (
            "src/session/modalities/mod.rs",
            "pub mod fluoro;\nmod modality;\n",
        ),
        (
            "src/session/modalities/modality.rs",
            "use crate::session::devices::Backends;\n",
        ),
        (
            "src/session/modalities/fluoro/mod.rs",
            "pub fn start() {}\n",
        ),
    ]);
    assert!(keys(&direct).is_empty());
    assert!(folder_keys(&direct).is_empty());
}

#[test]
fn a_layered_tree_has_no_file_or_folder_cycle() {
    // The device registry sits above the modalities and names their backends; the modalities
    // use only a leaf of the session (its configuration) and each other's shared trait.
    let g = graph(&[
        ("src/lib.rs", "pub mod gpu;\npub mod session;\n"),
        ("src/gpu.rs", "pub struct Context;\n"),
        (
            "src/session/mod.rs",
            "pub mod config;\npub mod devices;\npub mod modalities;\npub use config::Config;\n",
        ),
        ("src/session/config.rs", "pub struct Config;\n"),
        (
            "src/session/devices.rs",
            "use crate::gpu::Context;\nuse super::modalities::fluoro::Backend;\n\
             pub fn open(_c: Context) -> Backend {\n    Backend\n}\n",
        ),
        (
            "src/session/modalities/mod.rs",
            "pub mod fluoro;\nmod modality;\npub use modality::Modality;\n",
        ),
        (
            "src/session/modalities/modality.rs",
            "use crate::session::Config;\npub trait Modality {\n    fn c(&self) -> Config;\n}\n",
        ),
        (
            "src/session/modalities/fluoro.rs",
            "mod backend;\npub use backend::Backend;\n",
        ),
        (
            "src/session/modalities/fluoro/backend.rs",
            "use super::super::Modality;\npub struct Backend;\n",
        ),
    ]);
    assert_eq!(
        edges(&g),
        [
            "session::devices -> gpu",
            "session::devices -> session::modalities::fluoro",
            "session::devices -> session::modalities::fluoro::backend",
            "session::modalities::fluoro::backend -> session::modalities",
            "session::modalities::fluoro::backend -> session::modalities::modality",
            "session::modalities::modality -> session",
            "session::modalities::modality -> session::config",
        ]
    );
    // `fluoro.rs` beside its folder `fluoro/` is that folder's module file.
    assert_eq!(
        g.folder_edge_names().into_iter().collect::<Vec<_>>(),
        [
            ".: session/ -> gpu.rs",
            "session/modalities: fluoro/ -> mod.rs",
            "session/modalities: fluoro/ -> modality.rs",
            "session: devices.rs -> modalities/",
            "session: modalities/ -> config.rs",
            "session: modalities/ -> mod.rs",
        ]
    );
    assert!(keys(&g).is_empty());
    assert!(folder_keys(&g).is_empty());
}
