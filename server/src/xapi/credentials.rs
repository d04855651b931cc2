//! Admin endpoints for the LMS integrations' LRS credentials: create (the secret is shown once),
//! list, revoke. Every change is in the audit trail.

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use rand::RngCore;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::state::XapiState;
use crate::error::ApiError;
use crate::records::auth::{CurrentUser, Role};
use crate::records::extract::{ApiJson, ApiPath};
use crate::records::history::audit;

/// What a credential may do at the LRS.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Access {
    /// Read statements and documents only (e.g. an LMS gradebook or analytics).
    Read,
    /// Write statements and documents only (e.g. content that reports to the LRS).
    Write,
    /// Both.
    ReadWrite,
}

impl Access {
    fn scopes(self) -> (bool, bool) {
        match self {
            Access::Read => (true, false),
            Access::Write => (false, true),
            Access::ReadWrite => (true, true),
        }
    }
}

/// What an admin asks for.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewCredential {
    /// The integration's name, e.g. the LMS and course site (1 to 200 characters, not blank).
    #[schema(
        min_length = 1,
        max_length = 200,
        pattern = "^[^\\u0000]*[^\\s\\u0000][^\\u0000]*$"
    )]
    pub name: String,
    /// What it may do (default `read_write`).
    #[serde(default = "read_write")]
    pub access: Access,
    /// The xAPI version the integration speaks (default `2.0.0`).
    #[serde(default)]
    pub xapi_version: XapiVersion,
}

fn read_write() -> Access {
    Access::ReadWrite
}

/// The xAPI version an LMS integration speaks. Each request is still answered by the rules of the
/// version its `X-Experience-API-Version` header names; this one is named in the 400 answer to a
/// request that names none (or one this LRS does not accept).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema, Default)]
pub enum XapiVersion {
    /// xAPI 1.0.3 (most deployed LMS plugins, authoring tools and cmi5 players).
    #[serde(rename = "1.0.3")]
    V1_0_3,
    /// xAPI 2.0.0 (IEEE 9274.1.1).
    #[default]
    #[serde(rename = "2.0.0")]
    V2_0_0,
}

impl XapiVersion {
    /// The value stored in `lrs_credentials.xapi_version`.
    pub fn as_str(self) -> &'static str {
        match self {
            XapiVersion::V1_0_3 => "1.0.3",
            XapiVersion::V2_0_0 => "2.0.0",
        }
    }

    fn from_column(s: &str) -> XapiVersion {
        if s == "1.0.3" {
            XapiVersion::V1_0_3
        } else {
            XapiVersion::V2_0_0
        }
    }
}

/// A credential as listed (never with its secret).
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct Credential {
    /// Id.
    pub id: Uuid,
    /// Name.
    pub name: String,
    /// The HTTP Basic user name.
    pub key: String,
    /// May read.
    pub read: bool,
    /// May write.
    pub write: bool,
    /// The xAPI Agent set as authority of the statements stored through it.
    #[schema(value_type = Object)]
    pub authority: Value,
    /// The xAPI version the integration speaks.
    pub xapi_version: XapiVersion,
    /// When it was created.
    #[serde(with = "time::serde::rfc3339")]
    pub created_at: OffsetDateTime,
    /// When it was revoked, if it was.
    #[serde(with = "time::serde::rfc3339::option")]
    pub revoked_at: Option<OffsetDateTime>,
}

/// A new credential with its secret (shown this once).
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct CreatedCredential {
    /// The credential.
    #[serde(flatten)]
    pub credential: Credential,
    /// The HTTP Basic password: shown once, stored only as its SHA-256.
    pub secret: String,
    /// The LRS endpoint to give the LMS.
    pub endpoint: String,
}

fn random_hex(bytes: usize) -> String {
    let mut b = vec![0u8; bytes];
    rand::rng().fill_bytes(&mut b);
    hex::encode(b)
}

type Row = (
    Uuid,
    String,
    String,
    bool,
    bool,
    Value,
    OffsetDateTime,
    Option<OffsetDateTime>,
    String,
);

fn from_row(r: Row) -> Credential {
    Credential {
        id: r.0,
        name: r.1,
        key: r.2,
        read: r.3,
        write: r.4,
        authority: r.5,
        created_at: r.6,
        revoked_at: r.7,
        xapi_version: XapiVersion::from_column(&r.8),
    }
}

const COLUMNS: &str =
    "id, name, key, can_read, can_write, authority, created_at, revoked_at, xapi_version";

/// Create an LRS credential for an LMS integration (admin). The secret is in this response only.
#[utoipa::path(post, path = "/api/admin/lrs-credentials", tag = "lms", request_body = NewCredential,
    responses((status = 201, body = CreatedCredential, description = "Created; the secret is shown once"),
        (status = 400), (status = 401), (status = 403)))]
pub async fn create_credential(
    State(state): State<XapiState>,
    user: CurrentUser,
    ApiJson(req): ApiJson<NewCredential>,
) -> Result<(StatusCode, Json<CreatedCredential>), ApiError> {
    user.require(&[Role::Admin])?;
    // The documented limit is on the name as sent (the trimmed one is stored).
    let name = req.name.trim();
    if name.is_empty() || req.name.chars().count() > 200 {
        return Err(ApiError::BadRequest("name: 1 to 200 characters".into()));
    }
    if name.contains('\0') {
        return Err(ApiError::BadRequest(
            "name: must not contain NUL characters".into(),
        ));
    }
    let (read, write) = req.access.scopes();
    let (id, key, secret) = (Uuid::new_v4(), random_hex(16), random_hex(32));
    let authority = json!({
        "objectType": "Agent",
        "name": name,
        "account": { "homePage": format!("{}/xapi/", state.public_url), "name": key },
    });
    let mut tx = state.pool.begin().await?;
    let row: Row = sqlx::query_as(&format!(
        "INSERT INTO lrs_credentials
           (id, name, key, secret_sha256, can_read, can_write, authority, created_by, xapi_version)
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9) RETURNING {COLUMNS}"
    ))
    .bind(id)
    .bind(name)
    .bind(&key)
    .bind(Sha256::digest(secret.as_bytes()).to_vec())
    .bind(read)
    .bind(write)
    .bind(&authority)
    .bind(user.id)
    .bind(req.xapi_version.as_str())
    .fetch_one(&mut *tx)
    .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "lrs_credential_created",
        "lrs_credential",
        &id.to_string(),
        json!({ "name": name, "read": read, "write": write,
            "xapi_version": req.xapi_version.as_str() }),
    )
    .await?;
    tx.commit().await?;
    Ok((
        StatusCode::CREATED,
        Json(CreatedCredential {
            credential: from_row(row),
            secret,
            endpoint: format!("{}/xapi/", state.public_url),
        }),
    ))
}

/// List the LRS credentials, revoked ones included (admin).
#[utoipa::path(get, path = "/api/admin/lrs-credentials", tag = "lms",
    responses((status = 200, body = [Credential]), (status = 401), (status = 403)))]
pub async fn list_credentials(
    State(state): State<XapiState>,
    user: CurrentUser,
) -> Result<Json<Vec<Credential>>, ApiError> {
    user.require(&[Role::Admin])?;
    let rows: Vec<Row> = sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM lrs_credentials ORDER BY created_at, id"
    ))
    .fetch_all(&state.pool)
    .await?;
    Ok(Json(rows.into_iter().map(from_row).collect()))
}

/// Revoke an LRS credential (admin): it stops authenticating at once. Revoking a revoked one
/// changes nothing.
#[utoipa::path(post, path = "/api/admin/lrs-credentials/{id}/revoke", tag = "lms",
    params(("id" = Uuid, Path, description = "Credential id")),
    responses((status = 200, body = Credential, description = "Revoked"), (status = 401),
        (status = 403), (status = 404)))]
pub async fn revoke_credential(
    State(state): State<XapiState>,
    user: CurrentUser,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<Json<Credential>, ApiError> {
    user.require(&[Role::Admin])?;
    let mut tx = state.pool.begin().await?;
    let row: Option<Row> = sqlx::query_as(&format!(
        "UPDATE lrs_credentials SET revoked_at = coalesce(revoked_at, now()) WHERE id = $1
         RETURNING {COLUMNS}"
    ))
    .bind(id)
    .fetch_optional(&mut *tx)
    .await?;
    let row = row.ok_or_else(|| ApiError::NotFound("LRS credential".into()))?;
    audit(
        &mut *tx,
        Some(user.id),
        "lrs_credential_revoked",
        "lrs_credential",
        &id.to_string(),
        json!({}),
    )
    .await?;
    tx.commit().await?;
    Ok(Json(from_row(row)))
}
