//! TEMP placeholder (outbox branch) with the signature of the statements helper's
//! `insert_statements`; stores nothing. Replaced when `stmts` is merged.

use serde_json::Value;
use uuid::Uuid;

use crate::xapi::XapiError;

/// Placeholder: returns the statements' ids (every statement the projector makes has one).
pub async fn insert_statements(
    _conn: &mut sqlx::PgConnection,
    statements: Vec<Value>,
    _authority: &Value,
) -> Result<Vec<Uuid>, XapiError> {
    statements
        .iter()
        .map(|s| {
            s["id"]
                .as_str()
                .and_then(|i| i.parse().ok())
                .ok_or_else(|| XapiError::BadRequest("statement without id".into()))
        })
        .collect()
}
