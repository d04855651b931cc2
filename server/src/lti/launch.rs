//! LTI 1.3 core: OIDC third-party-initiated login (`/lti/login`), the launch (`/lti/launch`,
//! id_token verified against the platform's JWKS), and Deep Linking (`/lti/deep-link`).
//!
//! * Login stores a random state (its SHA-256) with a random nonce, single use, expiring after
//!   [`LOGIN_TTL`], and binds it to the browser with an HttpOnly cookie named after the state.
//! * Launch consumes the state first (so a refused launch cannot be retried with it), then checks
//!   the browser binding, the RS256 signature (platform keys cached by kid, the JWKS fetched again
//!   once for an unknown kid), `iss`, `aud` (and `azp` with several audiences), `exp`/`iat`/`nbf`
//!   with [`CLOCK_SKEW_S`], the nonce (single use across states), the deployment, the message
//!   type, the version and the roles. Only then does it map the platform user, context and role
//!   to an account, a course and a membership and open a session exactly as a password login
//!   does ([`crate::records::login::open_session`]).

use axum::Form;
use axum::extract::{Query, State};
use axum::http::header::{CONTENT_SECURITY_POLICY, CONTENT_TYPE, LOCATION, SET_COOKIE};
use axum::http::{HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use rsa::RsaPublicKey;
use serde::Deserialize;
use serde_json::{Value, json};
use uuid::Uuid;

use super::error::LtiError;
use super::jws::{self, random_hex, sha256};
use super::keys;
use super::platforms::{self, Platform};
use super::state::LtiState;
use crate::error::ApiError;
use crate::records::auth::Role;
use crate::records::history::audit;

/// How long a login state waits for its launch (our choice: the platform answers the
/// authentication request at once; ten minutes covers a slow page and a user at a login form).
pub const LOGIN_TTL_S: i64 = 600;
/// How long a deep-linking choice waits for the instructor (our choice).
pub const DEEP_LINK_TTL_S: i64 = 1800;
/// Tolerated clock difference with a platform for `exp`, `iat` and `nbf` (our choice; the IMS
/// Security Framework leaves it to the tool and mentions "a few minutes" at most).
pub const CLOCK_SKEW_S: f64 = 60.0;
/// Lifetime of the JWTs the tool signs (our choice, within the platforms' usual 5 minutes).
pub const TOOL_JWT_TTL_S: i64 = 300;

const LTI: &str = "https://purl.imsglobal.org/spec/lti/claim/";
const DL: &str = "https://purl.imsglobal.org/spec/lti-dl/claim/";
const AGS_ENDPOINT: &str = "https://purl.imsglobal.org/spec/lti-ags/claim/endpoint";
const NRPS: &str = "https://purl.imsglobal.org/spec/lti-nrps/claim/namesroleservice";

/// Prefix of the cookie that binds a login state to the browser.
pub const STATE_COOKIE_PREFIX: &str = "painsim_lti_";

/// The OIDC login initiation parameters (LTI 1.3 §5.1.1).
#[derive(Debug, Deserialize)]
pub struct LoginParams {
    /// Platform issuer.
    pub iss: String,
    /// Opaque user hint, passed back.
    pub login_hint: String,
    /// Where the launch should land.
    pub target_link_uri: String,
    /// Opaque message hint, passed back.
    #[serde(default)]
    pub lti_message_hint: Option<String>,
    /// The client id, when the platform registers the tool several times.
    #[serde(default)]
    pub client_id: Option<String>,
    /// The deployment, when the platform says it.
    #[serde(default)]
    pub lti_deployment_id: Option<String>,
}

/// `GET /lti/login`.
pub async fn login_get(
    State(state): State<LtiState>,
    Query(p): Query<LoginParams>,
) -> Result<Response, LtiError> {
    login(&state, p).await
}

/// `POST /lti/login` (form).
pub async fn login_post(
    State(state): State<LtiState>,
    Form(p): Form<LoginParams>,
) -> Result<Response, LtiError> {
    login(&state, p).await
}

async fn platform_for(
    state: &LtiState,
    iss: &str,
    client_id: Option<&str>,
) -> Result<Platform, LtiError> {
    let ids: Vec<Uuid> = sqlx::query_scalar(
        "SELECT id FROM lti_platforms WHERE issuer = $1 AND ($2::text IS NULL OR client_id = $2)",
    )
    .bind(iss)
    .bind(client_id)
    .fetch_all(&state.pool)
    .await?;
    let id = match ids.as_slice() {
        [id] => *id,
        [] => {
            return Err(LtiError::Refused(format!(
                "no registered platform has issuer {iss:?}"
            )));
        }
        _ => {
            return Err(ApiError::BadRequest(
                "several registrations share this issuer: the login must name the client_id".into(),
            )
            .into());
        }
    };
    platforms::get(&state.pool, id)
        .await?
        .ok_or_else(|| LtiError::Refused("the platform was just removed".into()))
}

fn cookie(state: &LtiState, name: &str, value: &str, max_age_s: i64) -> HeaderValue {
    // The launch arrives as a cross-site POST from the platform: with TLS the cookie must be
    // SameSite=None to come along; without (local runs) browsers accept no SameSite=None, and a
    // cookie without the attribute comes along on a top-level POST soon after it was set.
    let same_site = if state.records.config.cookie_secure {
        "; SameSite=None; Secure"
    } else {
        ""
    };
    HeaderValue::from_str(&format!(
        "{name}={value}; Path=/lti/; HttpOnly; Max-Age={max_age_s}{same_site}"
    ))
    .expect("hex cookie")
}

async fn login(state: &LtiState, p: LoginParams) -> Result<Response, LtiError> {
    let platform = platform_for(state, &p.iss, p.client_id.as_deref()).await?;
    if let Some(d) = &p.lti_deployment_id
        && !platform.deployment_ids.contains(d)
    {
        return Err(LtiError::Refused(format!(
            "deployment id {d:?} is not registered for this platform"
        )));
    }
    let target = p.target_link_uri.trim();
    if !target.starts_with(&format!("{}/", state.public_url)) {
        return Err(ApiError::BadRequest(format!(
            "target_link_uri must be on this tool ({}/...)",
            state.public_url
        ))
        .into());
    }
    let (st, nonce, browser) = (random_hex(32), random_hex(32), random_hex(32));
    sqlx::query("DELETE FROM lti_login_states WHERE expires_at < now()")
        .execute(&state.pool)
        .await?;
    sqlx::query(
        "INSERT INTO lti_login_states (state_sha256, nonce, browser_sha256, platform_id,
             target_link_uri, expires_at)
         VALUES ($1, $2, $3, $4, $5, now() + make_interval(secs => $6))",
    )
    .bind(sha256(&st))
    .bind(&nonce)
    .bind(sha256(&browser))
    .bind(platform.id)
    .bind(target)
    .bind(LOGIN_TTL_S as f64)
    .execute(&state.pool)
    .await?;
    let mut url = reqwest::Url::parse(&platform.auth_url)
        .map_err(|_| LtiError::Platform("the registered auth URL does not parse".into()))?;
    {
        let mut q = url.query_pairs_mut();
        q.append_pair("scope", "openid")
            .append_pair("response_type", "id_token")
            .append_pair("response_mode", "form_post")
            .append_pair("prompt", "none")
            .append_pair("client_id", &platform.client_id)
            .append_pair("redirect_uri", &format!("{}/lti/launch", state.public_url))
            .append_pair("login_hint", &p.login_hint)
            .append_pair("state", &st)
            .append_pair("nonce", &nonce);
        if let Some(h) = &p.lti_message_hint {
            q.append_pair("lti_message_hint", h);
        }
    }
    let mut resp = StatusCode::FOUND.into_response();
    let h = resp.headers_mut();
    h.insert(
        LOCATION,
        HeaderValue::from_str(url.as_str()).map_err(|_| ApiError::BadRequest("bad URL".into()))?,
    );
    h.append(
        SET_COOKIE,
        cookie(
            state,
            &format!("{STATE_COOKIE_PREFIX}{}", &st[..16]),
            &browser,
            LOGIN_TTL_S,
        ),
    );
    Ok(resp)
}

/// The authentication response (form_post).
#[derive(Debug, Deserialize)]
pub struct LaunchForm {
    /// The platform's signed id_token.
    #[serde(default)]
    pub id_token: Option<String>,
    /// Our state from the login.
    #[serde(default)]
    pub state: Option<String>,
    /// An OIDC error the platform reports instead.
    #[serde(default)]
    pub error: Option<String>,
    /// Its description.
    #[serde(default)]
    pub error_description: Option<String>,
}

/// The platform's key `kid` (cache, else the JWKS fetched again once).
async fn platform_key(
    state: &LtiState,
    platform: &Platform,
    kid: &str,
) -> Result<RsaPublicKey, LtiError> {
    let k = (platform.id, kid.to_owned());
    if let Some(key) = state.platform_keys.lock().expect("key cache").get(&k) {
        return Ok(key.clone());
    }
    let set: Value = state
        .http
        .get(&platform.jwks_url)
        .send()
        .await
        .and_then(|r| r.error_for_status())
        .map_err(|e| LtiError::Platform(format!("fetching the platform's JWKS: {e}")))?
        .json()
        .await
        .map_err(|e| LtiError::Platform(format!("the platform's JWKS is not JSON: {e}")))?;
    let keys = set["keys"].as_array().cloned().unwrap_or_default();
    let single = keys.len() == 1;
    let mut cache = state.platform_keys.lock().expect("key cache");
    cache.retain(|(p, _), _| *p != platform.id);
    for jwk in &keys {
        let Ok(key) = jws::key_from_jwk(jwk) else {
            continue;
        };
        let id = jwk["kid"].as_str().unwrap_or_default().to_owned();
        // A token without kid may use the only key of a set.
        if single {
            cache.insert((platform.id, String::new()), key.clone());
        }
        cache.insert((platform.id, id), key);
    }
    cache
        .get(&k)
        .cloned()
        .ok_or_else(|| LtiError::Refused(format!("the platform's JWKS has no RS256 key {kid:?}")))
}

fn now_s() -> f64 {
    time::OffsetDateTime::now_utc().unix_timestamp_nanos() as f64 / 1e9
}

/// Checks the registered claims of a verified id_token.
fn check_claims(c: &Value, platform: &Platform) -> Result<(), LtiError> {
    if c["iss"].as_str() != Some(platform.issuer.as_str()) {
        return Err(LtiError::Refused(
            "the id_token's issuer is not the platform's".into(),
        ));
    }
    let auds: Vec<&str> = match &c["aud"] {
        Value::String(s) => vec![s.as_str()],
        Value::Array(a) => a.iter().filter_map(Value::as_str).collect(),
        _ => vec![],
    };
    if !auds.contains(&platform.client_id.as_str()) {
        return Err(LtiError::Refused(
            "wrong audience: the id_token's aud does not include this tool's client id".into(),
        ));
    }
    match c.get("azp").and_then(Value::as_str) {
        Some(azp) if azp != platform.client_id => {
            return Err(LtiError::Refused(
                "the id_token's azp is not this tool's client id".into(),
            ));
        }
        None if auds.len() > 1 => {
            return Err(LtiError::Refused(
                "the id_token has several audiences and no azp".into(),
            ));
        }
        _ => {}
    }
    let now = now_s();
    let exp = c["exp"]
        .as_f64()
        .ok_or_else(|| LtiError::Refused("the id_token has no exp".into()))?;
    if exp + CLOCK_SKEW_S < now {
        return Err(LtiError::Refused("the id_token expired".into()));
    }
    let iat = c["iat"]
        .as_f64()
        .ok_or_else(|| LtiError::Refused("the id_token has no iat".into()))?;
    if iat - CLOCK_SKEW_S > now {
        return Err(LtiError::Refused(
            "the id_token was issued in the future".into(),
        ));
    }
    if c.get("nbf")
        .and_then(Value::as_f64)
        .is_some_and(|nbf| nbf - CLOCK_SKEW_S > now)
    {
        return Err(LtiError::Refused(
            "the id_token is not valid yet (nbf)".into(),
        ));
    }
    Ok(())
}

/// What the launch maps to.
struct Mapped {
    user: Uuid,
    course: Uuid,
    faculty: bool,
}

pub fn is_faculty(roles: &[&str]) -> bool {
    // LTI 1.3 §A.2: context Instructor (TeachingAssistant is a sub-role of it) and Administrator,
    // institution and system Administrator. An LMS administrator teaches here; never our admin.
    roles.iter().any(|r| {
        r.starts_with("http://purl.imsglobal.org/vocab/lis/v2/membership#Instructor")
            || r.starts_with("http://purl.imsglobal.org/vocab/lis/v2/membership/Instructor#")
            || r.ends_with("#Administrator")
            || *r == "Instructor"
            || *r == "Administrator"
    })
}

/// Account for (issuer, sub): found, or created (learner or faculty; never admin).
pub async fn account(
    tx: &mut sqlx::PgConnection,
    issuer: &str,
    sub: &str,
    name: Option<&str>,
    faculty: bool,
) -> Result<Uuid, LtiError> {
    let found: Option<(Uuid, bool)> = sqlx::query_as(
        "SELECT u.id, u.disabled_at IS NOT NULL FROM lti_users l JOIN users u ON u.id = l.user_id
         WHERE l.issuer = $1 AND l.sub = $2",
    )
    .bind(issuer)
    .bind(sub)
    .fetch_optional(&mut *tx)
    .await?;
    if let Some((id, disabled)) = found {
        if disabled {
            return Err(LtiError::Refused("this account is disabled".into()));
        }
        if faculty {
            sqlx::query("UPDATE users SET role = 'faculty' WHERE id = $1 AND role = 'learner'")
                .bind(id)
                .execute(&mut *tx)
                .await?;
        }
        return Ok(id);
    }
    let id = Uuid::new_v4();
    // Platform e-mails are never trusted to link to a local account: a synthetic, unroutable
    // address keeps (issuer, sub) the only key.
    let email = format!(
        "lti-{}@lti.invalid",
        &hex::encode(sha256(&format!("{issuer}\n{sub}")))[..24]
    );
    let display: String = name
        .map(str::trim)
        .filter(|n| !n.is_empty())
        .unwrap_or("LTI user")
        .chars()
        .take(200)
        .collect();
    sqlx::query(
        "INSERT INTO users (id, email, display_name, role, password_hash) VALUES ($1, $2, $3, $4, '!lti')",
    )
    .bind(id)
    .bind(&email)
    .bind(&display)
    .bind(if faculty { Role::Faculty.as_str() } else { Role::Learner.as_str() })
    .execute(&mut *tx)
    .await?;
    sqlx::query("INSERT INTO lti_users (issuer, sub, user_id) VALUES ($1, $2, $3)")
        .bind(issuer)
        .bind(sub)
        .bind(id)
        .execute(&mut *tx)
        .await?;
    audit(
        &mut *tx,
        None,
        "lti_account_created",
        "user",
        &id.to_string(),
        json!({ "issuer": issuer }),
    )
    .await?;
    Ok(id)
}

/// Course for a platform context: found, or created at first launch.
pub async fn course(
    tx: &mut sqlx::PgConnection,
    platform: &Platform,
    context: &Value,
) -> Result<Uuid, LtiError> {
    let cid = context["id"]
        .as_str()
        .filter(|s| !s.is_empty())
        .ok_or_else(|| ApiError::BadRequest("the launch has no context (course) id".into()))?;
    if let Some(id) = sqlx::query_scalar(
        "SELECT course_id FROM lti_contexts WHERE platform_id = $1 AND context_id = $2",
    )
    .bind(platform.id)
    .bind(cid)
    .fetch_optional(&mut *tx)
    .await?
    {
        return Ok(id);
    }
    let id = Uuid::new_v4();
    let code = format!(
        "lti-{}",
        &hex::encode(sha256(&format!("{}\n{cid}", platform.id)))[..16]
    );
    let title: String = ["title", "label"]
        .iter()
        .find_map(|k| context[*k].as_str().filter(|s| !s.trim().is_empty()))
        .unwrap_or("LTI course")
        .chars()
        .take(200)
        .collect();
    sqlx::query("INSERT INTO courses (id, code, title) VALUES ($1, $2, $3)")
        .bind(id)
        .bind(&code)
        .bind(&title)
        .execute(&mut *tx)
        .await?;
    sqlx::query(
        "INSERT INTO lti_contexts (platform_id, context_id, course_id) VALUES ($1, $2, $3)",
    )
    .bind(platform.id)
    .bind(cid)
    .bind(id)
    .execute(&mut *tx)
    .await?;
    audit(
        &mut *tx,
        None,
        "lti_course_created",
        "course",
        &id.to_string(),
        json!({ "context_id": cid }),
    )
    .await?;
    Ok(id)
}

/// Adds or updates a course membership.
pub async fn member(
    tx: &mut sqlx::PgConnection,
    course: Uuid,
    user: Uuid,
    faculty: bool,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "INSERT INTO course_members (course_id, user_id, role) VALUES ($1, $2, $3)
         ON CONFLICT (course_id, user_id) DO UPDATE SET role = EXCLUDED.role",
    )
    .bind(course)
    .bind(user)
    .bind(if faculty { "faculty" } else { "learner" })
    .execute(&mut *tx)
    .await?;
    Ok(())
}

/// The station a launch names: the custom parameter `station_id` (or `station`), else the
/// `station` query parameter of the target link.
fn station_of(state: &LtiState, claims: &Value) -> Option<String> {
    let custom = &claims[format!("{LTI}custom")];
    let from_custom = ["station_id", "station"]
        .iter()
        .find_map(|k| custom[*k].as_str().map(str::to_owned));
    let from_target = claims[format!("{LTI}target_link_uri")]
        .as_str()
        .and_then(|u| reqwest::Url::parse(u).ok())
        .and_then(|u| {
            u.query_pairs()
                .find(|(k, _)| k == "station")
                .map(|(_, v)| v.into_owned())
        });
    from_custom
        .or(from_target)
        .filter(|s| state.records.stations.get(s).is_some())
}

fn html(status: StatusCode, body: String) -> Response {
    let mut r = (status, body).into_response();
    r.headers_mut().insert(
        CONTENT_TYPE,
        HeaderValue::from_static("text/html; charset=utf-8"),
    );
    r
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&#39;")
}

/// `POST /lti/launch`: the platform's authentication response.
pub async fn launch(
    State(state): State<LtiState>,
    headers: HeaderMap,
    Form(f): Form<LaunchForm>,
) -> Result<Response, LtiError> {
    if let Some(e) = f.error {
        return Err(LtiError::Refused(format!(
            "the platform answered {e}: {}",
            f.error_description.unwrap_or_default()
        )));
    }
    let (Some(token), Some(st)) = (f.id_token, f.state) else {
        return Err(ApiError::BadRequest("the launch needs id_token and state".into()).into());
    };
    let parsed = jws::parse(&token).map_err(|e| LtiError::Refused(e.to_string()))?;
    // The state is used up whatever follows.
    let row: Option<(String, Vec<u8>, Uuid, bool)> = sqlx::query_as(
        "DELETE FROM lti_login_states WHERE state_sha256 = $1
         RETURNING nonce, browser_sha256, platform_id, expires_at > now()",
    )
    .bind(sha256(&st))
    .fetch_optional(&state.pool)
    .await?;
    let Some((nonce, browser_sha256, platform_id, fresh)) = row else {
        let replayed: bool =
            sqlx::query_scalar("SELECT EXISTS (SELECT 1 FROM lti_used_nonces WHERE nonce = $1)")
                .bind(parsed.claims["nonce"].as_str().unwrap_or_default())
                .fetch_one(&state.pool)
                .await?;
        return Err(LtiError::Refused(if replayed {
            "replayed launch: this id_token's nonce was used already".into()
        } else {
            "unknown or already used state (start the launch again from the platform)".into()
        }));
    };
    if !fresh {
        return Err(LtiError::Refused(
            "the login state expired (start the launch again)".into(),
        ));
    }
    let bound = st.get(..16).and_then(|p| {
        crate::records::auth::cookie_value(&headers, &format!("{STATE_COOKIE_PREFIX}{p}"))
    });
    if bound.map(sha256) != Some(browser_sha256) {
        return Err(LtiError::Refused(
            "the launch did not come back to the browser that started the login".into(),
        ));
    }
    let platform = platforms::get(&state.pool, platform_id)
        .await?
        .ok_or_else(|| LtiError::Refused("the platform was removed".into()))?;
    let key = platform_key(&state, &platform, parsed.kid().unwrap_or_default()).await?;
    if !parsed.verifies_with(&key) {
        return Err(LtiError::Refused(
            "bad signature: the id_token does not verify with the platform's keys".into(),
        ));
    }
    let c = &parsed.claims;
    check_claims(c, &platform)?;
    if c["nonce"].as_str() != Some(nonce.as_str()) {
        return Err(LtiError::Refused(
            "the id_token's nonce is not the one this login sent".into(),
        ));
    }
    let deployment = c[format!("{LTI}deployment_id")]
        .as_str()
        .unwrap_or_default();
    if !platform.deployment_ids.iter().any(|d| d == deployment) {
        return Err(LtiError::Refused(format!(
            "unknown deployment: {deployment:?} is not registered for this platform"
        )));
    }
    let message_type = c[format!("{LTI}message_type")].as_str().unwrap_or_default();
    if !matches!(
        message_type,
        "LtiResourceLinkRequest" | "LtiDeepLinkingRequest"
    ) {
        return Err(LtiError::Refused(format!(
            "unsupported message type {message_type:?}"
        )));
    }
    if c[format!("{LTI}version")].as_str() != Some("1.3.0") {
        return Err(LtiError::Refused("the LTI version is not 1.3.0".into()));
    }
    let roles: Vec<&str> = c[format!("{LTI}roles")]
        .as_array()
        .ok_or_else(|| LtiError::Refused("the id_token has no roles claim".into()))?
        .iter()
        .filter_map(Value::as_str)
        .collect();
    let sub = c["sub"]
        .as_str()
        .filter(|s| !s.is_empty())
        .ok_or_else(|| LtiError::Refused("anonymous launches (no sub) are not supported".into()))?;
    if message_type == "LtiResourceLinkRequest"
        && c[format!("{LTI}resource_link")]["id"].as_str().is_none()
    {
        return Err(LtiError::Refused(
            "the resource link claim has no id".into(),
        ));
    }
    let mut tx = state.pool.begin().await?;
    let expires = c["exp"].as_f64().unwrap_or_default() + CLOCK_SKEW_S;
    let fresh_nonce = sqlx::query(
        "INSERT INTO lti_used_nonces (platform_id, nonce, expires_at) VALUES ($1, $2, to_timestamp($3))
         ON CONFLICT DO NOTHING",
    )
    .bind(platform.id)
    .bind(&nonce)
    .bind(expires)
    .execute(&mut *tx)
    .await?;
    if fresh_nonce.rows_affected() != 1 {
        return Err(LtiError::Refused(
            "replayed launch: this id_token's nonce was used already".into(),
        ));
    }
    sqlx::query("DELETE FROM lti_used_nonces WHERE expires_at < now() - interval '1 day'")
        .execute(&mut *tx)
        .await?;
    let faculty = is_faculty(&roles);
    let name = c["name"].as_str().map(str::to_owned).or_else(|| {
        let parts: Vec<&str> = ["given_name", "family_name"]
            .iter()
            .filter_map(|k| c[*k].as_str())
            .collect();
        (!parts.is_empty()).then(|| parts.join(" "))
    });
    let user = account(&mut tx, &platform.issuer, sub, name.as_deref(), faculty).await?;
    let course = course(&mut tx, &platform, &c[format!("{LTI}context")]).await?;
    member(&mut tx, course, user, faculty).await?;
    let mapped = Mapped {
        user,
        course,
        faculty,
    };
    if let Some(u) = c[NRPS]["context_memberships_url"]
        .as_str()
        .or(platform.memberships_url.as_deref())
    {
        sqlx::query("UPDATE lti_contexts SET memberships_url = $3 WHERE platform_id = $1 AND course_id = $2")
            .bind(platform.id)
            .bind(course)
            .bind(u)
            .execute(&mut *tx)
            .await?;
    }
    let station = station_of(&state, c);
    if let (Some(station), Some(lineitem), false) = (
        &station,
        c[AGS_ENDPOINT]["lineitem"].as_str(),
        mapped.faculty,
    ) {
        sqlx::query(
            "INSERT INTO lti_grade_targets (user_id, course_id, station_id, platform_id, sub, lineitem_url)
             VALUES ($1, $2, $3, $4, $5, $6)
             ON CONFLICT (user_id, course_id, station_id) DO UPDATE
               SET platform_id = EXCLUDED.platform_id, sub = EXCLUDED.sub,
                   lineitem_url = EXCLUDED.lineitem_url, updated_at = now()",
        )
        .bind(mapped.user)
        .bind(mapped.course)
        .bind(station)
        .bind(platform.id)
        .bind(sub)
        .bind(lineitem)
        .execute(&mut *tx)
        .await?;
    }
    let opened =
        crate::records::login::open_session(&state.records, &mut tx, mapped.user, false, &headers)
            .await?;
    audit(
        &mut *tx,
        Some(mapped.user),
        "lti_launch",
        "user",
        &mapped.user.to_string(),
        json!({ "platform": platform.id, "message_type": message_type, "station": station }),
    )
    .await?;
    let body = if message_type == "LtiDeepLinkingRequest" {
        deep_link_page(&state, &mut tx, &platform, deployment, c).await?
    } else {
        let mut target = format!("/?course={}", mapped.course);
        if let Some(s) = &station {
            target.push_str(&format!("&station={s}"));
        }
        let t = esc(&target);
        format!(
            "<!doctype html><html lang=\"en\"><meta charset=\"utf-8\"><title>Opening the station</title>\
             <meta http-equiv=\"refresh\" content=\"0;url={t}\">\
             <p><a id=\"continue\" href=\"{t}\">Continue to the station</a></p></html>"
        )
    };
    tx.commit().await?;
    let mut resp = html(StatusCode::OK, body);
    opened.set_cookies(resp.headers_mut());
    // The state cookie has done its job.
    if let Some(p) = st.get(..16) {
        resp.headers_mut().append(
            SET_COOKIE,
            cookie(&state, &format!("{STATE_COOKIE_PREFIX}{p}"), "", 0),
        );
    }
    Ok(resp)
}

async fn deep_link_page(
    state: &LtiState,
    tx: &mut sqlx::PgConnection,
    platform: &Platform,
    deployment: &str,
    c: &Value,
) -> Result<String, LtiError> {
    let settings = &c[format!("{DL}deep_linking_settings")];
    let return_url = settings["deep_link_return_url"].as_str().ok_or_else(|| {
        LtiError::Refused("the deep-linking request has no deep_link_return_url".into())
    })?;
    if !platforms::acceptable_url(return_url) {
        return Err(LtiError::Refused(
            "the deep_link_return_url is not an https URL".into(),
        ));
    }
    let accepts = settings["accept_types"]
        .as_array()
        .is_none_or(|a| a.iter().any(|t| t == "ltiResourceLink"));
    if !accepts {
        return Err(LtiError::Refused(
            "the platform accepts no ltiResourceLink items here".into(),
        ));
    }
    let token = random_hex(32);
    sqlx::query("DELETE FROM lti_deep_links WHERE expires_at < now()")
        .execute(&mut *tx)
        .await?;
    sqlx::query(
        "INSERT INTO lti_deep_links (token_sha256, platform_id, deployment_id, return_url, data, expires_at)
         VALUES ($1, $2, $3, $4, $5, now() + make_interval(secs => $6))",
    )
    .bind(sha256(&token))
    .bind(platform.id)
    .bind(deployment)
    .bind(return_url)
    .bind(settings["data"].as_str())
    .bind(DEEP_LINK_TTL_S as f64)
    .execute(&mut *tx)
    .await?;
    let mut items = String::new();
    for (id, s) in &state.records.stations.stations {
        items.push_str(&format!(
            "<li><form method=\"post\" action=\"/lti/deep-link\"><input type=\"hidden\" name=\"token\" value=\"{token}\">\
             <input type=\"hidden\" name=\"station_id\" value=\"{}\"><button type=\"submit\">{}</button></form></li>",
            esc(id),
            esc(&s.station.title)
        ));
    }
    Ok(format!(
        "<!doctype html><html lang=\"en\"><meta charset=\"utf-8\"><title>Choose a station</title>\
         <h1>Choose a station for your course</h1><ul id=\"stations\">{items}</ul></html>"
    ))
}

/// The instructor's choice.
#[derive(Debug, Deserialize)]
pub struct DeepLinkChoice {
    /// The single-use token of the deep-linking page.
    pub token: String,
    /// The chosen station.
    pub station_id: String,
}

/// `POST /lti/deep-link`: signs the LtiDeepLinkingResponse and posts it back to the platform.
pub async fn deep_link_choose(
    State(state): State<LtiState>,
    Form(f): Form<DeepLinkChoice>,
) -> Result<Response, LtiError> {
    let station = state
        .records
        .stations
        .get(&f.station_id)
        .ok_or_else(|| ApiError::BadRequest(format!("no station {:?}", f.station_id)))?
        .station
        .clone();
    let row: Option<(Uuid, String, String, Option<String>)> = sqlx::query_as(
        "DELETE FROM lti_deep_links WHERE token_sha256 = $1 AND expires_at > now()
         RETURNING platform_id, deployment_id, return_url, data",
    )
    .bind(sha256(&f.token))
    .fetch_optional(&state.pool)
    .await?;
    let (platform_id, deployment, return_url, data) = row
        .ok_or_else(|| LtiError::Refused("unknown, used or expired deep-linking choice".into()))?;
    let platform = platforms::get(&state.pool, platform_id)
        .await?
        .ok_or_else(|| LtiError::Refused("the platform was removed".into()))?;
    let now = time::OffsetDateTime::now_utc().unix_timestamp();
    let mut claims = json!({
        "iss": platform.client_id,
        "aud": platform.issuer,
        "azp": platform.client_id,
        "iat": now,
        "exp": now + TOOL_JWT_TTL_S,
        "nonce": random_hex(16),
        format!("{LTI}deployment_id"): deployment,
        format!("{LTI}message_type"): "LtiDeepLinkingResponse",
        format!("{LTI}version"): "1.3.0",
        format!("{DL}content_items"): [{
            "type": "ltiResourceLink",
            "title": station.title,
            "text": station.description,
            "url": format!("{}/lti/launch", state.public_url),
            "custom": { "station_id": station.id },
            // The technical score, 0 to 100 (the rubric's weighted score in percent).
            "lineItem": { "scoreMaximum": 100, "label": station.title, "resourceId": station.id,
                          "tag": "technical-score" },
        }],
        format!("{DL}msg"): format!("Linked the station {}", station.title),
    });
    if let Some(d) = data {
        claims[format!("{DL}data")] = Value::String(d);
    }
    let jwt = keys::sign(&state.pool, &claims).await?;
    let origin = reqwest::Url::parse(&return_url)
        .map(|u| u.origin().ascii_serialization())
        .map_err(|_| ApiError::BadRequest("bad return URL".into()))?;
    let body = format!(
        "<!doctype html><html lang=\"en\"><meta charset=\"utf-8\"><title>Returning to the course</title>\
         <form id=\"deep-link-return\" method=\"post\" action=\"{}\"><input type=\"hidden\" name=\"JWT\" value=\"{}\">\
         <button type=\"submit\">Return to the course</button></form><script src=\"/lti/autosubmit.js\"></script></html>",
        esc(&return_url),
        esc(&jwt)
    );
    let mut resp = html(StatusCode::OK, body);
    resp.headers_mut().insert(
        CONTENT_SECURITY_POLICY,
        HeaderValue::from_str(&format!(
            "default-src 'none'; script-src 'self'; form-action {origin}; frame-ancestors 'none'; base-uri 'none'"
        ))
        .map_err(|_| ApiError::BadRequest("bad return URL".into()))?,
    );
    Ok(resp)
}

/// `GET /lti/autosubmit.js`: submits the page's form (inline script is not allowed by our CSP).
pub async fn autosubmit() -> Response {
    let mut r = "document.forms[0].submit();\n".into_response();
    r.headers_mut()
        .insert(CONTENT_TYPE, HeaderValue::from_static("text/javascript"));
    r
}
