//! The render workers' routes: `POST /api/workers` (registration and heartbeat, with the cluster
//! token, a well-formed body and an address the caller owns) and `GET /api/workers` (admins),
//! both on the shared state.

use axum::extract::{FromRequestParts, State};
use axum::http::StatusCode;
use axum::http::header::AUTHORIZATION;
use axum::http::request::Parts;
use render_worker::cluster::Registration;
use serde::Deserialize;
use serde_json::json;
use sha2::{Digest, Sha256};
use utoipa::ToSchema;

use super::route_state::{Caller, DispatchState};
use crate::error::ApiError;
use crate::records::auth::Role;
use crate::records::extract::ApiJson;

/// A render worker's announcement (`render_worker::cluster::Registration`).
#[derive(Debug, Deserialize, ToSchema)]
#[allow(dead_code, reason = "documents the body that `Registration` parses")]
pub struct WorkerRegistration {
    /// Base URL the server reaches the worker at: `http://host:port`.
    #[schema(example = "http://10.0.0.5:8081", pattern = "^http://[^/]+:[0-9]+/?$")]
    pub url: String,
    /// Most sessions at once.
    #[schema(minimum = 1, maximum = 10000)]
    pub capacity: u32,
    /// Renderer profile (CPU reference or GPU).
    #[schema(value_type = Object)]
    pub renderer: serde_json::Value,
    /// GPU adapter, when one was opened.
    #[schema(value_type = Option<Object>)]
    pub adapter: Option<serde_json::Value>,
    /// Sessions it holds now (its heartbeat's load).
    #[schema(minimum = 0)]
    pub sessions: Option<u32>,
    /// True while it drains before exiting (it takes no new sessions).
    pub draining: Option<bool>,
}

/// A request that carries the cluster token (`Authorization: Bearer ...`). Checked before the
/// body is read, so a caller without the token learns nothing about what a body must hold.
pub(super) struct ClusterToken;

impl FromRequestParts<DispatchState> for ClusterToken {
    type Rejection = ApiError;

    async fn from_request_parts(
        parts: &mut Parts,
        state: &DispatchState,
    ) -> Result<Self, ApiError> {
        let Some(token) = &state.dispatcher.inner.worker_token else {
            return Err(ApiError::Forbidden(
                "this server takes no remote render workers (PAINSIM_WORKER_TOKEN is unset)".into(),
            ));
        };
        let sent = parts
            .headers
            .get(AUTHORIZATION)
            .and_then(|v| v.to_str().ok())
            .and_then(|v| v.strip_prefix("Bearer "))
            .unwrap_or("");
        // Compare digests: equal length, no early exit on the first differing byte.
        if Sha256::digest(sent.as_bytes()) != Sha256::digest(token.as_bytes()) {
            return Err(ApiError::Unauthorized);
        }
        Ok(ClusterToken)
    }
}

/// `POST /api/workers`: a render worker announces itself, and repeats it as its heartbeat
/// (bearer: the cluster token). Any replica takes it: it is written to the shared state.
#[utoipa::path(post, path = "/api/workers", tag = "sessions", request_body = WorkerRegistration,
    security(("bearer" = [])),
    responses((status = 204, description = "Registered (or heartbeat taken)"), (status = 400, description = "Malformed registration"),
        (status = 401, description = "Missing or wrong cluster token"),
        (status = 403, description = "This server takes no remote render workers, or the announced address is not the caller's")))]
pub(super) async fn register_worker(
    State(state): State<DispatchState>,
    _token: ClusterToken,
    peer: Option<axum::Extension<axum::extract::ConnectInfo<std::net::SocketAddr>>>,
    ApiJson(reg): ApiJson<Registration>,
) -> Result<StatusCode, ApiError> {
    let Ok((authority, path)) = render_worker::cluster::split_url(&reg.url) else {
        return Err(ApiError::BadRequest(
            "url must be http://host:port and capacity 1 to 10000".into(),
        ));
    };
    let port_ok = authority
        .rsplit_once(':')
        .is_some_and(|(h, p)| !h.is_empty() && p.parse::<u16>().is_ok_and(|p| p > 0));
    if !port_ok
        || !(path.is_empty() || path == "/")
        || reg.capacity == 0
        || reg.capacity > 10_000
        || reg.sessions.is_some_and(|n| n > 1_000_000)
    {
        return Err(ApiError::BadRequest(
            "url must be http://host:port and capacity 1 to 10000".into(),
        ));
    }
    // A worker announces only an address it owns: the host must be (or resolve to) the address
    // the announcement comes from. Otherwise one token holder could point sessions anywhere.
    let Some(axum::Extension(axum::extract::ConnectInfo(peer))) = peer else {
        return Err(ApiError::Forbidden(
            "the caller's address is unknown, so the announced address cannot be checked".into(),
        ));
    };
    let mut reg = reg;
    reg.url = reg.url.trim_end_matches('/').to_string();
    if !owns_address(peer.ip(), &authority).await {
        return Err(ApiError::Forbidden(format!(
            "the announced address {} is not the caller's ({})",
            reg.url,
            peer.ip()
        )));
    }
    let beat = super::Heartbeat {
        sessions: reg.sessions.unwrap_or(0),
        draining: reg.draining,
    };
    state.dispatcher.registry().register(&reg, beat).await?;
    Ok(StatusCode::NO_CONTENT)
}

/// Whether `authority` (`host:port`) names `peer`: an IP literal equal to it, or a host name
/// whose every address is it (IPv4-mapped IPv6 addresses compare as IPv4): a name that also
/// resolves elsewhere could send sessions there.
async fn owns_address(peer: std::net::IpAddr, authority: &str) -> bool {
    // Loopback is one host however it is spelled (127.0.0.1, ::1: `localhost` resolves to both).
    let canonical = |ip: std::net::IpAddr| match ip {
        ip if ip.is_loopback() => std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST),
        std::net::IpAddr::V6(v6) => v6
            .to_ipv4_mapped()
            .map_or(std::net::IpAddr::V6(v6), std::net::IpAddr::V4),
        v4 => v4,
    };
    let peer = canonical(peer);
    let lookup = tokio::time::timeout(
        std::time::Duration::from_secs(2),
        tokio::net::lookup_host(authority.to_string()),
    );
    match lookup.await {
        Ok(Ok(addrs)) => {
            let addrs: Vec<std::net::IpAddr> = addrs.map(|a| canonical(a.ip())).collect();
            !addrs.is_empty() && addrs.iter().all(|a| *a == peer)
        }
        _ => false,
    }
}

/// `GET /api/workers`: registered workers (admins).
#[utoipa::path(get, path = "/api/workers", tag = "sessions",
    responses((status = 200, description = "The in-process host and the registered workers", body = Object), (status = 401), (status = 403, description = "Not an admin")))]
pub(super) async fn list_workers(
    State(state): State<DispatchState>,
    Caller(user): Caller,
) -> Result<axum::Json<serde_json::Value>, ApiError> {
    user.require(&[Role::Admin])?;
    let local = state.dispatcher.local_host().map(|h| h.health());
    let remote = state.dispatcher.workers().await?;
    Ok(axum::Json(json!({ "in_process": local, "remote": remote })))
}
