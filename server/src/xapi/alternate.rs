//! The Alternate Request Syntax of xAPI 1.0.3 (Communication 1.3): a client that cannot send
//! custom headers or methods (a browser form, an old LMS) POSTs to a resource with only
//! `method=GET|PUT|POST|DELETE` in the query string and an `application/x-www-form-urlencoded`
//! body whose parameters stand for the request's headers (`Authorization`,
//! `X-Experience-API-Version`, `Content-Type`, `Content-Length`, `If-Match`, `If-None-Match`), its
//! body (`content`) and its query parameters (all the others).
//!
//! This middleware runs before every other of the LRS: it rewrites such a request into the one it
//! stands for, so the version check, the credential and the handlers see an ordinary request. It
//! applies to 1.0.x requests only (the version named by the form, else by the header): xAPI 2.0
//! removed the syntax, so a 2.0 request with `method=` goes on unchanged and is refused as today.
//! A 1.0.x POST with `method=` that breaks the syntax's rules (another query parameter, a body
//! that is not form-encoded, an unknown method) is refused with 400 (Communication 1.3: "the LRS
//! MUST reject ... with 400 Bad Request").

use axum::body::{Body, to_bytes};
use axum::extract::{Request, State};
use axum::http::header::{CONTENT_LENGTH, CONTENT_TYPE};
use axum::http::{HeaderName, HeaderValue, Method, Uri};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::state::XapiState;
use super::version::{Spoken, VERSION_HEADER, accepted};
use crate::error::ApiError;

/// The form parameters that stand for headers (Communication 1.3, lower case).
const HEADER_PARAMS: [&str; 6] = [
    "authorization",
    "x-experience-api-version",
    "content-type",
    "content-length",
    "if-match",
    "if-none-match",
];

/// The pairs of a URL-encoded text (`+` is a space), decoded.
fn decode_pairs(encoded: &str) -> Vec<(String, String)> {
    let mut url = reqwest::Url::parse("http://lrs.invalid/").expect("a constant, valid URL");
    url.set_query(Some(encoded));
    url.query_pairs()
        .map(|(k, v)| (k.into_owned(), v.into_owned()))
        .collect()
}

/// The pairs URL-encoded as a query string.
fn encode_pairs(pairs: &[(String, String)]) -> String {
    let mut url = reqwest::Url::parse("http://lrs.invalid/").expect("a constant, valid URL");
    url.query_pairs_mut()
        .extend_pairs(pairs.iter().map(|(k, v)| (k.as_str(), v.as_str())));
    url.query().unwrap_or_default().to_owned()
}

/// True when a Content-Type names `application/x-www-form-urlencoded` (any parameters, any case).
fn is_form(content_type: Option<&HeaderValue>) -> bool {
    content_type
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.split(';').next())
        .is_some_and(|e| {
            e.trim()
                .eq_ignore_ascii_case("application/x-www-form-urlencoded")
        })
}

/// 400 for a request that breaks the syntax's rules, answered in version 1.0.3 (this middleware
/// runs outside the version middleware, so it sets the header itself).
fn refuse(message: String) -> Response {
    let mut resp =
        ApiError::BadRequest(format!("Alternate Request Syntax: {message}")).into_response();
    resp.headers_mut().insert(
        VERSION_HEADER,
        HeaderValue::from_static(Spoken::V1_0.answer()),
    );
    resp
}

/// Rewrites a 1.0.x Alternate Request Syntax request into the request it stands for.
pub async fn alternate_syntax(
    State(state): State<XapiState>,
    req: Request,
    next: Next,
) -> Response {
    // Most requests carry no `method` parameter: they pass without their query being decoded.
    if !req.uri().query().is_some_and(|q| q.contains("method")) {
        return next.run(req).await;
    }
    let query = req.uri().query().map(decode_pairs).unwrap_or_default();
    let Some(method) = query
        .iter()
        .find(|(k, _)| k == "method")
        .map(|(_, v)| v.clone())
    else {
        return next.run(req).await;
    };
    if req.method() != Method::POST {
        return next.run(req).await;
    }
    let (mut parts, body) = req.into_parts();
    let bytes = match to_bytes(body, state.max_body_bytes).await {
        Ok(b) => b,
        Err(_) => {
            let mut resp = ApiError::PayloadTooLarge(state.max_body_bytes).into_response();
            let answer = Spoken::of(&parts.headers).answer();
            resp.headers_mut()
                .insert(VERSION_HEADER, HeaderValue::from_static(answer));
            return resp;
        }
    };
    let form_body = is_form(parts.headers.get(CONTENT_TYPE));
    let form = if form_body {
        decode_pairs(&String::from_utf8_lossy(&bytes))
    } else {
        Vec::new()
    };
    let mut headers = parts.headers.clone();
    for (k, v) in &form {
        let name = k.to_ascii_lowercase();
        if name == VERSION_HEADER
            && let Ok(v) = HeaderValue::from_str(v)
        {
            headers.insert(VERSION_HEADER, v);
        }
    }
    let two_or_none = match headers.get(VERSION_HEADER).and_then(|v| v.to_str().ok()) {
        None => true,
        Some(v) => accepted(v.trim()) && Spoken::of(&headers) == Spoken::V2_0,
    };
    if two_or_none {
        // No version (the version check refuses it) or 2.0, which has no such syntax: the
        // request goes on as it came.
        return next
            .run(Request::from_parts(parts, Body::from(bytes)))
            .await;
    }
    if !form_body {
        return refuse("the body must be application/x-www-form-urlencoded".into());
    }
    if query.len() != 1 {
        return refuse(
            "the query string must hold only `method`; send the other \
             parameters in the form"
                .into(),
        );
    }
    let method = match method.to_ascii_uppercase().as_str() {
        "GET" => Method::GET,
        "PUT" => Method::PUT,
        "POST" => Method::POST,
        "DELETE" => Method::DELETE,
        _ => {
            return refuse(format!("method {method} is none of GET, PUT, POST, DELETE"));
        }
    };
    let mut content: Option<String> = None;
    let mut params = Vec::new();
    headers.remove(CONTENT_TYPE);
    headers.remove(CONTENT_LENGTH);
    for (k, v) in form {
        let name = k.to_ascii_lowercase();
        if name == "content" {
            content = Some(v);
        } else if HEADER_PARAMS.contains(&name.as_str()) {
            if name == "content-length" {
                continue;
            }
            match (
                HeaderName::from_bytes(name.as_bytes()),
                HeaderValue::from_str(&v),
            ) {
                (Ok(n), Ok(v)) => {
                    headers.insert(n, v);
                }
                _ => {
                    return refuse(format!("form parameter {k} is not a valid header value"));
                }
            }
        } else {
            params.push((k, v));
        }
    }
    let body = content.unwrap_or_default();
    if !body.is_empty() && !headers.contains_key(CONTENT_TYPE) {
        // Communication 1.3 lets the form omit Content-Type; statements and JSON documents are
        // what such clients send, so the content is read as JSON.
        headers.insert(CONTENT_TYPE, HeaderValue::from_static("application/json"));
    }
    headers.insert(CONTENT_LENGTH, HeaderValue::from(body.len()));
    let path_and_query = if params.is_empty() {
        parts.uri.path().to_owned()
    } else {
        format!("{}?{}", parts.uri.path(), encode_pairs(&params))
    };
    let Ok(uri) = path_and_query.parse::<Uri>() else {
        return refuse("unusable parameters".into());
    };
    parts.method = method;
    parts.uri = uri;
    parts.headers = headers;
    next.run(Request::from_parts(parts, Body::from(body))).await
}
