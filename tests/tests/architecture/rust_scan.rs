//! A small scanner for Rust source: what one file declares and which paths it names.
//!
//! It is not a parser: it tokenizes (dropping comments, string, char and number literals, so
//! their text is never read as a path), then walks the tokens once with a brace depth, and
//! records what the module graph needs: `mod` declarations, item names defined at module level,
//! `use` declarations (flattened to one leaf per imported name, with re-exports marked), and
//! every other path of two or more segments (`crate::a::f`, `super::X`, `child::g`). Items
//! under `#[cfg(test)]` (and a file under `#![cfg(test)]`) are skipped entirely.

/// One token; only what path scanning needs is kept apart.
#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    /// `::`
    PathSep,
    /// Any literal: string, raw string, byte string, char, number.
    Literal,
    Punct(char),
}

#[derive(Clone, Debug)]
struct Token {
    tok: Tok,
    line: u32,
}

/// What a `use` leaf binds in its module.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Binding {
    /// `use a::b;` binds `b`; `use a::b as c;` binds `c`; `use a::b::{self};` binds `b`.
    Name(String),
    /// `use a::b::*;`
    Glob,
    /// `use a::Trait as _;` binds nothing.
    Hidden,
}

/// One imported name of a `use` declaration, with the grouped prefix expanded.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UseLeaf {
    /// Inline modules (`mod x { ... }`) the declaration is in, relative to the file's module.
    pub scope: Vec<String>,
    /// The path as written; a leading `::` is kept as a `"::"` segment.
    pub path: Vec<String>,
    pub binding: Binding,
    /// `pub use` / `pub(crate) use` ...: a re-export.
    pub reexport: bool,
    pub line: u32,
}

/// A path of two or more segments outside `use` declarations.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PathRef {
    pub scope: Vec<String>,
    pub path: Vec<String>,
    pub line: u32,
}

/// A `mod name;` declaration (not under `#[cfg(test)]`): its module lives in another file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModDecl {
    pub scope: Vec<String>,
    pub name: String,
    pub line: u32,
}

/// Everything the module graph needs from one file.
#[derive(Debug, Default)]
pub struct FileScan {
    /// `#![cfg(test)]` at the top: the whole file is test code.
    pub test_only: bool,
    pub mods: Vec<ModDecl>,
    /// Inline modules (`mod x { ... }`, not under `#[cfg(test)]`), as scopes.
    pub inline_mods: Vec<Vec<String>>,
    /// `(scope, name)` of items defined at module level: functions, types, traits, constants,
    /// statics, macros.
    pub items: Vec<(Vec<String>, String)>,
    pub uses: Vec<UseLeaf>,
    pub paths: Vec<PathRef>,
}

/// Scans one file.
pub fn scan(src: &str) -> FileScan {
    let mut scanner = Scanner {
        toks: tokenize(src),
        i: 0,
        depth: 0,
        scopes: Vec::new(),
        out: FileScan::default(),
    };
    scanner.run();
    scanner.out
}

fn is_ident_start(c: char) -> bool {
    c == '_' || c.is_alphabetic()
}

fn is_ident_char(c: char) -> bool {
    c == '_' || c.is_alphanumeric()
}

fn tokenize(src: &str) -> Vec<Token> {
    let s: Vec<char> = src.chars().collect();
    let at = |i: usize| s.get(i).copied().unwrap_or('\0');
    let mut toks = Vec::new();
    let mut line = 1u32;
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        let start_line = line;
        let mut push = |tok| {
            toks.push(Token {
                tok,
                line: start_line,
            })
        };
        if c == '\n' {
            line += 1;
            i += 1;
        } else if c.is_whitespace() {
            i += 1;
        } else if c == '/' && at(i + 1) == '/' {
            while i < s.len() && s[i] != '\n' {
                i += 1;
            }
        } else if c == '/' && at(i + 1) == '*' {
            i = skip_block_comment(&s, i, &mut line);
        } else if c == '"' {
            i = skip_string(&s, i + 1, &mut line);
            push(Tok::Literal);
        } else if c == '\'' {
            if at(i + 1) == '\\' {
                // An escaped char literal: '\n', '\'', '\u{1F600}'.
                i += 3;
                while i < s.len() && s[i] != '\'' {
                    i += 1;
                }
                i += 1;
                push(Tok::Literal);
            } else if at(i + 2) == '\'' {
                i += 3;
                push(Tok::Literal);
            } else {
                // A lifetime or a loop label.
                i += 1;
                while i < s.len() && is_ident_char(s[i]) {
                    i += 1;
                }
            }
        } else if c.is_ascii_digit() {
            while i < s.len()
                && (is_ident_char(s[i]) || (s[i] == '.' && at(i + 1).is_ascii_digit()))
            {
                i += 1;
            }
            push(Tok::Literal);
        } else if is_ident_start(c) {
            let begin = i;
            while i < s.len() && is_ident_char(s[i]) {
                i += 1;
            }
            let word: String = s[begin..i].iter().collect();
            let next = at(i);
            match word.as_str() {
                "r" if next == '#' && is_ident_start(at(i + 1)) => {
                    // A raw identifier, r#type.
                    let begin = i + 1;
                    i = begin;
                    while i < s.len() && is_ident_char(s[i]) {
                        i += 1;
                    }
                    push(Tok::Ident(s[begin..i].iter().collect()));
                }
                "r" | "br" | "cr" if next == '"' || next == '#' => {
                    i = skip_raw_string(&s, i, &mut line);
                    push(Tok::Literal);
                }
                "b" | "c" if next == '"' => {
                    i = skip_string(&s, i + 1, &mut line);
                    push(Tok::Literal);
                }
                "b" if next == '\'' => {
                    i += 1; // the opening quote
                    i += if at(i) == '\\' { 2 } else { 1 };
                    while i < s.len() && s[i] != '\'' {
                        i += 1;
                    }
                    i += 1;
                    push(Tok::Literal);
                }
                _ => push(Tok::Ident(word)),
            }
        } else if c == ':' && at(i + 1) == ':' {
            i += 2;
            push(Tok::PathSep);
        } else {
            i += 1;
            push(Tok::Punct(c));
        }
    }
    toks
}

/// Skips a block comment whose `/*` starts at `i` (block comments nest in Rust); returns the
/// index after its closing `*/`, counting the newlines it passes in `line`.
pub fn skip_block_comment(s: &[char], mut i: usize, line: &mut u32) -> usize {
    let at = |k: usize| s.get(k).copied().unwrap_or('\0');
    let mut nest = 0;
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
        } else {
            *line += u32::from(s[i] == '\n');
            i += 1;
        }
    }
    i
}

/// Skips a string body starting after its opening quote; returns the index after the closing one.
pub fn skip_string(s: &[char], mut i: usize, line: &mut u32) -> usize {
    while i < s.len() && s[i] != '"' {
        if s[i] == '\\' {
            i += 1;
        }
        if s.get(i) == Some(&'\n') {
            *line += 1;
        }
        i += 1;
    }
    i + 1
}

/// Skips a raw string whose hashes (or opening quote) start at `i`.
pub fn skip_raw_string(s: &[char], mut i: usize, line: &mut u32) -> usize {
    let mut hashes = 0;
    while s.get(i) == Some(&'#') {
        hashes += 1;
        i += 1;
    }
    i += 1; // the opening quote
    while i < s.len() {
        if s[i] == '"' && (1..=hashes).all(|k| s.get(i + k) == Some(&'#')) {
            return i + 1 + hashes;
        }
        *line += u32::from(s[i] == '\n');
        i += 1;
    }
    i
}

/// Keywords that define a named item at module level.
const DEFINING: [&str; 9] = [
    "fn", "struct", "enum", "union", "trait", "type", "const", "static", "mod",
];

/// Words that can come between an item's start and its defining keyword.
const QUALIFIERS: [&str; 6] = ["pub", "async", "unsafe", "extern", "default", "const"];

struct Scanner {
    toks: Vec<Token>,
    i: usize,
    /// Depth of `{` nesting.
    depth: usize,
    /// Inline modules entered, with the depth of their bodies.
    scopes: Vec<(String, usize)>,
    out: FileScan,
}

impl Scanner {
    fn tok(&self, i: usize) -> Option<&Tok> {
        self.toks.get(i).map(|t| &t.tok)
    }

    fn ident(&self, i: usize) -> Option<&str> {
        match self.tok(i) {
            Some(Tok::Ident(s)) => Some(s),
            _ => None,
        }
    }

    fn punct(&self, i: usize, c: char) -> bool {
        self.tok(i) == Some(&Tok::Punct(c))
    }

    fn scope(&self) -> Vec<String> {
        self.scopes.iter().map(|(name, _)| name.clone()).collect()
    }

    /// Depth at which the current module's items live.
    fn module_depth(&self) -> usize {
        self.scopes.last().map_or(0, |&(_, d)| d)
    }

    fn run(&mut self) {
        let mut item_start = true;
        while self.i < self.toks.len() {
            let i = self.i;
            match self.tok(i).cloned() {
                Some(Tok::Punct('#'))
                    if self.punct(i + 1, '[')
                        || (self.punct(i + 1, '!') && self.punct(i + 2, '[')) =>
                {
                    let inner = self.punct(i + 1, '!');
                    let open = if inner { i + 2 } else { i + 1 };
                    let close = self.matching(open);
                    if self.is_cfg_test(open + 1, close) {
                        self.i = close + 1;
                        if inner {
                            // `#![cfg(test)]`: the enclosing module is test code.
                            if self.scopes.is_empty() {
                                self.out.test_only = true;
                                return;
                            }
                            self.skip_to_depth(self.depth - 1);
                        } else {
                            self.skip_item();
                        }
                    } else {
                        // Attribute arguments can name paths (`#[serde(with = ...)]` aside,
                        // which is a string): record them, then go on at the item.
                        self.record_paths(open + 1, close);
                        self.i = close + 1;
                    }
                    continue;
                }
                Some(Tok::Punct('{')) => {
                    self.depth += 1;
                    item_start = true;
                }
                Some(Tok::Punct('}')) => {
                    self.depth = self.depth.saturating_sub(1);
                    if self.scopes.last().is_some_and(|&(_, d)| d > self.depth) {
                        self.scopes.pop();
                    }
                    item_start = true;
                }
                Some(Tok::Punct(';')) => item_start = true,
                Some(Tok::Ident(_)) if item_start => {
                    item_start = self.item();
                    continue;
                }
                Some(Tok::Ident(_)) => {
                    self.i = self.path_at(i);
                    continue;
                }
                _ => item_start = false,
            }
            self.i += 1;
        }
    }

    /// At the start of an item or statement: records `use`, `mod` and defined names, and moves
    /// past what it read. Returns true when that was a whole declaration (`use ...;`, `mod x;`,
    /// `mod x {`), so the next token starts an item again.
    fn item(&mut self) -> bool {
        let mut j = self.i;
        let mut public = false;
        loop {
            match self.ident(j) {
                Some("pub") => {
                    public = true;
                    j += 1;
                    if self.punct(j, '(') {
                        j = self.matching(j) + 1;
                    }
                }
                Some("extern") if self.tok(j + 1) == Some(&Tok::Literal) => j += 2,
                Some("const")
                    if self
                        .ident(j + 1)
                        .is_some_and(|w| QUALIFIERS.contains(&w) || w == "fn") =>
                {
                    j += 1
                }
                Some(w) if QUALIFIERS.contains(&w) && w != "const" => j += 1,
                _ => break,
            }
        }
        let scope = self.scope();
        let at_module_level = self.depth == self.module_depth();
        match (self.ident(j), self.ident(j + 1)) {
            (Some("use"), _) => {
                self.i = j + 1;
                let mut leaves = Vec::new();
                self.use_tree(Vec::new(), &mut leaves);
                for (path, binding, line) in leaves {
                    self.out.uses.push(UseLeaf {
                        scope: scope.clone(),
                        path,
                        binding,
                        reexport: public,
                        line,
                    });
                }
                true
            }
            (Some("mod"), Some(name)) if self.punct(j + 2, ';') || self.punct(j + 2, '{') => {
                let name = name.to_owned();
                let line = self.toks[j].line;
                if self.punct(j + 2, ';') {
                    self.out.mods.push(ModDecl { scope, name, line });
                } else {
                    self.depth += 1;
                    self.scopes.push((name, self.depth));
                    self.out.inline_mods.push(self.scope());
                }
                self.i = j + 3;
                true
            }
            (Some("macro_rules"), _) if self.punct(j + 1, '!') => {
                if let (Some(name), true) = (self.ident(j + 2), at_module_level) {
                    self.out.items.push((scope, name.to_owned()));
                }
                self.i = j + 2;
                false
            }
            (Some(kw), Some(name)) if DEFINING.contains(&kw) && at_module_level && name != "_" => {
                let (name, next) = match (name, self.ident(j + 2)) {
                    ("mut", Some(name)) => (name.to_owned(), j + 3),
                    _ => (name.to_owned(), j + 2),
                };
                self.out.items.push((scope, name));
                self.i = next;
                false
            }
            _ => {
                self.i = self.path_at(self.i);
                false
            }
        }
    }

    /// Parses a use tree at `self.i` (after `use` or inside a group) into leaves; consumes the
    /// final `;` when at the top level.
    fn use_tree(&mut self, prefix: Vec<String>, leaves: &mut Vec<(Vec<String>, Binding, u32)>) {
        let top = prefix.is_empty();
        let mut path = prefix;
        if self.tok(self.i) == Some(&Tok::PathSep) {
            path.push("::".to_owned());
            self.i += 1;
        }
        loop {
            let line = self.toks.get(self.i).map_or(0, |t| t.line);
            match self.tok(self.i).cloned() {
                Some(Tok::Ident(seg)) => {
                    path.push(seg);
                    self.i += 1;
                    if self.tok(self.i) == Some(&Tok::PathSep) {
                        self.i += 1;
                        continue;
                    }
                    let mut binding = Binding::Name(path.last().cloned().unwrap_or_default());
                    if self.ident(self.i) == Some("as") {
                        binding = match self.ident(self.i + 1) {
                            Some("_") => Binding::Hidden,
                            Some(alias) => Binding::Name(alias.to_owned()),
                            None => Binding::Hidden,
                        };
                        self.i += 2;
                    }
                    if path.last().map(String::as_str) == Some("self") {
                        path.pop();
                        if binding == Binding::Name("self".to_owned()) {
                            binding = Binding::Name(path.last().cloned().unwrap_or_default());
                        }
                    }
                    leaves.push((path, binding, line));
                    break;
                }
                Some(Tok::Punct('*')) => {
                    self.i += 1;
                    leaves.push((path, Binding::Glob, line));
                    break;
                }
                Some(Tok::Punct('{')) => {
                    self.i += 1;
                    while self.i < self.toks.len() && !self.punct(self.i, '}') {
                        self.use_tree(path.clone(), leaves);
                        if self.punct(self.i, ',') {
                            self.i += 1;
                        }
                    }
                    self.i += 1;
                    break;
                }
                _ => break,
            }
        }
        if top {
            while self.i < self.toks.len() && !self.punct(self.i, ';') {
                self.i += 1;
            }
            self.i += 1;
        }
    }

    /// Records the path starting at `i` if it has two or more segments and does not continue
    /// another path (`::std::x`, `Vec::<u8>::new`); returns the index after it.
    fn path_at(&mut self, i: usize) -> usize {
        let continues = i > 0 && self.tok(i - 1) == Some(&Tok::PathSep);
        let mut path = Vec::new();
        let mut j = i;
        while let Some(seg) = self.ident(j) {
            path.push(seg.to_owned());
            if self.tok(j + 1) == Some(&Tok::PathSep) && self.ident(j + 2).is_some() {
                j += 2;
            } else {
                break;
            }
        }
        if path.len() >= 2 && !continues {
            let line = self.toks[i].line;
            self.out.paths.push(PathRef {
                scope: self.scope(),
                path,
                line,
            });
        }
        j + 1
    }

    fn record_paths(&mut self, from: usize, to: usize) {
        let mut i = from;
        while i < to {
            i = if self.ident(i).is_some() {
                self.path_at(i)
            } else {
                i + 1
            };
        }
    }

    /// Index of the delimiter closing the one at `open`.
    fn matching(&self, open: usize) -> usize {
        let mut depth = 0usize;
        for j in open..self.toks.len() {
            match self.tok(j) {
                Some(Tok::Punct('(' | '[' | '{')) => depth += 1,
                Some(Tok::Punct(')' | ']' | '}')) => {
                    depth -= 1;
                    if depth == 0 {
                        return j;
                    }
                }
                _ => {}
            }
        }
        self.toks.len()
    }

    /// `cfg(test)` or `cfg(all(test, ...))` between `from` and `to` (an attribute's inside).
    fn is_cfg_test(&self, from: usize, to: usize) -> bool {
        let words: Vec<&Tok> = (from..to).filter_map(|j| self.tok(j)).collect();
        let ident = |w: &str| Tok::Ident(w.to_owned());
        let open = Tok::Punct('(');
        match words.as_slice() {
            [cfg, o, test, _] => *cfg == &ident("cfg") && *o == &open && *test == &ident("test"),
            [cfg, o, all, o2, rest @ ..]
                if *cfg == &ident("cfg")
                    && *o == &open
                    && *all == &ident("all")
                    && *o2 == &open =>
            {
                // Only `test` at the top level of `all(...)` counts, not `all(not(test), ...)`.
                let mut depth = 0;
                rest.iter().any(|t| {
                    match t {
                        Tok::Punct('(') => depth += 1,
                        Tok::Punct(')') => depth -= 1,
                        _ => {}
                    }
                    depth == 0 && **t == ident("test")
                })
            }
            _ => false,
        }
    }

    /// Skips one item (after its attributes): up to a `;` or the `}` closing its body.
    fn skip_item(&mut self) {
        let mut depth = 0usize;
        while self.i < self.toks.len() {
            let tok = self.tok(self.i).cloned();
            self.i += 1;
            match tok {
                Some(Tok::Punct('(' | '[' | '{')) => depth += 1,
                Some(Tok::Punct(')' | ']')) => depth = depth.saturating_sub(1),
                Some(Tok::Punct('}')) => {
                    depth = depth.saturating_sub(1);
                    if depth == 0 {
                        return;
                    }
                }
                Some(Tok::Punct(';')) if depth == 0 => return,
                _ => {}
            }
        }
    }

    /// Skips to the `}` that brings the brace depth back to `depth` (leaving it to `run`).
    fn skip_to_depth(&mut self, depth: usize) {
        while self.i < self.toks.len() {
            match self.tok(self.i) {
                Some(Tok::Punct('{')) => self.depth += 1,
                Some(Tok::Punct('}')) if self.depth == depth + 1 => return,
                Some(Tok::Punct('}')) => self.depth -= 1,
                _ => {}
            }
            self.i += 1;
        }
    }
}
