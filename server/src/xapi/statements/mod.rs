//! The Statement resource of the LRS (`/xapi/statements`; xAPI 2.0, Communication 2.1): PUT one
//! statement with its id, POST one or a batch, GET one (`statementId`, `voidedStatementId`) or a
//! filtered page with `more` links, in the formats `exact`, `ids` and `canonical`, with
//! attachments as `multipart/mixed` and signed statements checked.
//!
//! Layers within: `timefmt`, `keys` and `format` (pure), `multipart` and `signature` (bodies),
//! `store` (writes) and `query` (reads), then the handlers here.
//!
//! A write is acknowledged only after its transaction commits; a batch is stored whole or not at
//! all (any invalid statement, conflict or attachment fault: 400/409 and nothing stored).

pub mod format;
pub mod keys;
pub mod multipart;
pub mod query;
pub mod signature;
pub mod store;
pub mod timefmt;

use std::collections::{HashMap, HashSet};

use axum::body::Body;
use axum::extract::rejection::QueryRejection;
use axum::extract::{Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde_json::{Value, json};
use time::OffsetDateTime;
use uuid::Uuid;

use self::format::Format;
use self::multipart::Part;
use self::signature::SIGNATURE_USAGE;
use super::auth::LrsClient;
use super::error::XapiError;
use super::state::XapiState;
use super::version::{Spoken, VersionHeader, statement_as_1_0};
use crate::error::ApiError;
use crate::records::extract::nul_field;

/// The response header naming the time through which all statements are available.
pub const CONSISTENT_THROUGH: &str = "x-experience-api-consistent-through";

type Pairs = Result<Query<Vec<(String, String)>>, QueryRejection>;

fn pairs(q: Pairs) -> Result<Vec<(String, String)>, ApiError> {
    q.map(|Query(p)| p)
        .map_err(|e| ApiError::BadRequest(format!("query string: {}", e.body_text())))
}

/// The time through which every statement stored is visible: the start of the oldest
/// transaction now open on the database (a statement's `stored` is its transaction's start),
/// less a millisecond for the truncation of `stored`.
async fn consistent_through(state: &XapiState) -> Result<HeaderValue, ApiError> {
    let (t,): (OffsetDateTime,) = sqlx::query_as(
        "SELECT COALESCE(min(xact_start), now()) - interval '1 millisecond'
           FROM pg_stat_activity
          WHERE datname = current_database() AND pid <> pg_backend_pid()
            AND xact_start IS NOT NULL",
    )
    .fetch_one(&state.pool)
    .await?;
    HeaderValue::from_str(&timefmt::iso_ms(t)).map_err(|e| ApiError::Internal(e.to_string()))
}

/// The request body, within the server's limit.
async fn read_body(state: &XapiState, body: Body) -> Result<Vec<u8>, ApiError> {
    axum::body::to_bytes(body, state.max_body_bytes)
        .await
        .map(|b| b.to_vec())
        .map_err(|_| ApiError::PayloadTooLarge(state.max_body_bytes))
}

/// The statements of a PUT/POST body and its attachments' raw data.
fn parse_body(headers: &HeaderMap, body: &[u8]) -> Result<(Value, Vec<Part>), ApiError> {
    let ct = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("application/json");
    let essence = ct
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    let (json, parts) = match essence.as_str() {
        "application/json" => (body.to_vec(), Vec::new()),
        "multipart/mixed" => multipart::parse(body, ct)?,
        _ => {
            return Err(ApiError::BadRequest(format!(
                "Content-Type {essence}: statements are sent as application/json or multipart/mixed \
                 (the alternate request syntax was removed in xAPI 2.0)"
            )));
        }
    };
    if let Some(field) = nul_field(&json) {
        return Err(ApiError::BadRequest(format!(
            "{field}: must not contain NUL characters (U+0000)"
        )));
    }
    let v: Value = serde_json::from_slice(&json)
        .map_err(|e| ApiError::BadRequest(format!("body is not JSON: {e}")))?;
    Ok((v, parts))
}

/// Attachment rules of a request: every attachment without `fileUrl` has its raw data in a part,
/// every part belongs to an attachment, signatures are well formed and match their statement.
fn check_attachments(statements: &[Value], parts: &[Part]) -> Result<(), ApiError> {
    let by_hash: HashMap<&str, &Part> = parts.iter().map(|p| (p.sha2.as_str(), p)).collect();
    let mut used = HashSet::new();
    for (i, s) in statements.iter().enumerate() {
        let Some(atts) = s.get("attachments").and_then(Value::as_array) else {
            continue;
        };
        for a in atts {
            let sha2 = a["sha2"].as_str().unwrap_or("").to_ascii_lowercase();
            let part = by_hash.get(sha2.as_str());
            if part.is_some() {
                used.insert(sha2.clone());
            }
            if part.is_none() && a.get("fileUrl").is_none() {
                return Err(ApiError::BadRequest(format!(
                    "statement {i}: attachment {sha2} has neither fileUrl nor raw data \
                     (send it as multipart/mixed)"
                )));
            }
            if a["usageType"].as_str() == Some(SIGNATURE_USAGE) {
                if a["contentType"].as_str() != Some("application/octet-stream") {
                    return Err(ApiError::BadRequest(format!(
                        "statement {i}: a signature attachment's contentType is \
                         application/octet-stream"
                    )));
                }
                let part = part.ok_or_else(|| {
                    ApiError::BadRequest(format!(
                        "statement {i}: a signature attachment needs its JWS as raw data"
                    ))
                })?;
                signature::verify(&part.content, s)
                    .map_err(|e| ApiError::BadRequest(format!("statement {i}: signature: {e}")))?;
            }
        }
    }
    if let Some(p) = parts.iter().find(|p| !used.contains(&p.sha2)) {
        return Err(ApiError::BadRequest(format!(
            "part {}: no attachment of the statements has this sha2",
            p.sha2
        )));
    }
    Ok(())
}

/// Validates and stores statements with their attachments' raw data in one transaction.
async fn write(
    state: &XapiState,
    client: &LrsClient,
    statements: Vec<Value>,
    parts: Vec<Part>,
) -> Result<Vec<Uuid>, ApiError> {
    check_attachments(&statements, &parts)?;
    let mut tx = state.pool.begin().await?;
    let stored = store::transaction_start(&mut tx).await?;
    let prepared = store::prepare(statements, &client.authority, stored)?;
    store::store(&mut tx, &prepared).await?;
    if !parts.is_empty() {
        let (mut h, mut ct, mut c) = (Vec::new(), Vec::new(), Vec::new());
        for p in parts {
            h.push(p.sha2);
            ct.push(p.content_type);
            c.push(p.content);
        }
        sqlx::query(
            "INSERT INTO xapi_attachments (sha2, content_type, content)
             SELECT * FROM UNNEST($1::text[], $2::text[], $3::bytea[])
             ON CONFLICT (sha2) DO NOTHING",
        )
        .bind(&h)
        .bind(&ct)
        .bind(&c)
        .execute(&mut *tx)
        .await?;
    }
    tx.commit().await?;
    Ok(prepared.iter().map(|p| p.id).collect())
}

fn refuse_params(pairs: &[(String, String)], allowed: &[&str]) -> Result<(), ApiError> {
    for (k, _) in pairs {
        if k == "method" {
            return Err(ApiError::BadRequest(
                "the alternate request syntax (method=) was removed in xAPI 2.0".into(),
            ));
        }
        if !allowed.contains(&k.as_str()) {
            return Err(ApiError::BadRequest(format!("unknown parameter {k:?}")));
        }
    }
    Ok(())
}

/// Stores one statement under the given id.
#[utoipa::path(put, path = "/xapi/statements", tag = "xapi",
    params(
        VersionHeader,
        ("statementId" = Uuid, Query, description = "The statement's id")),
    request_body(content = Object, content_type = "application/json",
        description = "One statement (also accepted as multipart/mixed with attachments' raw data)"),
    responses((status = 204, description = "Stored, or already stored with the same content"),
        (status = 400, description = "Invalid statement, id mismatch or attachment fault"),
        (status = 401, description = "No valid LRS credentials"),
        (status = 403, description = "The credential may not write"),
        (status = 409, description = "The id is stored with other content")))]
pub async fn put_statement(
    State(state): State<XapiState>,
    client: LrsClient,
    query: Pairs,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, XapiError> {
    client.require_write()?;
    let pairs = pairs(query)?;
    refuse_params(&pairs, &["statementId"])?;
    let id = pairs
        .iter()
        .find(|(k, _)| k == "statementId")
        .map(|(_, v)| Uuid::parse_str(v))
        .ok_or_else(|| ApiError::BadRequest("statementId: required".into()))?
        .map_err(|_| ApiError::BadRequest("statementId: must be a UUID".into()))?;
    let body = read_body(&state, body).await?;
    let (mut statement, parts) = parse_body(&headers, &body)?;
    let Some(o) = statement.as_object_mut() else {
        return Err(ApiError::BadRequest("PUT takes one statement (an object)".into()).into());
    };
    match o.get("id").map(|v| v.as_str().map(Uuid::parse_str)) {
        None => {
            o.insert("id".into(), Value::String(id.to_string()));
        }
        Some(Some(Ok(given))) if given == id => {}
        Some(_) => {
            return Err(
                ApiError::BadRequest("the statement's id differs from statementId".into()).into(),
            );
        }
    }
    write(&state, &client, vec![statement], parts).await?;
    let mut resp = StatusCode::NO_CONTENT.into_response();
    resp.headers_mut()
        .insert(CONSISTENT_THROUGH, consistent_through(&state).await?);
    Ok(resp)
}

/// Stores one statement or a batch; answers their ids in order.
#[utoipa::path(post, path = "/xapi/statements", tag = "xapi",
    params(
        VersionHeader),
    request_body(content = Object, content_type = "application/json",
        description = "One statement or an array of statements (also accepted as \
            multipart/mixed with attachments' raw data)"),
    responses((status = 200, body = [String], description = "The statements' ids, in order"),
        (status = 400, description = "An invalid statement or attachment fault: nothing stored"),
        (status = 401, description = "No valid LRS credentials"),
        (status = 403, description = "The credential may not write"),
        (status = 409, description = "An id is stored with other content: nothing stored")))]
pub async fn post_statements(
    State(state): State<XapiState>,
    client: LrsClient,
    query: Pairs,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, XapiError> {
    client.require_write()?;
    refuse_params(&pairs(query)?, &[])?;
    let body = read_body(&state, body).await?;
    let (v, parts) = parse_body(&headers, &body)?;
    let statements = match v {
        Value::Array(a) if a.is_empty() => {
            return Err(ApiError::BadRequest("an empty batch".into()).into());
        }
        Value::Array(a) => a,
        other => vec![other],
    };
    let ids = write(&state, &client, statements, parts).await?;
    let mut resp = axum::Json(ids).into_response();
    resp.headers_mut()
        .insert(CONSISTENT_THROUGH, consistent_through(&state).await?);
    Ok(resp)
}

/// Applies a format to a stored statement.
fn shaped(mut s: Value, format: Format, langs: &[String], defs: &HashMap<String, Value>) -> Value {
    match format {
        Format::Exact => {}
        Format::Ids => format::ids(&mut s),
        Format::Canonical => format::canonical(&mut s, langs, defs),
    }
    s
}

/// Reads one statement, or a page of statements matching the filters.
#[utoipa::path(get, path = "/xapi/statements", tag = "xapi",
    params(
        VersionHeader,
        ("statementId" = Option<Uuid>, Query, description = "One statement (not voided)"),
        ("voidedStatementId" = Option<Uuid>, Query, description = "One voided statement"),
        ("agent" = Option<String>, Query, description = "JSON Agent or identified Group: actor \
            or object (with related_agents: anywhere)"),
        ("verb" = Option<String>, Query, description = "Verb IRI"),
        ("activity" = Option<String>, Query, description = "Activity IRI: object (with \
            related_activities: anywhere)"),
        ("registration" = Option<Uuid>, Query, description = "Registration"),
        ("related_activities" = Option<bool>, Query, description = "Widen activity"),
        ("related_agents" = Option<bool>, Query, description = "Widen agent"),
        ("since" = Option<String>, Query, description = "Stored after (ISO 8601)"),
        ("until" = Option<String>, Query, description = "Stored at or before (ISO 8601)"),
        ("limit" = Option<u32>, Query, description = "Page size (0: the LRS's maximum, 250)"),
        ("format" = Option<String>, Query, description = "ids, exact (default) or canonical"),
        ("attachments" = Option<bool>, Query, description = "multipart/mixed with raw data"),
        ("ascending" = Option<bool>, Query, description = "Oldest first"),
        ("cursor" = Option<i64>, Query, description = "Opaque: as given in a `more` link")),
    responses((status = 200, body = Object, description = "A statement or a StatementResult \
            (multipart/mixed with attachments=true)"),
        (status = 400, description = "Bad or conflicting parameters"),
        (status = 401, description = "No valid LRS credentials"),
        (status = 403, description = "The credential may not read"),
        (status = 404, description = "No such statement")))]
pub async fn get_statements(
    State(state): State<XapiState>,
    client: LrsClient,
    query: Pairs,
    headers: HeaderMap,
) -> Result<Response, XapiError> {
    match read_statements(&state, client, query, headers).await {
        Ok(resp) => Ok(resp),
        // Every answer to a GET carries the header, refusals and 404s too (Communication 2.1.3:
        // "returns a header ... on all responses"; the conformance suite checks it on 400s).
        Err(e) => {
            let mut resp = e.into_response();
            if let Ok(h) = consistent_through(&state).await {
                resp.headers_mut().insert(CONSISTENT_THROUGH, h);
            }
            Ok(resp)
        }
    }
}

/// The work of [`get_statements`].
async fn read_statements(
    state: &XapiState,
    client: LrsClient,
    query: Pairs,
    headers: HeaderMap,
) -> Result<Response, XapiError> {
    let state = state.clone();
    client.require_read()?;
    let spoken = client.spoken;
    let p = query::parse(&pairs(query)?)?;
    let format = p.format.unwrap_or(Format::Exact);
    let langs = headers
        .get(header::ACCEPT_LANGUAGE)
        .and_then(|v| v.to_str().ok())
        .map(format::accept_languages)
        .unwrap_or_default();
    let mut conn = state.pool.acquire().await?;
    let single = p.statement_id.or(p.voided_statement_id);
    let (rows, more) = if let Some(id) = single {
        let row: Option<(i64, Value, OffsetDateTime, bool)> = sqlx::query_as(
            "SELECT seq, statement, stored, voided FROM xapi_statements WHERE id = $1",
        )
        .bind(id)
        .fetch_optional(&mut *conn)
        .await?;
        match row {
            Some((seq, s, stored, voided)) if voided == p.voided_statement_id.is_some() => {
                (vec![(seq, s, stored)], None)
            }
            _ => return Err(ApiError::NotFound("statement".into()).into()),
        }
    } else {
        let (rows, more) = query::page(&mut conn, &p).await?;
        (rows, Some(more))
    };
    let defs = if format == Format::Canonical {
        let mut ids = Vec::new();
        for (_, s, _) in &rows {
            format::activity_ids_of(s, &mut ids);
        }
        let found: Vec<(String, Value)> = sqlx::query_as(
            "SELECT activity_id, definition FROM xapi_activities WHERE activity_id = ANY($1)",
        )
        .bind(&ids)
        .fetch_all(&mut *conn)
        .await?;
        found.into_iter().collect()
    } else {
        HashMap::new()
    };
    let last_modified = rows.iter().map(|r| r.2).max();
    let mut hashes = Vec::new();
    if p.attachments {
        for (_, s, _) in &rows {
            for a in s["attachments"].as_array().into_iter().flatten() {
                if let Some(h) = a["sha2"].as_str() {
                    hashes.push(h.to_ascii_lowercase());
                }
            }
        }
    }
    let statements: Vec<Value> = rows
        .into_iter()
        .map(|(_, s, _)| shaped(s, format, &langs, &defs))
        .map(|s| match spoken {
            Spoken::V1_0 => statement_as_1_0(s),
            Spoken::V2_0 => s,
        })
        .collect();
    let body = match more {
        None => statements.into_iter().next().unwrap_or(Value::Null),
        Some(more) => json!({ "statements": statements, "more": more }),
    };
    let json = serde_json::to_vec(&body).map_err(|e| ApiError::Internal(e.to_string()))?;
    let mut resp = if p.attachments {
        hashes.sort();
        hashes.dedup();
        let parts: Vec<(String, String, Vec<u8>)> = sqlx::query_as(
            "SELECT sha2, content_type, content FROM xapi_attachments WHERE sha2 = ANY($1)
              ORDER BY sha2",
        )
        .bind(&hashes)
        .fetch_all(&mut *conn)
        .await?;
        let parts: Vec<Part> = parts
            .into_iter()
            .map(|(sha2, content_type, content)| Part {
                content_type,
                sha2,
                content,
            })
            .collect();
        let (ct, body) = multipart::build(&json, &parts);
        ([(header::CONTENT_TYPE, ct)], body).into_response()
    } else {
        (
            [(header::CONTENT_TYPE, "application/json".to_owned())],
            json,
        )
            .into_response()
    };
    drop(conn);
    let h = resp.headers_mut();
    h.insert(CONSISTENT_THROUGH, consistent_through(&state).await?);
    if let Some(t) = last_modified
        && let Ok(v) = HeaderValue::from_str(&timefmt::http_date(t))
    {
        h.insert(header::LAST_MODIFIED, v);
    }
    Ok(resp)
}
