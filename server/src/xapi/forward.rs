//! Forwarding to an institution's external LRS: the admin settings and status endpoints
//! (`/api/admin/lrs-forwarding`) and the outbox deliverer of kind [`FORWARD_KIND`].
//!
//! Every statement the platform produces ([`super::platform`]) is enqueued in the outbox with its
//! id as key. The [`Forwarder`] POSTs them in batches of up to [`BATCH_STATEMENTS`] to
//! `<endpoint>/statements` with HTTP Basic, speaking the version the LRS announces in its About
//! resource (`<endpoint>/about`, read before each delivery): 2.0.0 when it lists a 2.0.x, else
//! 1.0.3 when it lists a 1.0.x (statements then lose the properties 2.0 added, see
//! [`statement_as_1_0`]), else 2.0.0 (an LRS whose About cannot be read is spoken to as 2.0 and fails or
//! succeeds on its own terms). Statement ids
//! make this idempotent: a redelivery after a crash finds the statements already there. An LRS
//! answers a batch that holds one already-stored id with 409 (immutability) and stores nothing
//! of it, so on 409 (and on 400 or 413, to find the one statement at fault) the batch is sent
//! again one statement at a time with `PUT ?statementId=`, where 204 and 409 both mean "the LRS
//! has it".
//!
//! With no endpoint configured the items stay pending (a retryable "not configured" error, so the
//! backlog and the error show on the status) and go out once an admin sets one: saving the
//! settings makes every pending item due at once.

use std::sync::Arc;

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use base64::Engine;
use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};
use sqlx::PgPool;
use time::OffsetDateTime;
use utoipa::ToSchema;

use super::state::XapiState;
use super::version::{Spoken, statement_as_1_0};
use crate::error::ApiError;
use crate::outbox::{self, Deliver, DeliveryError, KindStatus};
use crate::records::auth::{CurrentUser, Role};
use crate::records::extract::ApiJson;
use crate::records::history::audit;

/// The outbox kind of statements to forward.
pub const FORWARD_KIND: &str = "xapi-forward";

/// Statements per POST (our choice: well under common LRS batch limits, a few hundred kB).
pub const BATCH_STATEMENTS: usize = 100;

/// The forwarding settings an admin sends. The schema states every rule the server checks.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ForwardingSettings {
    /// The external LRS's endpoint (`https://lrs.example.org/xapi/`); statements go to
    /// `<endpoint>/statements`. An http(s) URL without credentials, query or fragment.
    #[schema(
        max_length = 2000,
        pattern = "^https?://[^\\u0000-\\u0020/?#@\\u007f]+(/[^\\u0000-\\u0020?#\\u007f]*)?$"
    )]
    pub endpoint: String,
    /// HTTP Basic user name (no `:`).
    #[schema(min_length = 1, max_length = 200, pattern = "^[^:\\u0000]+$")]
    pub key: String,
    /// HTTP Basic password: write-only, never returned.
    #[schema(min_length = 1, max_length = 500, pattern = "^[^\\u0000]+$")]
    pub secret: String,
}

/// Forwarding settings and state, for admins (never the secret).
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct ForwardingView {
    /// Whether an external LRS is configured.
    pub configured: bool,
    /// Its endpoint.
    pub endpoint: Option<String>,
    /// The Basic user name.
    pub key: Option<String>,
    /// When the settings were last saved.
    #[serde(with = "time::serde::rfc3339::option")]
    pub updated_at: Option<OffsetDateTime>,
    /// The outbox of statements to forward: backlog, deliveries, last error.
    pub status: KindStatus,
    /// Records waiting to become statements.
    pub projection_queued: i64,
    /// Records whose projection failed (kept with their error).
    pub projection_failed: i64,
}

/// The stored settings.
#[derive(Debug, Clone)]
pub struct Settings {
    /// Endpoint, ending with `/`.
    pub endpoint: String,
    /// Basic user name.
    pub key: String,
    /// Basic password.
    pub secret: String,
}

/// The configured external LRS, if any.
pub async fn settings(pool: &PgPool) -> Result<Option<Settings>, sqlx::Error> {
    let row: Option<(String, String, String)> =
        sqlx::query_as("SELECT endpoint, key, secret FROM lrs_forwarding")
            .fetch_optional(pool)
            .await?;
    Ok(row.map(|(endpoint, key, secret)| Settings {
        endpoint,
        key,
        secret,
    }))
}

/// Checks `e` against [`ForwardingSettings::endpoint`]'s pattern; returns it ending with `/`.
fn normalize_endpoint(e: &str) -> Result<String, ApiError> {
    let bad = || {
        ApiError::BadRequest(
            "endpoint: an http(s) URL without credentials, query or fragment, at most 2000 characters"
                .into(),
        )
    };
    let forbidden = |c: char| c <= '\u{20}' || c == '\u{7f}' || c == '?' || c == '#';
    let rest = e
        .strip_prefix("http://")
        .or_else(|| e.strip_prefix("https://"))
        .ok_or_else(bad)?;
    let (host, path) = rest.split_at(rest.find('/').unwrap_or(rest.len()));
    if e.chars().count() > 2000
        || host.is_empty()
        || host.chars().any(|c| forbidden(c) || c == '@')
        || path.chars().any(forbidden)
    {
        return Err(bad());
    }
    // The pattern admits URLs by their shape; the endpoint must also parse as a URL with a host
    // (`http://[x` has the shape, names no host, and would only fail at every delivery).
    if !reqwest::Url::parse(e).is_ok_and(|u| u.host_str().is_some_and(|h| !h.is_empty())) {
        return Err(bad());
    }
    let mut s = e.to_owned();
    if !s.ends_with('/') {
        s.push('/');
    }
    Ok(s)
}

async fn view(pool: &PgPool) -> Result<ForwardingView, ApiError> {
    let row: Option<(String, String, OffsetDateTime)> =
        sqlx::query_as("SELECT endpoint, key, updated_at FROM lrs_forwarding")
            .fetch_optional(pool)
            .await?;
    let (queued, failed): (i64, i64) = sqlx::query_as(
        "SELECT count(*) FILTER (WHERE failed_at IS NULL), count(*) FILTER (WHERE failed_at IS NOT NULL)
         FROM xapi_projection_queue",
    )
    .fetch_one(pool)
    .await?;
    let status = outbox::kind_status(pool, FORWARD_KIND).await?;
    Ok(ForwardingView {
        configured: row.is_some(),
        endpoint: row.as_ref().map(|r| r.0.clone()),
        key: row.as_ref().map(|r| r.1.clone()),
        updated_at: row.map(|r| r.2),
        status,
        projection_queued: queued,
        projection_failed: failed,
    })
}

/// Forwarding settings and status (admin): the external LRS (never its secret), the backlog (how
/// many statements wait, the oldest one's age), deliveries and the last error.
#[utoipa::path(get, path = "/api/admin/lrs-forwarding", tag = "lms",
    responses((status = 200, body = ForwardingView), (status = 401), (status = 403)))]
pub async fn get_forwarding(
    State(state): State<XapiState>,
    user: CurrentUser,
) -> Result<Json<ForwardingView>, ApiError> {
    user.require(&[Role::Admin])?;
    Ok(Json(view(&state.pool).await?))
}

/// Point the platform at an external LRS (admin). The secret is write-only (never returned, sent
/// again with every change). Statements waiting in the backlog are sent at once.
#[utoipa::path(put, path = "/api/admin/lrs-forwarding", tag = "lms", request_body = ForwardingSettings,
    responses((status = 200, body = ForwardingView, description = "Saved"), (status = 400),
        (status = 401), (status = 403)))]
pub async fn put_forwarding(
    State(state): State<XapiState>,
    user: CurrentUser,
    ApiJson(req): ApiJson<ForwardingSettings>,
) -> Result<Json<ForwardingView>, ApiError> {
    user.require(&[Role::Admin])?;
    let endpoint = normalize_endpoint(&req.endpoint)?;
    let key = req.key.as_str();
    if key.is_empty() || key.chars().count() > 200 || key.contains([':', '\0']) {
        return Err(ApiError::BadRequest(
            "key: 1 to 200 characters, no ':'".into(),
        ));
    }
    let secret = req.secret.as_str();
    if secret.is_empty() || secret.chars().count() > 500 || secret.contains('\0') {
        return Err(ApiError::BadRequest("secret: 1 to 500 characters".into()));
    }
    let mut tx = state.pool.begin().await?;
    sqlx::query(
        "INSERT INTO lrs_forwarding (endpoint, key, secret, updated_by) VALUES ($1, $2, $3, $4)
         ON CONFLICT (singleton) DO UPDATE SET endpoint = $1, key = $2, secret = $3,
             updated_by = $4, updated_at = now()",
    )
    .bind(&endpoint)
    .bind(key)
    .bind(secret)
    .bind(user.id)
    .execute(&mut *tx)
    .await?;
    // The backlog goes out now, not after its backoff; the workers hear it at commit.
    sqlx::query(
        "UPDATE outbox SET next_attempt_at = now() WHERE kind = $1 AND delivered_at IS NULL
         AND failed_at IS NULL AND attempts > 0 AND next_attempt_at > now()",
    )
    .bind(FORWARD_KIND)
    .execute(&mut *tx)
    .await?;
    sqlx::query("SELECT pg_notify('outbox', $1)")
        .bind(FORWARD_KIND)
        .execute(&mut *tx)
        .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "lrs_forwarding_set",
        "lrs_forwarding",
        "settings",
        json!({ "endpoint": endpoint, "key": key }),
    )
    .await?;
    tx.commit().await?;
    Ok(Json(view(&state.pool).await?))
}

/// Stop forwarding (admin): the settings are removed; new statements wait in the backlog until an
/// external LRS is set again. Stopping when nothing is configured changes nothing.
#[utoipa::path(delete, path = "/api/admin/lrs-forwarding", tag = "lms",
    responses((status = 204, description = "Stopped"), (status = 401), (status = 403)))]
pub async fn delete_forwarding(
    State(state): State<XapiState>,
    user: CurrentUser,
) -> Result<StatusCode, ApiError> {
    user.require(&[Role::Admin])?;
    let mut tx = state.pool.begin().await?;
    let n = sqlx::query("DELETE FROM lrs_forwarding")
        .execute(&mut *tx)
        .await?
        .rows_affected();
    if n > 0 {
        audit(
            &mut *tx,
            Some(user.id),
            "lrs_forwarding_stopped",
            "lrs_forwarding",
            "settings",
            json!({}),
        )
        .await?;
    }
    tx.commit().await?;
    Ok(StatusCode::NO_CONTENT)
}

/// The outbox deliverer of [`FORWARD_KIND`]: reads the settings at each delivery, so changes take
/// effect at once.
pub struct Forwarder {
    pool: PgPool,
    client: reqwest::Client,
}

impl Forwarder {
    /// A forwarder reading its settings from `pool`.
    pub fn new(pool: PgPool) -> Arc<Forwarder> {
        let client = reqwest::Client::builder()
            // Our choice: a connection that cannot be made in this long counts as a failure to
            // retry (the outbox bounds the whole delivery too).
            .connect_timeout(std::time::Duration::from_secs(10))
            .timeout(std::time::Duration::from_secs(25))
            .build()
            .expect("building the HTTP client");
        Arc::new(Forwarder { pool, client })
    }

    fn request(
        &self,
        s: &Settings,
        spoken: Spoken,
        method: reqwest::Method,
        url: &str,
    ) -> reqwest::RequestBuilder {
        let basic =
            base64::engine::general_purpose::STANDARD.encode(format!("{}:{}", s.key, s.secret));
        self.client
            .request(method, url)
            .header("X-Experience-API-Version", spoken.answer())
            .header("Authorization", format!("Basic {basic}"))
    }

    /// The line the external LRS speaks, from its About resource.
    async fn negotiate(&self, s: &Settings) -> Spoken {
        let about = self
            .client
            .get(format!("{}about", s.endpoint))
            .send()
            .await
            .ok()
            .filter(|r| r.status().is_success());
        let versions = match about {
            Some(r) => r.json::<Value>().await.unwrap_or(Value::Null),
            None => Value::Null,
        };
        spoken_by(&versions)
    }

    async fn forward(&self, items: &[Value]) -> Result<(), DeliveryError> {
        let s = settings(&self.pool)
            .await
            .map_err(|e| DeliveryError::Retry(format!("reading the settings: {e}")))?
            .ok_or_else(|| DeliveryError::Retry("no external LRS is configured".into()))?;
        let spoken = self.negotiate(&s).await;
        let converted: Vec<Value>;
        let items = match spoken {
            Spoken::V2_0 => items,
            Spoken::V1_0 => {
                converted = items.iter().cloned().map(statement_as_1_0).collect();
                &converted[..]
            }
        };
        let url = format!("{}statements", s.endpoint);
        let resp = self
            .request(&s, spoken, reqwest::Method::POST, &url)
            .json(items)
            .send()
            .await
            .map_err(|e| DeliveryError::Retry(format!("POST {url}: {e}")))?;
        let status = resp.status();
        if status.is_success() {
            return Ok(());
        }
        let body = resp.text().await.unwrap_or_default();
        match status.as_u16() {
            400 | 409 | 413 if items.len() > 1 => self.one_by_one(&s, spoken, &url, items).await,
            409 => Ok(()),
            _ => Err(classify(status, &format!("POST {url}"), &body)),
        }
    }

    /// PUTs each statement by id: 204 stored, 409 already there (idempotent by id).
    async fn one_by_one(
        &self,
        s: &Settings,
        spoken: Spoken,
        url: &str,
        items: &[Value],
    ) -> Result<(), DeliveryError> {
        let mut permanent = Vec::new();
        for item in items {
            let id = item["id"].as_str().unwrap_or_default();
            let resp = self
                .request(s, spoken, reqwest::Method::PUT, url)
                .query(&[("statementId", id)])
                .json(item)
                .send()
                .await
                .map_err(|e| DeliveryError::Retry(format!("PUT {url}?statementId={id}: {e}")))?;
            let status = resp.status();
            if status.is_success() || status.as_u16() == 409 {
                continue;
            }
            let body = resp.text().await.unwrap_or_default();
            match classify(status, &format!("PUT {url}?statementId={id}"), &body) {
                DeliveryError::Permanent(e) => permanent.push(e),
                retry => return Err(retry),
            }
        }
        if permanent.is_empty() {
            Ok(())
        } else {
            Err(DeliveryError::Permanent(permanent.join("; ")))
        }
    }
}

/// The line to speak to an LRS whose About resource answered `about`: 2.0 when its `version`
/// list names a 2.0.x, else 1.0 when it names a 1.0.x, else 2.0.
pub fn spoken_by(about: &Value) -> Spoken {
    let listed: Vec<&str> = about["version"]
        .as_array()
        .map(|v| v.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    let speaks = |line: &str| listed.iter().any(|v| v.starts_with(line));
    if !speaks("2.0") && speaks("1.0") {
        Spoken::V1_0
    } else {
        Spoken::V2_0
    }
}

/// 400 and 413 are the statement's fault (never retried); anything else may pass later (wrong
/// credentials fixed by an admin, an LRS back from an outage).
fn classify(status: reqwest::StatusCode, what: &str, body: &str) -> DeliveryError {
    let body: String = body.chars().take(500).collect();
    let msg = format!("{what}: {status}: {body}");
    match status.as_u16() {
        400 | 413 => DeliveryError::Permanent(msg),
        _ => DeliveryError::Retry(msg),
    }
}

impl Deliver for Forwarder {
    fn kind(&self) -> &'static str {
        FORWARD_KIND
    }

    fn batch_size(&self) -> usize {
        BATCH_STATEMENTS
    }

    fn deliver<'a>(&'a self, items: &'a [Value]) -> BoxFuture<'a, Result<(), DeliveryError>> {
        Box::pin(self.forward(items))
    }
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::{Spoken, normalize_endpoint, spoken_by};

    #[test]
    fn the_version_spoken_is_the_newest_line_the_about_lists() {
        assert_eq!(
            spoken_by(&json!({"version": ["1.0.3", "2.0.0"]})),
            Spoken::V2_0
        );
        assert_eq!(
            spoken_by(&json!({"version": ["1.0.3", "1.0.2"]})),
            Spoken::V1_0
        );
        assert_eq!(spoken_by(&json!({"version": ["0.95"]})), Spoken::V2_0);
        assert_eq!(spoken_by(&json!(null)), Spoken::V2_0);
    }

    #[test]
    fn endpoints_are_urls_with_a_host() {
        assert_eq!(
            normalize_endpoint("https://lrs.example.org/xapi").unwrap(),
            "https://lrs.example.org/xapi/"
        );
        assert!(normalize_endpoint("http://127.0.0.1:8080/xapi/").is_ok());
        for bad in [
            "http://[x",
            "ftp://lrs.example.org/",
            "https://u@lrs.example.org/",
            "https://lrs.example.org/?a=1",
            "https:///xapi",
        ] {
            assert!(normalize_endpoint(bad).is_err(), "{bad}");
        }
    }
}
