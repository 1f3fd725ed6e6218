//! Terminal output for `antisurge events`: one line per event, either pretty
//! (`2024-05-01 14:34:56.123  surge_detected    surge_count_total=3 …`) or the stored JSON.

use std::io::Write;
use std::path::PathBuf;

use serde_json::Value;

use super::error::EventLogError;
use super::reader::{read_files, EventFilter, ReadStats, Record};

/// How [`print_events`] writes each record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PrintFormat {
    /// The stored line, byte for byte (`--json`): for `jq` and other tools.
    Json,
    /// Readable, time in the machine's local time zone.
    Pretty,
    /// Readable, time in UTC.
    PrettyUtc,
}

/// Width of the kind column (the longest kinds have 16 characters).
const KIND_WIDTH: usize = 16;

/// Write every record of `files` (oldest first, see
/// [`log_files`](super::reader::log_files)) that passes `filter` to `out`, one line each.
/// Returns what the read saw; the caller prints [`ReadStats::warnings`] to stderr.
pub fn print_events(
    out: &mut impl Write,
    files: &[PathBuf],
    filter: &EventFilter,
    format: PrintFormat,
) -> Result<ReadStats, EventLogError> {
    let mut line = String::with_capacity(256);
    let stats = read_files(files, filter, |_, record| {
        line.clear();
        match format {
            PrintFormat::Json => line.push_str(&record.raw),
            PrintFormat::Pretty => format_pretty(&mut line, record, false),
            PrintFormat::PrettyUtc => format_pretty(&mut line, record, true),
        }
        line.push('\n');
        out.write_all(line.as_bytes())
            .map_err(EventLogError::Output)
    })?;
    out.flush().map_err(EventLogError::Output)?;
    Ok(stats)
}

/// Append the readable form of `record` to `out` (no newline):
/// `YYYY-MM-DD HH:MM:SS.mmm  kind  key=value …`.
pub fn format_pretty(out: &mut String, record: &Record, utc: bool) {
    use std::fmt::Write as _;
    let c = if utc {
        record.ts.utc()
    } else {
        record.ts.local()
    };
    let _ = write!(
        out,
        "{:04}-{:02}-{:02} {:02}:{:02}:{:02}.{:03}  {:<width$}",
        c.year,
        c.month,
        c.day,
        c.hour,
        c.minute,
        c.second,
        c.micros / 1000,
        record.kind,
        width = KIND_WIDTH
    );
    for (key, value) in &record.fields {
        if key == "diff" {
            if let Value::Array(items) = value {
                if items.iter().all(is_change) {
                    for item in items {
                        push_change(out, item);
                    }
                    continue;
                }
            }
        }
        out.push_str("  ");
        out.push_str(key);
        out.push('=');
        push_value(out, value);
    }
    // Keep the listing one line per event even if a value carried a newline.
    if out.contains(['\n', '\r']) {
        *out = out.replace('\n', "\\n").replace('\r', "\\r");
    }
}

fn is_change(v: &Value) -> bool {
    matches!(v, Value::Object(m) if m.get("key").is_some_and(Value::is_string))
}

/// `key=old->new`, with `(unset)` for a missing side.
fn push_change(out: &mut String, item: &Value) {
    let side = |name: &str| match item.get(name) {
        None | Some(Value::Null) => Value::String("(unset)".into()),
        Some(v) => v.clone(),
    };
    out.push_str("  ");
    out.push_str(item.get("key").and_then(Value::as_str).unwrap_or("?"));
    out.push('=');
    push_value(out, &side("old"));
    out.push_str("->");
    push_value(out, &side("new"));
}

fn push_value(out: &mut String, v: &Value) {
    match v {
        Value::String(s) => push_text(out, s),
        Value::Array(items) => {
            out.push('[');
            for (i, item) in items.iter().enumerate() {
                if i > 0 {
                    out.push(',');
                }
                push_value(out, item);
            }
            out.push(']');
        }
        other => out.push_str(&other.to_string()),
    }
}

/// Bare if unambiguous, JSON-quoted if empty or holding spaces, quotes, `=` or controls.
fn push_text(out: &mut String, s: &str) {
    let plain = !s.is_empty()
        && !s.chars().any(|c| {
            c.is_whitespace() || c.is_control() || matches!(c, '"' | '=' | ',' | '[' | ']')
        });
    if plain {
        out.push_str(s);
    } else {
        out.push_str(&Value::String(s.to_string()).to_string());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::events::event::tests::examples;
    use crate::events::reader::parse_line;

    fn pretty(raw: &str) -> String {
        let r = parse_line(raw.as_bytes(), 1).expect("valid");
        let mut s = String::new();
        format_pretty(&mut s, &r, true);
        s
    }

    #[test]
    fn pretty_lines_for_every_kind() {
        let expected = [
            "started           version=0.1.0  config_path=/etc/antisurge/antisurge.toml  law=recycle-pi",
            "stopped           reason=SIGTERM",
            "surge_detected    surge_count_total=3  frequency_hz=8.5  min_flow_kg_s=-0.42  flow_reversal=true",
            "surge_counter     previous_count=3  count=0",
            "safety_on_shift   margin_pct=2.5  total_margin_pct=5.0  count=2",
            "mode_changed      from=auto  to=fail_safe",
            "law_changed       from=recycle-pi  to=ccv",
            "fallback_entered  input=orifice_dp  reason=stale  replaced_by=observer",
            "fallback_left     input=orifice_dp  replaced_by=observer  duration_ms=1520",
            "config_applied    file=/etc/antisurge/antisurge.toml  control.recycle.kp=0.8->1.2  surge.margin_pct=(unset)->10.0",
            "config_rejected   file=/etc/antisurge/antisurge.toml  key=control.recycle.kp  line=17  message=\"must be positive\"",
            "restart_required  keys=[io.can.interface,control.period_us]",
            "deadline_overrun  count=12  worst_lateness_us=340  window_s=10.0",
            "bus_state         interface=can0  state=bus_off",
            "recycle_trip      reason=surge_detected",
            "note              text=\"operator: \\\"valve stroke test\\\"\"",
            "events_dropped    count=7  cause=queue_full",
            "fallback_entered  input=orifice_dp  reason=frozen  replaced_by=observer",
            "fallback_entered  input=orifice_dp  reason=drift  replaced_by=observer  vs_observer_pct=12.5  vs_speed_line_pct=11.0",
        ];
        let ex = examples();
        assert_eq!(ex.len(), expected.len());
        for ((_, raw), want) in ex.iter().zip(expected) {
            assert_eq!(pretty(raw), format!("2024-05-01 12:34:56.123  {want}"));
        }
    }

    #[test]
    fn unknown_kinds_and_odd_values_stay_on_one_line() {
        let s = pretty(
            r#"{"ts":"2024-05-01T00:00:00.000999Z","seq":1,"event":"future_kind","a":null,"b":{"x":1},"c":"two\nlines","d":""}"#,
        );
        assert_eq!(
            s,
            r#"2024-05-01 00:00:00.000  future_kind       a=null  b={"x":1}  c="two\nlines"  d="""#
        );
        assert!(!s.contains('\n'));
    }

    #[test]
    fn json_output_is_the_stored_line_and_filter_applies() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("events.jsonl");
        let a = r#"{"ts":"2024-05-01T12:00:00.000000Z","seq":1,"event":"note","text":"a"}"#;
        let b = r#"{"ts":"2024-05-01T13:00:00.000000Z", "seq":2,"event":"note","text":"b"}"#;
        std::fs::write(&p, format!("{a}\n{b}\n{{torn")).expect("write");
        let filter = EventFilter {
            since: Some(
                crate::events::Timestamp::parse_rfc3339("2024-05-01T12:30:00Z").expect("t"),
            ),
            ..EventFilter::default()
        };
        let mut out = Vec::new();
        let stats = print_events(
            &mut out,
            std::slice::from_ref(&p),
            &filter,
            PrintFormat::Json,
        )
        .expect("print");
        assert_eq!(String::from_utf8(out).expect("utf8"), format!("{b}\n"));
        assert_eq!((stats.records, stats.matched), (2, 1));
        assert!(stats.torn_tail.is_some());

        let mut out = Vec::new();
        print_events(
            &mut out,
            &[p],
            &EventFilter::default(),
            PrintFormat::PrettyUtc,
        )
        .expect("print");
        assert_eq!(
            String::from_utf8(out).expect("utf8"),
            "2024-05-01 12:00:00.000  note              text=a\n\
             2024-05-01 13:00:00.000  note              text=b\n"
        );
    }
}
