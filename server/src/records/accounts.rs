//! Account management: a user changes their own password; an admin disables or enables an
//! account and starts a password reset that the user completes with a one-time token.
//!
//! * Changing a password needs the current one (a stolen session alone cannot take the account
//!   over); a wrong one counts as a failed login of that client and e-mail, so the login throttle
//!   bounds guessing here too. Every other session of the account is revoked.
//! * Disabling revokes every session at once and refuses logins (said only after a correct
//!   password); listeners of [`RecordsState::revocations`] close what the account holds open
//!   (live simulation sessions). An admin cannot disable their own account, so the last admin
//!   cannot lock everybody out by accident.
//! * A reset token is 32 random bytes (hex), shown once to the admin who started it, stored only
//!   as its SHA-256, valid for [`RESET_TOKEN_TTL`] and once; starting a new reset voids older
//!   unused tokens. Completing one sets the password, revokes every session and clears the
//!   account's failed logins.

use std::time::Duration;

use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::{CurrentUser, Role, random_token, sha256};
use super::extract::{ApiJson, ApiPath, ClientKey, limit};
use super::history::audit;
use super::password;
use super::state::RecordsState;
use crate::error::ApiError;

/// How long a password-reset token is valid. Our choice (OWASP Forgot Password Cheat Sheet asks
/// for a short expiry): a day covers handing it over out of band, e.g. at the next teaching day.
pub const RESET_TOKEN_TTL: Duration = Duration::from_secs(24 * 3600);

/// Hashes a new password after checking it.
async fn new_hash(state: &RecordsState, new_password: &str) -> Result<String, ApiError> {
    password::check_new_password(new_password)
        .map_err(|m| ApiError::BadRequest(format!("new_password: {m}")))?;
    let (pw, cost) = (new_password.to_owned(), state.config.argon2);
    tokio::task::spawn_blocking(move || password::hash_password(&pw, cost))
        .await
        .map_err(|e| ApiError::Internal(format!("password hashing: {e}")))?
        .map_err(|e| ApiError::Internal(format!("password hashing: {e}")))
}

/// Change of one's own password.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PasswordChange {
    /// The current password (accounts have passwords of 12 to 256 characters).
    #[schema(min_length = 1, max_length = 256, pattern = "^[^\\u0000]*$")]
    pub current_password: String,
    /// The new password (12 to 256 characters).
    #[schema(min_length = 12, max_length = 256, pattern = "^[^\\u0000]*$")]
    pub new_password: String,
}

/// Change one's own password: needs the current one; every other session of the account is
/// revoked.
#[utoipa::path(post, path = "/api/auth/password", tag = "auth", request_body = PasswordChange,
    responses((status = 204, description = "Changed; other sessions revoked"), (status = 400),
        (status = 401), (status = 403, description = "Wrong current password, or CSRF token missing"),
        (status = 429)))]
pub async fn change_password(
    State(state): State<RecordsState>,
    key: ClientKey,
    user: CurrentUser,
    ApiJson(req): ApiJson<PasswordChange>,
) -> Result<StatusCode, ApiError> {
    limit(&state, &key)?;
    if req.current_password.len() > 4 * password::MAX_PASSWORD_CHARS {
        return Err(ApiError::BadRequest(
            "current_password is absurdly long".into(),
        ));
    }
    let max = i64::from(state.config.login_max_failures);
    let failures: i64 = sqlx::query_scalar(
        "SELECT count(*) FROM login_failures WHERE email = $1 AND client = $2
           AND at > now() - make_interval(secs => $3)",
    )
    .bind(&user.email)
    .bind(&key.0)
    .bind(state.config.login_failure_window.as_secs_f64())
    .fetch_one(&state.pool)
    .await?;
    if failures >= max {
        return Err(ApiError::TooManyRequests(
            state.config.login_failure_window.as_secs(),
        ));
    }
    let hash: String = sqlx::query_scalar("SELECT password_hash FROM users WHERE id = $1")
        .bind(user.id)
        .fetch_one(&state.pool)
        .await?;
    let current = req.current_password.clone();
    let ok = tokio::task::spawn_blocking(move || password::verify_password(&current, &hash))
        .await
        .map_err(|e| ApiError::Internal(format!("password check: {e}")))?;
    if !ok {
        sqlx::query("INSERT INTO login_failures (email, client) VALUES ($1, $2)")
            .bind(&user.email)
            .bind(&key.0)
            .execute(&state.pool)
            .await?;
        return Err(ApiError::Forbidden("current_password is wrong".into()));
    }
    let hash = new_hash(&state, &req.new_password).await?;
    let mut tx = state.pool.begin().await?;
    sqlx::query("UPDATE users SET password_hash = $2 WHERE id = $1")
        .bind(user.id)
        .bind(&hash)
        .execute(&mut *tx)
        .await?;
    let revoked =
        sqlx::query("DELETE FROM auth_sessions WHERE user_id = $1 AND token_sha256 <> $2")
            .bind(user.id)
            .bind(&user.token_sha256)
            .execute(&mut *tx)
            .await?
            .rows_affected();
    audit(
        &mut *tx,
        Some(user.id),
        "password_changed",
        "user",
        &user.id.to_string(),
        serde_json::json!({ "other_sessions_revoked": revoked }),
    )
    .await?;
    tx.commit().await?;
    Ok(StatusCode::NO_CONTENT)
}

/// The account an admin acts on, locked for the change; 404 when there is none.
async fn target_account(
    tx: &mut sqlx::PgConnection,
    user_id: Uuid,
) -> Result<(String, bool), ApiError> {
    sqlx::query_as("SELECT email, disabled_at IS NOT NULL FROM users WHERE id = $1 FOR UPDATE")
        .bind(user_id)
        .fetch_optional(&mut *tx)
        .await?
        .ok_or_else(|| ApiError::NotFound("user".into()))
}

/// What an admin's account action did.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct AccountState {
    /// The account.
    pub user_id: Uuid,
    /// Whether it is disabled now.
    pub disabled: bool,
    /// Sessions revoked by this action.
    pub sessions_revoked: u64,
}

/// Disable an account (admin): revokes every session of it at once and refuses its logins until
/// it is enabled again. Admins cannot disable their own account.
#[utoipa::path(post, path = "/api/users/{user_id}/disable", tag = "users",
    params(("user_id" = Uuid, Path, description = "Account id")),
    responses((status = 200, body = AccountState), (status = 400), (status = 401),
        (status = 403, description = "Not an admin, or CSRF token missing"), (status = 404),
        (status = 409, description = "One's own account")))]
pub async fn disable_user(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(user_id): ApiPath<Uuid>,
) -> Result<axum::Json<AccountState>, ApiError> {
    user.require(&[Role::Admin])?;
    if user_id == user.id {
        return Err(ApiError::Conflict(
            "admins cannot disable their own account".into(),
        ));
    }
    let done = set_disabled(&state, &user, user_id, true).await?;
    // Nobody listening (no dispatch) is fine: there is then nothing else to close.
    let _ = state.revocations.send(user_id);
    Ok(axum::Json(done))
}

/// Enable a disabled account again (admin).
#[utoipa::path(post, path = "/api/users/{user_id}/enable", tag = "users",
    params(("user_id" = Uuid, Path, description = "Account id")),
    responses((status = 200, body = AccountState), (status = 400), (status = 401),
        (status = 403, description = "Not an admin, or CSRF token missing"), (status = 404)))]
pub async fn enable_user(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(user_id): ApiPath<Uuid>,
) -> Result<axum::Json<AccountState>, ApiError> {
    user.require(&[Role::Admin])?;
    Ok(axum::Json(
        set_disabled(&state, &user, user_id, false).await?,
    ))
}

/// Disables (revoking every session) or enables an account, with its audit entry.
async fn set_disabled(
    state: &RecordsState,
    admin: &CurrentUser,
    user_id: Uuid,
    disable: bool,
) -> Result<AccountState, ApiError> {
    let mut tx = state.pool.begin().await?;
    let (email, was_disabled) = target_account(&mut tx, user_id).await?;
    sqlx::query(
        "UPDATE users SET disabled_at = CASE WHEN $2 THEN COALESCE(disabled_at, now()) END WHERE id = $1",
    )
    .bind(user_id)
    .bind(disable)
    .execute(&mut *tx)
    .await?;
    let mut revoked = 0;
    if disable {
        revoked = sqlx::query("DELETE FROM auth_sessions WHERE user_id = $1")
            .bind(user_id)
            .execute(&mut *tx)
            .await?
            .rows_affected();
    }
    audit(
        &mut *tx,
        Some(admin.id),
        if disable { "user_disabled" } else { "user_enabled" },
        "user",
        &user_id.to_string(),
        serde_json::json!({ "email": email, "was_disabled": was_disabled, "sessions_revoked": revoked }),
    )
    .await?;
    tx.commit().await?;
    Ok(AccountState {
        user_id,
        disabled: disable,
        sessions_revoked: revoked,
    })
}

/// A password-reset token, shown once.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct PasswordResetStarted {
    /// The account.
    pub user_id: Uuid,
    /// Hand this to the user out of band; they set a new password with it at
    /// `POST /api/auth/password-reset`. It is not stored and cannot be shown again.
    pub reset_token: String,
    /// When it stops working.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub expires_at: OffsetDateTime,
}

/// Start a password reset for an account (admin): a one-time token, valid for a day, that the
/// user exchanges for a new password. Older unused tokens of the account stop working.
#[utoipa::path(post, path = "/api/users/{user_id}/password-reset", tag = "users",
    params(("user_id" = Uuid, Path, description = "Account id")),
    responses((status = 201, body = PasswordResetStarted), (status = 400), (status = 401),
        (status = 403, description = "Not an admin, or CSRF token missing"), (status = 404)))]
pub async fn start_password_reset(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(user_id): ApiPath<Uuid>,
) -> Result<(StatusCode, axum::Json<PasswordResetStarted>), ApiError> {
    user.require(&[Role::Admin])?;
    let token = random_token();
    let mut tx = state.pool.begin().await?;
    let (email, _) = target_account(&mut tx, user_id).await?;
    sqlx::query("DELETE FROM password_resets WHERE user_id = $1 AND used_at IS NULL")
        .bind(user_id)
        .execute(&mut *tx)
        .await?;
    let expires_at: OffsetDateTime = sqlx::query_scalar(
        "INSERT INTO password_resets (token_sha256, user_id, created_by, expires_at)
         VALUES ($1, $2, $3, now() + make_interval(secs => $4)) RETURNING expires_at",
    )
    .bind(sha256(&token))
    .bind(user_id)
    .bind(user.id)
    .bind(RESET_TOKEN_TTL.as_secs_f64())
    .fetch_one(&mut *tx)
    .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "password_reset_started",
        "user",
        &user_id.to_string(),
        serde_json::json!({ "email": email, "expires_at": expires_at.unix_timestamp() }),
    )
    .await?;
    tx.commit().await?;
    Ok((
        StatusCode::CREATED,
        axum::Json(PasswordResetStarted {
            user_id,
            reset_token: token,
            expires_at,
        }),
    ))
}

/// Completing a reset.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct PasswordResetCompletion {
    /// The token the admin handed over (64 hex digits).
    #[schema(min_length = 64, max_length = 64, pattern = "^[0-9a-f]{64}$")]
    pub reset_token: String,
    /// The new password (12 to 256 characters).
    #[schema(min_length = 12, max_length = 256, pattern = "^[^\\u0000]*$")]
    pub new_password: String,
}

/// Set a new password with a reset token (no login needed): the token is used up, every session
/// of the account is revoked, and its failed logins are forgiven.
#[utoipa::path(post, path = "/api/auth/password-reset", tag = "auth", request_body = PasswordResetCompletion,
    responses((status = 204, description = "Password set; log in with it"), (status = 400),
        (status = 401, description = "Unknown, used or expired token"), (status = 429)))]
pub async fn complete_password_reset(
    State(state): State<RecordsState>,
    key: ClientKey,
    ApiJson(req): ApiJson<PasswordResetCompletion>,
) -> Result<StatusCode, ApiError> {
    limit(&state, &key)?;
    let t = req.reset_token.trim();
    if t.len() != 64
        || !t
            .bytes()
            .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())
    {
        return Err(ApiError::BadRequest(
            "reset_token must be 64 lower-case hex digits".into(),
        ));
    }
    let hash = new_hash(&state, &req.new_password).await?;
    let mut tx = state.pool.begin().await?;
    let claimed: Option<(Uuid, String)> = sqlx::query_as(
        "UPDATE password_resets p SET used_at = now() FROM users u
         WHERE p.token_sha256 = $1 AND p.used_at IS NULL AND p.expires_at > now() AND u.id = p.user_id
         RETURNING u.id, u.email",
    )
    .bind(sha256(t))
    .fetch_optional(&mut *tx)
    .await?;
    let Some((user_id, email)) = claimed else {
        return Err(ApiError::InvalidCredentials(
            "the reset token is unknown, used or expired; ask an administrator for a new one"
                .into(),
        ));
    };
    sqlx::query("UPDATE users SET password_hash = $2 WHERE id = $1")
        .bind(user_id)
        .bind(&hash)
        .execute(&mut *tx)
        .await?;
    let revoked = sqlx::query("DELETE FROM auth_sessions WHERE user_id = $1")
        .bind(user_id)
        .execute(&mut *tx)
        .await?
        .rows_affected();
    sqlx::query("DELETE FROM login_failures WHERE email = $1")
        .bind(&email)
        .execute(&mut *tx)
        .await?;
    audit(
        &mut *tx,
        Some(user_id),
        "password_reset_completed",
        "user",
        &user_id.to_string(),
        serde_json::json!({ "sessions_revoked": revoked }),
    )
    .await?;
    tx.commit().await?;
    let _ = state.revocations.send(user_id);
    Ok(StatusCode::NO_CONTENT)
}
