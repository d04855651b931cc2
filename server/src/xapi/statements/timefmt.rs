//! Timestamps of the Statement resource: ISO 8601 in UTC for `stored`, the HTTP date of
//! `Last-Modified`, and the parsing of `since`/`until`/`timestamp`.

use time::format_description::well_known::{Iso8601, Rfc3339};
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

/// An HTTP-date (RFC 9110 5.6.7, IMF-fixdate), e.g. `Sun, 06 Nov 1994 08:49:37 GMT`.
pub fn http_date(t: OffsetDateTime) -> String {
    const DAYS: [&str; 7] = ["Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun"];
    const MONTHS: [&str; 12] = [
        "Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec",
    ];
    let t = t.to_offset(UtcOffset::UTC);
    format!(
        "{}, {:02} {} {:04} {:02}:{:02}:{:02} GMT",
        DAYS[t.weekday().number_days_from_monday() as usize],
        t.day(),
        MONTHS[t.month() as usize - 1],
        t.year(),
        t.hour(),
        t.minute(),
        t.second()
    )
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

/// A duration as statements are compared (xAPI 2.0 Data 4.6: precision beyond 0.01 s is not
/// compared): the seconds' fraction truncated to two digits, trailing zeros dropped.
pub fn comparable_duration(d: &str) -> String {
    let Some(body) = d.strip_suffix('S') else {
        return d.to_owned();
    };
    let start = body
        .rfind(|c: char| !(c.is_ascii_digit() || c == '.'))
        .map_or(0, |i| i + 1);
    let (head, seconds) = body.split_at(start);
    let Some((whole, fraction)) = seconds.split_once('.') else {
        return d.to_owned();
    };
    let kept = fraction[..fraction.len().min(2)].trim_end_matches('0');
    if kept.is_empty() {
        format!("{head}{whole}S")
    } else {
        format!("{head}{whole}.{kept}S")
    }
}

/// Replaces `result.duration` (of the statement and of a SubStatement object) by its
/// [`comparable_duration`].
pub fn comparable_durations(statement: &mut serde_json::Value) {
    for path in [
        &["result", "duration"][..],
        &["object", "result", "duration"][..],
    ] {
        let mut cur = Some(&mut *statement);
        for key in &path[..path.len() - 1] {
            cur = cur.and_then(|v| v.get_mut(*key));
        }
        if let Some(slot) = cur.and_then(|v| v.get_mut(path[path.len() - 1]))
            && let Some(d) = slot.as_str()
        {
            *slot = serde_json::Value::String(comparable_duration(d));
        }
    }
}

#[cfg(test)]
mod duration_tests {
    use super::comparable_duration;

    #[test]
    fn durations_compare_to_the_hundredth() {
        assert_eq!(comparable_duration("PT1.234S"), "PT1.23S");
        assert_eq!(comparable_duration("PT1.239S"), "PT1.23S");
        assert_eq!(comparable_duration("PT1.20S"), "PT1.2S");
        assert_eq!(comparable_duration("P1DT2H3.001S"), "P1DT2H3S");
        assert_eq!(comparable_duration("PT5M"), "PT5M");
        assert_eq!(comparable_duration("PT12S"), "PT12S");
    }
}
