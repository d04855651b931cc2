//! GET statements: the query parameters (xAPI 2.0, Communication 2.1.3), the SQL of a filtered
//! page and the `more` link.
//!
//! Results are ordered by `seq` (the order statements were stored in; `stored` is the storing
//! transaction's start, so the two agree but for statements stored by concurrent transactions
//! within the same moment). The `more` link repeats the query with `cursor`, the last seq
//! returned: statements stored later have larger seqs, so the pages of a descending query never
//! shift under concurrent inserts, and an ascending query's later pages include them.

use sqlx::{PgConnection, Postgres, QueryBuilder};
use time::OffsetDateTime;
use uuid::Uuid;

use super::format::Format;
use super::keys::agent_key;
use super::timefmt;
use crate::error::ApiError;
use crate::xapi::agent::parse_agent_param;

/// Largest page (simulator choice: a page of realistic statements stays well under 1 MiB... at
/// about 1 KiB each, 250 is about 250 KiB).
pub const MAX_LIMIT: i64 = 250;

/// A GET request's parameters.
#[derive(Debug, Default, Clone)]
pub struct Params {
    /// `statementId`.
    pub statement_id: Option<Uuid>,
    /// `voidedStatementId`.
    pub voided_statement_id: Option<Uuid>,
    /// Filter keys every result must carry (see the migration).
    pub keys: Vec<String>,
    /// `since` (exclusive).
    pub since: Option<OffsetDateTime>,
    /// `until` (inclusive).
    pub until: Option<OffsetDateTime>,
    /// Page size (1..=[`MAX_LIMIT`]).
    pub limit: i64,
    /// `format`.
    pub format: Option<Format>,
    /// `attachments`.
    pub attachments: bool,
    /// `ascending`.
    pub ascending: bool,
    /// Where the previous page ended (from a `more` link).
    pub cursor: Option<i64>,
    /// The query string without `cursor`, for the `more` link.
    pub base_query: String,
}

fn bad(msg: impl Into<String>) -> ApiError {
    ApiError::BadRequest(msg.into())
}

fn boolean(name: &str, v: &str) -> Result<bool, ApiError> {
    match v {
        "true" => Ok(true),
        "false" => Ok(false),
        _ => Err(bad(format!("{name}: must be true or false"))),
    }
}

fn uuid(name: &str, v: &str) -> Result<Uuid, ApiError> {
    Uuid::parse_str(v).map_err(|_| bad(format!("{name}: must be a UUID")))
}

fn iri(name: &str, v: &str) -> Result<String, ApiError> {
    let scheme_ok = v.split_once(':').is_some_and(|(s, rest)| {
        !s.is_empty()
            && !rest.is_empty()
            && s.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
            && s.chars()
                .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
    });
    if !scheme_ok || v.chars().any(char::is_whitespace) {
        return Err(bad(format!("{name}: must be an absolute IRI")));
    }
    Ok(v.to_owned())
}

fn timestamp(name: &str, v: &str) -> Result<OffsetDateTime, ApiError> {
    timefmt::parse(v).ok_or_else(|| bad(format!("{name}: must be an ISO 8601 timestamp")))
}

/// Parses the parameters (each at most once; unknown ones are refused).
pub fn parse(pairs: &[(String, String)]) -> Result<Params, ApiError> {
    let mut p = Params {
        limit: MAX_LIMIT,
        ..Params::default()
    };
    let mut seen = std::collections::HashSet::new();
    let (mut agent, mut activity, mut verb, mut registration) = (None, None, None, None);
    let (mut related_agents, mut related_activities) = (false, false);
    let mut base = Vec::new();
    for (k, v) in pairs {
        if !seen.insert(k.as_str()) {
            return Err(bad(format!("{k}: given more than once")));
        }
        if k != "cursor" {
            base.push((k.clone(), v.clone()));
        }
        match k.as_str() {
            "statementId" => p.statement_id = Some(uuid(k, v)?),
            "voidedStatementId" => p.voided_statement_id = Some(uuid(k, v)?),
            "agent" => {
                let a = parse_agent_param(v)?;
                agent = Some(
                    agent_key(&a)
                        .ok_or_else(|| bad("agent: must be an Agent or an identified Group"))?,
                );
            }
            "verb" => verb = Some(iri(k, v)?),
            "activity" => activity = Some(iri(k, v)?),
            "registration" => registration = Some(uuid(k, v)?),
            "related_agents" => related_agents = boolean(k, v)?,
            "related_activities" => related_activities = boolean(k, v)?,
            "since" => p.since = Some(timestamp(k, v)?),
            "until" => p.until = Some(timestamp(k, v)?),
            "limit" => {
                let n: i64 = v
                    .parse()
                    .ok()
                    .filter(|n| *n >= 0)
                    .ok_or_else(|| bad("limit: must be a whole number, 0 or more"))?;
                p.limit = if n == 0 { MAX_LIMIT } else { n.min(MAX_LIMIT) };
            }
            "format" => {
                p.format = Some(
                    Format::parse(v)
                        .ok_or_else(|| bad("format: must be ids, exact or canonical"))?,
                )
            }
            "attachments" => p.attachments = boolean(k, v)?,
            "ascending" => p.ascending = boolean(k, v)?,
            "cursor" => {
                p.cursor = Some(
                    v.parse()
                        .map_err(|_| bad("cursor: only as given in a more link"))?,
                )
            }
            "method" => {
                return Err(bad(
                    "the alternate request syntax (method=) was removed in xAPI 2.0",
                ));
            }
            other => return Err(bad(format!("unknown parameter {other:?}"))),
        }
    }
    if p.statement_id.is_some() || p.voided_statement_id.is_some() {
        let extra = seen.iter().find(|k| {
            !matches!(
                **k,
                "statementId" | "voidedStatementId" | "attachments" | "format"
            )
        });
        if p.statement_id.is_some() && p.voided_statement_id.is_some() {
            return Err(bad("statementId and voidedStatementId exclude each other"));
        }
        if let Some(k) = extra {
            return Err(bad(format!(
                "{k}: not allowed with statementId or voidedStatementId"
            )));
        }
    }
    // The first key drives the scan, the others are probed per row: most selective first
    // (a registration is one attempt, an agent one learner, an activity one station; a verb is
    // shared by a large part of the store).
    if let Some(r) = registration {
        p.keys.push(format!("r:{r}"));
    }
    if let Some(a) = agent {
        p.keys
            .push(format!("{}{a}", if related_agents { "A:" } else { "a:" }));
    }
    if let Some(a) = activity {
        p.keys.push(format!(
            "{}{a}",
            if related_activities { "O:" } else { "o:" }
        ));
    }
    if let Some(v) = verb {
        p.keys.push(format!("v:{v}"));
    }
    p.base_query = base
        .iter()
        .map(|(k, v)| format!("{}={}", percent_encode(k), percent_encode(v)))
        .collect::<Vec<_>>()
        .join("&");
    Ok(p)
}

/// Percent-encodes everything but RFC 3986 unreserved characters (a query component, or a path
/// segment of an IRI).
pub fn percent_encode(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b"-_.~".contains(&b) {
            out.push(char::from(b));
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// One page: rows (seq, statement, stored) and the `more` link ("" at the end).
pub async fn page(
    conn: &mut PgConnection,
    p: &Params,
) -> Result<(Vec<(i64, serde_json::Value, OffsetDateTime)>, String), ApiError> {
    let mut q: QueryBuilder<'_, Postgres> =
        QueryBuilder::new("SELECT s.seq, s.statement, s.stored ");
    let order_col;
    if let Some((first, rest)) = p.keys.split_first() {
        // The first condition drives the scan through the (key, seq) index in seq order.
        q.push(
            "FROM xapi_statement_keys k0 JOIN xapi_statements s ON s.seq = k0.seq WHERE k0.key = ",
        );
        q.push_bind(first.clone());
        for k in rest {
            // OFFSET 0 keeps the planner from turning the EXISTS into a semi-join that scans
            // every row of a common key (a verb's); probed per driving row, each is one index
            // lookup (the bench: agent + verb p99 57 ms before, over 10^6 statements).
            q.push(
                " AND EXISTS (SELECT 1 FROM xapi_statement_keys k WHERE k.seq = s.seq AND k.key = ",
            );
            q.push_bind(k.clone());
            q.push(" OFFSET 0)");
        }
        order_col = "k0.seq";
    } else {
        q.push("FROM xapi_statements s WHERE true");
        order_col = "s.seq";
    }
    q.push(" AND NOT s.voided");
    if let Some(t) = p.since {
        q.push(" AND s.stored > ").push_bind(t);
    }
    if let Some(t) = p.until {
        q.push(" AND s.stored <= ").push_bind(t);
    }
    if let Some(c) = p.cursor {
        q.push(format!(
            " AND {order_col} {} ",
            if p.ascending { ">" } else { "<" }
        ))
        .push_bind(c);
    }
    q.push(format!(
        " ORDER BY {order_col} {} LIMIT ",
        if p.ascending { "ASC" } else { "DESC" }
    ))
    .push_bind(p.limit + 1);
    let mut rows: Vec<(i64, serde_json::Value, OffsetDateTime)> =
        q.build_query_as().fetch_all(&mut *conn).await?;
    let more = if rows.len() as i64 > p.limit {
        rows.truncate(p.limit as usize);
        let last = rows.last().map(|r| r.0).unwrap_or_default();
        let sep = if p.base_query.is_empty() { "" } else { "&" };
        format!("/xapi/statements?{}{sep}cursor={last}", p.base_query)
    } else {
        String::new()
    };
    Ok((rows, more))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pairs(s: &[(&str, &str)]) -> Vec<(String, String)> {
        s.iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect()
    }

    #[test]
    fn parameters() {
        let p = parse(&pairs(&[
            ("verb", "http://adlnet.gov/expapi/verbs/voided"),
            ("limit", "0"),
            ("cursor", "17"),
        ]))
        .unwrap();
        assert_eq!(p.keys, ["v:http://adlnet.gov/expapi/verbs/voided"]);
        assert_eq!(p.limit, MAX_LIMIT);
        assert_eq!(p.cursor, Some(17));
        assert_eq!(
            p.base_query,
            "verb=http%3A%2F%2Fadlnet.gov%2Fexpapi%2Fverbs%2Fvoided&limit=0"
        );
        for bad in [
            &[("statementId", "x")][..],
            &[("limit", "-1")],
            &[("verb", "not an iri")],
            &[
                ("statementId", "4b7b7e8e-3d49-4a6f-9f39-1c9c2c7e0f10"),
                ("limit", "1"),
            ],
            &[("foo", "1")],
            &[("method", "PUT")],
            &[("ascending", "yes")],
        ] {
            assert!(parse(&pairs(bad)).is_err(), "{bad:?}");
        }
    }
}
