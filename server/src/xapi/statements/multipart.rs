//! `multipart/mixed` bodies of the Statement resource (xAPI 2.0, Data 2.4.11 "Attachments"):
//! the first part is the statement(s) as JSON, each further part the raw data of one attachment,
//! named by its SHA-256 in `X-Experience-API-Hash` and sent with
//! `Content-Transfer-Encoding: binary`.

use sha2::{Digest, Sha256};

use crate::error::ApiError;

/// One attachment's raw data.
#[derive(Debug, Clone)]
pub struct Part {
    /// The part's `Content-Type`.
    pub content_type: String,
    /// Its `X-Experience-API-Hash` (checked against the content).
    pub sha2: String,
    /// The bytes.
    pub content: Vec<u8>,
}

fn bad(msg: impl Into<String>) -> ApiError {
    ApiError::BadRequest(format!("multipart/mixed body: {}", msg.into()))
}

/// The `boundary` parameter of a `multipart/mixed` content type.
pub fn boundary(content_type: &str) -> Result<String, ApiError> {
    content_type
        .split(';')
        .skip(1)
        .filter_map(|p| p.split_once('='))
        .find(|(k, _)| k.trim().eq_ignore_ascii_case("boundary"))
        .map(|(_, v)| v.trim().trim_matches('"').to_owned())
        .filter(|b| !b.is_empty() && b.len() <= 70)
        .ok_or_else(|| bad("the Content-Type names no boundary"))
}

fn find(hay: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    hay.get(from..)?
        .windows(needle.len())
        .position(|w| w == needle)
        .map(|p| p + from)
}

/// A part's headers (name, value) and its content.
type RawPart = (Vec<(String, String)>, Vec<u8>);

/// Splits a body into (headers, content) parts.
fn split(body: &[u8], boundary: &str) -> Result<Vec<RawPart>, ApiError> {
    let delim = format!("--{boundary}");
    let mut pos = find(body, delim.as_bytes(), 0).ok_or_else(|| bad("no opening boundary"))?;
    let mut parts = Vec::new();
    loop {
        pos += delim.len();
        if body[pos..].starts_with(b"--") {
            return Ok(parts);
        }
        // The rest of the delimiter line.
        let line_end = find(body, b"\n", pos).ok_or_else(|| bad("truncated part"))?;
        let start = line_end + 1;
        let next = find(body, format!("\n{delim}").as_bytes(), start)
            .ok_or_else(|| bad("no closing boundary"))?;
        let mut end = next;
        if end > start && body[end - 1] == b'\r' {
            end -= 1;
        }
        let part = &body[start..end.max(start)];
        let (head_len, sep) = match (find(part, b"\r\n\r\n", 0), find(part, b"\n\n", 0)) {
            (Some(a), Some(b)) if b < a => (b, 2),
            (Some(a), _) => (a, 4),
            (None, Some(b)) => (b, 2),
            (None, None) => return Err(bad("a part has no header/body separator")),
        };
        let head = std::str::from_utf8(&part[..head_len]).map_err(|_| bad("part headers"))?;
        let headers = head
            .lines()
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                l.split_once(':')
                    .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
                    .ok_or_else(|| bad(format!("bad part header {l:?}")))
            })
            .collect::<Result<Vec<_>, _>>()?;
        parts.push((headers, part[head_len + sep..].to_vec()));
        pos = next + 1;
    }
}

fn header<'a>(h: &'a [(String, String)], name: &str) -> Option<&'a str> {
    h.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
}

/// Parses a request body: the statement JSON of the first part and the attachments' raw data.
pub fn parse(body: &[u8], content_type: &str) -> Result<(Vec<u8>, Vec<Part>), ApiError> {
    let b = boundary(content_type)?;
    let mut parts = split(body, &b)?.into_iter();
    let (h, json) = parts.next().ok_or_else(|| bad("no parts"))?;
    let first = header(&h, "content-type").unwrap_or("");
    if !first
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .eq_ignore_ascii_case("application/json")
    {
        return Err(bad(
            "the first part must be application/json (the statements)",
        ));
    }
    let mut out = Vec::new();
    for (h, content) in parts {
        let sha2 = header(&h, "x-experience-api-hash")
            .ok_or_else(|| bad("an attachment part has no X-Experience-API-Hash"))?
            .to_ascii_lowercase();
        match header(&h, "content-transfer-encoding") {
            Some(e) if e.eq_ignore_ascii_case("binary") => {}
            _ => {
                return Err(bad(
                    "attachment parts need Content-Transfer-Encoding: binary",
                ));
            }
        }
        if hex::encode(Sha256::digest(&content)) != sha2 {
            return Err(bad(format!(
                "part {sha2}: the content does not match its hash"
            )));
        }
        out.push(Part {
            content_type: header(&h, "content-type")
                .unwrap_or("application/octet-stream")
                .to_owned(),
            sha2,
            content,
        });
    }
    Ok((json, out))
}

/// A `multipart/mixed` response: the JSON first, then each attachment. Returns (content type,
/// body).
pub fn build(json: &[u8], parts: &[Part]) -> (String, Vec<u8>) {
    let boundary = format!("xapi-{}", uuid::Uuid::new_v4().simple());
    let mut body = Vec::with_capacity(json.len() + 256);
    body.extend_from_slice(
        format!("--{boundary}\r\nContent-Type: application/json\r\n\r\n").as_bytes(),
    );
    body.extend_from_slice(json);
    for p in parts {
        body.extend_from_slice(
            format!(
                "\r\n--{boundary}\r\nContent-Type: {}\r\nContent-Transfer-Encoding: binary\r\nX-Experience-API-Hash: {}\r\n\r\n",
                p.content_type, p.sha2
            )
            .as_bytes(),
        );
        body.extend_from_slice(&p.content);
    }
    body.extend_from_slice(format!("\r\n--{boundary}--\r\n").as_bytes());
    (format!("multipart/mixed; boundary={boundary}"), body)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let data = b"hello\r\n--not-the-boundary".to_vec();
        let part = Part {
            content_type: "text/plain".into(),
            sha2: hex::encode(Sha256::digest(&data)),
            content: data.clone(),
        };
        let (ct, body) = build(b"{\"a\":1}", &[part]);
        let (json, parts) = parse(&body, &ct).unwrap();
        assert_eq!(json, b"{\"a\":1}");
        assert_eq!(parts[0].content, data);
        assert!(parse(&body, "multipart/mixed").is_err());
    }
}
