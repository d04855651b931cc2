//! The web client's side of the bill: every package in web-client/package-lock.json
//! (lockfileVersion 2 or 3, written by npm 7 and later), which records each installed package's
//! path, version, licence, integrity digest and declared dependencies.

use std::collections::BTreeMap;
use std::path::Path;

use base64::Engine;
use serde_json::Value;

use crate::bom::{Component, License, purl_encode};

/// Subresource-integrity digests ("sha512-<base64>", several separated by spaces) as CycloneDX
/// hashes; algorithms CycloneDX has no name for are left out.
fn hashes(integrity: Option<&str>) -> anyhow::Result<Vec<(&'static str, String)>> {
    let mut out = Vec::new();
    for item in integrity.unwrap_or_default().split_whitespace() {
        let Some((alg, digest)) = item.split_once('-') else {
            continue;
        };
        let name = match alg {
            "sha512" => "SHA-512",
            "sha384" => "SHA-384",
            "sha256" => "SHA-256",
            "sha1" => "SHA-1",
            _ => continue,
        };
        let bytes = base64::engine::general_purpose::STANDARD.decode(digest)?;
        out.push((name, hex::encode(bytes)));
    }
    Ok(out)
}

/// The package a lockfile path (`node_modules/a/node_modules/@s/b`) holds: `@s/b`.
fn name_of_path(path: &str) -> &str {
    path.rsplit_once("node_modules/")
        .map_or(path, |(_, name)| name)
}

/// Where Node finds dependency `name` of the package at `path`: its own node_modules first,
/// then each enclosing node_modules up to the project's.
fn resolve<'a>(packages: &'a BTreeMap<String, Value>, path: &str, name: &str) -> Option<&'a str> {
    let mut base = path.to_owned();
    loop {
        let candidate = if base.is_empty() {
            format!("node_modules/{name}")
        } else {
            format!("{base}/node_modules/{name}")
        };
        if let Some((key, _)) = packages.get_key_value(&candidate) {
            return Some(key);
        }
        if base.is_empty() {
            return None;
        }
        // Step out of this package to the one whose node_modules holds it.
        base = match base.rfind("/node_modules/") {
            Some(i) => base[..i].to_owned(),
            None => String::new(),
        };
    }
}

fn purl(name: &str, version: &str) -> String {
    match name.split_once('/') {
        Some((scope, rest)) => format!(
            "pkg:npm/{}/{}@{}",
            purl_encode(scope),
            purl_encode(rest),
            purl_encode(version)
        ),
        None => format!("pkg:npm/{}@{}", purl_encode(name), purl_encode(version)),
    }
}

/// Components for the web client and every package its lockfile lists, and the web client's
/// bom-ref.
pub fn components(dir: &Path) -> anyhow::Result<(Vec<Component>, String)> {
    let lock: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("package-lock.json"))?)?;
    let packages: BTreeMap<String, Value> =
        serde_json::from_value(lock.get("packages").cloned().ok_or_else(|| {
            anyhow::anyhow!(
                "package-lock.json has no \"packages\" (lockfileVersion 2 or later is needed)"
            )
        })?)?;
    let text = |v: &Value, key: &str| v.get(key).and_then(Value::as_str).map(str::to_owned);
    let mut refs: BTreeMap<&str, String> = BTreeMap::new();
    for (path, entry) in &packages {
        let name = text(entry, "name").unwrap_or_else(|| name_of_path(path).to_owned());
        let version = text(entry, "version").unwrap_or_default();
        let bom_ref = if path.is_empty() {
            format!("pain-sim/{name}@{version}")
        } else {
            purl(&name, &version)
        };
        refs.insert(path, bom_ref);
    }
    // One component per package and version: npm may install the same one at two paths when
    // hoisting cannot share it, and both paths then stand for one component.
    let mut out: BTreeMap<String, Component> = BTreeMap::new();
    for (path, entry) in &packages {
        if entry.get("link").and_then(Value::as_bool) == Some(true) {
            continue; // A workspace link; its target has an entry of its own.
        }
        let full = text(entry, "name").unwrap_or_else(|| name_of_path(path).to_owned());
        let (group, name) = match full.split_once('/') {
            Some((scope, rest)) if scope.starts_with('@') => {
                (Some(scope.to_owned()), rest.to_owned())
            }
            _ => (None, full.clone()),
        };
        let mut depends_on = Vec::new();
        for field in [
            "dependencies",
            "devDependencies",
            "optionalDependencies",
            "peerDependencies",
        ] {
            for dep in entry
                .get(field)
                .and_then(Value::as_object)
                .into_iter()
                .flat_map(|m| m.keys())
            {
                // An optional or peer dependency that was not installed has no entry to point to.
                if let Some(key) = resolve(&packages, path, dep) {
                    depends_on.push(refs[key].clone());
                }
            }
        }
        let root = path.is_empty();
        let bom_ref = refs[path.as_str()].clone();
        if let Some(seen) = out.get_mut(&bom_ref) {
            seen.depends_on.extend(depends_on);
            continue;
        }
        out.insert(
            bom_ref.clone(),
            Component {
                bom_ref,
                kind: if root { "application" } else { "library" },
                group,
                name,
                version: text(entry, "version").unwrap_or_default(),
                purl: (!root).then(|| refs[path.as_str()].clone()),
                license: text(entry, "license").map(License::Expression),
                hashes: hashes(entry.get("integrity").and_then(Value::as_str))?,
                // The lockfile marks packages that only development (here: the browser tests) uses.
                required: entry.get("dev").and_then(Value::as_bool) != Some(true),
                depends_on,
            },
        );
    }
    let out = out.into_values().collect();
    let root = refs
        .get("")
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("package-lock.json lacks the project's own entry"))?;
    Ok((out, root))
}
