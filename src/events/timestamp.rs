//! Wall-clock timestamps for the event log: microseconds since the Unix epoch, written and
//! read as RFC 3339 UTC (`2024-05-01T12:34:56.123456Z`), and the one parser of the times an
//! operator types (`antisurge events --since/--until`): [`parse_time`].
//!
//! [`Timestamp`] stays an 8-byte `Copy` integer because the control thread stamps its events
//! with [`Timestamp::now`] (one `clock_gettime`, no allocation). Calendar arithmetic, time
//! zones, formatting and parsing are the `jiff` crate's; durations typed by the operator
//! (`5min`, `1h30m`) are the `humantime` crate's.

use std::fmt;
use std::str::FromStr;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Deserializer, Serialize, Serializer};

const US_PER_S: i64 = 1_000_000;
/// 0000-01-01T00:00:00Z, the earliest instant RFC 3339 can write.
const MIN_US: i64 = -62_167_219_200 * US_PER_S;
/// 9999-12-30T22:00:00Z, the latest instant `jiff` takes in microseconds (RFC 3339 could write
/// a day more).
const MAX_US: i64 = 253_402_207_200 * US_PER_S;

/// An instant in UTC with microsecond resolution, kept as microseconds since 1970-01-01.
///
/// `Copy` and 8 bytes, so the real-time path can carry it; it serializes as an RFC 3339
/// string with exactly six fractional digits and a `Z` suffix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Timestamp {
    unix_us: i64,
}

/// Why a string is not an RFC 3339 timestamp.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParseTimestampError(pub &'static str);

impl fmt::Display for ParseTimestampError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.0)
    }
}

impl std::error::Error for ParseTimestampError {}

/// A calendar date and time of day, as printed (no time zone attached).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CivilTime {
    /// Year, 0..=9999.
    pub year: i64,
    /// Month, 1..=12.
    pub month: u32,
    /// Day of month, 1..=31.
    pub day: u32,
    /// Hour, 0..=23.
    pub hour: u32,
    /// Minute, 0..=59.
    pub minute: u32,
    /// Second, 0..=59.
    pub second: u32,
    /// Microseconds within the second, 0..=999 999.
    pub micros: u32,
}

impl Timestamp {
    /// The Unix epoch, 1970-01-01T00:00:00Z.
    pub const UNIX_EPOCH: Timestamp = Timestamp { unix_us: 0 };

    /// The current wall-clock time. No allocation, no lock: one `clock_gettime` (vDSO).
    #[inline]
    pub fn now() -> Timestamp {
        Timestamp::from_system_time(SystemTime::now())
    }

    /// Convert from `SystemTime`, clamped to the years 0000..=9999 that RFC 3339 can write.
    #[inline]
    pub fn from_system_time(t: SystemTime) -> Timestamp {
        let us = match t.duration_since(UNIX_EPOCH) {
            Ok(d) => i64::try_from(d.as_micros()).unwrap_or(i64::MAX),
            Err(before) => {
                let d = before.duration();
                // Round towards the past so that formatting stays monotone.
                let whole = i64::try_from(d.as_micros()).unwrap_or(i64::MAX);
                let extra = i64::from(!d.subsec_nanos().is_multiple_of(1000));
                -(whole.saturating_add(extra))
            }
        };
        Timestamp::from_unix_micros(us)
    }

    /// From microseconds since the Unix epoch (clamped to 0000..=9999).
    #[inline]
    pub const fn from_unix_micros(us: i64) -> Timestamp {
        let us = if us < MIN_US {
            MIN_US
        } else if us > MAX_US {
            MAX_US
        } else {
            us
        };
        Timestamp { unix_us: us }
    }

    /// Microseconds since the Unix epoch.
    #[inline]
    pub const fn unix_micros(self) -> i64 {
        self.unix_us
    }

    /// This instant as a `SystemTime`.
    pub fn to_system_time(self) -> SystemTime {
        if self.unix_us >= 0 {
            UNIX_EPOCH + Duration::from_micros(self.unix_us as u64)
        } else {
            UNIX_EPOCH - Duration::from_micros(self.unix_us.unsigned_abs())
        }
    }

    /// `self - d`, clamped.
    pub fn saturating_sub(self, d: Duration) -> Timestamp {
        let us = i64::try_from(d.as_micros()).unwrap_or(i64::MAX);
        Timestamp::from_unix_micros(self.unix_us.saturating_sub(us))
    }

    /// `self + d`, clamped.
    pub fn saturating_add(self, d: Duration) -> Timestamp {
        let us = i64::try_from(d.as_micros()).unwrap_or(i64::MAX);
        Timestamp::from_unix_micros(self.unix_us.saturating_add(us))
    }

    /// Calendar fields in UTC.
    pub fn utc(self) -> CivilTime {
        self.civil_in(&jiff::tz::TimeZone::UTC)
    }

    /// Calendar fields in the machine's local time zone ([`zone`]: `TZ`, else
    /// `/etc/localtime`, with daylight saving). Falls back to UTC if the zone is unknown.
    pub fn local(self) -> CivilTime {
        self.civil_in(&zone(false))
    }

    /// Parse RFC 3339: `YYYY-MM-DDTHH:MM:SS[.fraction](Z|±HH:MM)` (`t`, `z` and a space
    /// separator accepted; fraction digits beyond microseconds truncated; a leap second
    /// `:60` is read as `:59`, as `jiff` does).
    pub fn parse_rfc3339(s: &str) -> Result<Timestamp, ParseTimestampError> {
        let b = s.as_bytes();
        // RFC 3339's shape, checked before jiff (which also reads ISO 8601's other forms)
        if b.len() < 20 {
            return Err(ParseTimestampError("too short for YYYY-MM-DDTHH:MM:SSZ"));
        }
        if !(b[4] == b'-'
            && b[7] == b'-'
            && matches!(b[10], b'T' | b't' | b' ')
            && b[13] == b':'
            && b[16] == b':')
        {
            return Err(ParseTimestampError("expected YYYY-MM-DDTHH:MM:SS"));
        }
        // byte 19 may fall inside a multi-byte character (fuzz input `…\u{3}\u{92}`): `get`
        let Some(zone) = s.get(19..) else {
            return Err(ParseTimestampError("expected YYYY-MM-DDTHH:MM:SS"));
        };
        let zone = zone
            .strip_prefix('.')
            .map_or(zone, |f| f.trim_start_matches(|c: char| c.is_ascii_digit()));
        let zone_ok = zone.eq_ignore_ascii_case("z")
            || (zone.len() == 6
                && matches!(zone.as_bytes()[0], b'+' | b'-')
                && zone.as_bytes()[3] == b':');
        if !zone_ok {
            return Err(ParseTimestampError(
                "expected a time zone at the end: Z or an offset like +02:00",
            ));
        }
        let t: jiff::Timestamp = s
            .parse()
            .map_err(|_| ParseTimestampError("not a valid RFC 3339 date and time"))?;
        Ok(Timestamp::from_jiff(t))
    }

    /// From a `jiff` timestamp (truncated to microseconds, towards the past).
    pub fn from_jiff(t: jiff::Timestamp) -> Timestamp {
        let ns = t.as_nanosecond();
        Timestamp::from_unix_micros(i64::try_from(ns.div_euclid(1000)).unwrap_or(i64::MAX))
    }

    /// As a `jiff` timestamp.
    pub fn to_jiff(self) -> jiff::Timestamp {
        jiff::Timestamp::from_microsecond(self.unix_us).unwrap_or(if self.unix_us > 0 {
            jiff::Timestamp::MAX
        } else {
            jiff::Timestamp::MIN
        })
    }

    fn civil_in(self, tz: &jiff::tz::TimeZone) -> CivilTime {
        let dt = tz.to_datetime(self.to_jiff());
        CivilTime {
            year: i64::from(dt.year()),
            month: dt.month() as u32,
            day: dt.day() as u32,
            hour: dt.hour() as u32,
            minute: dt.minute() as u32,
            second: dt.second() as u32,
            micros: self.unix_us.rem_euclid(US_PER_S) as u32,
        }
    }
}

/// The zone an operator's typed times and the printed times are in: UTC, or the machine's
/// own (`TZ`, else `/etc/localtime`; UTC if neither can be read).
pub fn zone(utc: bool) -> jiff::tz::TimeZone {
    if utc {
        jiff::tz::TimeZone::UTC
    } else {
        jiff::tz::TimeZone::try_system().unwrap_or(jiff::tz::TimeZone::UTC)
    }
}

/// Parse a time an operator typed, relative to `now` and in `tz` (see [`zone`]):
///
/// - what `antisurge events` prints, whole or cut: `2026-11-27 23:33:05.123`,
///   `2026-11-27 23:33`, `2026-11-27`, `23:33`, `23:33:05` (a time alone is the latest such
///   time not after `now`: `--since 23:50` just after midnight means yesterday's);
/// - RFC 3339 with its offset: `2026-11-27T22:33:05Z`, `…+01:00`;
/// - an age: `5min`, `10m`, `2h`, `1d`, `1w`, `1h30m`, `90s` (optionally followed by `ago`);
/// - `now`, `today` (midnight), `yesterday` (the midnight before).
pub fn parse_time(
    text: &str,
    now: Timestamp,
    tz: &jiff::tz::TimeZone,
) -> Result<Timestamp, String> {
    use jiff::civil;
    let t = text.trim();
    if t.is_empty() {
        return Err("empty".into());
    }
    let midnight = |days_back: i64| -> Result<Timestamp, String> {
        let today = tz.to_datetime(now.to_jiff()).date();
        let d = today
            .checked_sub(jiff::Span::new().days(days_back))
            .map_err(|e| e.to_string())?;
        d.to_zoned(tz.clone())
            .map(|z| Timestamp::from_jiff(z.timestamp()))
            .map_err(|e| e.to_string())
    };
    match t.to_ascii_lowercase().as_str() {
        "now" => return Ok(now),
        "today" => return midnight(0),
        "yesterday" => return midnight(1),
        _ => {}
    }
    let b = t.as_bytes();
    if b[0].is_ascii_digit() && !t.contains([':', '-']) {
        let age = t.strip_suffix("ago").unwrap_or(t).trim_end();
        let d = humantime::parse_duration(age).map_err(|e| {
            format!("{e}; an age is a number and a unit: 90s, 5min, 10m, 2h, 1d, 1w, 1h30m")
        })?;
        return Ok(now.saturating_sub(d));
    }
    // `get`: byte 19 may fall inside a multi-byte character (a fuzzer's find, CI 2026-11-28)
    let tail = t.get(19..).unwrap_or("");
    if t.len() >= 20 && (t.ends_with(['Z', 'z']) || tail.contains(['+', '-'])) {
        return Timestamp::parse_rfc3339(t).map_err(|e| e.to_string());
    }
    let in_zone = |dt: civil::DateTime| -> Result<Timestamp, String> {
        tz.to_ambiguous_zoned(dt)
            .compatible()
            .map(|z| Timestamp::from_jiff(z.timestamp()))
            .map_err(|e| e.to_string())
    };
    if let Ok(dt) = t.parse::<civil::DateTime>() {
        return in_zone(dt);
    }
    if let Ok(d) = t.parse::<civil::Date>() {
        return in_zone(d.to_datetime(civil::Time::midnight()));
    }
    if let Ok(time) = t.parse::<civil::Time>() {
        let today = tz.to_datetime(now.to_jiff()).date();
        let at = in_zone(today.to_datetime(time))?;
        if at <= now {
            return Ok(at);
        }
        let yesterday = today.yesterday().map_err(|e| e.to_string())?;
        return in_zone(yesterday.to_datetime(time));
    }
    Err(
        "not a time: use what `antisurge events` prints (2026-11-27 23:33, 23:33), RFC 3339 \
         (2026-11-27T22:33:00Z), an age (5min, 2h, 1d) or today / yesterday"
            .into(),
    )
}

impl fmt::Display for Timestamp {
    /// RFC 3339 UTC with microseconds, e.g. `2024-05-01T12:34:56.123456Z`. Allocation-free.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:.6}", self.to_jiff())
    }
}

impl FromStr for Timestamp {
    type Err = ParseTimestampError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Timestamp::parse_rfc3339(s)
    }
}

impl Serialize for Timestamp {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for Timestamp {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = Timestamp;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("an RFC 3339 timestamp")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Timestamp, E> {
                Timestamp::parse_rfc3339(v).map_err(E::custom)
            }
        }
        deserializer.deserialize_str(V)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ts(s: &str) -> Timestamp {
        Timestamp::parse_rfc3339(s).expect(s)
    }

    #[test]
    fn formats_with_micros_and_z() {
        assert_eq!(
            Timestamp::UNIX_EPOCH.to_string(),
            "1970-01-01T00:00:00.000000Z"
        );
        let t = Timestamp::from_unix_micros(1_714_566_896_123_456);
        assert_eq!(t.to_string(), "2024-05-01T12:34:56.123456Z");
        // Before the epoch: floor, not truncation.
        assert_eq!(
            Timestamp::from_unix_micros(-1).to_string(),
            "1969-12-31T23:59:59.999999Z"
        );
    }

    #[test]
    fn parses_variants() {
        let base = 1_714_566_896_000_000;
        assert_eq!(ts("2024-05-01T12:34:56Z").unix_micros(), base);
        assert_eq!(ts("2024-05-01t12:34:56z").unix_micros(), base);
        assert_eq!(ts("2024-05-01 12:34:56Z").unix_micros(), base);
        assert_eq!(ts("2024-05-01T12:34:56.5Z").unix_micros(), base + 500_000);
        assert_eq!(
            ts("2024-05-01T12:34:56.123456789Z").unix_micros(),
            base + 123_456
        );
        assert_eq!(ts("2024-05-01T14:34:56+02:00").unix_micros(), base);
        assert_eq!(ts("2024-05-01T07:04:56-05:30").unix_micros(), base);
        // A leap second is read as the second before it.
        assert_eq!(ts("2016-12-31T23:59:60Z"), ts("2016-12-31T23:59:59Z"));
    }

    #[test]
    fn rejects_malformed() {
        for bad in [
            "",
            "2024-05-01",
            "2024-05-01T12:34:56",
            "2024-13-01T00:00:00Z",
            "2023-02-29T00:00:00Z",
            "2024-05-01T24:00:00Z",
            "2024-05-01T12:34:56.Z",
            "2024-05-01T12:34:56Zjunk",
            "2024-05-01T12:34:56+0200",
            "2024/05/01T12:34:56Z",
        ] {
            assert!(Timestamp::parse_rfc3339(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn display_parse_round_trip() {
        for us in [
            0,
            1,
            -1,
            951_782_400_000_001,
            4_102_444_799_999_999,
            MIN_US,
            MAX_US,
        ] {
            let t = Timestamp::from_unix_micros(us);
            assert_eq!(ts(&t.to_string()), t);
        }
    }

    #[test]
    fn system_time_conversion_and_clamp() {
        let now = SystemTime::now();
        let t = Timestamp::from_system_time(now);
        let back = t.to_system_time();
        let diff = now
            .duration_since(back)
            .expect("truncation goes back in time");
        assert!(diff < Duration::from_micros(1));
        assert_eq!(
            Timestamp::from_unix_micros(i64::MAX).to_string(),
            "9999-12-30T22:00:00.000000Z"
        );
        assert_eq!(
            Timestamp::from_system_time(UNIX_EPOCH - Duration::from_nanos(1)).unix_micros(),
            -1
        );
    }

    #[test]
    fn local_time_is_utc_shifted_by_a_plausible_offset() {
        let t = Timestamp::from_unix_micros(1_714_566_896_123_456);
        let (u, l) = (t.utc(), t.local());
        let secs = |c: CivilTime| {
            jiff::civil::date(c.year as i16, c.month as i8, c.day as i8)
                .to_zoned(jiff::tz::TimeZone::UTC)
                .expect("date")
                .timestamp()
                .as_second()
                + i64::from(c.hour * 3600 + c.minute * 60 + c.second)
        };
        let offset = secs(l) - secs(u);
        assert_eq!(offset % 60, 0, "offset {offset} s is not whole minutes");
        assert!(offset.abs() <= 14 * 3600, "offset {offset} s");
        assert_eq!(l.micros, u.micros);
    }

    #[test]
    fn operator_times_in_every_printed_form() {
        let tz = jiff::tz::TimeZone::get("Europe/Oslo").unwrap_or(jiff::tz::TimeZone::UTC);
        let oslo = tz != jiff::tz::TimeZone::UTC;
        // 2026-11-27 23:40:00 in Oslo (UTC+1 in November)
        let now = ts("2026-11-27T22:40:00Z");
        let at = |s: &str| parse_time(s, now, &tz).map(|t| t.to_string());
        let local = |utc: &str| {
            if oslo {
                utc.to_string()
            } else {
                // without the zone database the zone is UTC: shift the expectation back
                let t = ts(utc).saturating_add(Duration::from_secs(3600));
                t.to_string()
            }
        };
        assert_eq!(
            at("2026-11-27 23:33").expect("printed, cut to minutes"),
            local("2026-11-27T22:33:00.000000Z")
        );
        assert_eq!(
            at("2026-11-27 23:33:05.250").expect("printed"),
            local("2026-11-27T22:33:05.250000Z")
        );
        assert_eq!(
            at("2026-11-27T23:33").expect("T"),
            local("2026-11-27T22:33:00.000000Z")
        );
        assert_eq!(
            at("23:33").expect("time alone"),
            local("2026-11-27T22:33:00.000000Z")
        );
        assert_eq!(
            at("23:50").expect("later today: yesterday's"),
            local("2026-11-26T22:50:00.000000Z")
        );
        assert_eq!(
            at("2026-11-27").expect("date"),
            local("2026-11-26T23:00:00.000000Z")
        );
        assert_eq!(
            at("today").expect("today"),
            local("2026-11-26T23:00:00.000000Z")
        );
        assert_eq!(
            at("yesterday").expect("yesterday"),
            local("2026-11-25T23:00:00.000000Z")
        );
        assert_eq!(at("5min").expect("5min"), "2026-11-27T22:35:00.000000Z");
        assert_eq!(at("5min ago").expect("ago"), "2026-11-27T22:35:00.000000Z");
        assert_eq!(at("10m").expect("10m"), "2026-11-27T22:30:00.000000Z");
        assert_eq!(at("1h30m").expect("1h30m"), "2026-11-27T21:10:00.000000Z");
        assert_eq!(at("1w").expect("1w"), "2026-11-20T22:40:00.000000Z");
        assert_eq!(at("now").expect("now"), "2026-11-27T22:40:00.000000Z");
        assert_eq!(
            at("2026-11-27T22:33:00Z").expect("rfc3339"),
            "2026-11-27T22:33:00.000000Z"
        );
        assert_eq!(
            at("2026-11-27T23:33:00+01:00").expect("offset"),
            "2026-11-27T22:33:00.000000Z"
        );
        for bad in [
            "",
            "10",
            "m",
            "10x",
            "-5m",
            "2026-13-01",
            "25:00",
            "tomorrowish",
        ] {
            assert!(parse_time(bad, now, &tz).is_err(), "{bad:?} accepted");
        }
        assert!(parse_time("99999999999999999999d", now, &tz).is_err());
        // a multi-byte character across byte 19 (the fuzzer's find, CI 2026-11-28): an error,
        // never a panic; likewise for the RFC 3339 parser
        let torn = "`2afri~ca/asmara\u{6}3\u{92}\u{1a}";
        assert!(!torn.is_char_boundary(19));
        assert!(parse_time(torn, now, &tz).is_err());
        for s in [
            "2024-05-01T12:34:5€Z",
            "2024-05-01T12:34:56€Z",
            "2024-05-01T12:34:€€Z",
        ] {
            assert!(Timestamp::parse_rfc3339(s).is_err(), "{s:?} accepted");
        }
    }

    #[test]
    fn serde_is_a_string() {
        let t = Timestamp::from_unix_micros(1_714_566_896_123_456);
        let j = serde_json::to_string(&t).expect("serialize");
        assert_eq!(j, "\"2024-05-01T12:34:56.123456Z\"");
        let back: Timestamp = serde_json::from_str(&j).expect("deserialize");
        assert_eq!(back, t);
        assert!(serde_json::from_str::<Timestamp>("\"yesterday\"").is_err());
    }
}
