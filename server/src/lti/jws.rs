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

/// Why a token is not a usable compact JWS.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JwsError {
    /// Not three dot-separated parts.
    #[error("the token is not a compact JWS (three parts)")]
    NotCompact,
    /// A part (`header`, `payload`, `signature`) does not decode.
    #[error("the token's {0} is not base64url")]
    NotBase64url(&'static str),
    /// The header or the payload (named) is not JSON.
    #[error("the token's {0} is not JSON")]
    NotJson(&'static str),
    /// Signed with another algorithm than RS256 (never `none`, never HMAC).
    #[error("the token is not signed with RS256")]
    NotRs256,
    /// The payload is JSON but no object.
    #[error("the token's claims are not a JSON object")]
    ClaimsNotObject,
}

/// Splits and decodes a compact JWS; only RS256 is accepted (never `none`, never HMAC).
pub fn parse(token: &str) -> Result<Parsed, JwsError> {
    let mut parts = token.split('.');
    let (Some(h), Some(p), Some(s), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(JwsError::NotCompact);
    };
    let decode = |part: &str, what: &'static str| {
        B64.decode(part.trim_end_matches('='))
            .map_err(|_| JwsError::NotBase64url(what))
    };
    let header: Value =
        serde_json::from_slice(&decode(h, "header")?).map_err(|_| JwsError::NotJson("header"))?;
    let claims: Value =
        serde_json::from_slice(&decode(p, "payload")?).map_err(|_| JwsError::NotJson("payload"))?;
    if header.get("alg").and_then(Value::as_str) != Some("RS256") {
        return Err(JwsError::NotRs256);
    }
    if !claims.is_object() {
        return Err(JwsError::ClaimsNotObject);
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

/// Why a JWK is not a usable RS256 signing key.
#[derive(Debug, thiserror::Error)]
pub enum JwkError {
    /// `kty` is not `RSA`.
    #[error("not an RSA key")]
    NotRsa,
    /// `use` names another use than `sig`.
    #[error("not a signing key")]
    NotSigning,
    /// `alg` names another algorithm than RS256.
    #[error("not an RS256 key")]
    NotRs256,
    /// The modulus `n` or exponent `e` is missing or does not decode.
    #[error("JWK member {0} is missing or not base64url")]
    Member(&'static str),
    /// The modulus and exponent make no RSA key.
    #[error("bad RSA key: {0}")]
    Key(#[from] rsa::Error),
}

/// An RSA public key from a JWK (`kty` RSA; a JWK for another use or algorithm is refused).
pub fn key_from_jwk(jwk: &Value) -> Result<RsaPublicKey, JwkError> {
    if jwk.get("kty").and_then(Value::as_str) != Some("RSA") {
        return Err(JwkError::NotRsa);
    }
    if jwk
        .get("use")
        .and_then(Value::as_str)
        .is_some_and(|u| u != "sig")
    {
        return Err(JwkError::NotSigning);
    }
    if jwk
        .get("alg")
        .and_then(Value::as_str)
        .is_some_and(|a| a != "RS256")
    {
        return Err(JwkError::NotRs256);
    }
    let field = |name: &'static str| {
        jwk.get(name)
            .and_then(Value::as_str)
            .and_then(|v| B64.decode(v.trim_end_matches('=')).ok())
            .map(|b| BigUint::from_bytes_be(&b))
            .ok_or(JwkError::Member(name))
    };
    Ok(RsaPublicKey::new(field("n")?, field("e")?)?)
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
