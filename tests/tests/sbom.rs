//! The SBOM generator (`cargo run -p tests --bin sbom`): its output must have the shape of a
//! CycloneDX 1.5 JSON document and describe exactly what the two lockfiles lock.

use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::process::Command;

use serde_json::Value;

fn repo() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// Runs the generator as a user would and parses what it wrote.
fn generate(extra: &[&str]) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bom.cdx.json");
    let status = Command::new(env!("CARGO_BIN_EXE_sbom"))
        .arg("--out")
        .arg(&out)
        .args(extra)
        .status()
        .expect("run the sbom binary");
    assert!(status.success(), "sbom exited with {status}");
    serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).expect("the SBOM is JSON")
}

/// Registry crates in Cargo.lock: (name, version) to checksum.
fn cargo_lock() -> HashMap<(String, String), String> {
    let lock: toml::Table = std::fs::read_to_string(repo().join("Cargo.lock"))
        .unwrap()
        .parse()
        .unwrap();
    lock["package"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|p| {
            let s = |k: &str| p.get(k).and_then(|v| v.as_str()).map(str::to_owned);
            Some(((s("name")?, s("version")?), s("checksum")?))
        })
        .collect()
}

fn npm_lock() -> Value {
    let text = std::fs::read_to_string(repo().join("web-client/package-lock.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn str_field<'a>(v: &'a Value, key: &str) -> &'a str {
    v[key]
        .as_str()
        .unwrap_or_else(|| panic!("{key} must be a string in {v}"))
}

/// The fields and value sets the CycloneDX 1.5 JSON schema (bom-1.5.schema.json) requires of a
/// document, its components, licences, hashes and dependency entries.
fn assert_cyclonedx_1_5_shape(bom: &Value) {
    assert_eq!(bom["bomFormat"], "CycloneDX");
    assert_eq!(bom["specVersion"], "1.5");
    assert_eq!(bom["version"], 1);
    let serial = str_field(bom, "serialNumber");
    let uuid = serial
        .strip_prefix("urn:uuid:")
        .expect("serialNumber is a urn:uuid");
    assert!(
        uuid.len() == 36 && uuid.chars().all(|c| c.is_ascii_hexdigit() || c == '-'),
        "{serial}"
    );
    assert!(str_field(&bom["metadata"], "timestamp").ends_with('Z'));
    let root = &bom["metadata"]["component"];
    assert_eq!(root["type"], "application");

    let mut refs = HashSet::from([str_field(root, "bom-ref").to_owned()]);
    for c in bom["components"].as_array().expect("components array") {
        assert!(
            ["application", "library", "framework"].contains(&str_field(c, "type")),
            "{c}"
        );
        assert!(!str_field(c, "name").is_empty() && !str_field(c, "version").is_empty());
        assert!(["required", "optional", "excluded"].contains(&str_field(c, "scope")));
        assert!(
            refs.insert(str_field(c, "bom-ref").to_owned()),
            "duplicate bom-ref in {c}"
        );
        if let Some(purl) = c.get("purl") {
            let purl = purl.as_str().unwrap();
            assert!(
                purl.starts_with("pkg:cargo/") || purl.starts_with("pkg:npm/"),
                "{purl}"
            );
            assert_eq!(purl, str_field(c, "bom-ref"));
        }
        for l in c["licenses"].as_array().into_iter().flatten() {
            let object = l.as_object().unwrap();
            assert_eq!(
                object.len(),
                1,
                "a licence choice is one of license or expression: {l}"
            );
            assert!(
                l.get("expression").is_some_and(Value::is_string)
                    || l["license"]["name"].is_string()
            );
        }
        for h in c["hashes"].as_array().into_iter().flatten() {
            let hex_len = match str_field(h, "alg") {
                "SHA-1" => 40,
                "SHA-256" => 64,
                "SHA-384" => 96,
                "SHA-512" => 128,
                other => panic!("unexpected hash algorithm {other}"),
            };
            let content = str_field(h, "content");
            assert!(
                content.len() == hex_len && content.chars().all(|c| c.is_ascii_hexdigit()),
                "{h}"
            );
        }
    }
    for d in bom["dependencies"].as_array().expect("dependencies array") {
        assert!(
            refs.contains(str_field(d, "ref")),
            "dependency of an unknown ref: {d}"
        );
        for on in d["dependsOn"].as_array().unwrap() {
            assert!(
                refs.contains(on.as_str().unwrap()),
                "depends on an unknown ref: {d}"
            );
        }
    }
}

fn component<'a>(bom: &'a Value, purl: &str) -> &'a Value {
    bom["components"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["purl"] == purl)
        .unwrap_or_else(|| panic!("no component {purl}"))
}

/// The bill is CycloneDX 1.5, lists every crate of Cargo.lock and every npm package of the web
/// client's lockfile with their pinned versions, digests and licences, and marks what ships.
#[test]
fn sbom_lists_both_lockfiles_in_cyclonedx_1_5() {
    let bom = generate(&[]);
    assert_cyclonedx_1_5_shape(&bom);

    let crates = cargo_lock();
    let listed: HashSet<(String, String)> = bom["components"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| {
            c["purl"]
                .as_str()
                .is_some_and(|p| p.starts_with("pkg:cargo/"))
        })
        .map(|c| {
            (
                str_field(c, "name").to_owned(),
                str_field(c, "version").to_owned(),
            )
        })
        .collect();
    let locked: HashSet<(String, String)> = crates.keys().cloned().collect();
    assert_eq!(
        listed, locked,
        "the SBOM lists exactly the registry crates of Cargo.lock"
    );

    let (_, wgpu_version) = locked
        .iter()
        .find(|(n, _)| n == "wgpu")
        .expect("wgpu in Cargo.lock");
    let wgpu = component(&bom, &format!("pkg:cargo/wgpu@{wgpu_version}"));
    assert_eq!(wgpu["scope"], "required", "render-worker links wgpu");
    assert_eq!(wgpu["hashes"][0]["alg"], "SHA-256");
    assert_eq!(
        wgpu["hashes"][0]["content"].as_str(),
        crates
            .get(&("wgpu".into(), wgpu_version.clone()))
            .map(String::as_str)
    );
    assert_eq!(wgpu["licenses"][0]["expression"], "MIT OR Apache-2.0");
    // tempfile is a dev-dependency of every crate that names it, so nothing shipped links it.
    let (_, tempfile_version) = locked.iter().find(|(n, _)| n == "tempfile").unwrap();
    let tempfile = component(&bom, &format!("pkg:cargo/tempfile@{tempfile_version}"));
    assert_eq!(tempfile["scope"], "excluded");

    // The chart library copied into the web client (web-client/vendor/uplot/vendor.json).
    let uplot = component(&bom, "pkg:npm/uplot@1.6.32");
    assert_eq!(uplot["scope"], "required", "served to browsers");
    assert_eq!(uplot["licenses"][0]["expression"], "MIT");
    assert_eq!(uplot["hashes"].as_array().unwrap().len(), 3, "{uplot}");

    let npm = npm_lock();
    let playwright = &npm["packages"]["node_modules/playwright-core"];
    let version = str_field(playwright, "version");
    let pw = component(&bom, &format!("pkg:npm/playwright-core@{version}"));
    assert_eq!(pw["version"], version);
    assert_eq!(
        pw["licenses"][0]["expression"],
        str_field(playwright, "license")
    );
    assert_eq!(
        pw["scope"], "excluded",
        "only the browser tests use playwright-core"
    );
    assert_eq!(pw["hashes"][0]["alg"], "SHA-512");

    // The platform depends on its crates and its web client, and the render worker on wgpu.
    let deps: HashMap<&str, Vec<&str>> = bom["dependencies"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| {
            let on = d["dependsOn"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_str().unwrap());
            (str_field(d, "ref"), on.collect())
        })
        .collect();
    let root = deps[str_field(&bom["metadata"]["component"], "bom-ref")].clone();
    assert!(
        root.iter()
            .any(|r| r.starts_with("pain-sim/render-worker@")),
        "{root:?}"
    );
    assert!(
        root.iter()
            .any(|r| r.starts_with("pain-sim/pain-sim-web-client@")),
        "{root:?}"
    );
    let worker = root
        .iter()
        .find(|r| r.starts_with("pain-sim/render-worker@"))
        .unwrap();
    assert!(deps[worker].contains(&str_field(wgpu, "bom-ref")));
}
