//! What the three document resources share: reading a request's document, the concurrency
//! rules, the JSON merge of POST, and the responses (xAPI 2.0, Communication "Document
//! Resources" and "Concurrency").
//!
//! - A document is any bytes with any Content-Type, stored exactly as sent (no Content-Type:
//!   `application/octet-stream`). An `application/json` document must be JSON.
//! - POST to a missing document stores it as PUT would; POST to an existing one merges: both must
//!   be `application/json` JSON objects (else 400 and nothing changes), and each top-level
//!   property posted replaces the stored one.
//! - ETag: the SHA-256 of the content in hex, quoted (a strong tag); for 1.0.x requests the
//!   SHA-1 of the content in hex, quoted (xAPI 1.0.3, Communication 3.1 "Concurrency": "the
//!   value SHOULD be calculated as a SHA1 hexadecimal value"), computed from the stored bytes so
//!   both lines see one document. `If-Match` (a list or `*`)
//!   and `If-None-Match` (a list or `*`) are honoured on PUT, POST and DELETE as RFC 9110
//!   describes: 412 when one fails, and nothing changes. A PUT with neither header to a document
//!   that exists is a 409 (the 2.0 rule: the client must say what it overwrites).
//! - Writes run in one transaction holding the document's row lock, so the precondition checked
//!   is the state written over.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::http::header::{CONTENT_TYPE, ETAG, IF_MATCH, IF_NONE_MATCH, LAST_MODIFIED};
use axum::http::{HeaderMap, HeaderName, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde_json::Value;
use sha1::Sha1;
use sha2::{Digest, Sha256};
use sqlx::PgPool;
use time::OffsetDateTime;
use utoipa::IntoParams;
use uuid::Uuid;

use super::store::{self, DocKey, Kind, Scope, Stored};
use crate::error::ApiError;
use crate::xapi::error::XapiError;
use crate::xapi::statements::timefmt::http_date;
use crate::xapi::version::Spoken;

/// Content-Type of a document sent without one (RFC 9110 8.3: the recipient may assume it).
pub const DEFAULT_CONTENT_TYPE: &str = "application/octet-stream";

/// How many times a write retries when a concurrent request created the same document between
/// its read and its insert (our choice: a second try always sees the row, so 2 would do).
const WRITE_ATTEMPTS: usize = 3;

/// A document as a request sends it.
#[derive(Debug)]
pub struct Incoming {
    /// Its Content-Type (as sent, trimmed).
    pub content_type: String,
    /// Its bytes.
    pub body: Bytes,
}

impl Incoming {
    /// The request's document, or 413 over the server's body limit, or 400 for a Content-Type
    /// that is not visible ASCII or an `application/json` body that is not JSON.
    pub fn read(
        headers: &HeaderMap,
        body: Result<Bytes, BytesRejection>,
        max_body_bytes: usize,
    ) -> Result<Incoming, ApiError> {
        let body = body.map_err(|r| {
            if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
                ApiError::PayloadTooLarge(max_body_bytes)
            } else {
                ApiError::BadRequest(format!("unreadable body: {}", r.body_text()))
            }
        })?;
        let content_type = match headers.get(CONTENT_TYPE) {
            None => DEFAULT_CONTENT_TYPE.to_owned(),
            Some(v) => {
                let v = v.to_str().map_err(|_| {
                    ApiError::BadRequest("Content-Type: must be visible ASCII".into())
                })?;
                match v.trim() {
                    "" => DEFAULT_CONTENT_TYPE.to_owned(),
                    t => t.to_owned(),
                }
            }
        };
        if is_json(&content_type) && serde_json::from_slice::<Value>(&body).is_err() {
            return Err(ApiError::BadRequest(
                "the document's Content-Type is application/json but it is not valid JSON".into(),
            ));
        }
        Ok(Incoming { content_type, body })
    }
}

/// True when a Content-Type names `application/json` (any parameters, any case).
pub fn is_json(content_type: &str) -> bool {
    content_type
        .split(';')
        .next()
        .is_some_and(|essence| essence.trim().eq_ignore_ascii_case("application/json"))
}

/// The ETag of some content: SHA-256 in hex.
pub fn etag_of(content: &[u8]) -> String {
    hex::encode(Sha256::digest(content))
}

/// The ETag a request of line `spoken` sees for a stored document: the stored SHA-256 for 2.0,
/// the SHA-1 of the same bytes for 1.0.
fn etag_seen(spoken: Spoken, doc: &Stored) -> String {
    match spoken {
        Spoken::V1_0 => hex::encode(Sha1::digest(&doc.content)),
        Spoken::V2_0 => doc.etag.clone(),
    }
}

fn header(resp: &mut Response, name: HeaderName, value: &str) {
    if let Ok(v) = HeaderValue::from_str(value) {
        resp.headers_mut().insert(name, v);
    }
}

/// The values of a header that may repeat, joined as one list (RFC 9110 5.3).
fn header_list(headers: &HeaderMap, name: HeaderName) -> Result<Option<String>, ApiError> {
    let mut values = Vec::new();
    for v in headers.get_all(&name) {
        values.push(
            v.to_str()
                .map_err(|_| ApiError::BadRequest(format!("{name}: must be visible ASCII")))?,
        );
    }
    Ok((!values.is_empty()).then(|| values.join(",")))
}

/// The concurrency headers of document writes, as the routes document them and
/// [`check_preconditions`] reads them.
#[derive(Debug, IntoParams)]
#[into_params(parameter_in = Header)]
pub struct Preconditions {
    /// Write only if the document's ETag is one of these (or `*`: if it exists); else 412.
    #[param(rename = "If-Match")]
    if_match: Option<String>,
    /// Write only if the document's ETag is none of these (or `*`: if it does not exist); else
    /// 412.
    #[param(rename = "If-None-Match")]
    if_none_match: Option<String>,
}

impl Preconditions {
    /// The request's `If-Match` and `If-None-Match`, each of its lines joined as one list; 400
    /// when one is not visible ASCII.
    pub fn read(headers: &HeaderMap) -> Result<Preconditions, ApiError> {
        Ok(Preconditions {
            if_match: header_list(headers, IF_MATCH)?,
            if_none_match: header_list(headers, IF_NONE_MATCH)?,
        })
    }
}

/// Whether an `If-Match`/`If-None-Match` list names `etag` (`*` names any document). A weak
/// tag (`W/"..."`) never matches in the strong comparison that If-Match uses; tags without
/// quotes are read leniently as the text they hold.
fn list_matches(list: &str, etag: &str, strong: bool) -> bool {
    list.split(',').map(str::trim).any(|tag| {
        if tag == "*" {
            return true;
        }
        let (weak, tag) = match tag.strip_prefix("W/") {
            Some(rest) => (true, rest),
            None => (false, tag),
        };
        let opaque = tag
            .strip_prefix('"')
            .and_then(|t| t.strip_suffix('"'))
            .unwrap_or(tag);
        !(strong && weak) && opaque == etag
    })
}

/// The write a request asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Write {
    /// Store, replacing.
    Put,
    /// Store, merging JSON objects.
    Post,
    /// Delete.
    Delete,
}

/// The concurrency rules for a write to a document whose current ETag is `current` (`None`: it
/// does not exist).
pub fn check_preconditions(
    preconditions: &Preconditions,
    current: Option<&str>,
    write: Write,
    kind: Kind,
    spoken: Spoken,
) -> Result<(), XapiError> {
    let Preconditions {
        if_match,
        if_none_match,
    } = preconditions;
    if let Some(list) = if_match {
        let holds = current.is_some_and(|etag| list_matches(list, etag, true));
        if !holds {
            return Err(XapiError::PreconditionFailed(match current {
                None => "If-Match: the document does not exist".into(),
                Some(_) => "If-Match: the document has changed (its ETag differs)".into(),
            }));
        }
    }
    if let (Some(list), Some(etag)) = (if_none_match, current)
        && list_matches(list, etag, false)
    {
        return Err(XapiError::PreconditionFailed(
            "If-None-Match: the document exists".into(),
        ));
    }
    let unconditional = write == Write::Put && if_match.is_none() && if_none_match.is_none();
    if unconditional && spoken == Spoken::V1_0 {
        return match (kind, current) {
            (Kind::State, _) => Ok(()),
            (_, None) => Err(ApiError::BadRequest(
                "a profile PUT needs If-Match with the document's ETag, or If-None-Match: * to \
                 create it only if absent"
                    .into(),
            )
            .into()),
            (_, Some(_)) => Err(ApiError::Conflict(
                "the document exists: send If-Match with its ETag to replace it".into(),
            )
            .into()),
        };
    }
    if unconditional && current.is_some() {
        return Err(ApiError::Conflict(
            "the document exists: send If-Match with its ETag to replace it (or If-None-Match: * \
             to create it only if absent)"
                .into(),
        )
        .into());
    }
    Ok(())
}

/// `200` with one stored document: its bytes, Content-Type, ETag and Last-Modified.
fn document_response(doc: Stored, spoken: Spoken) -> Response {
    let etag = etag_seen(spoken, &doc);
    let Stored {
        content_type,
        content,
        updated_at,
        ..
    } = doc;
    let mut resp = (StatusCode::OK, content).into_response();
    match HeaderValue::from_str(&content_type) {
        Ok(v) => resp.headers_mut().insert(CONTENT_TYPE, v),
        Err(_) => resp
            .headers_mut()
            .insert(CONTENT_TYPE, HeaderValue::from_static(DEFAULT_CONTENT_TYPE)),
    };
    header(&mut resp, ETAG, &format!("\"{etag}\""));
    header(&mut resp, LAST_MODIFIED, &http_date(updated_at));
    resp
}

/// `204` after a write, with the new ETag when there is a document.
fn no_content(etag: Option<&str>) -> Response {
    let mut resp = StatusCode::NO_CONTENT.into_response();
    if let Some(etag) = etag {
        header(&mut resp, ETAG, &format!("\"{etag}\""));
    }
    resp
}

/// GET of one document: 200, or 404 when there is none.
pub async fn get_one(pool: &PgPool, key: &DocKey, spoken: Spoken) -> Result<Response, ApiError> {
    store::get(pool, key)
        .await?
        .map(|doc| document_response(doc, spoken))
        .ok_or_else(|| ApiError::NotFound("document".into()))
}

/// GET of the ids of a scope's documents: a JSON array (maybe empty), with Last-Modified of the
/// newest when there is one.
pub async fn get_ids(
    pool: &PgPool,
    scope: &Scope,
    registration: Option<Uuid>,
    since: Option<OffsetDateTime>,
) -> Result<Response, ApiError> {
    let rows = store::list(pool, scope, registration, since).await?;
    let newest = rows.iter().map(|(_, t)| *t).max();
    let ids: Vec<String> = rows.into_iter().map(|(id, _)| id).collect();
    let mut resp = axum::Json(ids).into_response();
    if let Some(t) = newest {
        header(&mut resp, LAST_MODIFIED, &http_date(t));
    }
    Ok(resp)
}

/// PUT or POST of one document: 204 with its new ETag.
pub async fn store(
    pool: &PgPool,
    key: &DocKey,
    headers: &HeaderMap,
    write: Write,
    doc: Incoming,
    spoken: Spoken,
) -> Result<Response, XapiError> {
    let posted_object = match (write, is_json(&doc.content_type)) {
        (Write::Post, true) => match serde_json::from_slice::<Value>(&doc.body) {
            Ok(Value::Object(map)) => Some(map),
            _ => {
                return Err(ApiError::BadRequest(
                    "a POSTed application/json document must be a JSON object".into(),
                )
                .into());
            }
        },
        _ => None,
    };
    let preconditions = Preconditions::read(headers)?;
    for _ in 0..WRITE_ATTEMPTS {
        let mut tx = pool.begin().await?;
        let existing = store::get_for_update(&mut tx, key).await?;
        let current = existing.as_ref().map(|d| etag_seen(spoken, d));
        check_preconditions(
            &preconditions,
            current.as_deref(),
            write,
            key.scope.kind,
            spoken,
        )?;
        let merged = match (&existing, write) {
            (Some(old), Write::Post) => Some(merge(old, posted_object.as_ref())?),
            _ => None,
        };
        let (content_type, content): (&str, &[u8]) = match &merged {
            Some(bytes) => ("application/json", bytes.as_slice()),
            None => (doc.content_type.as_str(), &doc.body[..]),
        };
        let etag = etag_of(content);
        if existing.is_some() {
            store::update(&mut tx, key, content_type, content, &etag).await?;
        } else if !store::insert(&mut tx, key, content_type, content, &etag).await? {
            // Created by a concurrent request since our read: read it again, locked.
            continue;
        }
        tx.commit().await?;
        let seen = match spoken {
            Spoken::V1_0 => hex::encode(Sha1::digest(content)),
            Spoken::V2_0 => etag,
        };
        return Ok(no_content(Some(&seen)));
    }
    Err(ApiError::Conflict("the document was changed by concurrent requests; retry".into()).into())
}

/// The merge of POST (Communication 2.2 "JSON Procedure"): both documents JSON objects; the
/// posted top-level properties replace the stored ones.
fn merge(
    old: &Stored,
    posted: Option<&serde_json::Map<String, Value>>,
) -> Result<Vec<u8>, ApiError> {
    let Some(posted) = posted else {
        return Err(ApiError::BadRequest(
            "a document exists: a POST merges into it, so it must be an application/json \
             JSON object"
                .into(),
        ));
    };
    if !is_json(&old.content_type) {
        return Err(ApiError::BadRequest(
            "the stored document is not application/json, so nothing can be merged into it: \
             PUT replaces it"
                .into(),
        ));
    }
    let Ok(Value::Object(mut merged)) = serde_json::from_slice::<Value>(&old.content) else {
        return Err(ApiError::BadRequest(
            "the stored document is not a JSON object, so nothing can be merged into it: PUT \
             replaces it"
                .into(),
        ));
    };
    for (k, v) in posted {
        merged.insert(k.clone(), v.clone());
    }
    serde_json::to_vec(&Value::Object(merged)).map_err(|e| ApiError::Internal(e.to_string()))
}

/// DELETE of one document (204 whether or not it existed, unless a precondition fails).
pub async fn delete_one(
    pool: &PgPool,
    key: &DocKey,
    headers: &HeaderMap,
    spoken: Spoken,
) -> Result<Response, XapiError> {
    let mut tx = pool.begin().await?;
    let existing = store::get_for_update(&mut tx, key).await?;
    let preconditions = Preconditions::read(headers)?;
    let current = existing.as_ref().map(|d| etag_seen(spoken, d));
    check_preconditions(
        &preconditions,
        current.as_deref(),
        Write::Delete,
        key.scope.kind,
        spoken,
    )?;
    if existing.is_some() {
        store::delete(&mut tx, key).await?;
    }
    tx.commit().await?;
    Ok(no_content(None))
}

/// DELETE of all a scope's documents (of one registration if given): 204.
pub async fn delete_all(
    pool: &PgPool,
    scope: &Scope,
    registration: Option<Uuid>,
) -> Result<Response, ApiError> {
    store::delete_all(pool, scope, registration).await?;
    Ok(no_content(None))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(&str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(
                HeaderName::from_bytes(k.as_bytes()).unwrap(),
                HeaderValue::from_str(v).unwrap(),
            );
        }
        h
    }

    #[test]
    fn preconditions() {
        let tag = "abc";
        let ok = |h: &[(&str, &str)], cur: Option<&str>, w| {
            let pre = Preconditions::read(&headers(h)).unwrap();
            check_preconditions(&pre, cur, w, Kind::AgentProfile, Spoken::V2_0)
                .map_err(|e| e.status_and_code().0.as_u16())
        };
        let v1 = |kind, cur: Option<&str>| {
            let pre = Preconditions::read(&headers(&[])).unwrap();
            check_preconditions(&pre, cur, Write::Put, kind, Spoken::V1_0)
                .map_err(|e| e.status_and_code().0.as_u16())
        };
        assert_eq!(v1(Kind::AgentProfile, None), Err(400));
        assert_eq!(v1(Kind::ActivityProfile, Some(tag)), Err(409));
        assert_eq!(v1(Kind::State, Some(tag)), Ok(()));
        assert_eq!(v1(Kind::State, None), Ok(()));
        assert_eq!(ok(&[], None, Write::Put), Ok(()));
        assert_eq!(ok(&[], Some(tag), Write::Put), Err(409));
        assert_eq!(ok(&[], Some(tag), Write::Post), Ok(()));
        assert_eq!(ok(&[], Some(tag), Write::Delete), Ok(()));
        assert_eq!(
            ok(&[("if-match", "\"abc\"")], Some(tag), Write::Put),
            Ok(())
        );
        assert_eq!(
            ok(&[("if-match", "\"x\", \"abc\"")], Some(tag), Write::Put),
            Ok(())
        );
        assert_eq!(
            ok(
                &[("if-match", "\"x\""), ("if-match", "\"abc\"")],
                Some(tag),
                Write::Put
            ),
            Ok(())
        );
        assert_eq!(
            ok(&[("if-match", "W/\"abc\"")], Some(tag), Write::Put),
            Err(412)
        );
        assert_eq!(
            ok(&[("if-match", "\"1234\"")], Some(tag), Write::Delete),
            Err(412)
        );
        assert_eq!(ok(&[("if-match", "*")], Some(tag), Write::Post), Ok(()));
        assert_eq!(ok(&[("if-match", "*")], None, Write::Put), Err(412));
        assert_eq!(ok(&[("if-none-match", "*")], None, Write::Put), Ok(()));
        assert_eq!(
            ok(&[("if-none-match", "*")], Some(tag), Write::Put),
            Err(412)
        );
        assert_eq!(
            ok(&[("if-none-match", "W/\"abc\"")], Some(tag), Write::Put),
            Err(412)
        );
        assert_eq!(
            ok(&[("if-none-match", "\"other\"")], Some(tag), Write::Put),
            Ok(())
        );
    }

    #[test]
    fn dates_and_types() {
        // RFC 9110 5.6.7's example instant: 784111777 s after the epoch.
        let t = OffsetDateTime::from_unix_timestamp(784_111_777).unwrap();
        assert_eq!(http_date(t), "Sun, 06 Nov 1994 08:49:37 GMT");
        assert!(is_json("application/json"));
        assert!(is_json("Application/JSON; charset=utf-8"));
        assert!(!is_json("application/jsonx"));
        assert!(!is_json("text/plain"));
    }
}
