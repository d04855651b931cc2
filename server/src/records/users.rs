//! Accounts: creation (admin, the `create-admin` command, demo accounts) and listing.

use axum::extract::State;
use axum::http::StatusCode;
use serde::Deserialize;
use sqlx::PgPool;
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::{CurrentUser, Role, UserInfo};
use super::config::Argon2Cost;
use super::extract::ApiJson;
use super::history::audit;
use super::password;
use super::state::RecordsState;
use crate::error::ApiError;

/// Why an account could not be created.
#[derive(Debug, thiserror::Error)]
pub enum CreateUserError {
    /// A field is invalid (message safe to show).
    #[error("{0}")]
    Invalid(String),
    /// The e-mail is taken.
    #[error("an account with e-mail {0} already exists")]
    EmailTaken(String),
    /// Database failure.
    #[error("database error: {0}")]
    Database(#[from] sqlx::Error),
    /// Hashing failure.
    #[error("password hashing failed: {0}")]
    Hash(String),
}

impl From<CreateUserError> for ApiError {
    fn from(e: CreateUserError) -> ApiError {
        match e {
            CreateUserError::Invalid(m) => ApiError::BadRequest(m),
            CreateUserError::EmailTaken(_) => ApiError::Conflict(e.to_string()),
            CreateUserError::Database(d) => ApiError::Database(d),
            CreateUserError::Hash(h) => ApiError::Internal(h),
        }
    }
}

/// Normalizes and checks an e-mail address (lower case, one `@`, no spaces, at most 320 bytes).
pub fn normalize_email(email: &str) -> Result<String, CreateUserError> {
    let e = email.trim().to_lowercase();
    let ok = e.len() <= 320
        && !e.chars().any(char::is_whitespace)
        && e.split_once('@').is_some_and(|(local, domain)| {
            !local.is_empty() && !domain.is_empty() && !domain.contains('@')
        });
    if ok {
        Ok(e)
    } else {
        Err(CreateUserError::Invalid(format!(
            "{email:?} is not an e-mail address"
        )))
    }
}

/// Creates an account. Used by the API, the `create-admin` command and the demo accounts.
pub async fn create_user(
    pool: &PgPool,
    cost: Argon2Cost,
    email: &str,
    display_name: &str,
    role: Role,
    password_plain: &str,
    is_demo: bool,
) -> Result<UserInfo, CreateUserError> {
    let email = normalize_email(email)?;
    let display_name = display_name.trim().to_owned();
    if display_name.is_empty() || display_name.chars().count() > 200 {
        return Err(CreateUserError::Invalid(
            "display_name must have 1 to 200 characters".into(),
        ));
    }
    password::check_new_password(password_plain)
        .map_err(|e| CreateUserError::Invalid(e.to_string()))?;
    let pw = password_plain.to_owned();
    let hash = tokio::task::spawn_blocking(move || password::hash_password(&pw, cost))
        .await
        .map_err(|e| CreateUserError::Hash(e.to_string()))?
        .map_err(|e| CreateUserError::Hash(e.to_string()))?;
    let id = Uuid::new_v4();
    let inserted = sqlx::query(
        "INSERT INTO users (id, email, display_name, role, password_hash, is_demo) VALUES ($1, $2, $3, $4, $5, $6)
         ON CONFLICT (email) DO NOTHING",
    )
    .bind(id)
    .bind(&email)
    .bind(&display_name)
    .bind(role.as_str())
    .bind(&hash)
    .bind(is_demo)
    .execute(pool)
    .await?;
    if inserted.rows_affected() == 0 {
        return Err(CreateUserError::EmailTaken(email));
    }
    Ok(UserInfo {
        id,
        email,
        display_name,
        role,
        is_demo,
        disabled: false,
    })
}

/// The `server create-admin` command: creates an admin account. The password comes from the
/// caller (the binary reads it from `PAINSIM_ADMIN_PASSWORD` or standard input, never argv).
pub async fn create_admin(
    pool: &PgPool,
    cost: Argon2Cost,
    email: &str,
    password_plain: &str,
) -> Result<UserInfo, CreateUserError> {
    let user = create_user(
        pool,
        cost,
        email,
        "Administrator",
        Role::Admin,
        password_plain,
        false,
    )
    .await?;
    audit(
        pool,
        None,
        "admin_created_by_command",
        "user",
        &user.id.to_string(),
        serde_json::json!({ "email": user.email }),
    )
    .await?;
    Ok(user)
}

/// A new account.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewUser {
    /// E-mail (stored in lower case, unique).
    #[schema(
        max_length = 320,
        pattern = "^[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+@[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+$"
    )]
    pub email: String,
    /// Display name (1 to 200 characters, not blank: it is stored trimmed).
    #[schema(
        min_length = 1,
        max_length = 200,
        pattern = "^[^\\u0000]*[^\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000][^\\u0000]*$"
    )]
    pub display_name: String,
    /// Role.
    pub role: Role,
    /// Initial password (12 to 256 characters).
    #[schema(min_length = 12, max_length = 256, pattern = "^[^\\u0000]*$")]
    pub password: String,
}

/// Create an account (admin).
#[utoipa::path(post, path = "/api/users", tag = "users", request_body = NewUser,
    responses((status = 201, body = UserInfo), (status = 400), (status = 401), (status = 403), (status = 409, description = "E-mail taken")))]
pub async fn create_user_handler(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiJson(req): ApiJson<NewUser>,
) -> Result<(StatusCode, axum::Json<UserInfo>), ApiError> {
    user.require(&[Role::Admin])?;
    let created = create_user(
        &state.pool,
        state.config.argon2,
        &req.email,
        &req.display_name,
        req.role,
        &req.password,
        false,
    )
    .await?;
    audit(
        &state.pool,
        Some(user.id),
        "user_created",
        "user",
        &created.id.to_string(),
        serde_json::json!({ "role": created.role.as_str() }),
    )
    .await?;
    Ok((StatusCode::CREATED, axum::Json(created)))
}

/// Every account (admin).
#[utoipa::path(get, path = "/api/users", tag = "users",
    responses((status = 200, body = Vec<UserInfo>), (status = 401), (status = 403)))]
pub async fn list_users(
    State(state): State<RecordsState>,
    user: CurrentUser,
) -> Result<axum::Json<Vec<UserInfo>>, ApiError> {
    user.require(&[Role::Admin])?;
    let rows: Vec<(Uuid, String, String, String, bool, bool)> = sqlx::query_as(
        "SELECT id, email, display_name, role, is_demo, disabled_at IS NOT NULL FROM users ORDER BY email",
    )
    .fetch_all(&state.pool)
    .await?;
    Ok(axum::Json(
        rows.into_iter()
            .filter_map(|(id, email, display_name, role, is_demo, disabled)| {
                Some(UserInfo {
                    id,
                    email,
                    display_name,
                    role: Role::parse(&role)?,
                    is_demo,
                    disabled,
                })
            })
            .collect(),
    ))
}
