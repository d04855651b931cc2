//! The WGSL shaders never branch on uniform values alone. lavapipe inlines the uniforms that
//! decide an `if` and builds the shader again each time the uniform buffer changes (every frame),
//! keeping every build: the fluoroscopy resolve's `if (has_needle && params.full.z != 0u)` made a
//! session grow by 1.4 MB per frame with a needle (`benches/sessions.rs`, memory soak). A branch
//! on pipeline constants (`override`) is decided when the pipeline is made, and a branch on
//! anything per invocation is not inlined. This reads every shader's `if` conditions: one that
//! names a uniform variable and otherwise only uniform variables and pipeline constants fails.
//! (A uniform value copied into a local first is not seen: keep such decisions in constants.)

use std::collections::BTreeSet;

/// WGSL words that are not variables: literals, types and built-in functions.
const NOT_VARIABLES: &[&str] = &[
    "true",
    "false",
    "u32",
    "i32",
    "f32",
    "bool",
    "vec2",
    "vec3",
    "vec4",
    "abs",
    "all",
    "any",
    "min",
    "max",
    "select",
    "arrayLength",
];

fn identifiers(condition: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let bytes = condition.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i] as char;
        if c.is_ascii_alphabetic() || c == '_' {
            let start = i;
            while i < bytes.len()
                && ((bytes[i] as char).is_ascii_alphanumeric() || bytes[i] == b'_')
            {
                i += 1;
            }
            // A field after `.` is not a variable.
            let after_dot = start > 0 && bytes[start - 1] == b'.';
            let word = &condition[start..i];
            if !after_dot && !NOT_VARIABLES.contains(&word) {
                out.insert(word.to_string());
            }
        } else if c.is_ascii_digit() {
            // Skip a number with its suffix (`0u`, `1e-4`).
            while i < bytes.len()
                && ((bytes[i] as char).is_ascii_alphanumeric() || bytes[i] == b'.')
            {
                i += 1;
            }
        } else {
            i += 1;
        }
    }
    out
}

/// The conditions of every `if (...)` in `source`.
fn if_conditions(source: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut rest = source;
    while let Some(k) = rest.find("if (") {
        let body = &rest[k + 4..];
        let mut depth = 1;
        let end = body
            .char_indices()
            .find(|&(_, c)| {
                match c {
                    '(' => depth += 1,
                    ')' => depth -= 1,
                    _ => {}
                }
                depth == 0
            })
            .map_or(body.len(), |(j, _)| j);
        out.push(body[..end].to_string());
        rest = &body[end..];
    }
    out
}

/// Names declared by `keyword` at the start of a line up to the name (`var<uniform> NAME:`,
/// `override NAME:`).
fn declared(source: &str, keyword: &str) -> BTreeSet<String> {
    source
        .lines()
        .filter_map(|l| l.split_once(keyword).map(|(_, r)| r))
        .filter_map(|r| r.trim().split([':', ' ', ';']).next())
        .filter(|n| !n.is_empty())
        .map(str::to_string)
        .collect()
}

fn violations(source: &str) -> Vec<String> {
    let uniforms = declared(source, "var<uniform>");
    let constants = declared(source, "override ");
    if_conditions(source)
        .into_iter()
        .filter(|c| {
            let names = identifiers(c);
            names.iter().any(|n| uniforms.contains(n))
                && names
                    .iter()
                    .all(|n| uniforms.contains(n) || constants.contains(n))
        })
        .collect()
}

#[test]
fn no_shader_branches_on_uniform_values_alone() {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    for dir in ["fluoro", "ultrasound"] {
        for entry in std::fs::read_dir(src.join(dir)).expect("shader folder") {
            let path = entry.expect("entry").path();
            if path.extension().is_some_and(|e| e == "wgsl") {
                files.push(path);
            }
        }
    }
    assert!(files.len() >= 8, "the shaders were found: {files:?}");
    let mut found = Vec::new();
    for path in &files {
        let source = std::fs::read_to_string(path).expect("shader");
        for c in violations(&source) {
            found.push(format!("{}: if ({c})", path.display()));
        }
    }
    assert!(
        found.is_empty(),
        "branches on uniform values alone: {found:#?}"
    );
}

/// The check itself: the resolve's old condition is caught, per-invocation and constant-only
/// conditions are not.
#[test]
fn the_uniform_branch_check_catches_the_old_resolve_condition() {
    let shader = "override has_needle: bool = true;\n\
                  @group(0) @binding(0) var<uniform> params: Params;\n\
                  fn f(p: vec2<i32>) {\n\
                  if (has_needle && params.full.z != 0u) { }\n\
                  if (has_needle) { }\n\
                  if (params.misc.x < 0.0 || f32(p.x) > params.misc.y) { }\n\
                  if (abs(params.mu.x) > 1e-4) { }\n\
                  }";
    assert_eq!(
        violations(shader),
        vec![
            "has_needle && params.full.z != 0u".to_string(),
            "abs(params.mu.x) > 1e-4".to_string()
        ]
    );
}
