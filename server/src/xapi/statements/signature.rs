//! Signed statements (xAPI 2.0, Data 2.6): a JWS in compact serialization, attached with usageType
//! `http://adlnet.gov/expapi/attachments/signature` and contentType `application/octet-stream`,
//! signed with RS256, RS384 or RS512, whose payload is the statement as it was before the
//! signature was attached.
//!
//! The LRS checks that the JWS is well formed, that its algorithm is one of the three, that the
//! payload is logically equivalent to the statement received (ignoring what the LRS may set and
//! the attachments, which the signature cannot cover) and, when the header carries an X.509
//! chain (`x5c`), that the signature verifies against the first certificate's key. Without `x5c`
//! there is no key to check against, and the signature is accepted as well formed (the spec
//! leaves authenticating the signer outside its scope).

use base64::Engine;
use base64::engine::general_purpose::{STANDARD, URL_SAFE_NO_PAD};
use rsa::RsaPublicKey;
use rsa::pkcs1v15::{Signature, VerifyingKey};
use rsa::pkcs8::DecodePublicKey;
use rsa::signature::Verifier;
use serde_json::Value;
use sha2::{Sha256, Sha384, Sha512};

/// usageType of a signature attachment.
pub const SIGNATURE_USAGE: &str = "http://adlnet.gov/expapi/attachments/signature";

/// Why a statement's signature is refused (each a 400 at the HTTP boundary).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SignatureError {
    /// The attachment's raw data is not UTF-8.
    #[error("the signature is not text")]
    NotText,
    /// Not three dot-separated parts.
    #[error("the signature is not a JWS in compact serialization")]
    NotCompact,
    /// A part (`header`, `payload`, `signature`) does not decode.
    #[error("the JWS {0} is not base64url")]
    NotBase64url(&'static str),
    /// The protected header does not parse.
    #[error("the JWS header is not JSON")]
    HeaderNotJson,
    /// The payload is not a JSON object.
    #[error("the JWS payload is not a JSON statement")]
    PayloadNotStatement,
    /// An algorithm other than RS256, RS384 and RS512.
    #[error("JWS algorithm {0:?}: signed statements use RS256, RS384 or RS512")]
    Algorithm(String),
    /// The payload names another statement.
    #[error("the JWS payload's id is not the statement's")]
    IdMismatch,
    /// The payload is not logically equivalent to the statement.
    #[error("the JWS payload does not match the statement")]
    PayloadMismatch,
    /// `x5c` is no list of base64 certificates.
    #[error("x5c: not a list of base64 certificates")]
    ChainNotList,
    /// Its first entry is no X.509 certificate.
    #[error("x5c: not an X.509 certificate")]
    NotCertificate,
    /// The certificate's key is not an RSA key.
    #[error("x5c: the certificate's key is not RSA")]
    KeyNotRsa,
    /// The signature bytes are no RSA signature.
    #[error("bad signature")]
    BadSignature,
    /// The signature does not verify with the certificate's key.
    #[error("the JWS signature does not verify against its x5c certificate")]
    DoesNotVerify,
}

/// Checks the JWS `jws` of `statement` (as received); the error says what is wrong.
pub fn verify(jws: &[u8], statement: &Value) -> Result<(), SignatureError> {
    let text = std::str::from_utf8(jws).map_err(|_| SignatureError::NotText)?;
    let parts: Vec<&str> = text.trim().split('.').collect();
    let [h64, p64, s64] = parts[..] else {
        return Err(SignatureError::NotCompact);
    };
    let decode = |s: &str, what: &'static str| {
        URL_SAFE_NO_PAD
            .decode(s.trim_end_matches('='))
            .map_err(|_| SignatureError::NotBase64url(what))
    };
    let header: Value = serde_json::from_slice(&decode(h64, "header")?)
        .map_err(|_| SignatureError::HeaderNotJson)?;
    let payload: Value = serde_json::from_slice(&decode(p64, "payload")?)
        .map_err(|_| SignatureError::PayloadNotStatement)?;
    let sig = decode(s64, "signature")?;
    let alg = header["alg"].as_str().unwrap_or("");
    if !matches!(alg, "RS256" | "RS384" | "RS512") {
        return Err(SignatureError::Algorithm(alg.to_owned()));
    }
    if !payload.is_object() {
        return Err(SignatureError::PayloadNotStatement);
    }
    let id = |v: &Value| v["id"].as_str().map(str::to_ascii_lowercase);
    if let (Some(a), Some(b)) = (id(&payload), id(statement))
        && a != b
    {
        return Err(SignatureError::IdMismatch);
    }
    if comparable(&payload) != comparable(statement) {
        return Err(SignatureError::PayloadMismatch);
    }
    let Some(chain) = header.get("x5c") else {
        return Ok(());
    };
    let cert = chain
        .as_array()
        .and_then(|c| c.first())
        .and_then(Value::as_str)
        .and_then(|c| STANDARD.decode(c).ok())
        .ok_or(SignatureError::ChainNotList)?;
    let spki = certificate_spki(&cert).ok_or(SignatureError::NotCertificate)?;
    let key = RsaPublicKey::from_public_key_der(spki).map_err(|_| SignatureError::KeyNotRsa)?;
    let signed = format!("{h64}.{p64}");
    let sig = Signature::try_from(sig.as_slice()).map_err(|_| SignatureError::BadSignature)?;
    let ok = match alg {
        "RS256" => VerifyingKey::<Sha256>::new(key).verify(signed.as_bytes(), &sig),
        "RS384" => VerifyingKey::<Sha384>::new(key).verify(signed.as_bytes(), &sig),
        _ => VerifyingKey::<Sha512>::new(key).verify(signed.as_bytes(), &sig),
    };
    ok.map_err(|_| SignatureError::DoesNotVerify)
}

/// A statement for comparison with a signature's payload: without the properties the LRS sets
/// and without attachments (ids are compared apart).
fn comparable(s: &Value) -> Value {
    let mut s = s.clone();
    if let Some(o) = s.as_object_mut() {
        for k in ["id", "stored", "authority", "version", "attachments"] {
            o.remove(k);
        }
    }
    super::timefmt::comparable_durations(&mut s);
    s
}

/// One DER element: (tag, content, rest).
fn der(input: &[u8]) -> Option<(u8, &[u8], &[u8])> {
    let (&tag, rest) = input.split_first()?;
    let (&first, mut rest) = rest.split_first()?;
    let len = if first < 0x80 {
        usize::from(first)
    } else {
        let n = usize::from(first & 0x7f);
        if n == 0 || n > 4 || rest.len() < n {
            return None;
        }
        let len = rest[..n]
            .iter()
            .fold(0usize, |a, &b| (a << 8) | usize::from(b));
        rest = &rest[n..];
        len
    };
    (rest.len() >= len).then(|| (tag, &rest[..len], &rest[len..]))
}

/// The SubjectPublicKeyInfo (whole DER element) of an X.509 certificate (RFC 5280, 4.1).
fn certificate_spki(cert: &[u8]) -> Option<&[u8]> {
    let (0x30, certificate, _) = der(cert)? else {
        return None;
    };
    let (0x30, tbs, _) = der(certificate)? else {
        return None;
    };
    let mut rest = tbs;
    // [0] version is optional.
    if rest.first() == Some(&0xa0) {
        rest = der(rest)?.2;
    }
    // serialNumber, signature, issuer, validity, subject.
    for _ in 0..5 {
        rest = der(rest)?.2;
    }
    let (tag, _, after) = der(rest)?;
    (tag == 0x30).then(|| &rest[..rest.len() - after.len()])
}
