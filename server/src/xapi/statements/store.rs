//! Storing statements: validation of a whole batch, the properties the LRS fills (`id`,
//! `stored`, `authority`, `version`, `timestamp`), immutability (same id and content: no-op;
//! other content: 409), voiding, the filter keys and the activity definitions, in a handful of
//! set-based queries per batch (UNNEST arrays, never a query per statement).
//!
//! Everything happens on the caller's connection: inside its transaction a batch is stored whole
//! or not at all.

use std::collections::{BTreeMap, HashSet};

use serde_json::{Map, Value};
use sqlx::PgConnection;
use time::OffsetDateTime;
use uuid::Uuid;

use super::keys::statement_keys;
use super::timefmt;
use crate::error::ApiError;
use crate::xapi::validate;
use crate::xapi::version::LRS_VERSION;

/// The verb of a voiding statement (xAPI 2.0, Data 2.3.2).
pub const VOIDED_VERB: &str = "http://adlnet.gov/expapi/verbs/voided";

/// One statement ready to be stored.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// Its id.
    pub id: Uuid,
    /// The statement as stored (and returned).
    pub statement: Value,
    /// The statement less what the LRS may set: compared for immutability.
    pub content: Value,
    /// The statement it voids, when it is a voiding statement.
    pub voids: Option<Uuid>,
    /// The statement it targets (a StatementRef object), voiding or not.
    pub target: Option<Uuid>,
    /// Its own filter keys (see the migration).
    pub keys: Vec<String>,
}

/// Validates `statements` (400 naming the statement and property on the first fault) and fills
/// what the LRS sets; `stored` is the same for the whole batch.
pub fn prepare(
    statements: Vec<Value>,
    authority: &Value,
    stored: OffsetDateTime,
) -> Result<Vec<Prepared>, ApiError> {
    let batch = statements.len() > 1;
    let stored_text = timefmt::iso_ms(stored);
    let mut seen = HashSet::new();
    let mut out = Vec::with_capacity(statements.len());
    for (i, mut s) in statements.into_iter().enumerate() {
        let at = |msg: String| {
            if batch {
                ApiError::BadRequest(format!("statement {i}: {msg}"))
            } else {
                ApiError::BadRequest(msg)
            }
        };
        if let Some(o) = s.as_object_mut()
            && o.get("timestamp").is_some_and(Value::is_null)
        {
            // A null timestamp says "none": the LRS fills it like an absent one.
            o.remove("timestamp");
        }
        validate::statement(&s).map_err(|e| at(e.0))?;
        let o = s
            .as_object_mut()
            .ok_or_else(|| at("must be an object".into()))?;
        let id = match o.get("id").and_then(Value::as_str) {
            Some(text) => Uuid::parse_str(text).map_err(|_| at("id: must be a UUID".into()))?,
            None => Uuid::new_v4(),
        };
        if !seen.insert(id) {
            return Err(at(format!("id {id} is used twice in this batch")));
        }
        normalize_context_activities(o);
        if let Some(Value::Object(sub)) = o.get_mut("object") {
            normalize_context_activities(sub);
        }
        let content = content_of(o);
        o.insert("id".into(), Value::String(id.to_string()));
        o.insert("stored".into(), Value::String(stored_text.clone()));
        o.insert("authority".into(), authority.clone());
        if !o.contains_key("version") {
            o.insert("version".into(), Value::String(LRS_VERSION.into()));
        }
        if !o.contains_key("timestamp") {
            o.insert("timestamp".into(), Value::String(stored_text.clone()));
        }
        let target = statement_ref(&o["object"]);
        let voids = (o["verb"]["id"].as_str() == Some(VOIDED_VERB))
            .then_some(target)
            .flatten();
        if o["verb"]["id"].as_str() == Some(VOIDED_VERB) && target.is_none() {
            return Err(at(
                "object: a voiding statement's object must be a StatementRef".into(),
            ));
        }
        let keys = statement_keys(&s);
        out.push(Prepared {
            id,
            statement: s,
            content,
            voids,
            target,
            keys,
        });
    }
    Ok(out)
}

/// Each contextActivities entry given as one Activity becomes an array of one (Data 2.4.6.2: "an
/// LRS returns a ContextActivity in an array, even if only a single ContextActivity is returned"),
/// so stored, compared and returned statements have one shape.
fn normalize_context_activities(statement: &mut Map<String, Value>) {
    let Some(Value::Object(ca)) = statement
        .get_mut("context")
        .and_then(|c| c.get_mut("contextActivities"))
    else {
        return;
    };
    for value in ca.values_mut() {
        if value.is_object() {
            *value = Value::Array(vec![value.take()]);
        }
    }
}

/// The id of a StatementRef object.
fn statement_ref(object: &Value) -> Option<Uuid> {
    (object["objectType"].as_str() == Some("StatementRef"))
        .then(|| object["id"].as_str().and_then(|s| Uuid::parse_str(s).ok()))
        .flatten()
}

/// The statement less the properties an LRS may set or serialize differently (xAPI 2.0, Data
/// 2.3.1 "Statement Immutability"): id, stored, authority, version; the timestamp compared as
/// an instant; a Group's members as an unordered list.
fn content_of(o: &Map<String, Value>) -> Value {
    let mut c = o.clone();
    for key in ["id", "stored", "authority", "version"] {
        c.remove(key);
    }
    if let Some(t) = c.get("timestamp").and_then(Value::as_str)
        && let Some(instant) = timefmt::parse(t)
    {
        c.insert("timestamp".into(), Value::String(timefmt::iso_us(instant)));
    }
    let mut v = Value::Object(c);
    sort_members(&mut v);
    timefmt::comparable_durations(&mut v);
    v
}

/// Sorts every Group's `member` list (unordered by the spec) by its serialization.
fn sort_members(v: &mut Value) {
    match v {
        Value::Object(o) => {
            for (k, child) in o.iter_mut() {
                if k == "member"
                    && let Value::Array(a) = child
                {
                    a.sort_by_cached_key(|m| m.to_string());
                }
                sort_members(child);
            }
        }
        Value::Array(a) => a.iter_mut().for_each(sort_members),
        _ => {}
    }
}

/// Stores `statements` (as a client sent them) with `authority` on the caller's connection:
/// validates them all first, fills id/stored/authority/version/timestamp, treats a statement
/// whose id is stored with the same content as done and one with other content as a conflict
/// (409, nothing of the batch written by this call survives if the caller rolls back), applies
/// voiding, records filter keys and activity definitions. Returns the ids in order.
pub async fn insert_statements(
    conn: &mut PgConnection,
    statements: Vec<Value>,
    authority: &Value,
) -> Result<Vec<Uuid>, ApiError> {
    let stored = transaction_start(conn).await?;
    let prepared = prepare(statements, authority, stored)?;
    store(conn, &prepared).await?;
    Ok(prepared.iter().map(|p| p.id).collect())
}

/// The start of the connection's transaction truncated to milliseconds: the `stored` of the
/// statements it writes (so `X-Experience-API-Consistent-Through`, the start of the oldest open
/// transaction, never passes a statement not yet committed).
pub async fn transaction_start(conn: &mut PgConnection) -> Result<OffsetDateTime, ApiError> {
    let (t,): (OffsetDateTime,) = sqlx::query_as("SELECT date_trunc('milliseconds', now())")
        .fetch_one(&mut *conn)
        .await?;
    Ok(t)
}

/// Stores prepared statements (see [`insert_statements`]).
pub async fn store(conn: &mut PgConnection, prepared: &[Prepared]) -> Result<(), ApiError> {
    if prepared.is_empty() {
        return Ok(());
    }
    let stored = prepared[0].statement["stored"]
        .as_str()
        .and_then(timefmt::parse)
        .ok_or_else(|| ApiError::Internal("stored unset".into()))?;
    let ids: Vec<Uuid> = prepared.iter().map(|p| p.id).collect();
    let statements: Vec<Value> = prepared.iter().map(|p| p.statement.clone()).collect();
    let contents: Vec<Value> = prepared.iter().map(|p| p.content.clone()).collect();
    let voids: Vec<Option<Uuid>> = prepared.iter().map(|p| p.voids).collect();
    // Same id already stored: the same content is a no-op, other content a conflict. The
    // unique index makes a concurrent insert of the same id wait for the other transaction.
    let inserted: Vec<(i64, Uuid)> = sqlx::query_as(
        "INSERT INTO xapi_statements (id, statement, stored, voids, content)
         SELECT n.id, n.statement, $3, n.voids, n.content
           FROM UNNEST($1::uuid[], $2::jsonb[], $4::uuid[], $5::jsonb[])
                WITH ORDINALITY AS n(id, statement, voids, content, ord)
          ORDER BY n.ord
         ON CONFLICT (id) DO NOTHING
         RETURNING seq, id",
    )
    .bind(&ids)
    .bind(&statements)
    .bind(stored)
    .bind(&voids)
    .bind(&contents)
    .fetch_all(&mut *conn)
    .await?;
    if inserted.len() < prepared.len() {
        let new: HashSet<Uuid> = inserted.iter().map(|(_, id)| *id).collect();
        let (old_ids, old_contents): (Vec<Uuid>, Vec<Value>) = prepared
            .iter()
            .filter(|p| !new.contains(&p.id))
            .map(|p| (p.id, p.content.clone()))
            .unzip();
        let differing: Option<(Uuid,)> = sqlx::query_as(
            "SELECT e.id FROM UNNEST($1::uuid[], $2::jsonb[]) AS n(id, content)
               JOIN xapi_statements e ON e.id = n.id
              WHERE e.content <> n.content
              LIMIT 1",
        )
        .bind(&old_ids)
        .bind(&old_contents)
        .fetch_optional(&mut *conn)
        .await?;
        if let Some((id,)) = differing {
            return Err(ApiError::Conflict(format!(
                "statement {id} is already stored with other content (statements are immutable)"
            )));
        }
    }
    if inserted.is_empty() {
        return Ok(());
    }
    let by_id: BTreeMap<Uuid, &Prepared> = prepared.iter().map(|p| (p.id, p)).collect();
    let (mut key_texts, mut key_seqs) = (Vec::new(), Vec::new());
    let (mut ref_seqs, mut ref_targets) = (Vec::new(), Vec::new());
    let mut new_seqs = Vec::with_capacity(inserted.len());
    let mut definitions: BTreeMap<String, Value> = BTreeMap::new();
    for (seq, id) in &inserted {
        let p = by_id[id];
        new_seqs.push(*seq);
        for k in &p.keys {
            key_texts.push(k.clone());
            key_seqs.push(*seq);
        }
        if let Some(t) = p.target {
            ref_seqs.push(*seq);
            ref_targets.push(t);
        }
        collect_definitions(&p.statement, &mut definitions);
    }
    sqlx::query(
        "INSERT INTO xapi_statement_keys (key, seq)
         SELECT * FROM UNNEST($1::text[], $2::bigint[]) ON CONFLICT DO NOTHING",
    )
    .bind(&key_texts)
    .bind(&key_seqs)
    .execute(&mut *conn)
    .await?;
    if !ref_seqs.is_empty() {
        // A statement targeting another meets the filter conditions its target meets (xAPI
        // 2.0, Communication 2.1.3 "Filter Conditions for StatementRefs"), recursively: the
        // target's keys already include its own target's.
        sqlx::query(
            "INSERT INTO xapi_statement_keys (key, seq)
             SELECT k.key, n.seq
               FROM UNNEST($1::bigint[], $2::uuid[]) AS n(seq, target)
               JOIN xapi_statements t ON t.id = n.target
               JOIN xapi_statement_keys k ON k.seq = t.seq
             ON CONFLICT DO NOTHING",
        )
        .bind(&ref_seqs)
        .bind(&ref_targets)
        .execute(&mut *conn)
        .await?;
        // Voiding: the targets of the new voiding statements, unless they are voiding
        // statements themselves (a voiding statement cannot be voided; such a request is
        // stored and ignored).
        sqlx::query(
            "UPDATE xapi_statements SET voided = true
              WHERE id IN (SELECT voids FROM xapi_statements
                            WHERE seq = ANY($1) AND voids IS NOT NULL)
                AND voids IS NULL AND NOT voided",
        )
        .bind(&ref_seqs)
        .execute(&mut *conn)
        .await?;
    }
    // New statements that an earlier voiding statement already targets.
    sqlx::query(
        "UPDATE xapi_statements s SET voided = true
          WHERE s.seq = ANY($1) AND s.voids IS NULL
            AND EXISTS (SELECT 1 FROM xapi_statements v WHERE v.voids = s.id)",
    )
    .bind(&new_seqs)
    .execute(&mut *conn)
    .await?;
    if !definitions.is_empty() {
        let (aids, defs): (Vec<String>, Vec<Value>) = definitions.into_iter().unzip();
        // The latest definition wins property by property; language maps merge (a later
        // statement's languages replace the same languages only).
        sqlx::query(
            "INSERT INTO xapi_activities (activity_id, definition)
             SELECT * FROM UNNEST($1::text[], $2::jsonb[])
             ON CONFLICT (activity_id) DO UPDATE SET
               definition = (xapi_activities.definition || EXCLUDED.definition)
                 || jsonb_strip_nulls(jsonb_build_object(
                      'name', (xapi_activities.definition -> 'name')
                              || (EXCLUDED.definition -> 'name'),
                      'description', (xapi_activities.definition -> 'description')
                              || (EXCLUDED.definition -> 'description'))),
               updated_at = now()",
        )
        .bind(&aids)
        .bind(&defs)
        .execute(&mut *conn)
        .await?;
    }
    Ok(())
}

/// Every activity with a definition in `s` (object, context activities, a SubStatement's),
/// merged in order when one appears twice.
fn collect_definitions(s: &Value, out: &mut BTreeMap<String, Value>) {
    let mut visit = |a: &Value| {
        if let (Some(id), Some(def)) = (a["id"].as_str(), a.get("definition"))
            && def.is_object()
        {
            match out.get_mut(id) {
                Some(Value::Object(old)) => {
                    for (k, v) in def.as_object().into_iter().flatten() {
                        match (old.get_mut(k), v) {
                            (Some(Value::Object(o)), Value::Object(n))
                                if k == "name" || k == "description" =>
                            {
                                o.extend(n.clone())
                            }
                            _ => {
                                old.insert(k.clone(), v.clone());
                            }
                        }
                    }
                }
                _ => {
                    out.insert(id.to_owned(), def.clone());
                }
            }
        }
    };
    super::keys::for_each_activity(s, &mut visit);
}
