//! Typed errors at every crate boundary: no public function of a workspace crate returns
//! `Result<_, String>` (ARCHITECTURE.md, the server's error strategy). A `String` error carries no
//! kind a caller can match on and invites stringly error handling across the seams.

use std::path::{Path, PathBuf};

/// Public (not `pub(crate)`/`pub(super)`) functions in `src` whose return type is a `Result`
/// with a `String` error, as `path:line: signature`. Signatures are read from `pub fn` to the
/// body's brace, comments removed, so multi-line signatures count too.
pub fn string_errors(file: &Path, src: &str) -> Vec<String> {
    let code: String = src
        .lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n");
    let mut found = Vec::new();
    let mut rest = code.as_str();
    let mut offset = 0;
    while let Some(i) = rest.find("pub ") {
        let at = offset + i;
        let after = &code[at + 4..];
        let after = after.trim_start();
        let after = after.strip_prefix("async ").unwrap_or(after).trim_start();
        let after = after.strip_prefix("const ").unwrap_or(after).trim_start();
        if after.starts_with("fn ") {
            let end = after.find(['{', ';']).unwrap_or(after.len());
            let sig: String = after[..end]
                .split_whitespace()
                .collect::<Vec<_>>()
                .join(" ");
            if let Some(ret) = sig.split("->").nth(1) {
                let compact: String = ret
                    .chars()
                    .filter(|c| !c.is_whitespace())
                    .collect::<String>()
                    .replace(",>", ">");
                if compact.starts_with("Result<")
                    && (compact.ends_with(",String>") || compact.contains(",String>where"))
                {
                    let line = code[..at].matches('\n').count() + 1;
                    found.push(format!("{}:{line}: {sig}", file.display()));
                }
            }
        }
        offset = at + 4;
        rest = &code[offset..];
    }
    found
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn no_public_function_returns_a_string_error() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut found = Vec::new();
    for krate in ["sim-core", "render-worker", "server", "tests"] {
        let mut files = Vec::new();
        rust_files(&root.join(krate).join("src"), &mut files);
        files.sort();
        for f in files {
            let src = std::fs::read_to_string(&f).expect("readable source");
            found.extend(string_errors(f.strip_prefix(&root).unwrap_or(&f), &src));
        }
    }
    assert!(
        found.is_empty(),
        "public functions returning Result<_, String> (give them a typed error):\n{}",
        found.join("\n")
    );
}

#[test]
fn string_errors_are_found_in_multi_line_signatures_and_not_in_typed_ones() {
    let src = "pub fn a() -> Result<u8, String> {}\n\
               pub(crate) fn hidden() -> Result<u8, String> {}\n\
               pub async fn b(\n    x: u8,\n) -> Result<\n    Vec<u8>,\n    String,\n> {\n}\n\
               pub fn c() -> Result<u8, MyError> {}\n\
               // pub fn d() -> Result<u8, String> {}\n\
               pub fn e() -> Result<String, MyError> {}\n";
    let found = string_errors(Path::new("x.rs"), src);
    assert_eq!(found.len(), 2, "{found:?}");
    assert!(found[0].starts_with("x.rs:1: fn a()"), "{found:?}");
    assert!(found[1].starts_with("x.rs:3: fn b("), "{found:?}");
}
