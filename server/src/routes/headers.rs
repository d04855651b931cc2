//! Security headers on every response, and `Cache-Control: no-store` on the JSON API.
//!
//! The Content-Security-Policy fits the web client: scripts, styles, fetches and websockets
//! only from the server's own origin (no inline script or style), frames decoded from blobs,
//! no plug-ins, and no framing by other sites (OWASP Secure Headers Project, "Content Security
//! Policy" and "X-Frame-Options"; `frame-ancestors` supersedes the latter). HSTS is sent only
//! when the deployment serves over TLS (the same switch as `Secure` cookies), since a browser
//! ignores it over plain HTTP and a loopback development server must stay reachable that way.

use axum::extract::{Request, State};
use axum::http::HeaderValue;
use axum::http::header::{
    CACHE_CONTROL, CONTENT_SECURITY_POLICY, REFERRER_POLICY, STRICT_TRANSPORT_SECURITY,
    X_CONTENT_TYPE_OPTIONS,
};
use axum::middleware::Next;
use axum::response::Response;

use crate::error::ApiError;

/// The Content-Security-Policy of every response.
pub const CONTENT_SECURITY_POLICY_VALUE: &str = "default-src 'self'; script-src 'self'; \
     style-src 'self'; img-src 'self' blob: data:; connect-src 'self'; font-src 'self'; \
     object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'";

/// The Permissions-Policy: the client uses no device or payment API.
pub const PERMISSIONS_POLICY_VALUE: &str =
    "camera=(), microphone=(), geolocation=(), payment=(), usb=()";

/// HSTS for TLS deployments: one year, subdomains included (OWASP HTTP Strict Transport
/// Security cheat sheet's recommended max-age).
pub const HSTS_VALUE: &str = "max-age=31536000; includeSubDomains";

/// Whether responses carry HSTS.
#[derive(Debug, Clone, Copy)]
pub struct Tls(pub bool);

/// Adds the security headers (and `no-store` to `/api/` responses).
pub async fn security_headers(State(tls): State<Tls>, req: Request, next: Next) -> Response {
    let api = req.uri().path().starts_with("/api/");
    let mut res = next.run(req).await;
    let h = res.headers_mut();
    // A handler that needs another policy sets its own (the LTI deep-linking response posts a
    // form to the platform); every other response gets the client's.
    h.entry(CONTENT_SECURITY_POLICY)
        .or_insert(HeaderValue::from_static(CONTENT_SECURITY_POLICY_VALUE));
    h.insert(X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    h.insert(
        "permissions-policy",
        HeaderValue::from_static(PERMISSIONS_POLICY_VALUE),
    );
    if api {
        h.insert(CACHE_CONTROL, HeaderValue::from_static("no-store"));
    }
    if tls.0 {
        h.insert(
            STRICT_TRANSPORT_SECURITY,
            HeaderValue::from_static(HSTS_VALUE),
        );
    }
    res
}

/// Any `/api/` path no route serves: a JSON 404, never the web client's page.
pub async fn api_not_found() -> ApiError {
    ApiError::NotFound("API endpoint".into())
}
