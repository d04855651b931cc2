//! Storage of the three document resources in `xapi_documents` (migration 0803): keys, reads,
//! locked reads for writes, and multiple-document queries.

use sha2::{Digest, Sha256};
use sqlx::{PgConnection, PgPool};
use time::OffsetDateTime;
use uuid::Uuid;

/// Which document resource.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// `/xapi/activities/state`.
    State,
    /// `/xapi/activities/profile`.
    ActivityProfile,
    /// `/xapi/agents/profile`.
    AgentProfile,
}

impl Kind {
    /// The value of the `kind` column.
    pub fn as_str(self) -> &'static str {
        match self {
            Kind::State => "state",
            Kind::ActivityProfile => "activity_profile",
            Kind::AgentProfile => "agent_profile",
        }
    }
}

/// The documents of one resource for one activity and/or agent.
#[derive(Debug, Clone)]
pub struct Scope {
    /// The resource.
    pub kind: Kind,
    /// The Activity's IRI ('' for agent profiles).
    pub activity_id: String,
    /// The agent's identity key ('' for activity profiles).
    pub agent_key: String,
}

/// One document: its scope, registration (State only) and id.
#[derive(Debug, Clone)]
pub struct DocKey {
    /// Resource, activity, agent.
    pub scope: Scope,
    /// The registration (State only).
    pub registration: Option<Uuid>,
    /// The `stateId` or `profileId`.
    pub document_id: String,
}

/// SHA-256 of length-prefixed parts, so that no two different tuples share the bytes hashed.
fn digest(parts: &[&[u8]]) -> Vec<u8> {
    let mut h = Sha256::new();
    for p in parts {
        h.update((p.len() as u64).to_be_bytes());
        h.update(p);
    }
    h.finalize().to_vec()
}

impl Scope {
    fn digest(&self) -> Vec<u8> {
        digest(&[
            self.kind.as_str().as_bytes(),
            self.activity_id.as_bytes(),
            self.agent_key.as_bytes(),
        ])
    }
}

impl DocKey {
    fn digest(&self) -> Vec<u8> {
        let reg = self.registration.map(|r| r.into_bytes());
        digest(&[
            self.scope.digest().as_slice(),
            reg.as_ref().map_or(&[][..], |r| &r[..]),
            self.document_id.as_bytes(),
        ])
    }
}

/// A stored document.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct Stored {
    /// Its Content-Type as sent.
    pub content_type: String,
    /// Its bytes as sent (or as merged).
    pub content: Vec<u8>,
    /// SHA-256 of the content, hex.
    pub etag: String,
    /// When it was last stored.
    pub updated_at: OffsetDateTime,
}

/// The document, if there is one.
pub async fn get(pool: &PgPool, key: &DocKey) -> Result<Option<Stored>, sqlx::Error> {
    sqlx::query_as(
        "SELECT content_type, content, etag, updated_at FROM xapi_documents WHERE doc_sha256 = $1",
    )
    .bind(key.digest())
    .fetch_optional(pool)
    .await
}

/// The document, if there is one, locked until the transaction ends.
pub async fn get_for_update(
    conn: &mut PgConnection,
    key: &DocKey,
) -> Result<Option<Stored>, sqlx::Error> {
    sqlx::query_as(
        "SELECT content_type, content, etag, updated_at FROM xapi_documents
          WHERE doc_sha256 = $1 FOR UPDATE",
    )
    .bind(key.digest())
    .fetch_optional(conn)
    .await
}

/// Stores a new document; false when another request stored it first.
pub async fn insert(
    conn: &mut PgConnection,
    key: &DocKey,
    content_type: &str,
    content: &[u8],
    etag: &str,
) -> Result<bool, sqlx::Error> {
    let done = sqlx::query(
        "INSERT INTO xapi_documents (doc_sha256, scope_sha256, kind, activity_id, agent_key,
                registration, document_id, content_type, content, etag)
         VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10) ON CONFLICT DO NOTHING",
    )
    .bind(key.digest())
    .bind(key.scope.digest())
    .bind(key.scope.kind.as_str())
    .bind(&key.scope.activity_id)
    .bind(&key.scope.agent_key)
    .bind(key.registration)
    .bind(&key.document_id)
    .bind(content_type)
    .bind(content)
    .bind(etag)
    .execute(conn)
    .await?;
    Ok(done.rows_affected() == 1)
}

/// Replaces a stored document.
pub async fn update(
    conn: &mut PgConnection,
    key: &DocKey,
    content_type: &str,
    content: &[u8],
    etag: &str,
) -> Result<(), sqlx::Error> {
    sqlx::query(
        "UPDATE xapi_documents SET content_type = $2, content = $3, etag = $4, updated_at = now()
          WHERE doc_sha256 = $1",
    )
    .bind(key.digest())
    .bind(content_type)
    .bind(content)
    .bind(etag)
    .execute(conn)
    .await?;
    Ok(())
}

/// Deletes one document (nothing when there is none).
pub async fn delete(conn: &mut PgConnection, key: &DocKey) -> Result<(), sqlx::Error> {
    sqlx::query("DELETE FROM xapi_documents WHERE doc_sha256 = $1")
        .bind(key.digest())
        .execute(conn)
        .await?;
    Ok(())
}

/// The ids and times of the scope's documents (of one registration if given), stored after
/// `since` (exclusive) if given, oldest first.
pub async fn list(
    pool: &PgPool,
    scope: &Scope,
    registration: Option<Uuid>,
    since: Option<OffsetDateTime>,
) -> Result<Vec<(String, OffsetDateTime)>, sqlx::Error> {
    sqlx::query_as(
        "SELECT document_id, updated_at FROM xapi_documents
          WHERE scope_sha256 = $1 AND ($2::uuid IS NULL OR registration = $2)
            AND ($3::timestamptz IS NULL OR updated_at > $3)
          ORDER BY updated_at, document_id",
    )
    .bind(scope.digest())
    .bind(registration)
    .bind(since)
    .fetch_all(pool)
    .await
}

/// Deletes the scope's documents (of one registration if given); returns how many.
pub async fn delete_all(
    pool: &PgPool,
    scope: &Scope,
    registration: Option<Uuid>,
) -> Result<u64, sqlx::Error> {
    let done = sqlx::query(
        "DELETE FROM xapi_documents
          WHERE scope_sha256 = $1 AND ($2::uuid IS NULL OR registration = $2)",
    )
    .bind(scope.digest())
    .bind(registration)
    .execute(pool)
    .await?;
    Ok(done.rows_affected())
}
