//! One name per setting: the settings tables (`server::config::SETTINGS` and
//! `render_worker::session::config::WORKER_SETTINGS`) are the only description of the
//! environment variables, the code reads exactly their rows and nothing else, and the README's
//! Configuration tables are those rows.
//!
//! The checks read the real code paths (each configuration reader run through a lookup that
//! records the names it asks for) and the real sources and documents of the repository; none of
//! them needs a database.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use render_worker::session::config::{self as worker_config, WORKER_SETTINGS, WorkerConfig};
use server::config::{self, RETIRED, SETTINGS, Setting, SettingDefault};

/// The repository root.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The names a configuration reader asks for, when every variable is unset.
fn names_read(read: impl FnOnce(&dyn Fn(&str) -> Option<String>)) -> BTreeSet<String> {
    let asked = Mutex::new(BTreeSet::new());
    let lookup = |name: &str| {
        asked.lock().unwrap().insert(name.to_owned());
        None
    };
    read(&lookup);
    asked.into_inner().unwrap()
}

fn table_names(table: &[Setting]) -> BTreeSet<String> {
    table.iter().map(|s| s.name.to_owned()).collect()
}

/// Variables only the test harness reads (never the shipped code), allowed under `tests/`.
const TEST_HARNESS_NAMES: &[&str] = &[
    "PAINSIM_TEST_WORKER_REGISTER",
    "PAINSIM_TEST_WORKER_TOKEN",
    "PAINSIM_TEST_WORKER_DRAIN_MS",
    "PAINSIM_E2E_SCREENSHOTS",
];

/// Variables set at build time (read with `option_env!` when compiling, never at run time).
const BUILD_TIME_NAMES: &[&str] = &["RENDER_WORKER_GIT_REVISION"];

/// The files that read the environment at run time.
const CONFIG_MODULES: &[&str] = &[
    "server/src/config.rs",
    "render-worker/src/session/config.rs",
];

/// Environment reads outside the configuration modules that are not settings of the platform:
/// (file, variable, why).
const NOT_SETTINGS: &[(&str, &str, &str)] = &[
    (
        "server/src/embedded_pg.rs",
        "\"PATH\"",
        "the operating system's executable search path, searched for initdb and postgres",
    ),
    (
        "render-worker/src/alloc.rs",
        "\"MALLOC_ARENA_MAX\"",
        "glibc's own malloc tunable: read only so that a value the operator set is left in \
         place instead of the binaries' cap of 2 arenas",
    ),
    (
        "render-worker/src/gpu.rs",
        "\"REQUIRE_GPU\"",
        "a test-support switch (compiled only with the test-support feature) that turns a \
         missing GPU into a test failure",
    ),
];

#[test]
fn the_code_reads_every_row_and_nothing_else() {
    let server = names_read(|lookup| {
        config::Config::from_lookup(lookup).expect("the defaults are valid");
        config::admin_password(lookup);
        config::embedded_pg_user(lookup);
        config::log_filter(lookup);
    });
    let retired: BTreeSet<String> = RETIRED.iter().map(|r| r.name.to_owned()).collect();
    assert!(
        server.is_superset(&retired),
        "start-up must look for every retired name"
    );
    let server: BTreeSet<String> = server.difference(&retired).cloned().collect();
    assert_eq!(
        server,
        table_names(SETTINGS),
        "the server reads exactly the rows of SETTINGS"
    );

    let worker = names_read(|lookup| {
        WorkerConfig::from_lookup(lookup).expect("the defaults are valid");
        WorkerConfig::log_filter(lookup);
        worker_config::ultrasound_renderer(lookup);
    });
    assert_eq!(
        worker,
        table_names(WORKER_SETTINGS),
        "render-worker reads exactly the rows of WORKER_SETTINGS"
    );

    for table in [SETTINGS, WORKER_SETTINGS] {
        let names: Vec<&str> = table.iter().map(|s| s.name).collect();
        let unique: BTreeSet<&str> = names.iter().copied().collect();
        assert_eq!(
            unique.len(),
            names.len(),
            "a name appears twice in one table: {names:?}"
        );
        for s in table {
            assert!(
                !s.meaning.contains('|') && !s.meaning.contains('\n'),
                "{}: one Markdown table cell",
                s.name
            );
        }
    }
    for r in RETIRED {
        assert!(
            !table_names(SETTINGS).contains(r.name)
                && !table_names(WORKER_SETTINGS).contains(r.name),
            "{} is retired and cannot be a setting again",
            r.name
        );
    }
}

/// The files under `dir` (recursively) whose names end in one of `suffixes`, as paths relative
/// to the repository root.
fn files_under(dir: &str, suffixes: &[&str], out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(root().join(dir)) else {
        return;
    };
    for e in entries.flatten() {
        let rel = format!("{dir}/{}", e.file_name().to_string_lossy());
        if e.path().is_dir() {
            files_under(&rel, suffixes, out);
        } else if suffixes.iter().any(|s| rel.ends_with(s)) {
            out.push(rel);
        }
    }
}

fn rust_files(dir: &str, out: &mut Vec<String>) {
    files_under(dir, &[".rs"], out);
}

#[test]
fn only_the_configuration_modules_read_the_environment() {
    let mut files = Vec::new();
    for dir in ["server/src", "render-worker/src", "sim-core/src"] {
        rust_files(dir, &mut files);
    }
    assert!(
        files.len() > 50,
        "the scan found the sources ({} files)",
        files.len()
    );
    let mut found_config_reads = 0;
    let mut stray = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(root().join(file)).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.trim_start();
            if code.starts_with("//") {
                continue;
            }
            // `env::var`, `env::var_os`, `env::vars`; and tracing-subscriber's own read of RUST_LOG.
            let reads = code.contains("env::var") || code.contains("from_default_env");
            if !reads {
                continue;
            }
            if CONFIG_MODULES.contains(&file.as_str()) {
                found_config_reads += 1;
                continue;
            }
            let allowed = NOT_SETTINGS
                .iter()
                .any(|(f, var, _why)| f == file && code.contains(var));
            if !allowed {
                stray.push(format!("{file}:{}: {}", n + 1, code));
            }
        }
    }
    assert!(
        found_config_reads >= 1,
        "the configuration modules read the environment"
    );
    assert!(
        stray.is_empty(),
        "these lines read the environment outside the configuration modules ({CONFIG_MODULES:?}); \
         add a row to the settings table and take the value from the configuration:\n{}",
        stray.join("\n")
    );
}

/// Every `PAINSIM_*` and `RENDER_WORKER_*` name in `text`.
fn names_in(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for prefix in ["PAINSIM_", "RENDER_WORKER_"] {
        let mut rest = text;
        while let Some(i) = rest.find(prefix) {
            let before = rest[..i].chars().next_back();
            let tail = &rest[i..];
            let len = tail
                .find(|c: char| !(c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_'))
                .unwrap_or(tail.len());
            if !before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') {
                out.push(tail[..len].trim_end_matches('_').to_owned());
            }
            rest = &tail[len..];
        }
    }
    out
}

#[test]
fn every_name_in_code_and_documents_is_a_setting() {
    let mut files = Vec::new();
    for dir in [
        "server/src",
        "server/tests",
        "server/benches",
        "render-worker/src",
        "render-worker/tests",
        "render-worker/benches",
        "sim-core/src",
    ] {
        rust_files(dir, &mut files);
    }
    files.extend(
        [
            "README.md",
            "ARCHITECTURE.md",
            "docker-compose.yml",
            "server/Dockerfile",
            "render-worker/build.rs",
        ]
        .map(String::from),
    );
    files_under("docs", &[".md"], &mut files);
    // The CI scripts have no extension.
    files_under(".ci", &[""], &mut files);
    let settings: BTreeSet<String> = table_names(SETTINGS)
        .union(&table_names(WORKER_SETTINGS))
        .cloned()
        .collect();
    let retired: BTreeSet<&str> = RETIRED.iter().map(|r| r.name).collect();
    // Where a retired name may still appear: its table, the README's list, and the tests of
    // its refusal.
    let retired_allowed = [
        "server/src/config.rs",
        "README.md",
        "server/tests/configuration.rs",
    ];
    let mut unknown = Vec::new();
    for file in &files {
        let Ok(text) = std::fs::read_to_string(root().join(file)) else {
            continue;
        };
        for name in names_in(&text) {
            let ok = settings.contains(&name)
                || BUILD_TIME_NAMES.contains(&name.as_str())
                || (retired.contains(name.as_str()) && retired_allowed.contains(&file.as_str()))
                || (TEST_HARNESS_NAMES.contains(&name.as_str()) && file.contains("/tests/"))
                // The prefixes themselves, in this test and in prose about the naming.
                || name == "PAINSIM" || name == "RENDER_WORKER";
            if !ok {
                unknown.push(format!("{file}: {name}"));
            }
        }
    }
    unknown.sort();
    unknown.dedup();
    assert!(
        unknown.is_empty(),
        "names that are not rows of a settings table (or retired names used outside their \
         refusal):\n{}",
        unknown.join("\n")
    );
}

/// A default as the README shows it.
fn shown(default: SettingDefault) -> String {
    match default {
        SettingDefault::Value(v) => format!("`{v}`"),
        SettingDefault::Number(n) => format!("`{n}`"),
        SettingDefault::Unset => "unset".to_owned(),
        SettingDefault::Derived(words) => words.to_owned(),
    }
}

/// The Markdown table of `table`.
fn markdown(table: &[Setting]) -> String {
    let mut out = String::from("| variable | default | meaning |\n|---|---|---|\n");
    for s in table {
        out.push_str(&format!(
            "| `{}` | {} | {} |\n",
            s.name,
            shown(s.default),
            s.meaning
        ));
    }
    out
}

/// The README's list of retired names.
fn retired_markdown() -> String {
    let mut out = String::from(
        "Names no longer read (start-up stops with an error naming what to set instead):\n\n",
    );
    for r in RETIRED {
        out.push_str(&format!("- `{}`: {}\n", r.name, r.instead));
    }
    out
}

/// The text between `<!-- begin {id} -->` and `<!-- end {id} -->` in `readme`.
fn block<'a>(readme: &'a str, id: &str) -> &'a str {
    let begin = format!("<!-- begin {id} -->\n");
    let end = format!("<!-- end {id} -->");
    let start = readme
        .find(&begin)
        .unwrap_or_else(|| panic!("README.md has no `{}` line", begin.trim()))
        + begin.len();
    let stop = readme[start..]
        .find(&end)
        .unwrap_or_else(|| panic!("README.md has no `{end}` line"))
        + start;
    &readme[start..stop]
}

#[test]
fn readme_tables_are_the_settings_tables() {
    let readme = std::fs::read_to_string(root().join("README.md")).unwrap();
    let mut differ = Vec::new();
    for (id, expected) in [
        (
            "server settings (generated from server::config::SETTINGS)",
            markdown(SETTINGS),
        ),
        (
            "retired settings (generated from server::config::RETIRED)",
            retired_markdown(),
        ),
        (
            "render-worker settings (generated from render_worker::session::config::WORKER_SETTINGS)",
            markdown(WORKER_SETTINGS),
        ),
    ] {
        if block(&readme, id) != expected {
            differ.push(format!("<!-- begin {id} -->\n{expected}<!-- end {id} -->"));
        }
    }
    assert!(
        differ.is_empty(),
        "README.md's Configuration tables differ from the settings tables; replace these blocks \
         (markers included):\n\n{}",
        differ.join("\n\n")
    );
}

#[test]
fn a_retired_name_stops_the_server_before_it_starts() {
    let data = tempfile::tempdir().unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_server"))
        .env("PAINSIM_SESSION_IDLE_SECS", "600")
        .env("PAINSIM_DATA_DIR", data.path())
        .env("PAINSIM_BIND", "127.0.0.1:0")
        .output()
        .expect("run the server");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(2),
        "configuration errors exit with 2: {stderr}"
    );
    for name in [
        "PAINSIM_SESSION_IDLE_SECS",
        "PAINSIM_LOGIN_IDLE_SECS",
        "PAINSIM_LIVE_SESSION_IDLE_SECS",
    ] {
        assert!(stderr.contains(name), "the error names {name}: {stderr}");
    }
    assert!(
        !data.path().join("pg").exists(),
        "nothing started before the configuration was read"
    );
}
