//! Authentication of LMS integrations at the LRS: HTTP Basic with a per-integration credential
//! (see [`super::credentials`]), checked on every request by the [`LrsClient`] extractor.
//!
//! The credential's key is the user name and its secret the password. The database keeps only the
//! secret's SHA-256; the comparison is constant-time. A revoked credential fails like an unknown
//! one (401), from the next request on.

use axum::extract::{FromRef, FromRequestParts};
use axum::http::HeaderMap;
use axum::http::header::AUTHORIZATION;
use axum::http::request::Parts;
use base64::Engine;
use serde_json::Value;
use sha2::{Digest, Sha256};
use uuid::Uuid;

use super::error::XapiError;
use super::state::XapiState;
use super::version::Spoken;
use crate::error::ApiError;
use crate::records::auth::constant_time_eq;

/// An authenticated LMS integration.
#[derive(Debug, Clone)]
pub struct LrsClient {
    /// Credential id.
    pub credential_id: Uuid,
    /// The integration's name (as the admin gave it).
    pub name: String,
    /// May read statements and documents.
    pub can_read: bool,
    /// May write statements and documents.
    pub can_write: bool,
    /// The xAPI Agent set as `authority` of the statements it stores.
    pub authority: Value,
    /// The xAPI line this request speaks (its `X-Experience-API-Version` header).
    pub spoken: Spoken,
}

impl LrsClient {
    /// 403 unless the credential may read.
    pub fn require_read(&self) -> Result<(), ApiError> {
        if self.can_read {
            Ok(())
        } else {
            Err(ApiError::Forbidden("this credential may not read".into()))
        }
    }

    /// 403 unless the credential may write.
    pub fn require_write(&self) -> Result<(), ApiError> {
        if self.can_write {
            Ok(())
        } else {
            Err(ApiError::Forbidden("this credential may not write".into()))
        }
    }
}

/// The key and secret of an `Authorization: Basic` header, if it is one.
pub fn basic_credentials(value: &str) -> Option<(String, String)> {
    let (scheme, rest) = value.trim().split_once(' ')?;
    if !scheme.eq_ignore_ascii_case("basic") {
        return None;
    }
    let raw = base64::engine::general_purpose::STANDARD
        .decode(rest.trim())
        .ok()?;
    let text = String::from_utf8(raw).ok()?;
    let (key, secret) = text.split_once(':')?;
    Some((key.to_owned(), secret.to_owned()))
}

impl<S> FromRequestParts<S> for LrsClient
where
    S: Send + Sync,
    XapiState: FromRef<S>,
{
    type Rejection = XapiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, XapiError> {
        let state = XapiState::from_ref(state);
        let c = authenticate(&state, &parts.headers).await?;
        Ok(LrsClient {
            credential_id: c.id,
            name: c.name,
            can_read: c.can_read,
            can_write: c.can_write,
            authority: c.authority,
            spoken: Spoken::of(&parts.headers),
        })
    }
}

/// The credential a request's `Authorization: Basic` header names, with its secret checked.
pub struct Authenticated {
    /// Credential id.
    pub id: Uuid,
    /// The integration's name.
    pub name: String,
    /// May read.
    pub can_read: bool,
    /// May write.
    pub can_write: bool,
    /// The authority of the statements it stores.
    pub authority: Value,
    /// The xAPI line the integration speaks (its credential's `xapi_version`).
    pub speaks: Spoken,
}

/// Checks a request's HTTP Basic credential: 401 ([`XapiError::Unauthorized`]) for a missing,
/// malformed, unknown, revoked or wrong one.
pub async fn authenticate(
    state: &XapiState,
    headers: &HeaderMap,
) -> Result<Authenticated, XapiError> {
    let (key, secret) = headers
        .get(AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(basic_credentials)
        .ok_or(XapiError::Unauthorized)?;
    if key.is_empty() || key.len() > 64 {
        return Err(XapiError::Unauthorized);
    }
    type Row = (Uuid, String, bool, bool, Value, Vec<u8>, String);
    let row: Option<Row> = sqlx::query_as(
        "SELECT id, name, can_read, can_write, authority, secret_sha256, xapi_version
           FROM lrs_credentials WHERE key = $1 AND revoked_at IS NULL",
    )
    .bind(&key)
    .fetch_optional(&state.pool)
    .await?;
    let Some((id, name, can_read, can_write, authority, stored, version)) = row else {
        return Err(XapiError::Unauthorized);
    };
    if !constant_time_eq(&Sha256::digest(secret.as_bytes()), &stored) {
        return Err(XapiError::Unauthorized);
    }
    Ok(Authenticated {
        id,
        name,
        can_read,
        can_write,
        authority,
        speaks: Spoken::of_version(&version),
    })
}

#[cfg(test)]
mod tests {
    use super::basic_credentials;

    #[test]
    fn basic_header_parsing() {
        // "key:se:cret" in base64: the secret may contain colons, the key may not.
        assert_eq!(
            basic_credentials("Basic a2V5OnNlOmNyZXQ="),
            Some(("key".into(), "se:cret".into()))
        );
        assert_eq!(
            basic_credentials("basic a2V5OnNlOmNyZXQ="),
            Some(("key".into(), "se:cret".into()))
        );
        assert_eq!(basic_credentials("Bearer a2V5OnNlOmNyZXQ="), None);
        assert_eq!(basic_credentials("Basic !!!"), None);
        assert_eq!(basic_credentials("Basic a2V5"), None);
    }
}
