//! Times as people type them and read them: RFC 3339 in UTC, unix milliseconds, and relative
//! offsets (`-10m`). The CLI's `--since`/`--until` and the gateway's `?since=` use the same rules.

/// The current unix time in milliseconds (0 if the system clock is before 1970).
pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// Parses a time: RFC 3339 (`2026-11-21T10:00:00Z`, `2026-11-21T11:00:00.250+01:00`), a unix time
/// in milliseconds (`1795255200000`), or an offset from `now_ms` (`-30s`, `-10m`, `-2h`, `-1d`).
/// The error is one line saying what is accepted.
pub fn parse_time(text: &str, now_ms: i64) -> Result<i64, String> {
    let t = text.trim();
    let bad = || {
        format!(
            "bad time {text:?}: give RFC 3339 (2026-11-21T10:00:00Z), unix milliseconds, \
             or an offset like -10m, -2h, -1d"
        )
    };
    if t.is_empty() {
        return Err(bad());
    }
    if let Some(rel) = t.strip_prefix('-') {
        let (num, unit) = rel.split_at(rel.char_indices().last().map_or(0, |(i, _)| i));
        let n: i64 = num.parse().map_err(|_| bad())?;
        let scale = match unit {
            "s" => 1_000,
            "m" => 60_000,
            "h" => 3_600_000,
            "d" => 86_400_000,
            _ => return Err(bad()),
        };
        let back = n.checked_mul(scale).ok_or_else(bad)?;
        return now_ms.checked_sub(back).ok_or_else(bad);
    }
    if t.bytes().all(|b| b.is_ascii_digit()) {
        return t.parse().map_err(|_| bad());
    }
    parse_rfc3339(t).ok_or_else(bad)
}

fn digits(s: &str) -> Option<i64> {
    if s.is_empty() || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

/// `YYYY-MM-DDTHH:MM:SS[.frac](Z|±HH:MM)`; `t` or a space may stand for `T`.
fn parse_rfc3339(s: &str) -> Option<i64> {
    let b = s.as_bytes();
    if b.len() < 20 || b[4] != b'-' || b[7] != b'-' || !matches!(b[10], b'T' | b't' | b' ') {
        return None;
    }
    if b[13] != b':' || b[16] != b':' {
        return None;
    }
    let year = digits(s.get(0..4)?)?;
    let month = digits(s.get(5..7)?)?;
    let day = digits(s.get(8..10)?)?;
    let hour = digits(s.get(11..13)?)?;
    let min = digits(s.get(14..16)?)?;
    let sec = digits(s.get(17..19)?)?;
    if !(1..=12).contains(&month) || day < 1 || day > days_in_month(year, month) {
        return None;
    }
    if hour > 23 || min > 59 || sec > 60 {
        return None;
    }
    let mut rest = s.get(19..)?;
    let mut millis = 0;
    if let Some(frac) = rest.strip_prefix('.') {
        let end = frac.bytes().position(|c| !c.is_ascii_digit()).unwrap_or(frac.len());
        if end == 0 {
            return None;
        }
        let f = &frac[..end];
        let padded: String = f.chars().chain("000".chars()).take(3).collect();
        millis = digits(&padded)?;
        rest = &frac[end..];
    }
    let offset_min = match rest {
        "Z" | "z" => 0,
        _ => {
            let rb = rest.as_bytes();
            if rb.len() != 6 || rb[3] != b':' {
                return None;
            }
            let sign = match rb[0] {
                b'+' => 1,
                b'-' => -1,
                _ => return None,
            };
            let oh = digits(rest.get(1..3)?)?;
            let om = digits(rest.get(4..6)?)?;
            if oh > 23 || om > 59 {
                return None;
            }
            sign * (oh * 60 + om)
        }
    };
    let days = days_from_civil(year, month, day);
    let secs = days * 86_400 + hour * 3_600 + min * 60 + sec - offset_min * 60;
    Some(secs * 1_000 + millis)
}

fn is_leap(y: i64) -> bool {
    (y % 4 == 0 && y % 100 != 0) || y % 400 == 0
}

fn days_in_month(y: i64, m: i64) -> i64 {
    match m {
        2 if is_leap(y) => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's algorithm).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (m + 9) % 12;
    let doy = (153 * mp + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1_460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

/// Formats unix milliseconds as RFC 3339 in UTC: `2026-11-21T10:00:00Z`, with `.mmm` only when
/// the milliseconds are not zero.
pub fn format_rfc3339(ms: i64) -> String {
    let secs = ms.div_euclid(1_000);
    let millis = ms.rem_euclid(1_000);
    let days = secs.div_euclid(86_400);
    let sod = secs.rem_euclid(86_400);
    let (y, m, d) = civil_from_days(days);
    let (hh, mm, ss) = (sod / 3_600, sod % 3_600 / 60, sod % 60);
    if millis == 0 {
        format!("{y:04}-{m:02}-{d:02}T{hh:02}:{mm:02}:{ss:02}Z")
    } else {
        format!("{y:04}-{m:02}-{d:02}T{hh:02}:{mm:02}:{ss:02}.{millis:03}Z")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rfc3339_round_trip() {
        assert_eq!(parse_time("1970-01-01T00:00:00Z", 0), Ok(0));
        let t = parse_time("2026-11-21T10:00:00Z", 0).unwrap();
        assert_eq!(t, 1_795_255_200_000);
        assert_eq!(format_rfc3339(t), "2026-11-21T10:00:00Z");
        assert_eq!(parse_time("2026-11-21T11:00:00.25+01:00", 0), Ok(t + 250));
        assert_eq!(format_rfc3339(t + 250), "2026-11-21T10:00:00.250Z");
        assert_eq!(
            parse_time("2024-02-29T23:59:59Z", 0).map(format_rfc3339).unwrap(),
            "2024-02-29T23:59:59Z"
        );
        assert_eq!(format_rfc3339(-1), "1969-12-31T23:59:59.999Z");
    }

    #[test]
    fn relative_and_millis() {
        let now = 1_000_000_000;
        assert_eq!(parse_time("-10m", now), Ok(now - 600_000));
        assert_eq!(parse_time("-2h", now), Ok(now - 7_200_000));
        assert_eq!(parse_time("-1d", now), Ok(now - 86_400_000));
        assert_eq!(parse_time("-30s", now), Ok(now - 30_000));
        assert_eq!(parse_time("1795255200000", now), Ok(1_795_255_200_000));
    }

    #[test]
    fn bad_times_are_errors() {
        for bad in [
            "",
            "-",
            "-m",
            "-10",
            "-10y",
            "yesterday",
            "2026-13-01T00:00:00Z",
            "2026-02-30T00:00:00Z",
            "2026-11-21T10:00:00",
            "2026-11-21T25:00:00Z",
            "2026-11-21T10:00:00+1:00",
            "2026-11-21T10:00:00.Z",
            "-99999999999999999d",
            "99999999999999999999999",
            "-10µ",
            "2026-11-21T10:00:00µZ",
        ] {
            let e = parse_time(bad, 0).unwrap_err();
            assert!(e.contains("RFC 3339"), "{bad:?}: {e}");
        }
    }
}
