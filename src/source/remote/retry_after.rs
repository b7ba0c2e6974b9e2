//! The `Retry-After` header (RFC 9110 §10.2.3): a delay in seconds, or an HTTP date.

use std::time::{Duration, SystemTime};

/// How long `value` (a `Retry-After` header's value) asks to wait, at `now`: a whole number of
/// seconds (`120`), or an HTTP date (`Fri, 31 Dec 1999 23:59:59 GMT`, and the obsolete RFC 850
/// and asctime forms RFC 9110 says to accept), a date already past being no wait at all.
/// `None` for anything else (the header is then ignored, and the backoff alone applies).
pub fn parse(value: &str, now: SystemTime) -> Option<Duration> {
    let value = value.trim();
    if !value.is_empty() && value.bytes().all(|b| b.is_ascii_digit()) {
        // Seconds too many for a u64 are a very long wait (capped by the caller anyway).
        return Some(Duration::from_secs(value.parse().unwrap_or(u64::MAX)));
    }
    let at = httpdate::parse_http_date(value).ok()?;
    Some(at.duration_since(now).unwrap_or(Duration::ZERO))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 1999-12-31T23:59:00Z.
    fn now() -> SystemTime {
        SystemTime::UNIX_EPOCH + Duration::from_secs(946_684_740)
    }

    #[test]
    fn seconds_are_a_delay() {
        assert_eq!(parse("120", now()), Some(Duration::from_secs(120)));
        assert_eq!(parse(" 0 ", now()), Some(Duration::ZERO));
        assert_eq!(parse("99999999999999999999999", now()), Some(Duration::from_secs(u64::MAX)));
    }

    #[test]
    fn an_http_date_is_the_time_left_until_it_in_all_three_forms() {
        for date in ["Fri, 31 Dec 1999 23:59:59 GMT", "Friday, 31-Dec-99 23:59:59 GMT", "Fri Dec 31 23:59:59 1999"] {
            assert_eq!(parse(date, now()), Some(Duration::from_secs(59)), "{date}");
        }
    }

    #[test]
    fn a_date_already_past_is_no_wait() {
        assert_eq!(parse("Fri, 31 Dec 1999 23:00:00 GMT", now()), Some(Duration::ZERO));
    }

    #[test]
    fn anything_else_is_ignored() {
        for v in ["", "-5", "1.5", "soon", "Fri, 31 Dec 1999 25:00:00 GMT", "31 Dec 1999"] {
            assert_eq!(parse(v, now()), None, "{v:?}");
        }
    }
}
