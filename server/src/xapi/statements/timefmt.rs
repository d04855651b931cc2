//! Timestamps of the Statement resource: ISO 8601 in UTC for `stored`, the HTTP date of
//! `Last-Modified`, and the parsing of `since`/`until`/`timestamp`.

use time::format_description::well_known::{Iso8601, Rfc2822, Rfc3339};
use time::{OffsetDateTime, UtcOffset};

/// `2026-11-27T04:03:21.123Z`: UTC with milliseconds (the precision xAPI asks an LRS to keep).
pub fn iso_ms(t: OffsetDateTime) -> String {
    let t = t.to_offset(UtcOffset::UTC);
    format!(
        "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second(),
        t.millisecond()
    )
}

/// UTC with microseconds (PostgreSQL's precision): the canonical instant of a timestamp.
pub fn iso_us(t: OffsetDateTime) -> String {
    let t = t.to_offset(UtcOffset::UTC);
    format!("{}{:03}Z", &iso_ms(t)[..23], t.microsecond() % 1000)
}

/// An HTTP date (`Last-Modified`): `Fri, 27 Nov 2026 04:03:21 GMT`.
pub fn http_date(t: OffsetDateTime) -> String {
    let t = t.to_offset(UtcOffset::UTC);
    t.format(&Rfc2822)
        .map(|s| s.replace("+0000", "GMT"))
        .unwrap_or_default()
}

/// Parses an ISO 8601 / RFC 3339 timestamp with an offset or `Z`.
pub fn parse(s: &str) -> Option<OffsetDateTime> {
    OffsetDateTime::parse(s, &Rfc3339)
        .or_else(|_| OffsetDateTime::parse(s, &Iso8601::DEFAULT))
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats() {
        let t = parse("2026-11-27T05:03:21.123456+01:00").unwrap();
        assert_eq!(iso_ms(t), "2026-11-27T04:03:21.123Z");
        assert_eq!(iso_us(t), "2026-11-27T04:03:21.123456Z");
        assert_eq!(http_date(t), "Fri, 27 Nov 2026 04:03:21 GMT");
        assert!(parse("yesterday").is_none());
    }
}
