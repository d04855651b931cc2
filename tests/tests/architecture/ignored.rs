//! No check of what ships hides behind `#[ignore]`: an ignored test never runs in `cargo test`,
//! so one that asserts something (about the default phantoms, a shipped asset, anything a user
//! gets) must be run by CI with `--ignored`, by name, in `.ci/test`. An ignored test that only
//! prints figures or writes pictures for a person to look at holds no assertion and may stay
//! ignored.
//!
//! What counts as an assertion: the `assert!` family (`assert_eq!`, `assert_ne!`, `debug_assert*`
//! included) and calls of helpers named `check_*` (the project's name for asserting helpers, such
//! as `check_region` and `check_solid`). `unwrap` and `expect` do not count: in a report-only test
//! they only say the report could be made.

use super::rust_scan::{skip_block_comment, skip_raw_string, skip_string};

/// An `#[ignore]`d test: its function name, the 1-based line of its attribute, and whether its
/// body holds an assertion.
#[derive(Debug, Clone, PartialEq)]
pub struct IgnoredTest {
    pub name: String,
    pub line: u32,
    pub asserts: bool,
}

/// `src` with every comment and every string and char literal blanked to spaces (newlines kept),
/// so braces, names and macros inside them are never read as code.
pub fn code_only(src: &str) -> String {
    let s: Vec<char> = src.chars().collect();
    let at = |i: usize| s.get(i).copied().unwrap_or('\0');
    let mut out: Vec<char> = s.clone();
    let blank = |out: &mut Vec<char>, from: usize, to: usize| {
        for c in out.iter_mut().take(to.min(s.len())).skip(from) {
            if *c != '\n' {
                *c = ' ';
            }
        }
    };
    let mut line = 1u32;
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        let prev_ident = i > 0 && (s[i - 1].is_alphanumeric() || s[i - 1] == '_');
        if c == '/' && at(i + 1) == '/' {
            let begin = i;
            while i < s.len() && s[i] != '\n' {
                i += 1;
            }
            blank(&mut out, begin, i);
        } else if c == '/' && at(i + 1) == '*' {
            let begin = i;
            i = skip_block_comment(&s, i, &mut line);
            blank(&mut out, begin, i);
        } else if c == '"' {
            let begin = i;
            i = skip_string(&s, i + 1, &mut line);
            blank(&mut out, begin, i);
        } else if let Some(end) = (!prev_ident).then(|| literal_prefix(&s, i)).flatten() {
            // A byte string `b"..."`, a raw string `r#"..."#` or a raw byte string.
            let begin = i;
            i = if s[end] == '"' && (c == 'b' && at(i + 1) == '"') {
                skip_string(&s, end + 1, &mut line)
            } else {
                skip_raw_string(&s, end, &mut line)
            };
            blank(&mut out, begin, i);
        } else if c == '\'' && at(i + 1) == '\\' {
            // An escaped char literal: '\n', '\'', '\u{7f}'.
            let begin = i;
            i += 2;
            while i < s.len() && s[i] != '\'' {
                i += 1;
            }
            i += 1;
            blank(&mut out, begin, i);
        } else if c == '\'' && at(i + 2) == '\'' {
            blank(&mut out, i, i + 3);
            i += 3;
        } else {
            i += 1;
        }
    }
    out.into_iter().collect()
}

/// Where a byte, raw or raw byte string literal starting at `i` has its hashes or quote: `b"`
/// gives the quote, `r#"`, `r"`, `br#"` and `br"` the first hash or the quote. `None` for
/// anything else (a raw identifier `r#type` included).
fn literal_prefix(s: &[char], i: usize) -> Option<usize> {
    let at = |k: usize| s.get(k).copied().unwrap_or('\0');
    let start = match (at(i), at(i + 1)) {
        ('b', '"') => return Some(i + 1),
        ('b', 'r') => i + 2,
        ('r', _) => i + 1,
        _ => return None,
    };
    let hashes = (start..).take_while(|&k| at(k) == '#').count();
    (at(start + hashes) == '"').then_some(start)
}

/// The `#[ignore]`d functions of a Rust source.
pub fn ignored_tests(src: &str) -> Vec<IgnoredTest> {
    let code = code_only(src);
    let mut found = Vec::new();
    let mut from = 0;
    while let Some(k) = code[from..].find("#[ignore") {
        let at = from + k;
        from = at + 1;
        let line = 1 + code[..at].matches('\n').count() as u32;
        let Some(f) = code[at..].find("fn ") else {
            break;
        };
        let name_start = at + f + 3;
        let name: String = code[name_start..]
            .chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect();
        let Some(open) = code[name_start..].find('{').map(|o| name_start + o) else {
            break;
        };
        let mut depth = 0usize;
        let mut end = code.len();
        for (j, ch) in code[open..].char_indices() {
            match ch {
                '{' => depth += 1,
                '}' => {
                    depth -= 1;
                    if depth == 0 {
                        end = open + j + 1;
                        break;
                    }
                }
                _ => {}
            }
        }
        found.push(IgnoredTest {
            name,
            line,
            asserts: holds_assertion(&code[open..end]),
        });
    }
    found
}

/// Whether code (comments and literals blanked) holds an assertion macro or a `check_*` call.
pub fn holds_assertion(code: &str) -> bool {
    let words: Vec<(usize, &str)> = code
        .match_indices(|c: char| !(c.is_alphanumeric() || c == '_'))
        .scan(0usize, |start, (i, sep)| {
            let word = (*start, &code[*start..i]);
            *start = i + sep.len();
            Some(word)
        })
        .collect();
    words.iter().any(|&(i, w)| {
        let next = code[i + w.len()..].trim_start().chars().next();
        let macro_call = w.starts_with("assert") || w.starts_with("debug_assert");
        (macro_call && next == Some('!')) || (w.starts_with("check_") && next == Some('('))
    })
}

/// Whether `.ci/test` runs the ignored test `name`: a line of it holds `--ignored` and the name as
/// a whole word.
pub fn ci_runs_ignored(ci_script: &str, name: &str) -> bool {
    ci_script.lines().any(|l| {
        l.contains("--ignored")
            && l.split(|c: char| !(c.is_alphanumeric() || c == '_'))
                .any(|w| w == name)
    })
}

/// The scan on planted sources: what it must flag, and what it must let through.
#[test]
fn the_ignored_test_scan_flags_assertions_only() {
    let src = r####"
/// A doc comment with #[ignore] and assert!(x) in it is not code.
#[test]
#[ignore = "slow: builds the default phantom"]
fn default_build() {
    let r = build();
    check_region(&r, &params);
}

#[test]
#[ignore]
fn prints_a_table() {
    let s = "assert!(false) { in a string";
    let raw = r#"check_x( } "#;
    let c = '{';
    eprintln!("{s} {raw} {c}");
    let t = build().unwrap();
}

#[test]
#[ignore = "slow"]
fn compares() {
    let v = b"}";
    assert_eq!(v.len(), 1);
}

#[test]
fn runs() { assert!(true); }
"####;
    let found = ignored_tests(src);
    let summary: Vec<(&str, bool)> = found.iter().map(|t| (t.name.as_str(), t.asserts)).collect();
    assert_eq!(
        summary,
        [
            ("default_build", true),
            ("prints_a_table", false),
            ("compares", true)
        ]
    );
    assert_eq!(found[0].line, 4);
    let ci = "cargo test -p sim-core --test tests -- --ignored --exact phantom::default_build\n";
    assert!(ci_runs_ignored(ci, "default_build"));
    assert!(!ci_runs_ignored(ci, "compares"));
    assert!(!ci_runs_ignored(
        "cargo test -- default_build",
        "default_build"
    ));
    assert!(!holds_assertion("let checked = x; my_assert_like(y);"));
    assert!(holds_assertion("debug_assert! (x)"));
}
