//! Every number's source is written next to it: a paper, a standard, a measurement (the test or
//! bench that measures it, with its figure) or "Simulator choice: <reason>". An issue of the
//! project's tracker is none of these: its text is not in the repository, it changes, and a
//! reader of the code cannot check it. So no comment in `sim-core`, `render-worker` or `server`
//! may point to one ("the issue's figure", "issue 5's bound", "(issue 20, point 3)").
//!
//! The scan reads comments only (line, block and doc comments); string and char literals are
//! skipped, so a test's input text or a message is never taken for a comment. An upstream bug
//! that a comment must name is cited by its URL: a comment line holding `://` is not checked.

use std::path::PathBuf;

use super::rust_scan::{skip_raw_string, skip_string};

/// The crates whose comments are checked.
const CHECKED_CRATES: [&str; 3] = ["sim-core", "render-worker", "server"];

/// One comment line: its 1-based line number in the file and its text (without `//`, `///`,
/// `//!` or the block delimiters).
#[derive(Debug, Clone, PartialEq)]
pub struct CommentLine {
    pub line: u32,
    pub text: String,
}

/// The comment lines of a Rust source, in order. A block comment gives one entry per line.
pub fn comment_lines(src: &str) -> Vec<CommentLine> {
    let s: Vec<char> = src.chars().collect();
    let at = |i: usize| s.get(i).copied().unwrap_or('\0');
    let ident = |c: char| c == '_' || c.is_alphanumeric();
    let mut out = Vec::new();
    let mut line = 1u32;
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        if c == '\n' {
            line += 1;
            i += 1;
        } else if c == '/' && at(i + 1) == '/' {
            let begin = i + 2;
            while i < s.len() && s[i] != '\n' {
                i += 1;
            }
            out.push(CommentLine {
                line,
                text: s[begin..i].iter().collect(),
            });
        } else if c == '/' && at(i + 1) == '*' {
            // Block comments nest in Rust; each of their lines is an entry.
            let mut nest = 0;
            let mut text = String::new();
            while i < s.len() {
                if s[i] == '/' && at(i + 1) == '*' {
                    nest += 1;
                    i += 2;
                } else if s[i] == '*' && at(i + 1) == '/' {
                    nest -= 1;
                    i += 2;
                    if nest == 0 {
                        break;
                    }
                } else if s[i] == '\n' {
                    out.push(CommentLine {
                        line,
                        text: std::mem::take(&mut text),
                    });
                    line += 1;
                    i += 1;
                } else {
                    text.push(s[i]);
                    i += 1;
                }
            }
            out.push(CommentLine { line, text });
        } else if c == '"' {
            i = skip_string(&s, i + 1, &mut line);
        } else if c == '\'' {
            if at(i + 1) == '\\' {
                // An escaped char literal: '\n', '\'', '\u{1F600}'.
                i += 3;
                while i < s.len() && s[i] != '\'' {
                    i += 1;
                }
                i += 1;
            } else if at(i + 2) == '\'' {
                i += 3;
            } else {
                // A lifetime or a loop label.
                i += 1;
            }
        } else if ident(c) {
            let begin = i;
            while i < s.len() && ident(s[i]) {
                i += 1;
            }
            let word: String = s[begin..i].iter().collect();
            let next = at(i);
            match word.as_str() {
                "r" | "br" | "cr" if next == '"' || (next == '#' && !ident(at(i + 1))) => {
                    i = skip_raw_string(&s, i, &mut line);
                }
                "b" | "c" if next == '"' => i = skip_string(&s, i + 1, &mut line),
                "b" if next == '\'' => {
                    i += if at(i + 1) == '\\' { 3 } else { 2 };
                    while i < s.len() && s[i] != '\'' {
                        i += 1;
                    }
                    i += 1;
                }
                _ => {}
            }
        } else {
            i += 1;
        }
    }
    out
}

/// Where `text` points to a tracker issue: the word "issue" (singular, so "the issue", "issue
/// 5's bound", "Issue threshold"), or "issues" followed by a number ("issues 14 and 20").
/// Words that merely contain it ("tissue", "issued", "issuer") do not count. `next` is the
/// following comment line, so that "issues" at the end of a line and its number at the start
/// of the next are seen together. Returns the phrase found.
pub fn issue_citation(text: &str, next: Option<&str>) -> Option<String> {
    if text.contains("://") {
        return None;
    }
    let joined = format!("{} {}", text, next.unwrap_or("")).to_lowercase();
    let chars: Vec<char> = joined.chars().collect();
    let own = text.chars().count();
    let word = |c: char| c == '_' || c.is_alphanumeric();
    let target: Vec<char> = "issue".chars().collect();
    for start in 0..own {
        if !chars[start..].starts_with(&target) || (start > 0 && word(chars[start - 1])) {
            continue;
        }
        let after = start + target.len();
        // The phrase as found, with a few characters of what follows it.
        let phrase = || {
            chars[start..(after + 6).min(chars.len())]
                .iter()
                .collect::<String>()
                .trim()
                .to_owned()
        };
        match chars.get(after).copied() {
            Some('s') => {
                // "issues": only with a number after it.
                let mut j = after + 1;
                if chars.get(j).is_some_and(|&c| word(c)) {
                    continue;
                }
                while chars.get(j).is_some_and(|c| c.is_whitespace()) {
                    j += 1;
                }
                if chars.get(j) == Some(&'#') {
                    j += 1;
                }
                if chars.get(j).is_some_and(char::is_ascii_digit) {
                    return Some(phrase());
                }
            }
            Some(c) if word(c) => {}
            _ => return Some(phrase()),
        }
    }
    None
}

/// Every `*.rs` file of the checked crates (sources, tests, benches, build scripts).
fn checked_files() -> Vec<PathBuf> {
    let meta = super::metadata();
    let mut files = Vec::new();
    for pkg in meta.workspace_packages() {
        if CHECKED_CRATES.contains(&pkg.name.as_str()) {
            let dir = pkg.manifest_path.parent().expect("crate folder");
            super::rust_files(dir.as_std_path(), &mut files);
        }
    }
    files.sort();
    files
}

/// No comment in sim-core, render-worker or server cites a tracker issue: each number says
/// where it comes from in the comment itself (see the module docs).
#[test]
fn no_comment_cites_an_issue_as_a_source() {
    let root = super::metadata().workspace_root.into_std_path_buf();
    let files = checked_files();
    assert!(
        files.len() > 100,
        "the scan sees the crates' sources: {} files",
        files.len()
    );
    let mut found = Vec::new();
    for file in files {
        let src = std::fs::read_to_string(&file).expect("source file");
        let comments = comment_lines(&src);
        for (k, c) in comments.iter().enumerate() {
            let next = comments
                .get(k + 1)
                .filter(|n| n.line == c.line + 1)
                .map(|n| n.text.as_str());
            if let Some(phrase) = issue_citation(&c.text, next) {
                let relative = file.strip_prefix(&root).unwrap_or(&file).display();
                found.push(format!("{relative}:{}: \"{phrase}\"", c.line));
            }
        }
    }
    assert!(
        found.is_empty(),
        "comments that cite a tracker issue (write the source itself: the paper or standard, \
         the test or bench that measures the number and its figure, or \"Simulator choice: \
         <reason>\"):\n{}",
        found.join("\n")
    );
}

#[test]
fn comments_are_read_and_literals_are_not() {
    let src = r####"//! Module doc.
/// Item doc.
fn f<'a>(x: &'a str) -> char { // trailing
    let s = "// not a comment";
    let r = r#"/* nor this */"#;
    let b = b"//x";
    let c = '"';
    let q = '\'';
    /* block
       second line */
    'label: loop { break 'label; }
    c
}
"####;
    let comments = comment_lines(src);
    let got: Vec<(u32, &str)> = comments.iter().map(|c| (c.line, c.text.trim())).collect();
    let want = vec![
        (1, "! Module doc."),
        (2, "/ Item doc."),
        (3, "trailing"),
        (9, "block"),
        (10, "second line"),
    ];
    assert_eq!(got, want);
}

#[test]
fn issue_citations_are_found_and_tissue_is_not() {
    for (text, next, want) in [
        ("0.45 mm at 5 MHz (the issue's figure)", None, "issue's fig"),
        ("1e-9 mm is issue 5's bound", None, "issue 5's b"),
        ("Issue threshold: within 5 %", None, "issue thres"),
        ("(issue 20, point 3)", None, "issue 20, p"),
        ("The result path (issues 14 and 20)", None, "issues 14 a"),
        (
            "see issues",
            Some("14 and 20 for the limits"),
            "issues 14 a",
        ),
        ("see issue #27", None, "issue #27"),
    ] {
        assert_eq!(issue_citation(text, next).as_deref(), Some(want), "{text}");
    }
    for text in [
        "soft tissue 0.20 per cm",
        "Commands issued to the needle",
        "the platform's issuer",
        "No issues found in the report",
        "tissues 3 and 4",
        "upstream bug https://github.com/gfx-rs/wgpu/issues/4963 (issue 4963)",
    ] {
        assert_eq!(issue_citation(text, None), None, "{text}");
    }
}
