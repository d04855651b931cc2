//! Admin endpoints to register LTI 1.3 platforms (issuer, client id, deployment ids, OIDC auth,
//! token and JWKS URLs, optional AGS/NRPS defaults): create, list, update, delete. Every change
//! is in the audit trail.

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use serde_json::json;
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::state::LtiState;
use crate::error::ApiError;
use crate::records::auth::{CurrentUser, Role};
use crate::records::extract::{ApiJson, ApiPath};
use crate::records::history::audit;

/// A platform as an admin registers it.
#[derive(Debug, Clone, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PlatformSettings {
    /// A name for people (1 to 200 characters), e.g. "Moodle, school of medicine".
    #[schema(min_length = 1, max_length = 200, pattern = "^[^\\u0000]*$")]
    pub name: String,
    /// The platform's issuer (`iss` of its id_tokens), an https URL (http only on loopback).
    #[schema(min_length = 1, max_length = 2000, pattern = "^[^\\u0000]*$")]
    pub issuer: String,
    /// The client id the platform gave this tool.
    #[schema(min_length = 1, max_length = 2000, pattern = "^[^\\u0000]*$")]
    pub client_id: String,
    /// The deployment ids this registration accepts (at least one).
    #[schema(min_items = 1, max_items = 100)]
    pub deployment_ids: Vec<String>,
    /// The platform's OIDC authorisation endpoint.
    #[schema(
        min_length = 1,
        max_length = 2000,
        pattern = "^(https://|http://(localhost|127\\.0\\.0\\.1|\\[::1\\])([:/]|$))[^\\u0000-\\u0020]*$"
    )]
    pub auth_url: String,
    /// The platform's OAuth 2 token endpoint (LTI Advantage services).
    #[schema(
        min_length = 1,
        max_length = 2000,
        pattern = "^(https://|http://(localhost|127\\.0\\.0\\.1|\\[::1\\])([:/]|$))[^\\u0000-\\u0020]*$"
    )]
    pub token_url: String,
    /// The platform's JSON Web Key Set.
    #[schema(
        min_length = 1,
        max_length = 2000,
        pattern = "^(https://|http://(localhost|127\\.0\\.0\\.1|\\[::1\\])([:/]|$))[^\\u0000-\\u0020]*$"
    )]
    pub jwks_url: String,
    /// Optional AGS line items URL used when a launch carries none.
    #[serde(default)]
    #[schema(
        min_length = 1,
        max_length = 2000,
        pattern = "^(https://|http://(localhost|127\\.0\\.0\\.1|\\[::1\\])([:/]|$))[^\\u0000-\\u0020]*$"
    )]
    pub lineitems_url: Option<String>,
    /// Optional NRPS context memberships URL used when a launch carries none.
    #[serde(default)]
    #[schema(
        min_length = 1,
        max_length = 2000,
        pattern = "^(https://|http://(localhost|127\\.0\\.0\\.1|\\[::1\\])([:/]|$))[^\\u0000-\\u0020]*$"
    )]
    pub memberships_url: Option<String>,
}

/// A registered platform.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct Platform {
    /// Id.
    pub id: Uuid,
    /// Name.
    pub name: String,
    /// Issuer.
    pub issuer: String,
    /// Client id.
    pub client_id: String,
    /// Accepted deployment ids.
    pub deployment_ids: Vec<String>,
    /// OIDC authorisation endpoint.
    pub auth_url: String,
    /// Token endpoint.
    pub token_url: String,
    /// JWKS URL.
    pub jwks_url: String,
    /// AGS default.
    pub lineitems_url: Option<String>,
    /// NRPS default.
    pub memberships_url: Option<String>,
    /// Created.
    #[serde(with = "time::serde::rfc3339")]
    pub created_at: OffsetDateTime,
    /// Last changed.
    #[serde(with = "time::serde::rfc3339")]
    pub updated_at: OffsetDateTime,
}

/// Columns of [`Platform`], in order.
pub const COLUMNS: &str = "id, name, issuer, client_id, deployment_ids, auth_url, token_url, jwks_url, \
    lineitems_url, memberships_url, created_at, updated_at";

type Row = (
    Uuid,
    String,
    String,
    String,
    Vec<String>,
    String,
    String,
    String,
    Option<String>,
    Option<String>,
    OffsetDateTime,
    OffsetDateTime,
);

/// A row of `lti_platforms` selected with [`COLUMNS`].
pub fn from_row(r: Row) -> Platform {
    Platform {
        id: r.0,
        name: r.1,
        issuer: r.2,
        client_id: r.3,
        deployment_ids: r.4,
        auth_url: r.5,
        token_url: r.6,
        jwks_url: r.7,
        lineitems_url: r.8,
        memberships_url: r.9,
        created_at: r.10,
        updated_at: r.11,
    }
}

/// One platform by id.
pub async fn get(pool: &sqlx::PgPool, id: Uuid) -> Result<Option<Platform>, sqlx::Error> {
    let row: Option<Row> = sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM lti_platforms WHERE id = $1"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await?;
    Ok(row.map(from_row))
}

/// True for an https URL, or an http one on a loopback host (local platforms and tests): the
/// documented pattern (which it never widens) and a URL that parses with a host.
pub fn acceptable_url(u: &str) -> bool {
    let loopback = ["http://localhost", "http://127.0.0.1", "http://[::1]"]
        .iter()
        .any(|p| {
            u.strip_prefix(p)
                .is_some_and(|rest| rest.is_empty() || rest.starts_with([':', '/']))
        });
    if !(u.starts_with("https://") || loopback) || u.chars().any(|c| c <= ' ') {
        return false;
    }
    let Ok(url) = reqwest::Url::parse(u) else {
        return false;
    };
    match url.scheme() {
        "https" => url.host_str().is_some(),
        "http" => matches!(url.host_str(), Some("localhost" | "127.0.0.1" | "[::1]")),
        _ => false,
    }
}

fn check(s: &PlatformSettings) -> Result<PlatformSettings, ApiError> {
    let mut s = s.clone();
    s.name = s.name.trim().to_owned();
    if s.name.is_empty() || s.name.chars().count() > 200 || s.name.contains('\0') {
        return Err(ApiError::BadRequest("name: 1 to 200 characters".into()));
    }
    for (field, v) in [("issuer", &s.issuer), ("client_id", &s.client_id)] {
        if v.trim().is_empty() || v.chars().count() > 2000 || v.contains('\0') {
            return Err(ApiError::BadRequest(format!(
                "{field}: 1 to 2000 characters"
            )));
        }
    }
    s.deployment_ids.retain(|d| !d.trim().is_empty());
    if s.deployment_ids.is_empty() || s.deployment_ids.len() > 100 {
        return Err(ApiError::BadRequest(
            "deployment_ids: 1 to 100 non-empty ids".into(),
        ));
    }
    if s.deployment_ids
        .iter()
        .any(|d| d.len() > 255 || d.contains('\0'))
    {
        return Err(ApiError::BadRequest(
            "deployment_ids: at most 255 characters each".into(),
        ));
    }
    let urls = [
        ("auth_url", Some(&s.auth_url)),
        ("token_url", Some(&s.token_url)),
        ("jwks_url", Some(&s.jwks_url)),
        ("lineitems_url", s.lineitems_url.as_ref()),
        ("memberships_url", s.memberships_url.as_ref()),
    ];
    for (field, u) in urls {
        if let Some(u) = u
            && (u.chars().count() > 2000 || !acceptable_url(u))
        {
            return Err(ApiError::BadRequest(format!(
                "{field}: an https URL (http only on a loopback host)"
            )));
        }
    }
    Ok(s)
}

type PlatformQuery<'q> = sqlx::query::QueryAs<'q, sqlx::Postgres, Row, sqlx::postgres::PgArguments>;

/// Binds `$1` (the id) to `$10` (the settings) in the order of the insert and update statements.
fn bind_settings<'q>(q: PlatformQuery<'q>, id: Uuid, s: &'q PlatformSettings) -> PlatformQuery<'q> {
    q.bind(id)
        .bind(&s.name)
        .bind(&s.issuer)
        .bind(&s.client_id)
        .bind(&s.deployment_ids)
        .bind(&s.auth_url)
        .bind(&s.token_url)
        .bind(&s.jwks_url)
        .bind(&s.lineitems_url)
        .bind(&s.memberships_url)
}

fn unique_violation(e: sqlx::Error) -> ApiError {
    match &e {
        sqlx::Error::Database(d) if d.is_unique_violation() => {
            ApiError::Conflict("a platform with this issuer and client id is registered".into())
        }
        _ => ApiError::from(e),
    }
}

/// Register an LTI 1.3 platform (admin).
#[utoipa::path(post, path = "/api/admin/lti/platforms", tag = "lms", request_body = PlatformSettings,
    responses((status = 201, body = Platform, description = "Registered"), (status = 400),
        (status = 401), (status = 403),
        (status = 409, description = "This issuer and client id are registered already")))]
pub async fn create_platform(
    State(state): State<LtiState>,
    user: CurrentUser,
    ApiJson(req): ApiJson<PlatformSettings>,
) -> Result<(StatusCode, Json<Platform>), ApiError> {
    user.require(&[Role::Admin])?;
    let s = check(&req)?;
    let id = Uuid::new_v4();
    let mut tx = state.pool.begin().await?;
    let row: Row = bind_settings(
        sqlx::query_as(&format!(
        "INSERT INTO lti_platforms (id, name, issuer, client_id, deployment_ids, auth_url, token_url,
             jwks_url, lineitems_url, memberships_url)
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10) RETURNING {COLUMNS}"
    )),
        id,
        &s,
    )
    .fetch_one(&mut *tx)
    .await
    .map_err(unique_violation)?;
    audit(
        &mut *tx,
        Some(user.id),
        "lti_platform_created",
        "lti_platform",
        &id.to_string(),
        json!({ "issuer": s.issuer, "client_id": s.client_id }),
    )
    .await?;
    tx.commit().await?;
    Ok((StatusCode::CREATED, Json(from_row(row))))
}

/// List the registered LTI platforms (admin).
#[utoipa::path(get, path = "/api/admin/lti/platforms", tag = "lms",
    responses((status = 200, body = [Platform]), (status = 401), (status = 403)))]
pub async fn list_platforms(
    State(state): State<LtiState>,
    user: CurrentUser,
) -> Result<Json<Vec<Platform>>, ApiError> {
    user.require(&[Role::Admin])?;
    let rows: Vec<Row> = sqlx::query_as(&format!(
        "SELECT {COLUMNS} FROM lti_platforms ORDER BY created_at, id"
    ))
    .fetch_all(&state.pool)
    .await?;
    Ok(Json(rows.into_iter().map(from_row).collect()))
}

/// Change a registered LTI platform (admin): every setting is replaced.
#[utoipa::path(put, path = "/api/admin/lti/platforms/{id}", tag = "lms", request_body = PlatformSettings,
    params(("id" = Uuid, Path, description = "Platform id")),
    responses((status = 200, body = Platform, description = "Changed"), (status = 400),
        (status = 401), (status = 403), (status = 404),
        (status = 409, description = "Another platform has this issuer and client id")))]
pub async fn update_platform(
    State(state): State<LtiState>,
    user: CurrentUser,
    ApiPath(id): ApiPath<Uuid>,
    ApiJson(req): ApiJson<PlatformSettings>,
) -> Result<Json<Platform>, ApiError> {
    user.require(&[Role::Admin])?;
    let s = check(&req)?;
    let mut tx = state.pool.begin().await?;
    let row: Option<Row> = bind_settings(
        sqlx::query_as(&format!(
        "UPDATE lti_platforms SET name = $2, issuer = $3, client_id = $4, deployment_ids = $5,
             auth_url = $6, token_url = $7, jwks_url = $8, lineitems_url = $9, memberships_url = $10,
             updated_at = now()
         WHERE id = $1 RETURNING {COLUMNS}"
    )),
        id,
        &s,
    )
    .fetch_optional(&mut *tx)
    .await
    .map_err(unique_violation)?;
    let row = row.ok_or_else(|| ApiError::NotFound("LTI platform".into()))?;
    audit(
        &mut *tx,
        Some(user.id),
        "lti_platform_changed",
        "lti_platform",
        &id.to_string(),
        json!({ "issuer": s.issuer, "client_id": s.client_id }),
    )
    .await?;
    tx.commit().await?;
    // Keys cached for the old JWKS URL must not verify launches any more.
    state
        .platform_keys
        .lock()
        .expect("key cache")
        .retain(|(p, _), _| *p != id);
    Ok(Json(from_row(row)))
}

/// Delete a registered LTI platform (admin): its launches stop at once; the accounts and courses
/// it created stay.
#[utoipa::path(delete, path = "/api/admin/lti/platforms/{id}", tag = "lms",
    params(("id" = Uuid, Path, description = "Platform id")),
    responses((status = 204, description = "Deleted"), (status = 401), (status = 403),
        (status = 404)))]
pub async fn delete_platform(
    State(state): State<LtiState>,
    user: CurrentUser,
    ApiPath(id): ApiPath<Uuid>,
) -> Result<StatusCode, ApiError> {
    user.require(&[Role::Admin])?;
    let mut tx = state.pool.begin().await?;
    let done = sqlx::query("DELETE FROM lti_platforms WHERE id = $1")
        .bind(id)
        .execute(&mut *tx)
        .await?;
    if done.rows_affected() == 0 {
        return Err(ApiError::NotFound("LTI platform".into()));
    }
    audit(
        &mut *tx,
        Some(user.id),
        "lti_platform_deleted",
        "lti_platform",
        &id.to_string(),
        json!({}),
    )
    .await?;
    tx.commit().await?;
    state
        .platform_keys
        .lock()
        .expect("key cache")
        .retain(|(p, _), _| *p != id);
    Ok(StatusCode::NO_CONTENT)
}
