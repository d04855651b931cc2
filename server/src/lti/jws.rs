//! Compact JWS with RS256 (RFC 7515, RFC 7518 §3.3) and RSA JWKs (RFC 7517, thumbprints RFC 7638):
//! the only JOSE that LTI 1.3 needs, on the `rsa` crate.

use base64::Engine;
use base64::engine::general_purpose::URL_SAFE_NO_PAD as B64;
use rsa::pkcs1v15::{Signature, SigningKey, VerifyingKey};
use rsa::signature::{SignatureEncoding, Signer, Verifier};
use rsa::traits::PublicKeyParts;
use rsa::{BigUint, RsaPrivateKey, RsaPublicKey};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};

/// Signs `claims` as a compact JWS with RS256 and the key id `kid`.
pub fn sign(claims: &Value, kid: &str, key: &RsaPrivateKey) -> String {
    let header = json!({ "alg": "RS256", "typ": "JWT", "kid": kid });
    let input = format!(
        "{}.{}",
        B64.encode(header.to_string()),
        B64.encode(claims.to_string())
    );
    let sig = SigningKey::<Sha256>::new(key.clone()).sign(input.as_bytes());
    format!("{input}.{}", B64.encode(sig.to_bytes()))
}

/// A compact JWS split and decoded, not verified yet.
#[derive(Debug)]
pub struct Parsed {
    /// The protected header.
    pub header: Value,
    /// The payload (JSON claims).
    pub claims: Value,
    input: String,
    signature: Vec<u8>,
}

impl Parsed {
    /// The header's `kid`, if any.
    pub fn kid(&self) -> Option<&str> {
        self.header.get("kid").and_then(Value::as_str)
    }

    /// True when the RS256 signature verifies with `key`.
    pub fn verifies_with(&self, key: &RsaPublicKey) -> bool {
        let Ok(sig) = Signature::try_from(self.signature.as_slice()) else {
            return false;
        };
        VerifyingKey::<Sha256>::new(key.clone())
            .verify(self.input.as_bytes(), &sig)
            .is_ok()
    }
}

/// Splits and decodes a compact JWS; only RS256 is accepted (never `none`, never HMAC).
pub fn parse(token: &str) -> Result<Parsed, String> {
    let mut parts = token.split('.');
    let (Some(h), Some(p), Some(s), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err("the token is not a compact JWS (three parts)".into());
    };
    let decode = |part: &str, what: &str| {
        B64.decode(part.trim_end_matches('='))
            .map_err(|_| format!("the token's {what} is not base64url"))
    };
    let header: Value = serde_json::from_slice(&decode(h, "header")?)
        .map_err(|_| "the token's header is not JSON".to_string())?;
    let claims: Value = serde_json::from_slice(&decode(p, "payload")?)
        .map_err(|_| "the token's payload is not JSON".to_string())?;
    if header.get("alg").and_then(Value::as_str) != Some("RS256") {
        return Err("the token is not signed with RS256".into());
    }
    if !claims.is_object() {
        return Err("the token's claims are not a JSON object".into());
    }
    Ok(Parsed {
        header,
        claims,
        input: format!("{h}.{p}"),
        signature: decode(s, "signature")?,
    })
}

/// The public JWK of `key` (with `kid`, `alg` RS256, `use` sig).
pub fn public_jwk(key: &RsaPublicKey, kid: &str) -> Value {
    json!({
        "kty": "RSA",
        "alg": "RS256",
        "use": "sig",
        "kid": kid,
        "n": B64.encode(key.n().to_bytes_be()),
        "e": B64.encode(key.e().to_bytes_be()),
    })
}

/// The RFC 7638 thumbprint of `key` (base64url SHA-256): our key ids.
pub fn thumbprint(key: &RsaPublicKey) -> String {
    let canonical = format!(
        r#"{{"e":"{}","kty":"RSA","n":"{}"}}"#,
        B64.encode(key.e().to_bytes_be()),
        B64.encode(key.n().to_bytes_be())
    );
    B64.encode(Sha256::digest(canonical.as_bytes()))
}

/// An RSA public key from a JWK (`kty` RSA; a JWK for another use or algorithm is refused).
pub fn key_from_jwk(jwk: &Value) -> Result<RsaPublicKey, String> {
    if jwk.get("kty").and_then(Value::as_str) != Some("RSA") {
        return Err("not an RSA key".into());
    }
    if jwk
        .get("use")
        .and_then(Value::as_str)
        .is_some_and(|u| u != "sig")
    {
        return Err("not a signing key".into());
    }
    if jwk
        .get("alg")
        .and_then(Value::as_str)
        .is_some_and(|a| a != "RS256")
    {
        return Err("not an RS256 key".into());
    }
    let field = |name: &str| {
        jwk.get(name)
            .and_then(Value::as_str)
            .and_then(|v| B64.decode(v.trim_end_matches('=')).ok())
            .map(|b| BigUint::from_bytes_be(&b))
            .ok_or_else(|| format!("JWK member {name} is missing or not base64url"))
    };
    RsaPublicKey::new(field("n")?, field("e")?).map_err(|e| format!("bad RSA key: {e}"))
}

/// Random bytes as lower-case hex (state, nonce, tokens).
pub fn random_hex(bytes: usize) -> String {
    use rand::RngCore;
    let mut b = vec![0u8; bytes];
    rand::rng().fill_bytes(&mut b);
    hex::encode(b)
}

/// SHA-256 of a string.
pub fn sha256(s: &str) -> Vec<u8> {
    Sha256::digest(s.as_bytes()).to_vec()
}
