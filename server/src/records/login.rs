//! Login, logout, the caller's session, and TOTP enrolment: the handlers that open, describe and
//! close the sessions [`super::auth`] checks.
//!
//! * Login always issues a new token and deletes the session presented with it (rotation:
//!   a fixed session id cannot be carried across login).
//! * Failed logins are counted per client and e-mail together in the database (throttled after
//!   `login_max_failures` within the window, before any password check), so a client that
//!   guesses cannot lock the account for anyone else (OWASP Authentication Cheat Sheet, "Login
//!   Throttling"). Only a distributed attack, [`ACCOUNT_WIDE_FACTOR`] times that many failures
//!   on one account from all clients together, throttles the account everywhere. All
//!   `/api/auth/*` requests also pass a per-client token bucket.

/// An account is throttled for every client once all clients together failed this many times
/// its per-client limit within the window. Simulator choice: a distributed guesser is slowed
/// (with the default of 5, after 100 failures in 15 minutes) while one client's mistakes never
/// lock a real user out.
pub const ACCOUNT_WIDE_FACTOR: i64 = 20;

use axum::extract::State;
use axum::http::header::SET_COOKIE;
use axum::http::{HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::{
    CSRF_COOKIE, CurrentUser, Role, SESSION_COOKIE, UserInfo, cookie_value, random_token, sha256,
};
use super::extract::{ApiJson, ClientKey, limit};
use super::history::audit;
use super::state::RecordsState;
use super::{password, totp};
use crate::error::ApiError;

/// Login request.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct LoginRequest {
    /// E-mail (case-insensitive).
    #[schema(
        max_length = 320,
        pattern = "^[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+@[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+$"
    )]
    pub email: String,
    /// Password (accounts have passwords of 12 to 256 characters).
    #[schema(min_length = 1, max_length = 256, pattern = "^[^\\u0000]*$")]
    pub password: String,
    /// Current TOTP code (six digits); required when the account has TOTP enabled.
    #[serde(default)]
    #[schema(pattern = "^[0-9]{6}$")]
    pub totp_code: Option<String>,
}

/// The caller's session.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct SessionInfo {
    /// The account.
    pub user: UserInfo,
    /// Send this in `X-CSRF-Token` on every write.
    pub csrf_token: String,
    /// The session was opened with a TOTP code.
    pub mfa: bool,
    /// Whether the account has TOTP enabled.
    pub totp_enabled: bool,
    /// Idle expiry in seconds.
    pub idle_timeout_s: u64,
}

fn cookie(
    state: &RecordsState,
    name: &str,
    value: &str,
    http_only: bool,
    max_age_s: u64,
) -> HeaderValue {
    let mut c = format!("{name}={value}; Path=/; SameSite=Strict; Max-Age={max_age_s}");
    if http_only {
        c.push_str("; HttpOnly");
    }
    if state.config.cookie_secure {
        c.push_str("; Secure");
    }
    HeaderValue::from_str(&c).expect("cookie values are hex")
}

async fn totp_enabled(state: &RecordsState, user: Uuid) -> Result<bool, ApiError> {
    Ok(
        sqlx::query_scalar("SELECT totp_secret IS NOT NULL FROM users WHERE id = $1")
            .bind(user)
            .fetch_one(&state.pool)
            .await?,
    )
}

type LoginRow = (
    Uuid,
    String,
    String,
    String,
    bool,
    Option<Vec<u8>>,
    Option<i64>,
    bool,
);

/// Log in: returns the session and sets the session and CSRF cookies.
#[utoipa::path(post, path = "/api/auth/login", tag = "auth", request_body = LoginRequest,
    responses(
        (status = 200, description = "Logged in; cookies set", body = SessionInfo),
        (status = 400, description = "Malformed request"),
        (status = 401, description = "Wrong e-mail, password or TOTP code, or a TOTP code is required"),
        (status = 429, description = "Too many attempts (per client or per account)"),
    ))]
pub async fn login(
    State(state): State<RecordsState>,
    key: ClientKey,
    headers: HeaderMap,
    ApiJson(req): ApiJson<LoginRequest>,
) -> Result<Response, ApiError> {
    limit(&state, &key)?;
    let email = req.email.trim().to_lowercase();
    if email.is_empty()
        || email.len() > 320
        || req.password.len() > 4 * password::MAX_PASSWORD_CHARS
    {
        return Err(ApiError::BadRequest(
            "email and password are required (and not absurdly long)".into(),
        ));
    }
    let cfg = &state.config;
    let window_s = cfg.login_failure_window.as_secs_f64();
    sqlx::query("DELETE FROM login_failures WHERE at < now() - make_interval(secs => $1)")
        .bind(window_s)
        .execute(&state.pool)
        .await?;
    let (from_client, all): (i64, i64) = sqlx::query_as(
        "SELECT count(*) FILTER (WHERE client = $2), count(*) FROM login_failures WHERE email = $1",
    )
    .bind(&email)
    .bind(&key.0)
    .fetch_one(&state.pool)
    .await?;
    let max = i64::from(cfg.login_max_failures);
    if from_client >= max || all >= max * ACCOUNT_WIDE_FACTOR {
        return Err(ApiError::TooManyRequests(
            cfg.login_failure_window.as_secs(),
        ));
    }
    let row: Option<LoginRow> = sqlx::query_as(
        "SELECT id, display_name, role, password_hash, is_demo, totp_secret, totp_last_step, disabled_at IS NOT NULL
         FROM users WHERE email = $1",
    )
    .bind(&email)
    .fetch_optional(&state.pool)
    .await?;
    let known = row.as_ref().map(|r| r.3.clone());
    let (decoy, cost, pw) = (state.decoy_hash.clone(), cfg.argon2, req.password.clone());
    let ok = tokio::task::spawn_blocking(move || {
        let hash =
            known.unwrap_or_else(|| decoy.get_or_init(|| password::decoy_hash(cost)).clone());
        password::verify_password(&pw, &hash)
    })
    .await
    .map_err(|e| ApiError::Internal(format!("password check: {e}")))?;
    let client = key.0.clone();
    let fail = |state: RecordsState, email: String, message: &'static str| async move {
        sqlx::query("INSERT INTO login_failures (email, client) VALUES ($1, $2)")
            .bind(&email)
            .bind(&client)
            .execute(&state.pool)
            .await?;
        Err::<Response, ApiError>(ApiError::InvalidCredentials(message.into()))
    };
    let Some((id, display_name, role, _, is_demo, totp_secret, totp_last_step, disabled)) =
        row.filter(|_| ok)
    else {
        return fail(state, email, "wrong e-mail or password").await;
    };
    // Said only to someone who knows the password (no account enumeration).
    if disabled {
        return Err(ApiError::Forbidden(
            "this account is disabled; ask an administrator".into(),
        ));
    }
    let mut mfa = false;
    if let Some(secret) = totp_secret {
        let Some(code) = req.totp_code.as_deref() else {
            // Not a failure: the password was right and the client must now ask for the code.
            return Err(ApiError::TotpRequired);
        };
        let Some(step) = totp::verify(&secret, code, totp::unix_now(), totp_last_step) else {
            return fail(state, email, "wrong or already used TOTP code").await;
        };
        let claimed = sqlx::query("UPDATE users SET totp_last_step = $2 WHERE id = $1 AND (totp_last_step IS NULL OR totp_last_step < $2)")
            .bind(id)
            .bind(step)
            .execute(&state.pool)
            .await?;
        if claimed.rows_affected() != 1 {
            return fail(state, email, "wrong or already used TOTP code").await;
        }
        mfa = true;
    }
    let role = Role::parse(&role)
        .ok_or_else(|| ApiError::Internal(format!("user {id} has unknown role")))?;
    let mut tx = state.pool.begin().await?;
    sqlx::query("DELETE FROM login_failures WHERE email = $1 AND client = $2")
        .bind(&email)
        .bind(&key.0)
        .execute(&mut *tx)
        .await?;
    let opened = open_session(&state, &mut tx, id, mfa, &headers).await?;
    audit(
        &mut *tx,
        Some(id),
        "login",
        "user",
        &id.to_string(),
        serde_json::json!({ "mfa": mfa }),
    )
    .await?;
    tx.commit().await?;
    let info = SessionInfo {
        user: UserInfo {
            id,
            email,
            display_name,
            role,
            is_demo,
            disabled: false,
        },
        csrf_token: opened.csrf.clone(),
        mfa,
        totp_enabled: mfa,
        idle_timeout_s: cfg.session_idle.as_secs(),
    };
    let mut resp = axum::Json(info).into_response();
    opened.set_cookies(resp.headers_mut());
    Ok(resp)
}

/// A session just opened by [`open_session`]: its CSRF token and its two cookies.
pub struct OpenedSession {
    /// The session's CSRF token (also in the readable cookie).
    pub csrf: String,
    cookies: [HeaderValue; 2],
}

impl OpenedSession {
    /// Appends the session and CSRF cookies to a response's headers.
    pub fn set_cookies(self, headers: &mut HeaderMap) {
        for c in self.cookies {
            headers.append(SET_COOKIE, c);
        }
    }
}

/// Opens a new session for `user` in the caller's transaction: deletes the account's expired
/// sessions and the session presented in `headers` (rotation), stores the new one and returns
/// its cookies. Every way in (password login, an LTI launch) goes through here.
pub async fn open_session(
    state: &RecordsState,
    tx: &mut sqlx::PgConnection,
    user: Uuid,
    mfa: bool,
    headers: &HeaderMap,
) -> Result<OpenedSession, ApiError> {
    let cfg = &state.config;
    let token = random_token();
    let csrf = random_token();
    // Expired sessions of this account go now rather than lingering until a sweep.
    sqlx::query(
        "DELETE FROM auth_sessions WHERE user_id = $1
           AND (expires_at <= now() OR last_seen_at <= now() - make_interval(secs => $2))",
    )
    .bind(user)
    .bind(cfg.session_idle.as_secs_f64())
    .execute(&mut *tx)
    .await?;
    if let Some(old) = cookie_value(headers, SESSION_COOKIE) {
        sqlx::query("DELETE FROM auth_sessions WHERE token_sha256 = $1")
            .bind(sha256(old))
            .execute(&mut *tx)
            .await?;
    }
    sqlx::query(
        "INSERT INTO auth_sessions (token_sha256, user_id, csrf_token, mfa, expires_at)
         VALUES ($1, $2, $3, $4, now() + make_interval(secs => $5))",
    )
    .bind(sha256(&token))
    .bind(user)
    .bind(&csrf)
    .bind(mfa)
    .bind(cfg.session_absolute.as_secs_f64())
    .execute(&mut *tx)
    .await?;
    let max_age = cfg.session_absolute.as_secs();
    Ok(OpenedSession {
        cookies: [
            cookie(state, SESSION_COOKIE, &token, true, max_age),
            cookie(state, CSRF_COOKIE, &csrf, false, max_age),
        ],
        csrf,
    })
}

/// Log out: deletes the session and clears the cookies.
#[utoipa::path(post, path = "/api/auth/logout", tag = "auth",
    responses((status = 204, description = "Logged out"), (status = 401), (status = 403, description = "CSRF token missing")))]
pub async fn logout(
    State(state): State<RecordsState>,
    user: CurrentUser,
) -> Result<Response, ApiError> {
    sqlx::query("DELETE FROM auth_sessions WHERE token_sha256 = $1")
        .bind(&user.token_sha256)
        .execute(&state.pool)
        .await?;
    let mut resp = StatusCode::NO_CONTENT.into_response();
    resp.headers_mut()
        .append(SET_COOKIE, cookie(&state, SESSION_COOKIE, "", true, 0));
    resp.headers_mut()
        .append(SET_COOKIE, cookie(&state, CSRF_COOKIE, "", false, 0));
    Ok(resp)
}

/// The caller's session and account.
#[utoipa::path(get, path = "/api/auth/me", tag = "auth",
    responses((status = 200, body = SessionInfo), (status = 401)))]
pub async fn me(
    State(state): State<RecordsState>,
    user: CurrentUser,
) -> Result<axum::Json<SessionInfo>, ApiError> {
    let totp_enabled = totp_enabled(&state, user.id).await?;
    Ok(axum::Json(SessionInfo {
        user: UserInfo {
            id: user.id,
            email: user.email,
            display_name: user.display_name,
            role: user.role,
            is_demo: user.is_demo,
            disabled: false,
        },
        csrf_token: user.csrf_token,
        mfa: user.mfa,
        totp_enabled,
        idle_timeout_s: state.config.session_idle.as_secs(),
    }))
}

/// A TOTP secret to add to an authenticator app.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct TotpEnrolment {
    /// `otpauth://totp/...` URL (for a QR code).
    pub otpauth_url: String,
    /// The secret in base32, for typing in.
    pub secret_base32: String,
}

/// Start TOTP enrolment (faculty and admin): a new pending secret, active after confirmation.
#[utoipa::path(post, path = "/api/auth/totp/enroll", tag = "auth",
    responses((status = 200, body = TotpEnrolment), (status = 401), (status = 403), (status = 409, description = "TOTP already enabled"), (status = 429)))]
pub async fn totp_enroll(
    State(state): State<RecordsState>,
    key: ClientKey,
    user: CurrentUser,
) -> Result<axum::Json<TotpEnrolment>, ApiError> {
    limit(&state, &key)?;
    user.require(&[Role::Faculty, Role::Admin])?;
    let secret = totp::new_secret();
    let done =
        sqlx::query("UPDATE users SET totp_pending = $2 WHERE id = $1 AND totp_secret IS NULL")
            .bind(user.id)
            .bind(&secret)
            .execute(&state.pool)
            .await?;
    if done.rows_affected() == 0 {
        return Err(ApiError::Conflict(
            "TOTP is already enabled for this account".into(),
        ));
    }
    let (otpauth_url, secret_base32) = totp::enrolment(&secret, &user.email)
        .ok_or_else(|| ApiError::Internal("building the TOTP URL".into()))?;
    Ok(axum::Json(TotpEnrolment {
        otpauth_url,
        secret_base32,
    }))
}

/// A TOTP code.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TotpCode {
    /// Six digits from the authenticator app.
    #[schema(pattern = "^[0-9]{6}$")]
    pub code: String,
}

/// Confirm TOTP enrolment with a current code; the current session counts as TOTP-verified.
#[utoipa::path(post, path = "/api/auth/totp/confirm", tag = "auth", request_body = TotpCode,
    responses((status = 204, description = "TOTP enabled"), (status = 400, description = "Wrong code"), (status = 401), (status = 403), (status = 409, description = "No enrolment pending"), (status = 429)))]
pub async fn totp_confirm(
    State(state): State<RecordsState>,
    key: ClientKey,
    user: CurrentUser,
    ApiJson(req): ApiJson<TotpCode>,
) -> Result<StatusCode, ApiError> {
    limit(&state, &key)?;
    user.require(&[Role::Faculty, Role::Admin])?;
    let pending: Option<Vec<u8>> =
        sqlx::query_scalar("SELECT totp_pending FROM users WHERE id = $1 AND totp_secret IS NULL")
            .bind(user.id)
            .fetch_optional(&state.pool)
            .await?
            .flatten();
    let pending = pending.ok_or_else(|| {
        ApiError::Conflict("no TOTP enrolment is pending (start one first)".into())
    })?;
    let step = totp::verify(&pending, &req.code, totp::unix_now(), None)
        .ok_or_else(|| ApiError::BadRequest("wrong TOTP code".into()))?;
    let mut tx = state.pool.begin().await?;
    let done = sqlx::query(
        "UPDATE users SET totp_secret = totp_pending, totp_pending = NULL, totp_last_step = $2
         WHERE id = $1 AND totp_secret IS NULL AND totp_pending = $3",
    )
    .bind(user.id)
    .bind(step)
    .bind(&pending)
    .execute(&mut *tx)
    .await?;
    if done.rows_affected() != 1 {
        return Err(ApiError::Conflict(
            "the enrolment changed meanwhile; start again".into(),
        ));
    }
    sqlx::query("UPDATE auth_sessions SET mfa = TRUE WHERE token_sha256 = $1")
        .bind(&user.token_sha256)
        .execute(&mut *tx)
        .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "totp_enabled",
        "user",
        &user.id.to_string(),
        serde_json::json!({}),
    )
    .await?;
    tx.commit().await?;
    Ok(StatusCode::NO_CONTENT)
}
