//! Attachments and signed statements at the Statement resource (xAPI 2.0, Data 2.4.11 and 2.6):
//! `multipart/mixed` requests whose parts are named by their SHA-256, `fileUrl`-only attachments
//! in plain JSON, GET with `attachments=true`, and JWS signatures (RS256/384/512, `x5c`).

use axum::http::{Method, StatusCode};
use base64::Engine;
use base64::engine::general_purpose::URL_SAFE_NO_PAD;
use rsa::pkcs8::DecodePrivateKey;
use rsa::signature::{SignatureEncoding, Signer};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};

use crate::records_support::Response;
use crate::xapi_statements::{get, post, stmt};
use crate::xapi_support::Lrs;

const SIGNATURE: &str = "http://adlnet.gov/expapi/attachments/signature";

fn sha(data: &[u8]) -> String {
    hex::encode(Sha256::digest(data))
}

fn attachment(data: &[u8], content_type: &str) -> Value {
    json!({
        "usageType": "http://example.org/attachment/report",
        "display": { "en-US": "report" },
        "contentType": content_type,
        "length": data.len(),
        "sha2": sha(data)
    })
}

/// A multipart/mixed body: the JSON, then each (content type, data, extra headers) part.
fn multipart(json: &Value, parts: &[(&str, &[u8], &str)]) -> (String, Vec<u8>) {
    let b = "abcABC0123456789";
    let mut body = format!("--{b}\r\nContent-Type: application/json\r\n\r\n{json}").into_bytes();
    for (ct, data, extra) in parts {
        body.extend(
            format!(
                "\r\n--{b}\r\nContent-Type: {ct}\r\n{extra}X-Experience-API-Hash: {}\r\n\r\n",
                sha(data)
            )
            .as_bytes(),
        );
        body.extend_from_slice(data);
    }
    body.extend(format!("\r\n--{b}--\r\n").as_bytes());
    (format!("multipart/mixed; boundary={b}"), body)
}

const BINARY: &str = "Content-Transfer-Encoding: binary\r\n";

async fn send_multipart(lrs: &Lrs, ct: &str, body: Vec<u8>) -> Response {
    lrs.raw(
        Method::POST,
        "/xapi/statements",
        Some(&lrs.cred),
        &[],
        Some((ct, body)),
    )
    .await
}

#[tokio::test]
async fn multipart_attachments_round_trip_and_faults_are_400() {
    let lrs = Lrs::new().await;
    let data: &[u8] = b"line one\r\n--abcABC not a boundary\r\n\x00\xff binary";
    let mut s = stmt("att", "attached", "report");
    s["attachments"] = json!([attachment(data, "application/octet-stream")]);
    let (ct, body) = multipart(&s, &[("application/octet-stream", data, BINARY)]);
    let r = send_multipart(&lrs, &ct, body).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
    let id = r.json[0].as_str().unwrap().to_owned();

    // attachments=true: multipart/mixed, the statement first, then the raw data.
    let req = axum::http::Request::get(format!(
        "/xapi/statements?statementId={id}&attachments=true"
    ))
    .header("x-experience-api-version", "2.0.0")
    .header("authorization", lrs.cred.basic())
    .body(axum::body::Body::empty())
    .unwrap();
    let resp = tower::ServiceExt::oneshot(lrs.app.router.clone(), req)
        .await
        .unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    let ct = resp.headers()["content-type"].to_str().unwrap().to_owned();
    assert!(ct.starts_with("multipart/mixed; boundary="), "{ct}");
    let raw = axum::body::to_bytes(resp.into_body(), 1 << 20)
        .await
        .unwrap();
    let (json, parts) = server::xapi::statements::multipart::parse(&raw, &ct).unwrap();
    let back: Value = serde_json::from_slice(&json).unwrap();
    assert_eq!(back["id"], id.as_str());
    assert_eq!(parts.len(), 1);
    assert_eq!(parts[0].sha2, sha(data));
    assert_eq!(parts[0].content, data);
    // Without attachments=true: JSON only.
    let g = get(&lrs, &format!("statementId={id}&attachments=false")).await;
    assert_eq!(g.headers["content-type"], "application/json");
    let q = get(&lrs, "attachments=true").await;
    assert!(
        q.headers["content-type"]
            .to_str()
            .unwrap()
            .starts_with("multipart/mixed")
    );

    let mut faults: Vec<(&str, String, Vec<u8>)> = Vec::new();
    let other: &[u8] = b"other data";
    // A part no attachment names.
    let (c, b) = multipart(
        &s,
        &[
            ("application/octet-stream", data, BINARY),
            ("text/plain", other, BINARY),
        ],
    );
    faults.push(("extra part", c, b));
    // An attachment without fileUrl and without its part.
    let (c, b) = multipart(&s, &[]);
    faults.push(("missing part", c, b));
    // No Content-Transfer-Encoding, or another one.
    let (c, b) = multipart(&s, &[("application/octet-stream", data, "")]);
    faults.push(("no transfer encoding", c, b));
    let (c, b) = multipart(
        &s,
        &[(
            "application/octet-stream",
            data,
            "Content-Transfer-Encoding: base64\r\n",
        )],
    );
    faults.push(("base64 transfer encoding", c, b));
    // The hash header does not match the content.
    let (c, b) = multipart(&s, &[("application/octet-stream", data, BINARY)]);
    let b = String::from_utf8_lossy(&b)
        .replace(&sha(data), &sha(other))
        .into_bytes();
    faults.push(("hash mismatch", c, b));
    // No boundary; a first part that is not JSON.
    let (_, b) = multipart(&s, &[("application/octet-stream", data, BINARY)]);
    faults.push(("no boundary", "multipart/mixed".into(), b.clone()));
    let (c, b2) = multipart(&s, &[("application/octet-stream", data, BINARY)]);
    let b2 = String::from_utf8_lossy(&b2)
        .replacen("application/json", "text/plain", 1)
        .into_bytes();
    faults.push(("first part not JSON", c, b2));
    for (what, c, b) in faults {
        let r = send_multipart(&lrs, &c, b).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{what}: {}", r.text);
    }
    // Plain JSON: an attachment needs a fileUrl.
    let r = post(&lrs, s.clone()).await;
    assert_eq!(r.status, StatusCode::BAD_REQUEST, "{}", r.text);
    s["attachments"][0]["fileUrl"] = json!("https://example.org/report.pdf");
    let r = post(&lrs, s).await;
    assert_eq!(r.status, StatusCode::OK, "{}", r.text);
}

include!("xapi_statements_keys.rs");

/// A compact JWS of `payload` by the test key with `alg`, with `x5c` when given.
fn jws(payload: &Value, alg: &str, x5c: Option<&str>) -> String {
    let mut header = json!({ "alg": alg });
    if let Some(c) = x5c {
        header["x5c"] = json!([c]);
    }
    let h = URL_SAFE_NO_PAD.encode(header.to_string());
    let p = URL_SAFE_NO_PAD.encode(payload.to_string());
    let input = format!("{h}.{p}");
    let key = rsa::RsaPrivateKey::from_pkcs8_pem(TEST_KEY_PEM).unwrap();
    let sig = match alg {
        "RS384" => rsa::pkcs1v15::SigningKey::<sha2::Sha384>::new(key)
            .sign(input.as_bytes())
            .to_vec(),
        "RS512" => rsa::pkcs1v15::SigningKey::<sha2::Sha512>::new(key)
            .sign(input.as_bytes())
            .to_vec(),
        _ => rsa::pkcs1v15::SigningKey::<Sha256>::new(key)
            .sign(input.as_bytes())
            .to_vec(),
    };
    format!("{input}.{}", URL_SAFE_NO_PAD.encode(sig))
}

/// A signed statement's request: the statement with its signature attachment, and the JWS part.
fn signed(s: &Value, sig: &str, content_type: &str) -> (String, Vec<u8>) {
    let mut s = s.clone();
    let mut a = attachment(sig.as_bytes(), content_type);
    a["usageType"] = json!(SIGNATURE);
    s["attachments"] = json!([a]);
    multipart(&s, &[(content_type, sig.as_bytes(), BINARY)])
}

#[tokio::test]
async fn signed_statements_are_checked() {
    let lrs = Lrs::new().await;
    let mut s = stmt("sig", "signed", "doc");
    s["id"] = json!(uuid::Uuid::new_v4().to_string());
    for alg in ["RS256", "RS384", "RS512"] {
        for x5c in [Some(TEST_CERT_B64), None] {
            // A new id each time: another signature is other content (409 under one id).
            let mut s = s.clone();
            s["id"] = json!(uuid::Uuid::new_v4().to_string());
            let (c, b) = signed(&s, &jws(&s, alg, x5c), "application/octet-stream");
            let r = send_multipart(&lrs, &c, b).await;
            assert_eq!(r.status, StatusCode::OK, "{alg} {}", r.text);
        }
    }
    let mut tampered = s.clone();
    tampered["verb"]["id"] = json!("http://example.org/verbs/forged");
    let cases = [
        (
            "payload differs",
            signed(
                &tampered,
                &jws(&s, "RS256", None),
                "application/octet-stream",
            ),
        ),
        (
            "wrong content type",
            signed(&s, &jws(&s, "RS256", None), "text/plain"),
        ),
        (
            "HS256",
            signed(&s, &jws(&s, "HS256", None), "application/octet-stream"),
        ),
        (
            "not a JWS",
            signed(&s, "not.a-jws", "application/octet-stream"),
        ),
        (
            "payload not JSON",
            signed(
                &s,
                &format!(
                    "{}.{}.AAAA",
                    URL_SAFE_NO_PAD.encode(r#"{"alg":"RS256"}"#),
                    URL_SAFE_NO_PAD.encode("{'x")
                ),
                "application/octet-stream",
            ),
        ),
        (
            "other certificate",
            signed(
                &s,
                &jws(&s, "RS256", Some(OTHER_CERT_B64)),
                "application/octet-stream",
            ),
        ),
    ];
    for (what, (c, b)) in cases {
        let r = send_multipart(&lrs, &c, b).await;
        assert_eq!(r.status, StatusCode::BAD_REQUEST, "{what}: {}", r.text);
    }
}
