//! Authentication of the caller: server-side sessions in PostgreSQL, cookies, CSRF; the
//! [`CurrentUser`] extractor every handler uses. Login, logout and TOTP enrolment (the handlers
//! that open and close sessions) are in the `login` module, which builds on this one.
//!
//! * The session cookie (`painsim_session`) holds 256 random bits; the database keeps only their
//!   SHA-256. Cookies are `HttpOnly; SameSite=Strict; Path=/` and `Secure` unless configured off
//!   for plain-http local runs.
//! * Sessions expire after `session_idle` without use and `session_absolute` after login; the
//!   check and the touch are one `UPDATE ... RETURNING`, so an expired session is never extended.
//! * Every cookie-authenticated request other than GET/HEAD/OPTIONS must send the session's CSRF
//!   token in `X-CSRF-Token` (synchronizer token, also readable by the web client from the
//!   non-HttpOnly `painsim_csrf` cookie).

use axum::extract::FromRequestParts;
use axum::http::header::COOKIE;
use axum::http::request::Parts;
use axum::http::{HeaderMap, Method};
use rand::RngCore;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use utoipa::ToSchema;
use uuid::Uuid;

use super::state::RecordsState;
use crate::error::ApiError;

/// Name of the session cookie.
pub const SESSION_COOKIE: &str = "painsim_session";
/// Name of the readable cookie carrying the CSRF token.
pub const CSRF_COOKIE: &str = "painsim_csrf";
/// Header that must carry the CSRF token on cookie-authenticated writes.
pub const CSRF_HEADER: &str = "x-csrf-token";

/// A platform role.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Does attempts in the courses they are enrolled in.
    Learner,
    /// Reviews attempts in the courses they teach.
    Faculty,
    /// Manages accounts and courses; may review any attempt but their own.
    Admin,
}

impl Role {
    /// Stored name.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::Learner => "learner",
            Role::Faculty => "faculty",
            Role::Admin => "admin",
        }
    }

    /// Parses a stored name.
    pub fn parse(s: &str) -> Option<Role> {
        match s {
            "learner" => Some(Role::Learner),
            "faculty" => Some(Role::Faculty),
            "admin" => Some(Role::Admin),
            _ => None,
        }
    }
}

/// The authenticated caller, from a valid session.
#[derive(Debug, Clone)]
pub struct CurrentUser {
    /// User id.
    pub id: Uuid,
    /// E-mail (lower case).
    pub email: String,
    /// Display name.
    pub display_name: String,
    /// Role.
    pub role: Role,
    /// Demo account.
    pub is_demo: bool,
    /// This session was opened with a valid TOTP code.
    pub mfa: bool,
    /// This session's CSRF token.
    pub csrf_token: String,
    /// SHA-256 of the session token (the key of `auth_sessions`).
    pub(super) token_sha256: Vec<u8>,
}

impl CurrentUser {
    /// 403 unless the caller has one of `roles`.
    pub fn require(&self, roles: &[Role]) -> Result<(), ApiError> {
        if roles.contains(&self.role) {
            Ok(())
        } else {
            let names: Vec<_> = roles.iter().map(|r| r.as_str()).collect();
            Err(ApiError::Forbidden(format!(
                "this needs the role {}",
                names.join(" or ")
            )))
        }
    }

    /// True for the admin role.
    pub fn is_admin(&self) -> bool {
        self.role == Role::Admin
    }
}

pub fn cookie_value<'a>(headers: &'a HeaderMap, name: &str) -> Option<&'a str> {
    headers
        .get_all(COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == name)
        .map(|(_, v)| v)
}

pub(super) fn sha256(token: &str) -> Vec<u8> {
    Sha256::digest(token.as_bytes()).to_vec()
}

pub(super) fn random_token() -> String {
    let mut b = [0u8; 32];
    rand::rng().fill_bytes(&mut b);
    hex::encode(b)
}

/// Compares secrets in time independent of where they differ.
pub fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

type SessionRow = (Uuid, String, String, String, bool, bool, String);

impl<S> FromRequestParts<S> for CurrentUser
where
    S: Send + Sync,
    RecordsState: axum::extract::FromRef<S>,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        let state = &<RecordsState as axum::extract::FromRef<S>>::from_ref(state);
        let token = cookie_value(&parts.headers, SESSION_COOKIE).ok_or(ApiError::Unauthorized)?;
        let token_sha256 = sha256(token);
        let row: Option<SessionRow> = sqlx::query_as(
            "UPDATE auth_sessions s SET last_seen_at = now()
             FROM users u
             WHERE s.token_sha256 = $1 AND u.id = s.user_id
               AND u.disabled_at IS NULL
               AND s.expires_at > now()
               AND s.last_seen_at > now() - make_interval(secs => $2)
             RETURNING u.id, u.email, u.display_name, u.role, u.is_demo, s.mfa, s.csrf_token",
        )
        .bind(&token_sha256)
        .bind(state.config.session_idle.as_secs_f64())
        .fetch_optional(&state.pool)
        .await?;
        let (id, email, display_name, role, is_demo, mfa, csrf_token) =
            row.ok_or(ApiError::Unauthorized)?;
        let role = Role::parse(&role)
            .ok_or_else(|| ApiError::Internal(format!("user {id} has unknown role {role:?}")))?;
        let safe = matches!(parts.method, Method::GET | Method::HEAD | Method::OPTIONS);
        if !safe {
            let sent = parts
                .headers
                .get(CSRF_HEADER)
                .map(|v| v.as_bytes())
                .unwrap_or_default();
            if !constant_time_eq(sent, csrf_token.as_bytes()) {
                return Err(ApiError::Forbidden(
                    "missing or wrong CSRF token: send the session's token in the X-CSRF-Token header".into(),
                ));
            }
            // Writes are bounded per account, whichever route they go to (429 with Retry-After).
            state
                .write_limiter
                .check(&id.to_string())
                .map_err(ApiError::TooManyRequests)?;
        }
        Ok(CurrentUser {
            id,
            email,
            display_name,
            role,
            is_demo,
            mfa,
            csrf_token,
            token_sha256,
        })
    }
}

/// Public view of an account.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct UserInfo {
    /// Id.
    pub id: Uuid,
    /// E-mail.
    pub email: String,
    /// Display name.
    pub display_name: String,
    /// Role.
    pub role: Role,
    /// A demo account of the embedded-default run (not a real person).
    pub is_demo: bool,
    /// Disabled by an admin: cannot log in, and every session was revoked.
    #[serde(default)]
    pub disabled: bool,
}
