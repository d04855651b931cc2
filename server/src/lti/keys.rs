//! The tool's own RSA keys: generated at first need, stored in the database (the private key
//! never leaves the server), published at `GET /lti/jwks`, rotated by an admin. After a rotation
//! the new key signs and the old ones stay published for [`RETIRED_KEY_GRACE`], so a platform
//! that cached our JWKS (or holds a token signed just before) still verifies.

use std::time::Duration;

use axum::Json;
use axum::extract::State;
use rsa::RsaPrivateKey;
use rsa::pkcs8::{DecodePrivateKey, EncodePrivateKey, LineEnding};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use sqlx::PgPool;
use utoipa::ToSchema;

use super::jws;
use super::state::LtiState;
use crate::error::ApiError;
use crate::records::auth::{CurrentUser, Role};
use crate::records::history::audit;

/// RSA modulus size in bits (IMS Security Framework §6.1: RS256 with keys of at least 2048 bits).
pub const KEY_BITS: usize = 2048;

/// How long a retired key stays in the JWKS (simulator choice: a week covers platforms that cache
/// a tool's key set for a day and our tokens' 5-minute lifetime many times over).
pub const RETIRED_KEY_GRACE: Duration = Duration::from_secs(7 * 24 * 3600);

fn generate() -> Result<(String, String, Value), ApiError> {
    let key = RsaPrivateKey::new(&mut rsa::rand_core::OsRng, KEY_BITS)
        .map_err(|e| ApiError::Internal(format!("RSA key generation: {e}")))?;
    let public = key.to_public_key();
    let kid = jws::thumbprint(&public);
    let pem = key
        .to_pkcs8_pem(LineEnding::LF)
        .map_err(|e| ApiError::Internal(format!("PKCS#8 encoding: {e}")))?;
    let jwk = jws::public_jwk(&public, &kid);
    Ok((kid, pem.to_string(), jwk))
}

/// The active signing key (generated and stored when there is none yet): its kid and key.
pub async fn signing_key(pool: &PgPool) -> Result<(String, RsaPrivateKey), ApiError> {
    for _ in 0..2 {
        let row: Option<(String, String)> = sqlx::query_as(
            "SELECT kid, private_pkcs8_pem FROM lti_tool_keys WHERE retired_at IS NULL",
        )
        .fetch_optional(pool)
        .await?;
        if let Some((kid, pem)) = row {
            let key = RsaPrivateKey::from_pkcs8_pem(&pem)
                .map_err(|e| ApiError::Internal(format!("stored LTI key {kid}: {e}")))?;
            return Ok((kid, key));
        }
        let (kid, pem, jwk) = tokio::task::spawn_blocking(generate)
            .await
            .map_err(|e| ApiError::Internal(e.to_string()))??;
        // Two first needs at once: the unique index keeps one active key, the other is dropped.
        sqlx::query(
            "INSERT INTO lti_tool_keys (kid, private_pkcs8_pem, public_jwk) VALUES ($1, $2, $3)
             ON CONFLICT DO NOTHING",
        )
        .bind(&kid)
        .bind(&pem)
        .bind(&jwk)
        .execute(pool)
        .await?;
    }
    Err(ApiError::Internal(
        "no active LTI key after generating one".into(),
    ))
}

/// Signs `claims` with the active key.
pub async fn sign(pool: &PgPool, claims: &Value) -> Result<String, ApiError> {
    let (kid, key) = signing_key(pool).await?;
    Ok(jws::sign(claims, &kid, &key))
}

/// The tool's JSON Web Key Set: the active key and the keys retired within the grace period.
pub async fn jwks(State(state): State<LtiState>) -> Result<Json<Value>, ApiError> {
    signing_key(&state.pool).await?;
    let keys: Vec<Value> = sqlx::query_scalar(
        "SELECT public_jwk FROM lti_tool_keys
         WHERE retired_at IS NULL OR retired_at > now() - make_interval(secs => $1)
         ORDER BY retired_at DESC NULLS FIRST, created_at DESC",
    )
    .bind(RETIRED_KEY_GRACE.as_secs_f64())
    .fetch_all(&state.pool)
    .await?;
    Ok(Json(json!({ "keys": keys })))
}

/// The key set after a rotation.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct Rotated {
    /// The new signing key's id.
    pub kid: String,
    /// Every published key id, the new one first.
    pub published: Vec<String>,
}

/// Rotate the tool's LTI signing key (admin): a new key signs from now on; the old ones stay in
/// the JWKS for a week.
#[utoipa::path(post, path = "/api/admin/lti/keys/rotate", tag = "lms",
    responses((status = 200, body = Rotated, description = "Rotated"), (status = 401),
        (status = 403)))]
pub async fn rotate(
    State(state): State<LtiState>,
    user: CurrentUser,
) -> Result<Json<Rotated>, ApiError> {
    user.require(&[Role::Admin])?;
    let (kid, pem, jwk) = tokio::task::spawn_blocking(generate)
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))??;
    let mut tx = state.pool.begin().await?;
    sqlx::query("UPDATE lti_tool_keys SET retired_at = now() WHERE retired_at IS NULL")
        .execute(&mut *tx)
        .await?;
    sqlx::query(
        "INSERT INTO lti_tool_keys (kid, private_pkcs8_pem, public_jwk) VALUES ($1, $2, $3)",
    )
    .bind(&kid)
    .bind(&pem)
    .bind(&jwk)
    .execute(&mut *tx)
    .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "lti_key_rotated",
        "lti_tool_key",
        &kid,
        json!({}),
    )
    .await?;
    tx.commit().await?;
    let Json(set) = jwks(State(state)).await?;
    let published = set["keys"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|k| k["kid"].as_str().map(str::to_owned))
        .collect();
    Ok(Json(Rotated { kid, published }))
}
