//! Wall-clock timestamps for the event log: microseconds since the Unix epoch, written and
//! read as RFC 3339 UTC (`2024-05-01T12:34:56.123456Z`).
//!
//! Hand-written rather than pulled from a date crate: the log needs only UTC formatting and
//! RFC 3339 parsing, and [`Timestamp::now`] must be cheap and allocation-free because the
//! control thread stamps its events with it. The civil-date conversion is the proleptic
//! Gregorian "days from civil" arithmetic (400-year eras of 146 097 days).

use std::fmt;
use std::str::FromStr;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Deserializer, Serialize, Serializer};

const US_PER_S: i64 = 1_000_000;
const S_PER_DAY: i64 = 86_400;
/// 0000-01-01T00:00:00Z, the earliest instant RFC 3339 can write.
const MIN_US: i64 = -62_167_219_200 * US_PER_S;
/// 9999-12-31T23:59:59.999999Z, the latest instant RFC 3339 can write.
const MAX_US: i64 = 253_402_300_800 * US_PER_S - 1;

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
        civil_from_unix_micros(self.unix_us)
    }

    /// Calendar fields in the machine's local time zone (via the C library's `localtime_r`,
    /// which honours `TZ` and daylight saving). Falls back to UTC if the zone is unknown.
    pub fn local(self) -> CivilTime {
        let secs = self.unix_us.div_euclid(US_PER_S);
        let offset_s = local_utc_offset_s(secs).unwrap_or(0);
        civil_from_unix_micros(self.unix_us.saturating_add(offset_s * US_PER_S))
    }

    /// Parse RFC 3339: `YYYY-MM-DDTHH:MM:SS[.fraction](Z|±HH:MM)`. `t`, `z` and a space
    /// separator are accepted; fraction digits beyond microseconds are truncated; a leap
    /// second `:60` is folded into the next second.
    pub fn parse_rfc3339(s: &str) -> Result<Timestamp, ParseTimestampError> {
        let b = s.as_bytes();
        if b.len() < 20 {
            return Err(ParseTimestampError("too short for YYYY-MM-DDTHH:MM:SSZ"));
        }
        let year = digits(b, 0, 4)?;
        expect(b, 4, b'-')?;
        let month = digits(b, 5, 2)?;
        expect(b, 7, b'-')?;
        let day = digits(b, 8, 2)?;
        if !matches!(b[10], b'T' | b't' | b' ') {
            return Err(ParseTimestampError("expected 'T' between date and time"));
        }
        let hour = digits(b, 11, 2)?;
        expect(b, 13, b':')?;
        let minute = digits(b, 14, 2)?;
        expect(b, 16, b':')?;
        let second = digits(b, 17, 2)?;
        if !(1..=12).contains(&month) {
            return Err(ParseTimestampError("month out of range"));
        }
        if day < 1 || day > days_in_month(year, month as u32) as i64 {
            return Err(ParseTimestampError("day out of range for the month"));
        }
        if hour > 23 || minute > 59 || second > 60 {
            return Err(ParseTimestampError("time of day out of range"));
        }
        let mut i = 19;
        let mut micros = 0i64;
        if b.get(i) == Some(&b'.') {
            i += 1;
            let start = i;
            while i < b.len() && b[i].is_ascii_digit() {
                if i - start < 6 {
                    micros = micros * 10 + i64::from(b[i] - b'0');
                }
                i += 1;
            }
            let n = i - start;
            if n == 0 {
                return Err(ParseTimestampError("empty fraction of a second"));
            }
            for _ in n..6 {
                micros *= 10;
            }
        }
        let offset_s = match b.get(i) {
            Some(b'Z' | b'z') => {
                i += 1;
                0
            }
            Some(&sign @ (b'+' | b'-')) => {
                if b.len() < i + 6 {
                    return Err(ParseTimestampError("truncated UTC offset"));
                }
                let oh = digits(b, i + 1, 2)?;
                expect(b, i + 3, b':')?;
                let om = digits(b, i + 4, 2)?;
                if oh > 23 || om > 59 {
                    return Err(ParseTimestampError("UTC offset out of range"));
                }
                i += 6;
                let o = oh * 3600 + om * 60;
                if sign == b'-' {
                    -o
                } else {
                    o
                }
            }
            _ => {
                return Err(ParseTimestampError(
                    "missing time zone: end with Z or an offset like +02:00",
                ))
            }
        };
        if i != b.len() {
            return Err(ParseTimestampError(
                "trailing characters after the time zone",
            ));
        }
        let days = days_from_civil(year, month as u32, day as u32);
        let secs = days * S_PER_DAY + hour * 3600 + minute * 60 + second - offset_s;
        Ok(Timestamp::from_unix_micros(secs * US_PER_S + micros))
    }
}

impl fmt::Display for Timestamp {
    /// RFC 3339 UTC with microseconds, e.g. `2024-05-01T12:34:56.123456Z`. Allocation-free.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let c = self.utc();
        write!(
            f,
            "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:06}Z",
            c.year, c.month, c.day, c.hour, c.minute, c.second, c.micros
        )
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

fn digits(b: &[u8], at: usize, n: usize) -> Result<i64, ParseTimestampError> {
    let mut v = 0i64;
    for &c in b.get(at..at + n).ok_or(ParseTimestampError("truncated"))? {
        if !c.is_ascii_digit() {
            return Err(ParseTimestampError("expected a digit"));
        }
        v = v * 10 + i64::from(c - b'0');
    }
    Ok(v)
}

fn expect(b: &[u8], at: usize, c: u8) -> Result<(), ParseTimestampError> {
    if b.get(at) == Some(&c) {
        Ok(())
    } else {
        Err(ParseTimestampError("unexpected separator"))
    }
}

fn is_leap(year: i64) -> bool {
    (year % 4 == 0 && year % 100 != 0) || year % 400 == 0
}

fn days_in_month(year: i64, month: u32) -> u32 {
    match month {
        1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
        4 | 6 | 9 | 11 => 30,
        _ if is_leap(year) => 29,
        _ => 28,
    }
}

/// Days since 1970-01-01 of a proleptic Gregorian date.
///
/// Counting years from March makes the leap day the last day of the year, so the day of the
/// year follows from the month by the linear formula `(153 * m + 2) / 5`.
pub(crate) fn days_from_civil(year: i64, month: u32, day: u32) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let year_of_era = y.rem_euclid(400); // 0..=399
    let m = i64::from(month);
    let month_from_march = if m > 2 { m - 3 } else { m + 9 }; // 0..=11
    let day_of_year = (153 * month_from_march + 2) / 5 + i64::from(day) - 1; // 0..=365
    let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
    // 719 468 days separate 0000-03-01 from 1970-01-01.
    era * 146_097 + day_of_era - 719_468
}

/// Inverse of [`days_from_civil`]: (year, month, day).
pub(crate) fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let day_of_era = z.rem_euclid(146_097); // 0..=146 096
    let year_of_era =
        (day_of_era - day_of_era / 1460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
    let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
    let month_from_march = (5 * day_of_year + 2) / 153;
    let day = day_of_year - (153 * month_from_march + 2) / 5 + 1;
    let month = if month_from_march < 10 {
        month_from_march + 3
    } else {
        month_from_march - 9
    };
    let year = year_of_era + era * 400 + i64::from(month <= 2);
    (year, month as u32, day as u32)
}

fn civil_from_unix_micros(us: i64) -> CivilTime {
    let secs = us.div_euclid(US_PER_S);
    let micros = us.rem_euclid(US_PER_S) as u32;
    let days = secs.div_euclid(S_PER_DAY);
    let sod = secs.rem_euclid(S_PER_DAY) as u32;
    let (year, month, day) = civil_from_days(days);
    CivilTime {
        year,
        month,
        day,
        hour: sod / 3600,
        minute: sod / 60 % 60,
        second: sod % 60,
        micros,
    }
}

/// Offset of local time from UTC at `unix_s`, in seconds east of Greenwich.
fn local_utc_offset_s(unix_s: i64) -> Option<i64> {
    let t = libc::time_t::try_from(unix_s).ok()?;
    // SAFETY: `tm` is plain old data for which all-zero bytes are a valid value.
    let mut tm: libc::tm = unsafe { std::mem::zeroed() };
    // SAFETY: both pointers refer to live, properly aligned locals; localtime_r is the
    // re-entrant variant and writes only into `tm`.
    let r = unsafe { libc::localtime_r(&t, &mut tm) };
    if r.is_null() {
        None
    } else {
        // `c_long`: i64 on 64-bit Linux, i32 on 32-bit targets.
        Some(tm.tm_gmtoff as i64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ts(s: &str) -> Timestamp {
        Timestamp::parse_rfc3339(s).expect(s)
    }

    #[test]
    fn known_days() {
        assert_eq!(days_from_civil(1970, 1, 1), 0);
        assert_eq!(days_from_civil(2000, 3, 1), 11_017);
        assert_eq!(days_from_civil(1969, 12, 31), -1);
        assert_eq!(days_from_civil(2024, 2, 29), 19_782);
        assert_eq!(civil_from_days(19_782), (2024, 2, 29));
        assert_eq!(civil_from_days(-719_468), (0, 3, 1));
    }

    #[test]
    fn days_round_trip_over_centuries() {
        // Every day from 1600 to 2400 (both leap-century rules exercised).
        let start = days_from_civil(1600, 1, 1);
        let end = days_from_civil(2400, 12, 31);
        let mut expected = (1600i64, 1u32, 1u32);
        for d in start..=end {
            assert_eq!(civil_from_days(d), expected, "day {d}");
            assert_eq!(days_from_civil(expected.0, expected.1, expected.2), d);
            let (y, m, dd) = expected;
            expected = if dd < days_in_month(y, m) {
                (y, m, dd + 1)
            } else if m < 12 {
                (y, m + 1, 1)
            } else {
                (y + 1, 1, 1)
            };
        }
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
        // Leap second folds into the next second.
        assert_eq!(ts("2016-12-31T23:59:60Z"), ts("2017-01-01T00:00:00Z"));
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
            "9999-12-31T23:59:59.999999Z"
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
            days_from_civil(c.year, c.month, c.day) * S_PER_DAY
                + i64::from(c.hour * 3600 + c.minute * 60 + c.second)
        };
        let offset = secs(l) - secs(u);
        assert_eq!(offset % 60, 0, "offset {offset} s is not whole minutes");
        assert!(offset.abs() <= 14 * 3600, "offset {offset} s");
        assert_eq!(l.micros, u.micros);
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
