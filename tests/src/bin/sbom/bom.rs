//! The CycloneDX 1.5 side of the generator: the component model both lockfile readers fill in,
//! and the JSON document built from it.

use serde_json::{Value, json};

/// One entry of the bill: a crate, an npm package, or a workspace member.
#[derive(Debug)]
pub struct Component {
    /// Unique within the document; the package URL where there is one.
    pub bom_ref: String,
    /// CycloneDX component type: "library" or "application".
    pub kind: &'static str,
    /// npm scope (`@scope`), CycloneDX's "group".
    pub group: Option<String>,
    pub name: String,
    pub version: String,
    pub purl: Option<String>,
    pub license: Option<License>,
    /// (CycloneDX algorithm name, lowercase hex digest).
    pub hashes: Vec<(&'static str, String)>,
    /// Whether a shipped program needs it at run time ("required") or not ("excluded").
    pub required: bool,
    /// bom-refs of the components this one depends on directly.
    pub depends_on: Vec<String>,
}

/// What a package declares about its licence.
#[derive(Debug)]
pub enum License {
    /// An SPDX licence expression.
    Expression(String),
    /// Free text, for a package that names a licence file instead of an SPDX expression.
    Named(String),
}

/// The characters a package URL keeps unencoded in a name or version (the purl specification's
/// "unreserved" set; everything else, `+` of semver build metadata and `@` of an npm scope
/// included, is percent-encoded).
pub fn purl_encode(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for byte in text.bytes() {
        if byte.is_ascii_alphanumeric() || matches!(byte, b'.' | b'-' | b'_' | b'~') {
            out.push(char::from(byte));
        } else {
            out.push_str(&format!("%{byte:02X}"));
        }
    }
    out
}

fn component_json(c: &Component) -> Value {
    let mut object = json!({
        "type": c.kind,
        "bom-ref": c.bom_ref,
        "name": c.name,
        "version": c.version,
        "scope": if c.required { "required" } else { "excluded" },
    });
    let map = object.as_object_mut().expect("a JSON object");
    if let Some(group) = &c.group {
        map.insert("group".into(), json!(group));
    }
    if let Some(purl) = &c.purl {
        map.insert("purl".into(), json!(purl));
    }
    match &c.license {
        Some(License::Expression(e)) => {
            map.insert("licenses".into(), json!([{ "expression": e }]));
        }
        Some(License::Named(n)) => {
            map.insert("licenses".into(), json!([{ "license": { "name": n } }]));
        }
        None => {}
    }
    if !c.hashes.is_empty() {
        let hashes: Vec<Value> = c
            .hashes
            .iter()
            .map(|(alg, content)| json!({ "alg": alg, "content": content }))
            .collect();
        map.insert("hashes".into(), json!(hashes));
    }
    object
}

/// The whole document. `components` must have unique bom-refs; `roots` are the bom-refs the
/// platform itself depends on directly (the workspace crates and the web client).
pub fn document(mut components: Vec<Component>, roots: Vec<String>) -> anyhow::Result<Value> {
    components.sort_by(|a, b| a.bom_ref.cmp(&b.bom_ref));
    for pair in components.windows(2) {
        anyhow::ensure!(
            pair[0].bom_ref != pair[1].bom_ref,
            "two components share the bom-ref {}",
            pair[0].bom_ref
        );
    }
    let version = env!("CARGO_PKG_VERSION");
    let root_ref = format!("pain-sim@{version}");
    let mut dependencies = vec![json!({ "ref": root_ref, "dependsOn": roots })];
    for c in &components {
        let mut on = c.depends_on.clone();
        on.sort();
        on.dedup();
        dependencies.push(json!({ "ref": c.bom_ref, "dependsOn": on }));
    }
    let timestamp = time::OffsetDateTime::now_utc()
        .replace_nanosecond(0)?
        .format(&time::format_description::well_known::Rfc3339)?;
    Ok(json!({
        "bomFormat": "CycloneDX",
        "specVersion": "1.5",
        "serialNumber": format!("urn:uuid:{}", uuid::Uuid::new_v4()),
        "version": 1,
        "metadata": {
            "timestamp": timestamp,
            "tools": { "components": [{
                "type": "application",
                "name": "pain-sim sbom",
                "version": version,
            }] },
            "component": {
                "type": "application",
                "bom-ref": root_ref,
                "name": "pain-sim",
                "version": version,
                "licenses": [{ "expression": "Apache-2.0" }],
            },
        },
        "components": components.iter().map(component_json).collect::<Vec<_>>(),
        "dependencies": dependencies,
    }))
}
