//! A worker in a cluster: registration with the server, and the small HTTP/1.1 JSON client that
//! server and worker use to talk to each other.
//!
//! A `render-worker` process started with `RENDER_WORKER_REGISTER_URL` (the server's
//! `/api/workers` endpoint) and `RENDER_WORKER_TOKEN` announces itself there: its URL, capacity,
//! renderer and adapter. It repeats the announcement every [`HEARTBEAT`] with its load and
//! whether it drains: that heartbeat is what the servers' shared state (PostgreSQL) knows of
//! it, and a worker whose heartbeats stop is marked dead by whichever server replica notices
//! first.
//!
//! The client speaks plain HTTP/1.1 with `Connection: close` over TCP, which is all that the
//! cluster-internal calls need (loopback or a private network; TLS is the job of the network
//! in front). It avoids pulling a full HTTP client stack into both binaries.

use std::sync::Arc;
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::Notify;

/// How often a worker re-announces itself (its heartbeat). Simulator choice: a server marks a
/// worker dead after three missed heartbeats (6 s), and a draining worker's state reaches
/// every replica within 2 s; one small request every 2 s costs nothing.
pub const HEARTBEAT: Duration = Duration::from_secs(2);

/// Time limit of one cluster-internal request. Simulator choice: these are loopback or LAN calls
/// that answer in milliseconds; restoring a session (which may load a region) is the slow one.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(60);

/// Largest response body read, bytes (a snapshot with a long log is well below this).
const MAX_RESPONSE_BYTES: usize = 64 << 20;

/// What a worker tells the server about itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Registration {
    /// Base URL the server reaches the worker at, e.g. `http://10.0.0.5:8081`.
    pub url: String,
    /// Most sessions at once.
    pub capacity: usize,
    /// Renderer profile (CPU reference or GPU) as JSON.
    pub renderer: serde_json::Value,
    /// GPU adapter, when one was opened (`null` for software-only workers).
    pub adapter: Option<serde_json::Value>,
    /// Sessions it holds now (heartbeats carry it; absent counts as 0).
    #[serde(default)]
    pub sessions: Option<usize>,
    /// True while it drains before exiting: it takes no new sessions.
    #[serde(default)]
    pub draining: bool,
}

/// Why a URL cannot be requested by this client.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UrlError {
    /// Not an `http://` URL (TLS is the job of the network in front).
    #[error("{0}: only http:// URLs are supported")]
    UnsupportedScheme(String),
    /// Nothing between `http://` and the path.
    #[error("{0}: no host")]
    NoHost(String),
}

/// Why bytes read from a peer are not a complete HTTP/1.1 response.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ResponseError {
    /// The header never ends (no blank line).
    #[error("no complete response header")]
    NoHeader,
    /// The header holds bytes that are not UTF-8.
    #[error("response header is not UTF-8")]
    HeaderNotUtf8,
    /// The first line has no numeric status.
    #[error("bad status line {0:?}")]
    BadStatusLine(String),
    /// Fewer body bytes than the `Content-Length` header announced.
    #[error("response body shorter than its Content-Length")]
    BodyShort,
    /// A chunk's size line never ends.
    #[error("truncated chunk size")]
    TruncatedChunkSize,
    /// A chunk's size line holds bytes that are not UTF-8.
    #[error("bad chunk size")]
    ChunkSizeNotUtf8,
    /// A chunk's size is not a hexadecimal number.
    #[error("bad chunk size {0:?}")]
    BadChunkSize(String),
    /// A chunk is shorter than its size, or lacks its line end.
    #[error("truncated chunk")]
    TruncatedChunk,
}

/// Why a cluster-internal request got no usable answer.
#[derive(Debug, thiserror::Error)]
pub enum HttpError {
    /// The URL cannot be requested.
    #[error(transparent)]
    Url(#[from] UrlError),
    /// No complete answer within [`REQUEST_TIMEOUT`].
    #[error("{method} {url}: no answer within {timeout_s} s")]
    Timeout {
        /// Request method.
        method: String,
        /// Request URL.
        url: String,
        /// The limit, seconds.
        timeout_s: u64,
    },
    /// Connecting, writing or reading failed.
    #[error("{method} {url}: {source}")]
    Io {
        /// Request method.
        method: String,
        /// Request URL.
        url: String,
        /// The socket's error.
        source: std::io::Error,
    },
    /// A header name or value would split the request (CR or LF in it).
    #[error("{method} {url}: header {header} contains a line break")]
    HeaderLineBreak {
        /// Request method.
        method: String,
        /// Request URL.
        url: String,
        /// The header's name.
        header: String,
    },
    /// The answer is not an HTTP/1.1 response.
    #[error("{method} {url}: {source}")]
    Response {
        /// Request method.
        method: String,
        /// Request URL.
        url: String,
        /// What is wrong with it.
        source: ResponseError,
    },
    /// The body is not JSON ([`HttpResponse::json`]).
    #[error("response is not JSON: {0}")]
    NotJson(#[source] serde_json::Error),
}

/// A response: status, headers and body.
#[derive(Debug, Clone)]
pub struct HttpResponse {
    /// HTTP status code.
    pub status: u16,
    /// Header names (lower case) and values, in order.
    pub headers: Vec<(String, String)>,
    /// Body bytes.
    pub body: Vec<u8>,
}

impl HttpResponse {
    /// The body as JSON.
    pub fn json(&self) -> Result<serde_json::Value, HttpError> {
        serde_json::from_slice(&self.body).map_err(HttpError::NotJson)
    }
}

/// Splits `http://host:port/path` into `(host:port, /path)`.
pub fn split_url(url: &str) -> Result<(String, String), UrlError> {
    let rest = url
        .strip_prefix("http://")
        .ok_or_else(|| UrlError::UnsupportedScheme(url.to_string()))?;
    let (authority, path) = match rest.find('/') {
        Some(i) => (&rest[..i], &rest[i..]),
        None => (rest, "/"),
    };
    if authority.is_empty() {
        return Err(UrlError::NoHost(url.to_string()));
    }
    let authority = if authority.contains(':') {
        authority.to_string()
    } else {
        format!("{authority}:80")
    };
    Ok((authority, path.to_string()))
}

/// One request with an optional JSON body and bearer token; `Connection: close`.
pub async fn request(
    method: &str,
    url: &str,
    body: Option<&serde_json::Value>,
    bearer: Option<&str>,
) -> Result<HttpResponse, HttpError> {
    let auth = bearer.map(|t| format!("Bearer {t}"));
    let headers: Vec<(&str, &str)> = auth.iter().map(|a| ("Authorization", a.as_str())).collect();
    request_with_headers(method, url, body, &headers).await
}

/// [`request`] with arbitrary extra headers (cookies and CSRF tokens in tests and benches).
pub async fn request_with_headers(
    method: &str,
    url: &str,
    body: Option<&serde_json::Value>,
    headers: &[(&str, &str)],
) -> Result<HttpResponse, HttpError> {
    tokio::time::timeout(REQUEST_TIMEOUT, request_inner(method, url, body, headers))
        .await
        .map_err(|_| HttpError::Timeout {
            method: method.to_string(),
            url: url.to_string(),
            timeout_s: REQUEST_TIMEOUT.as_secs(),
        })?
}

async fn request_inner(
    method: &str,
    url: &str,
    body: Option<&serde_json::Value>,
    headers: &[(&str, &str)],
) -> Result<HttpResponse, HttpError> {
    let io = |source: std::io::Error| HttpError::Io {
        method: method.to_string(),
        url: url.to_string(),
        source,
    };
    let (authority, path) = split_url(url)?;
    let mut stream = TcpStream::connect(&authority).await.map_err(io)?;
    let payload = body.map(|b| b.to_string()).unwrap_or_default();
    let mut head = format!(
        "{method} {path} HTTP/1.1\r\nHost: {authority}\r\nConnection: close\r\nAccept: application/json\r\n"
    );
    for (k, v) in headers {
        if k.contains(['\r', '\n']) || v.contains(['\r', '\n']) {
            return Err(HttpError::HeaderLineBreak {
                method: method.to_string(),
                url: url.to_string(),
                header: (*k).to_string(),
            });
        }
        head.push_str(&format!("{k}: {v}\r\n"));
    }
    if body.is_some() {
        head.push_str(&format!(
            "Content-Type: application/json\r\nContent-Length: {}\r\n",
            payload.len()
        ));
    }
    head.push_str("\r\n");
    stream.write_all(head.as_bytes()).await.map_err(io)?;
    stream.write_all(payload.as_bytes()).await.map_err(io)?;
    let mut raw = Vec::new();
    stream
        .take(MAX_RESPONSE_BYTES as u64 + 64 * 1024)
        .read_to_end(&mut raw)
        .await
        .map_err(io)?;
    parse_response(&raw).map_err(|source| HttpError::Response {
        method: method.to_string(),
        url: url.to_string(),
        source,
    })
}

/// Parses an HTTP/1.1 response read to the end (Content-Length or chunked or read-to-close).
pub fn parse_response(raw: &[u8]) -> Result<HttpResponse, ResponseError> {
    let end = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or(ResponseError::NoHeader)?;
    let head = std::str::from_utf8(&raw[..end]).map_err(|_| ResponseError::HeaderNotUtf8)?;
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap_or_default();
    let status: u16 = status_line
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| ResponseError::BadStatusLine(status_line.to_string()))?;
    let mut length = None;
    let mut chunked = false;
    let mut headers = Vec::new();
    for l in lines {
        if let Some((k, v)) = l.split_once(':') {
            let (k, v) = (k.trim().to_ascii_lowercase(), v.trim());
            if k == "content-length" {
                length = v.parse::<usize>().ok();
            } else if k == "transfer-encoding" && v.eq_ignore_ascii_case("chunked") {
                chunked = true;
            }
            headers.push((k, v.to_string()));
        }
    }
    let rest = &raw[end + 4..];
    let body = if chunked {
        dechunk(rest)?
    } else if let Some(n) = length {
        rest.get(..n).ok_or(ResponseError::BodyShort)?.to_vec()
    } else {
        rest.to_vec()
    };
    Ok(HttpResponse {
        status,
        headers,
        body,
    })
}

fn dechunk(mut b: &[u8]) -> Result<Vec<u8>, ResponseError> {
    let mut out = Vec::new();
    loop {
        let eol = b
            .windows(2)
            .position(|w| w == b"\r\n")
            .ok_or(ResponseError::TruncatedChunkSize)?;
        let size_text =
            std::str::from_utf8(&b[..eol]).map_err(|_| ResponseError::ChunkSizeNotUtf8)?;
        let size = usize::from_str_radix(size_text.split(';').next().unwrap_or("").trim(), 16)
            .map_err(|_| ResponseError::BadChunkSize(size_text.to_string()))?;
        b = &b[eol + 2..];
        if size == 0 {
            return Ok(out);
        }
        out.extend_from_slice(b.get(..size).ok_or(ResponseError::TruncatedChunk)?);
        b = b.get(size + 2..).ok_or(ResponseError::TruncatedChunk)?;
    }
}

/// Announces the worker to the server now and every [`HEARTBEAT`] (forever; run it as a task),
/// with what `me` says at each announcement (a capacity that a calibration changed reaches the
/// server at the next one). Failures are logged and retried: the server may start after the
/// worker.
pub async fn register_forever(
    register_url: String,
    token: String,
    me: impl Fn() -> Registration + Send + 'static,
) {
    heartbeat_forever(register_url, token, me, Arc::new(Notify::new())).await;
}

/// [`register_forever`], and a heartbeat at once whenever `now` is notified (a worker that
/// starts draining tells the servers without waiting for the next beat).
pub async fn heartbeat_forever(
    register_url: String,
    token: String,
    me: impl Fn() -> Registration + Send + 'static,
    now: Arc<Notify>,
) {
    let mut announced = false;
    loop {
        let body = match serde_json::to_value(me()) {
            Ok(b) => b,
            Err(e) => {
                tracing::error!("cannot encode the registration: {e}");
                return;
            }
        };
        match request("POST", &register_url, Some(&body), Some(&token)).await {
            Ok(r) if (200..300).contains(&r.status) => {
                if !announced {
                    tracing::info!(server = %register_url, "registered with the server");
                    announced = true;
                }
            }
            Ok(r) => {
                tracing::warn!(status = r.status, body = %String::from_utf8_lossy(&r.body), "the server refused the registration");
                announced = false;
            }
            Err(e) => {
                tracing::warn!("cannot register with the server: {e}");
                announced = false;
            }
        }
        tokio::select! {
            () = tokio::time::sleep(HEARTBEAT) => {}
            () = now.notified() => {}
        }
    }
}

/// How a worker process serves: where it registers, the address it announces, and how long it
/// drains when asked to stop.
#[derive(Debug, Clone)]
pub struct Serving {
    /// The server's `/api/workers` and the cluster token; `None` for a standalone worker.
    pub register: Option<(String, String)>,
    /// The URL announced; `None`: `http://` and the listener's address.
    pub public_url: Option<String>,
    /// Longest wait for live sessions to end after the stop signal, before the rest are handed
    /// back to the servers (which restore them elsewhere from snapshot and log).
    pub drain: Duration,
}

/// `listener` as the server and the worker serve sessions on it: Nagle's algorithm off on every
/// accepted connection, so that a frame's last segment leaves at once instead of waiting for
/// the client's acknowledgement of the segments before it (measured through the server, one
/// learner on loopback: 0.16 ms median, 13.7 ms at p90 and 35 ms at most from the frame's
/// socket write to the client's read with Nagle on; 0.10 / 0.15 / 0.24 ms with it off).
pub fn accepting(
    listener: tokio::net::TcpListener,
) -> axum::serve::TapIo<tokio::net::TcpListener, fn(&mut TcpStream)> {
    fn no_delay(tcp: &mut TcpStream) {
        if let Err(e) = tcp.set_nodelay(true) {
            tracing::debug!("TCP_NODELAY on an accepted connection: {e}");
        }
    }
    axum::serve::ListenerExt::tap_io(listener, no_delay as fn(&mut TcpStream))
}

/// Serves `host` on `listener` (heartbeats to the server when registered) until `stop`
/// resolves, then drains: no new sessions (503 `draining`, `/readyz` 503, the next heartbeat
/// says so at once), live sessions go on until they end or `serving.drain` passes, then the
/// rest are ended, which the servers' relays see as a lost worker: they restore each session
/// on another worker from its initial snapshot and log, and send again what was not
/// acknowledged (nothing is applied twice). Returns once the sessions' threads have finished.
pub async fn serve_until_drained(
    listener: tokio::net::TcpListener,
    host: crate::session::SessionHost,
    serving: Serving,
    stop: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let addr = listener.local_addr()?;
    let beat_now = Arc::new(Notify::new());
    if let Some((url, token)) = serving.register.clone() {
        let announced = host.clone();
        let me_url = serving
            .public_url
            .clone()
            .unwrap_or_else(|| format!("http://{addr}"));
        let me = move || {
            let health = announced.health();
            Registration {
                url: me_url.clone(),
                capacity: health.capacity,
                renderer: serde_json::to_value(&health.renderer).unwrap_or_default(),
                adapter: health.adapter,
                sessions: Some(health.sessions),
                draining: health.draining,
            }
        };
        tokio::spawn(heartbeat_forever(url, token, me, beat_now.clone()));
    }
    let (quit_tx, quit_rx) = tokio::sync::oneshot::channel::<()>();
    let router = crate::session::http::router(host.clone());
    let served = tokio::spawn(async move {
        axum::serve(accepting(listener), router)
            .with_graceful_shutdown(async move {
                let _ = quit_rx.await;
            })
            .await
    });
    stop.await;
    host.start_draining();
    beat_now.notify_one();
    let live = host.health().sessions;
    tracing::info!(
        sessions = live,
        drain_s = serving.drain.as_secs_f64(),
        "draining: no new sessions; waiting for the live ones"
    );
    let deadline = tokio::time::Instant::now() + serving.drain;
    while host.health().sessions > 0 && tokio::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let left = host.health().sessions;
    if left > 0 {
        tracing::info!(
            sessions = left,
            "drain time is up: handing the live sessions back to the servers"
        );
    }
    // Ending the sessions closes their sockets: each relay restores its session elsewhere.
    let ended = host.clone();
    let _ = tokio::task::spawn_blocking(move || ended.shutdown()).await;
    let _ = quit_tx.send(());
    match tokio::time::timeout(Duration::from_secs(5), served).await {
        Ok(Ok(r)) => r,
        Ok(Err(e)) => Err(std::io::Error::other(e)),
        Err(_) => Ok(()),
    }
}

/// The stop signal of a worker process: SIGTERM (an orchestrator's) or SIGINT.
pub async fn stop_signal() {
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    tokio::select! {
        () = term => {}
        _ = tokio::signal::ctrl_c() => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_and_responses_parse() {
        assert_eq!(
            split_url("http://127.0.0.1:81/a/b").unwrap(),
            ("127.0.0.1:81".into(), "/a/b".into())
        );
        assert_eq!(
            split_url("http://w1").unwrap(),
            ("w1:80".into(), "/".into())
        );
        assert_eq!(
            split_url("https://w1"),
            Err(UrlError::UnsupportedScheme("https://w1".into()))
        );
        assert_eq!(
            split_url("http:///a").unwrap_err().to_string(),
            "http:///a: no host"
        );
        let r =
            parse_response(b"HTTP/1.1 201 Created\r\nContent-Length: 2\r\n\r\n{}extra").unwrap();
        assert_eq!((r.status, r.body.as_slice()), (201, b"{}".as_slice()));
        let r = parse_response(b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n3\r\nabc\r\n2\r\nde\r\n0\r\n\r\n").unwrap();
        assert_eq!(r.body, b"abcde");
        assert_eq!(
            parse_response(b"HTTP/1.1 200 OK\r\nContent-Length: 9\r\n\r\nabc").unwrap_err(),
            ResponseError::BodyShort
        );
        assert_eq!(
            parse_response(b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n")
                .unwrap_err()
                .to_string(),
            "bad chunk size \"zz\""
        );
    }
}
